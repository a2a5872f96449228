// Pictures and numbers a person can look at after a fit: for every view (the fitted ones and any
// held-out one) the input, the fitted volume rendered through the camera and their difference as
// a Delta E heat map; a plot of error against time; the trace as CSV; a Markdown summary.
#ifndef FLAMERIG_PIPELINE_FIT_REPORT_H_
#define FLAMERIG_PIPELINE_FIT_REPORT_H_

#include <string>
#include <vector>

#include "fitting/fit.h"

namespace flamerig {

// One line of a plot: points (x, y) and a name for the legend.
struct PlotSeries {
  std::string name;
  std::vector<double> x, y;
};

// A line plot (axes, ticks, legend) as an RGB image. log_x: logarithmic time axis (x > 0 only).
ImageU8 PlotLines(const std::vector<PlotSeries>& series, const std::string& title,
                  const std::string& x_label, const std::string& y_label, bool log_x,
                  int width = 800, int height = 500);

struct ViewScore {
  std::string name;
  bool held_out = false;
  double mean_delta_e = 0;  // over all pixels
  double fire_delta_e = 0;  // over pixels where the input or the render is not black
  std::size_t fire_pixels = 0;  // how many
  double p95_delta_e = 0;   // 95th percentile over those pixels
};

// Renders `result.volume` through each view at `result.exposure`, scores it and, when `dir` is
// not empty, writes <dir>/views.png (input | rendered | Delta E x10 per view), <dir>/error.png
// (mean Delta E against time), <dir>/trace.csv and <dir>/report.md. Returns the scores, and the
// rendered 8-bit views (fitted, then held out) through *rendered when not null.
std::vector<ViewScore> WriteFitReport(const std::string& dir, const FitResult& result,
                                      const std::vector<FitView>& fitted,
                                      const std::vector<FitView>& held_out,
                                      const AbsorptionModel& absorption,
                                      const RenderOptions& render, const std::string& title,
                                      std::vector<ImageU8>* rendered = nullptr);


}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_FIT_REPORT_H_
