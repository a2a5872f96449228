#include "pipeline/fit_report.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>

#include "core/atomic_file.h"
#include "core/log.h"
#include "fitting/colour.h"
#include "pipeline/picture.h"
#include "pipeline/plot.h"
#include "pipeline/report_page.h"
#include "pipeline/run_report.h"
#include "pipeline/simulate.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {
// The Delta E maps' colour scale runs from 0 to this (and saturates above): 1 is about the
// smallest difference a person sees, above 10 colours differ at a glance.
constexpr double kDeltaEScale = 20;
}  // namespace

std::vector<ViewScore> WriteFitReport(const std::string& dir, const FitResult& result,
                                      const std::vector<FitView>& fitted,
                                      const std::vector<FitView>& held_out,
                                      const AbsorptionModel& absorption,
                                      const RenderOptions& render, const std::string& title,
                                      std::vector<ImageU8>* rendered_out, const FireVolume* truth) {
  const FireVolume& v = result.volume;
  // One renderer per camera response, made when a view needs it (views of one response are
  // usually together).
  std::unique_ptr<FireRenderer> renderer;
  std::shared_ptr<const ChannelResponse> renderer_response;
  auto renderer_for = [&](const FitView& view) -> const FireRenderer& {
    const auto want = view.response ? view.response : render.response;
    if (!renderer || want != renderer_response) {
      RenderOptions options = render;
      options.response = want;
      renderer = std::make_unique<FireRenderer>(absorption, options);
      renderer->SetVolume(v.geometry, v.temperature_k, v.density_per_m3);
      renderer_response = want;
    }
    return *renderer;
  };
  std::vector<ViewScore> scores;
  PictureGrid views;
  views.column_labels = {"input", "rendered from the fit", "Delta E (CIELab)"};
  views.bars.push_back(
      {"Delta E", "", 0, kDeltaEScale, [](double de) { return ViridisColour(de / kDeltaEScale); }});
  std::vector<const FitView*> all;
  for (const auto& f : fitted) all.push_back(&f);
  for (const auto& f : held_out) all.push_back(&f);
  for (std::size_t k = 0; k < all.size(); ++k) {
    const FitView& view = *all[k];
    ImageF linear;
    renderer_for(view).Render(*view.rays, &linear);
    const ImageU8 rendered = ApplyCameraResponse(linear, result.exposure);
    ImageU8 heat(rendered.width, rendered.height, 3, 0);
    std::vector<double> fire;
    double sum = 0;
    for (std::size_t p = 0; p < rendered.num_pixels(); ++p) {
      // The measurement as the fit takes it (objective.h): the camera's signal when it has one.
      const Eigen::Vector3d lab_in =
          view.signal.empty()
              ? colour::SrgbU8ToLab(view.image.pixels[3 * p], view.image.pixels[3 * p + 1],
                                    view.image.pixels[3 * p + 2])
              : CameraLab(Eigen::Vector3d(view.signal.pixels[3 * p], view.signal.pixels[3 * p + 1],
                                          view.signal.pixels[3 * p + 2]),
                          1.0);
      const Eigen::Vector3d lab_out = CameraLab(
          Eigen::Vector3d(linear.pixels[3 * p], linear.pixels[3 * p + 1], linear.pixels[3 * p + 2]),
          result.exposure);
      const double de = colour::DeltaE76(lab_in, lab_out);
      sum += de;
      if (lab_in[0] > 1 || lab_out[0] > 1) fire.push_back(de);
      // Heat map on the report's Delta E scale.
      const Rgb c = ViridisColour(de / kDeltaEScale);
      for (int ch = 0; ch < 3; ++ch) heat.pixels[3 * p + ch] = c[ch];
    }
    ViewScore s;
    s.name = view.name;
    s.held_out = k >= fitted.size();
    s.mean_delta_e = rendered.num_pixels() ? sum / rendered.num_pixels() : 0;
    s.fire_pixels = fire.size();
    if (!fire.empty()) {
      double fs_sum = 0;
      for (double d : fire) fs_sum += d;
      s.fire_delta_e = fs_sum / fire.size();
      std::sort(fire.begin(), fire.end());
      s.p95_delta_e = fire[static_cast<std::size_t>(0.95 * (fire.size() - 1))];
    }
    scores.push_back(s);
    views.row_labels.push_back(fmt::format("{} ({}): mean Delta E {:.2f} over {} fire pixels",
                                           view.name, s.held_out ? "held out" : "fitted",
                                           s.fire_delta_e, s.fire_pixels));
    views.rows.push_back({view.image, rendered, heat});
    if (rendered_out) rendered_out->push_back(rendered);
  }
  if (dir.empty()) return scores;
  fs::create_directories(dir);
  WritePng((fs::path(dir) / "views.png").string(), DrawPictureGrid(views));
  PlotSpec plot;
  plot.title = title + ": mean Delta E of the fitted views against time";
  plot.x_label = "time since the fit began (s, log scale)";
  plot.y_label = "mean Delta E of the fitted views (CIELab)";
  plot.log_x = true;
  plot.series.push_back({result.method, {}, {}});
  for (const auto& p : result.trace) {
    plot.series[0].x.push_back(std::max(1e-3, p.seconds));
    plot.series[0].y.push_back(p.mean_delta_e);
  }
  std::string plot_error;
  const bool plotted = WritePlot(plot, (fs::path(dir) / "error").string(), &plot_error);
  if (!plotted) Log().warn("fit report: no error plot: {}", plot_error);
  const bool sliced = v.temperature_k.size() == v.geometry.num_voxels() &&
                      v.density_per_m3.size() == v.geometry.num_voxels();
  if (sliced) WritePng((fs::path(dir) / "slices.png").string(), SlicesPicture(v, truth));
  {
    std::ostringstream csv;
    csv << "seconds,energy,mean_delta_e,level,stage\n";
    for (const auto& p : result.trace)
      csv << p.seconds << "," << p.energy << "," << p.mean_delta_e << "," << p.level << ",\""
          << p.stage << "\"\n";
    WriteFileAtomically((fs::path(dir) / "trace.csv").string(), csv.str());
  }
  std::ostringstream md;
  md << "# " << title << "\n\n" << result.BriefReport() << "\n\n";
  md << "| view | role | mean Delta E (all pixels) | mean Delta E (fire pixels) | 95th percentile "
        "(fire pixels) |\n|---|---|---|---|---|\n";
  for (const auto& s : scores) {
    md << "| " << s.name << " | " << (s.held_out ? "held out" : "fitted") << " | " << s.mean_delta_e
       << " | " << s.fire_delta_e << " | " << s.p95_delta_e << " |\n";
  }
  md << "\n![each view: input, rendered from the fit, Delta E (0 to 20, viridis)](views.png)\n\n"
     << (sliced ? "![temperature slices](slices.png)\n\n" : "")
     << "![error against time](error.png)\n";
  WriteFileAtomically((fs::path(dir) / "report.md").string(), md.str());

  ReportPage page(title);
  page.Section("Result");
  page.Text(result.BriefReport());
  std::vector<std::vector<std::string>> rows;
  for (const auto& s : scores)
    rows.push_back({s.name, s.held_out ? "held out" : "fitted",
                    fmt::format("{:.3f}", s.mean_delta_e), fmt::format("{:.3f}", s.fire_delta_e),
                    fmt::format("{:.2f}", s.p95_delta_e), std::to_string(s.fire_pixels)});
  page.Table({"view", "role", "mean Delta E (all pixels)", "mean Delta E (fire pixels)",
              "95th percentile (fire pixels)", "fire pixels"},
             rows);
  page.Section("Views");
  page.Figure("views.png",
              "Each view: its input, the fitted volume rendered through it, and their Delta E "
              "(CIELab, 0 to 20 on viridis; 1 is about the smallest difference a person sees).");
  if (sliced) {
    page.Section("Temperature slices");
    page.Figure("slices.png",
                std::string("Front (x-y) and side (z-y) slices through the box's middle, y up; "
                            "dark grey: no medium. The fitted temperature") +
                    (truth ? ", the truth on the fit's grid and fit - truth (blue too cold, red "
                             "too hot)"
                           : "") +
                    (v.temperature_sigma_k.empty() ? "." : ", and its one-sigma uncertainty."));
  }
  page.Section("Error against time");
  if (!plotted) page.Warning("No plot: " + plot_error);
  if (plotted)
    page.Figure("error.png", "Mean Delta E of the fitted views as the fit ran (log time axis).");
  page.Section("Data");
  page.Files({{"trace.csv", "the fit's energy and Delta E at each step"},
              {"error.dat", "the plot's data; error.gp redraws it with gnuplot"},
              {"report.md", "this report as Markdown"}});
  page.Write((fs::path(dir) / "index.html").string());
  return scores;
}

}  // namespace flamerig
