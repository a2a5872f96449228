#include "pipeline/fit_report.h"

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <memory>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/atomic_file.h"
#include "fitting/colour.h"
#include "pipeline/simulate.h"

namespace flamerig {

namespace fs = std::filesystem;

ImageU8 PlotLines(const std::vector<PlotSeries>& series, const std::string& title,
                  const std::string& x_label, const std::string& y_label, bool log_x, int width,
                  int height) {
  cv::Mat img(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  const int left = 80, right = 20, top = 52, bottom = 60;
  double x0 = 1e300, x1 = -1e300, y0 = 0, y1 = -1e300;
  auto tx = [&](double x) { return log_x ? std::log10(std::max(x, 1e-6)) : x; };
  for (const auto& s : series)
    for (std::size_t i = 0; i < s.x.size(); ++i) {
      if (log_x && !(s.x[i] > 0)) continue;
      x0 = std::min(x0, tx(s.x[i]));
      x1 = std::max(x1, tx(s.x[i]));
      y1 = std::max(y1, s.y[i]);
    }
  if (!(x1 > x0)) {
    x0 = log_x ? -1 : 0;
    x1 = x0 + 1;
  }
  if (!(y1 > y0)) y1 = y0 + 1;
  y1 *= 1.05;
  auto px = [&](double x) { return left + (tx(x) - x0) / (x1 - x0) * (width - left - right); };
  auto py = [&](double y) { return top + (1 - (y - y0) / (y1 - y0)) * (height - top - bottom); };
  const cv::Scalar black(0, 0, 0), grey(200, 200, 200);
  cv::rectangle(img, cv::Point(left, top), cv::Point(width - right, height - bottom), black, 1);
  // Ticks: decades on a log axis, 5 steps otherwise.
  std::vector<double> xticks;
  if (log_x) {
    for (int e = static_cast<int>(std::floor(x0)); e <= static_cast<int>(std::ceil(x1)); ++e)
      if (e >= x0 - 1e-9 && e <= x1 + 1e-9) xticks.push_back(std::pow(10.0, e));
  } else {
    for (int k = 0; k <= 5; ++k) xticks.push_back(x0 + (x1 - x0) * k / 5);
  }
  char buf[64];
  for (double x : xticks) {
    const int X = static_cast<int>(px(x));
    cv::line(img, cv::Point(X, top), cv::Point(X, height - bottom), grey, 1);
    std::snprintf(buf, sizeof(buf), "%g", x);
    cv::putText(img, buf, cv::Point(X - 12, height - bottom + 18), cv::FONT_HERSHEY_SIMPLEX, 0.4,
                black, 1, cv::LINE_AA);
  }
  for (int k = 0; k <= 5; ++k) {
    const double y = y0 + (y1 - y0) * k / 5;
    const int Y = static_cast<int>(py(y));
    cv::line(img, cv::Point(left, Y), cv::Point(width - right, Y), grey, 1);
    std::snprintf(buf, sizeof(buf), "%.3g", y);
    cv::putText(img, buf, cv::Point(8, Y + 4), cv::FONT_HERSHEY_SIMPLEX, 0.4, black, 1,
                cv::LINE_AA);
  }
  const cv::Scalar colours[] = {cv::Scalar(200, 80, 0),  cv::Scalar(0, 0, 220),
                                cv::Scalar(0, 150, 0),   cv::Scalar(150, 0, 150),
                                cv::Scalar(0, 140, 200), cv::Scalar(100, 100, 100)};
  for (std::size_t s = 0; s < series.size(); ++s) {
    const cv::Scalar c = colours[s % 6];
    std::vector<cv::Point> pts;
    for (std::size_t i = 0; i < series[s].x.size(); ++i) {
      if (log_x && !(series[s].x[i] > 0)) continue;
      pts.emplace_back(static_cast<int>(px(series[s].x[i])), static_cast<int>(py(series[s].y[i])));
    }
    if (pts.size() > 1) cv::polylines(img, pts, false, c, 2, cv::LINE_AA);
    for (const auto& p : pts) cv::circle(img, p, 2, c, cv::FILLED);
    cv::line(img, cv::Point(left + 10, top + 15 + 18 * static_cast<int>(s)),
             cv::Point(left + 40, top + 15 + 18 * static_cast<int>(s)), c, 2);
    cv::putText(img, series[s].name, cv::Point(left + 46, top + 19 + 18 * static_cast<int>(s)),
                cv::FONT_HERSHEY_SIMPLEX, 0.45, black, 1, cv::LINE_AA);
  }
  cv::putText(img, title, cv::Point(left, 20), cv::FONT_HERSHEY_SIMPLEX, 0.6, black, 1,
              cv::LINE_AA);
  cv::putText(img, x_label + (log_x ? " (log scale)" : ""), cv::Point(width / 2 - 60, height - 18),
              cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1, cv::LINE_AA);
  cv::putText(img, y_label, cv::Point(8, top - 8), cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1,
              cv::LINE_AA);
  ImageU8 out(width, height, 3);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      const cv::Vec3b v = img.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) out.at(x, y, c) = v[2 - c];  // BGR -> RGB
    }
  return out;
}

std::vector<ViewScore> WriteFitReport(const std::string& dir, const FitResult& result,
                                      const std::vector<FitView>& fitted,
                                      const std::vector<FitView>& held_out,
                                      const AbsorptionModel& absorption,
                                      const RenderOptions& render, const std::string& title,
                                      std::vector<ImageU8>* rendered_out) {
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
  std::vector<ImageU8> tiles;
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
      // Heat map: Delta E x 10 in grey levels, red above 25.
      const int g = static_cast<int>(std::min(255.0, de * 10));
      heat.pixels[3 * p] = static_cast<std::uint8_t>(de > 25 ? 255 : g);
      heat.pixels[3 * p + 1] = static_cast<std::uint8_t>(de > 25 ? 0 : g);
      heat.pixels[3 * p + 2] = static_cast<std::uint8_t>(de > 25 ? 0 : g);
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
    tiles.push_back(view.image);
    tiles.push_back(rendered);
    tiles.push_back(heat);
    if (rendered_out) rendered_out->push_back(rendered);
  }
  if (dir.empty()) return scores;
  fs::create_directories(dir);
  WritePng((fs::path(dir) / "views.png").string(), ContactSheet(tiles, 240));
  PlotSeries series{result.method, {}, {}};
  for (const auto& p : result.trace) {
    series.x.push_back(std::max(1e-3, p.seconds));
    series.y.push_back(p.mean_delta_e);
  }
  WritePng((fs::path(dir) / "error.png").string(),
           PlotLines({series}, title + ": mean Delta E of the fitted views against time", "seconds",
                     "mean Delta E", true));
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
  md << "\n![views: input, rendered, Delta E x10 (red above 25)](views.png)\n\n"
        "![error against time](error.png)\n";
  WriteFileAtomically((fs::path(dir) / "report.md").string(), md.str());
  return scores;
}

}  // namespace flamerig
