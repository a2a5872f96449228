// Line plots for the reports, drawn by gnuplot (Debian's gnuplot-nox, the tool mrcal's own plots
// use) rather than by hand: labelled axes with units, one colour per series (ten distinct colours,
// then the same colours dashed), the legend below the plot where it covers no curve, integer ticks
// on a frame axis, and a second y axis for series in other units.
//
// WritePlot(spec, "DIR/errors") writes:
//   DIR/errors.png  the plot (pngcairo)
//   DIR/errors.svg  the same, scalable
//   DIR/errors.dat  the data, one block per series ("# name" above it), gnuplot's `index N`
//   DIR/errors.gp   the script that drew them: `gnuplot errors.gp` redraws both after an edit
// The data and the script are written first, so they are there even when gnuplot is not.
//
// Errors: a missing gnuplot or a failed plot is not an exception (a report is still worth writing
// without one picture): WritePlot returns false and says why in *error.
#ifndef FLAMERIG_PIPELINE_PLOT_H_
#define FLAMERIG_PIPELINE_PLOT_H_

#include <string>
#include <utility>
#include <vector>

namespace flamerig {

// One line of a plot: points (x, y) and a name for the legend. Non-finite points are left out.
struct PlotSeries {
  PlotSeries() = default;
  PlotSeries(std::string series_name, std::vector<double> xs = {}, std::vector<double> ys = {},
             bool on_right_axis = false)
      : name(std::move(series_name)),
        x(std::move(xs)),
        y(std::move(ys)),
        right_axis(on_right_axis) {}

  std::string name;
  std::vector<double> x, y;
  bool right_axis = false;  // against the second y axis (PlotSpec::y2_label)
  // Error bars of +- y_error[i] at each point (empty: none; a non-finite or negative one: none
  // at that point).
  std::vector<double> y_error;
  // Drawn dashed in the colour of series `reference_of` (an index into PlotSpec::series), as a
  // reference beside it (a truth beside its fit); -1, or a series that draws no point or is a
  // reference itself: its own colour.
  int reference_of = -1;
};

struct PlotSpec {
  std::string title;
  std::string x_label, y_label;   // with their units, e.g. "time (s)"
  std::string y2_label;           // the right axis, when any series is on it
  bool log_x = false;             // logarithmic x axis (x <= 0 left out)
  bool integer_x = false;         // ticks on whole numbers only (frames)
  bool y_from_zero = true;        // the y axes start at 0 (errors, times); otherwise autoscaled
  int width = 900, height = 480;  // pixels of the PNG
  std::vector<PlotSeries> series;
};

// Writes base + ".png", ".svg", ".dat" and ".gp" (see above). `base` has no extension; its folder
// must exist. Returns false with the reason in *error (when not null) when gnuplot is missing or
// fails; throws IoError only when the data or the script cannot be written.
bool WritePlot(const PlotSpec& spec, const std::string& base, std::string* error = nullptr);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_PLOT_H_
