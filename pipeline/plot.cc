#include "pipeline/plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/atomic_file.h"
#include "core/error.h"
#include "pipeline/subprocess.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

// Ten colours that stay apart for people with common colour-vision deficiencies too (Tableau 10);
// series past the tenth repeat them dashed, past the twentieth dotted. A reference series
// (PlotSeries::reference_of) is drawn dashed in its series' colour.
constexpr const char* kColours[] = {"#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
                                    "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"};

// A gnuplot single-quoted string: quotes doubled, line breaks as spaces.
std::string Quoted(const std::string& text) {
  std::string q = "'";
  for (char c : text)
    q += c == '\'' ? std::string("''") : c == '\n' ? std::string(" ") : std::string(1, c);
  return q + "'";
}

bool Usable(const PlotSpec& spec, double x, double y) {
  return std::isfinite(x) && std::isfinite(y) && (!spec.log_x || x > 0);
}

// Runs `gnuplot -e VARS script` in `dir`; false with gnuplot's complaint in *error.
bool RunGnuplot(const fs::path& dir, const std::string& script, const std::string& vars,
                std::string* error) {
  const ProgramResult r = RunProgram({"gnuplot", "-e", vars, script}, dir.string());
  if (r.ok()) return true;
  if (error) {
    if (!r.started)
      *error = r.error + ": install gnuplot-nox (scripts/install-deps.sh)";
    else
      *error = "gnuplot failed on " + (dir / script).string() + ": " +
               r.error.substr(0, std::min<std::size_t>(r.error.size(), 400));
  }
  return false;
}

}  // namespace

bool WritePlot(const PlotSpec& spec, const std::string& base, std::string* error) {
  const fs::path base_path(base);
  const fs::path dir = base_path.parent_path().empty() ? fs::path(".") : base_path.parent_path();
  const std::string name = base_path.filename().string();

  // The data: one block per series with points, two blank lines apart (gnuplot's `index`).
  std::ostringstream data;
  std::vector<std::size_t> plotted;  // series with at least one usable point, in order
  char buf[64];
  for (std::size_t s = 0; s < spec.series.size(); ++s) {
    const PlotSeries& series = spec.series[s];
    std::ostringstream block;
    std::size_t points = 0;
    for (std::size_t i = 0; i < std::min(series.x.size(), series.y.size()); ++i) {
      if (!Usable(spec, series.x[i], series.y[i])) continue;
      std::snprintf(buf, sizeof buf, "%.17g %.17g", series.x[i], series.y[i]);
      block << buf;
      if (!series.y_error.empty()) {
        const double e = i < series.y_error.size() ? series.y_error[i] : 0.0;
        std::snprintf(buf, sizeof buf, " %.17g", std::isfinite(e) && e > 0 ? e : 0.0);
        block << buf;
      }
      block << "\n";
      ++points;
    }
    if (!points) continue;
    if (!plotted.empty()) data << "\n\n";
    data << "# " << series.name << "\n" << block.str();
    plotted.push_back(s);
  }
  WriteFileAtomically((dir / (name + ".dat")).string(), data.str());

  // The script.
  bool any_right = false;
  double x_lo = 1e300, x_hi = -1e300;
  for (std::size_t s : plotted) {
    any_right |= spec.series[s].right_axis;
    for (std::size_t i = 0; i < spec.series[s].x.size(); ++i)
      if (Usable(spec, spec.series[s].x[i], spec.series[s].y[i])) {
        x_lo = std::min(x_lo, spec.series[s].x[i]);
        x_hi = std::max(x_hi, spec.series[s].x[i]);
      }
  }
  std::ostringstream gp;
  gp << "# Drawn by flamerig (pipeline/plot.h). Redraw after an edit: gnuplot " << name << ".gp\n"
     << "if (!exists('png_out')) png_out = " << Quoted(name + ".png") << "\n"
     << "if (!exists('svg_out')) svg_out = " << Quoted(name + ".svg") << "\n"
     << "set title " << Quoted(spec.title) << "\n"
     << "set xlabel " << Quoted(spec.x_label) << "\n"
     << "set ylabel " << Quoted(spec.y_label) << "\n"
     << "set key below horizontal maxrows 4\n"
     << "set grid xtics ytics lc rgb '#dddddd'\n"
     << "set border 3 lw 1\n";
  if (any_right)
    gp << "set border 11 lw 1\nset y2label " << Quoted(spec.y2_label)
       << "\nset ytics nomirror\nset y2tics nomirror\n";
  else
    gp << "set tics nomirror\n";
  if (spec.log_x) gp << "set logscale x 10\n";
  if (spec.integer_x && !plotted.empty()) {
    // Whole-number ticks, about ten of them at most.
    const double range = std::max(1.0, x_hi - x_lo);
    const double step = std::max(1.0, std::ceil(range / 10));
    // Half a frame of room on each side, so that the first and last points are off the axes.
    char range_text[96];
    std::snprintf(range_text, sizeof range_text, "[%.17g:%.17g]", std::floor(x_lo) - 0.5,
                  std::ceil(x_hi) + 0.5);
    gp << "set xtics " << step << "\nset format x '%.0f'\nset xrange " << range_text << "\n";
  }
  if (spec.y_from_zero) gp << "set yrange [0:*]\nset y2range [0:*]\n";
  // Colours go to the series drawn in their own; a reference takes its series' colour, dashed (a
  // reference whose series drew nothing takes a colour of its own).
  auto drawn_reference = [&](std::size_t s) {
    const int r = spec.series[s].reference_of;
    return r >= 0 && static_cast<std::size_t>(r) < spec.series.size() &&
           std::find(plotted.begin(), plotted.end(), static_cast<std::size_t>(r)) !=
               plotted.end() &&
           spec.series[r].reference_of < 0;
  };
  std::vector<int> colour(spec.series.size(), -1);
  int own = 0;
  for (std::size_t s : plotted)
    if (!drawn_reference(s)) colour[s] = own++;
  for (std::size_t k = 0; k < plotted.size(); ++k) {
    const std::size_t s = plotted[k];
    const bool reference = drawn_reference(s);
    const int c = reference ? colour[spec.series[s].reference_of] : colour[s];
    const int dash = reference ? 2 : c < 10 ? 1 : c < 20 ? 2 : 3;
    gp << "set linetype " << k + 1 << " lc rgb '" << kColours[c % 10] << "' lw 2 pt 7 ps 0.5 dt "
       << dash << "\n";
  }
  gp << "do for [term = 1:2] {\n"
     << "  if (term == 1) { set terminal pngcairo size " << spec.width << "," << spec.height
     << " font 'Sans,11' noenhanced; set output png_out }\n"
     << "  if (term == 2) { set terminal svg size " << spec.width << "," << spec.height
     << " font 'Sans,11' noenhanced; set output svg_out }\n";
  if (plotted.empty()) {
    gp << "  set label 1 'no data' at graph 0.5, 0.5 center\n"
       << "  plot " << (spec.log_x ? "[1:10]" : "[0:1]") << " [0:1] NaN notitle\n";
  } else {
    gp << "  plot ";
    for (std::size_t k = 0; k < plotted.size(); ++k) {
      const PlotSeries& s = spec.series[plotted[k]];
      gp << (k ? ", \\\n       " : "") << Quoted(name + ".dat") << " index " << k
         << (s.y_error.empty() ? " using 1:2 with linespoints" : " using 1:2:3 with yerrorlines")
         << " lt " << k + 1 << " title " << Quoted(s.name) << (s.right_axis ? " axes x1y2" : "");
    }
    gp << "\n";
  }
  gp << "  unset output\n}\n";
  WriteFileAtomically((dir / (name + ".gp")).string(), gp.str());

  // The pictures, under temporary names renamed when whole.
  AtomicFile png((dir / (name + ".png")).string());
  AtomicFile svg((dir / (name + ".svg")).string());
  const std::string vars = "png_out=" + Quoted(fs::path(png.temp_path()).filename().string()) +
                           "; svg_out=" + Quoted(fs::path(svg.temp_path()).filename().string());
  if (!RunGnuplot(dir, name + ".gp", vars, error)) return false;
  png.Commit();
  svg.Commit();
  return true;
}

}  // namespace flamerig
