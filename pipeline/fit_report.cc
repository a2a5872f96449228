#include "pipeline/fit_report.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>

#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/error.h"
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

// What a researcher quotes beside the images' error, as rows of (quantity, value): the sigma's
// summary when the fit has one, and with a truth that has temperatures the scores `fit --truth`
// prints (CompareWithTruth).
std::vector<std::vector<std::string>> Quotables(const FitResult& result, const FireVolume* truth,
                                                const Rigid3& fit_from_truth,
                                                const TruthError* truth_error,
                                                const AbsorptionModel& absorption,
                                                const TruthError* limit_error) {
  std::vector<std::vector<std::string>> rows;
  const VoxelUncertainty& u = result.uncertainty;
  if (!u.temperature_sigma_k.empty()) {
    std::vector<float> sigmas = u.temperature_sigma_k;
    auto mid = sigmas.begin() + std::ptrdiff_t(sigmas.size() / 2);
    std::nth_element(sigmas.begin(), mid, sigmas.end());
    rows.push_back({"voxels the images determine",
                    fmt::format("{} of {} active{}", u.determined_count, sigmas.size(),
                                u.one_band ? " (one band: the temperature is the prior's)" : "")});
    rows.push_back({"median temperature sigma", fmt::format("{:.0f} K", *mid)});
  }
  if (!truth || !truth->HasTemperatureAndDensity()) return rows;
  const TruthError t =
      truth_error ? *truth_error : CompareWithTruth(*truth, result.volume, fit_from_truth);
  if (!t.compared || !t.counted) {
    rows.push_back({"truth", "not compared: " +
                                 (t.why_not.empty() ? "no visible voxel with medium" : t.why_not)});
    return rows;
  }
  rows.push_back({"truth's visible voxels (>= 1300 K, >= 1% of the peak emission) with medium",
                  fmt::format("{} of {}", t.counted, t.visible)});
  rows.push_back({"temperature RMS, mean (fit - truth)",
                  fmt::format("{:.1f} K, {:+.1f} K", t.rms_k, t.mean_k)});
  rows.push_back(
      {"the truth's spread (the best constant's RMS)", fmt::format("{:.1f} K", t.truth_spread_k)});
  rows.push_back({"emission-weighted RMS (the truth's spread)",
                  fmt::format("{:.1f} K ({:.1f} K)", t.weighted_rms_k, t.weighted_truth_spread_k)});
  if (t.have_sigma)
    rows.push_back({"error within one, two sigma",
                    fmt::format("{:.0f}%, {:.0f}% (a calibrated sigma: 68%, 95%)",
                                100 * t.within_1_sigma, 100 * t.within_2_sigma)});
  if (t.have_determined) {
    auto rms = [](double k) { return k < 0 ? std::string("none") : fmt::format("{:.1f} K", k); };
    rows.push_back({"temperature RMS on the determined voxels, on the rest",
                    rms(t.determined_rms_k) + ", " + rms(t.undetermined_rms_k)});
  }
  if (t.truth_soot > 0)
    rows.push_back(
        {"soot particles, of the truth's", fmt::format("{:.3f}", t.fit_soot / t.truth_soot)});
  if (t.truth_visible_soot > 0)
    rows.push_back({"soot particles in the truth's visible voxels, of the truth's there",
                    fmt::format("{:.3f} (they hold {:.3f} of the truth's)",
                                t.fit_visible_soot / t.truth_visible_soot,
                                t.truth_visible_soot / t.truth_soot)});
  // The fit's limit: what its grid (its rings) shows of the truth's light, scored alike.
  const TruthError limit = limit_error ? *limit_error
                                       : CompareLimitWithTruth(*truth, result.volume, absorption,
                                                               result.ring_profile, fit_from_truth);
  if (limit.compared && limit.counted && limit.truth_visible_soot > 0)
    rows.push_back(
        {fmt::format("its limit, the truth's light given exactly to each fitted {}: temperature "
                     "RMS, mean; soot in the truth's visible voxels, of the truth's there",
                     result.ring_profile.empty() ? "voxel" : "ring"),
         fmt::format("{:.1f} K, {:+.1f} K; {:.3f}", limit.rms_k, limit.mean_k,
                     limit.fit_visible_soot / limit.truth_visible_soot)});
  return rows;
}

// A profile's truth, when given, has one value per ring.
void CheckRingTruth(const std::vector<RingProfilePoint>& profile,
                    const std::vector<RingTruth>* truth) {
  if (truth && truth->size() != profile.size())
    throw InputError("ring profile: " + std::to_string(truth->size()) + " truth rings for " +
                     std::to_string(profile.size()) + " rings");
}
}  // namespace

void WriteRingProfileCsv(const std::string& path, const std::vector<RingProfilePoint>& profile,
                         const std::vector<RingTruth>* truth) {
  CheckRingTruth(profile, truth);
  std::ostringstream csv;
  csv << "layer,height_m,axis_x_m,axis_y_m,axis_z_m,radius_voxels,radius_m,voxels,temperature_k,"
         "temperature_sigma_k,density_per_m3,log_density_sigma,soot_volume_fraction"
      << (truth ? ",truth_temperature_k,truth_voxels" : "") << "\n";
  for (std::size_t r = 0; r < profile.size(); ++r) {
    const RingProfilePoint& p = profile[r];
    csv << fmt::format(
        "{},{:.9g},{:.9g},{:.9g},{:.9g},{},{:.9g},{},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g}", p.layer,
        p.height_m, p.axis_x_m, p.axis_y_m, p.axis_z_m, p.radius_voxels, p.radius_m, p.voxels,
        p.temperature_k, p.temperature_sigma_k, p.density_per_m3, p.log_density_sigma,
        p.soot_volume_fraction);
    if (truth) {
      const RingTruth& t = (*truth)[r];
      csv << "," << (t.voxels ? fmt::format("{:.6g}", t.temperature_k) : std::string()) << ","
          << t.voxels;
    }
    csv << "\n";
  }
  WriteFileAtomically(path, csv.str());
}

std::vector<RingProfilePoint> ReadRingProfileCsv(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw IoError(path + ": cannot be read");
  std::string line;
  if (!std::getline(in, line)) throw DataError(path + ": empty, no header");
  const std::vector<std::string> header = SplitCsvRow(line);
  auto column = [&](const std::string& name) {
    const auto it = std::find(header.begin(), header.end(), name);
    if (it == header.end()) throw DataError(path + ": line 1: no '" + name + "' column");
    return static_cast<std::size_t>(it - header.begin());
  };
  const std::size_t c_layer = column("layer"), c_height = column("height_m"),
                    c_x = column("axis_x_m"), c_z = column("axis_z_m"),
                    c_radius = column("radius_voxels"), c_radius_m = column("radius_m"),
                    c_voxels = column("voxels"), c_t = column("temperature_k"),
                    c_ts = column("temperature_sigma_k"), c_n = column("density_per_m3"),
                    c_ns = column("log_density_sigma");
  // Columns added later, absent from older files: the volume fraction (2026-11-29) reads as 0,
  // axis_y_m (2026-12-02) as height_m, which was the rig y until then.
  auto optional_column = [&](const std::string& name) {
    return static_cast<std::size_t>(std::find(header.begin(), header.end(), name) - header.begin());
  };
  const std::size_t c_fv = optional_column("soot_volume_fraction"),
                    c_y = optional_column("axis_y_m");
  std::vector<RingProfilePoint> profile;
  for (int number = 2; std::getline(in, line); ++number) {
    if (line.empty()) continue;
    const std::vector<std::string> cells = SplitCsvRow(line);
    const std::string where = path + ": line " + std::to_string(number);
    if (cells.size() != header.size())
      throw DataError(where + ": " + std::to_string(cells.size()) + " values for " +
                      std::to_string(header.size()) + " columns");
    auto number_at = [&](std::size_t c) {
      std::size_t used = 0;
      double value = 0;
      try {
        value = std::stod(cells[c], &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used == 0 || used != cells[c].size() || !std::isfinite(value))
        throw DataError(where + ": " + header[c] + " '" + cells[c] + "' is not a finite number");
      return value;
    };
    RingProfilePoint p;
    p.layer = static_cast<int>(number_at(c_layer));
    p.height_m = number_at(c_height);
    p.axis_x_m = number_at(c_x);
    p.axis_y_m = c_y < header.size() ? number_at(c_y) : p.height_m;
    p.axis_z_m = number_at(c_z);
    p.radius_voxels = static_cast<int>(number_at(c_radius));
    p.radius_m = number_at(c_radius_m);
    p.voxels = static_cast<std::size_t>(number_at(c_voxels));
    p.temperature_k = number_at(c_t);
    p.temperature_sigma_k = number_at(c_ts);
    p.density_per_m3 = number_at(c_n);
    p.log_density_sigma = number_at(c_ns);
    if (c_fv < header.size()) p.soot_volume_fraction = number_at(c_fv);
    profile.push_back(p);
  }
  return profile;
}

bool WriteRingProfilePlot(const std::string& base, const std::vector<RingProfilePoint>& profile,
                          const std::vector<RingTruth>* truth, const std::string& title,
                          std::string* error) {
  CheckRingTruth(profile, truth);
  // Up to five layers spread evenly over those with rings (the profile is sorted by layer).
  std::vector<int> layers;
  for (const auto& p : profile)
    if (layers.empty() || layers.back() != p.layer) layers.push_back(p.layer);
  std::vector<int> shown;
  const std::size_t count = std::min<std::size_t>(5, layers.size());
  for (std::size_t k = 0; k < count; ++k) {
    const int layer = layers[(2 * k + 1) * layers.size() / (2 * count)];
    if (shown.empty() || shown.back() != layer) shown.push_back(layer);
  }
  PlotSpec plot;
  plot.title = title + ": temperature against the distance from the flame's axis";
  plot.x_label = "radius (mm)";
  plot.y_label = "temperature (K)";
  plot.y_from_zero = false;
  for (int layer : shown) {
    PlotSeries fit, reference;
    double height = 0;
    for (std::size_t r = 0; r < profile.size(); ++r) {
      const RingProfilePoint& p = profile[r];
      if (p.layer != layer) continue;
      height = p.height_m;
      fit.x.push_back(1e3 * p.radius_m);
      fit.y.push_back(p.temperature_k);
      fit.y_error.push_back(p.temperature_sigma_k);
      if (truth && (*truth)[r].voxels) {
        reference.x.push_back(1e3 * p.radius_m);
        reference.y.push_back((*truth)[r].temperature_k);
      }
    }
    fit.name = fmt::format("height {:.1f} mm", 1e3 * height);
    reference.name = fmt::format("truth at {:.1f} mm", 1e3 * height);
    reference.reference_of = static_cast<int>(plot.series.size());
    plot.series.push_back(fit);
    if (truth) plot.series.push_back(reference);
  }
  return WritePlot(plot, base, error);
}

std::vector<ViewScore> WriteFitReport(
    const std::string& dir, const FitResult& result, const std::vector<FitView>& fitted,
    const std::vector<FitView>& held_out, const AbsorptionModel& absorption,
    const RenderOptions& render, const std::string& title, std::vector<ImageU8>* rendered_out,
    const FireVolume* truth, const Rigid3& fit_from_truth, const Eigen::Vector3d& up_in_rig,
    const TruthError* truth_error, const TruthError* limit_error) {
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
    // A Bayer camera's view as its host decodes it (objective.h): its signal at exposure 1.
    double exposure = result.exposure;
    if (view.mosaic) {
      linear = view.mosaic->Forward(linear, exposure);
      exposure = 1.0;
    }
    const ImageU8 rendered = ApplyCameraResponse(linear, exposure);
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
          exposure);
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
    views.row_labels.push_back(fmt::format(
        "{} ({}{}): mean Delta E {:.2f} over {} fire pixels", view.name,
        s.held_out ? "held out" : "fitted",
        view.mosaic ? fmt::format(", through its {} mosaic", ToString(view.mosaic->layout())) : "",
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
  const bool sliced = v.HasTemperatureAndDensity();
  if (sliced)
    WritePng((fs::path(dir) / "slices.png").string(),
             SlicesPicture(v, truth, fit_from_truth, up_in_rig));
  // An axisymmetric fit's radial profile, and the truth's on the same rings.
  const bool profiled = !result.ring_profile.empty();
  bool profile_plotted = false, profile_truth = false;
  std::string profile_error;
  if (profiled) {
    // A truth without temperatures (an emission volume) is shown nowhere in the profile.
    profile_truth = truth && truth->HasTemperatureAndDensity();
    if (truth && !profile_truth)
      Log().warn("fit report: the truth has no temperature and density grids: not on the profile");
    std::vector<RingTruth> on_rings;
    if (profile_truth)
      on_rings = TruthOnRings(*truth, v.geometry, result.ring_profile, fit_from_truth);
    const std::vector<RingTruth>* t = profile_truth ? &on_rings : nullptr;
    WriteRingProfileCsv((fs::path(dir) / "profile.csv").string(), result.ring_profile, t);
    profile_plotted = WriteRingProfilePlot((fs::path(dir) / "profile").string(),
                                           result.ring_profile, t, title, &profile_error);
    if (!profile_plotted) Log().warn("fit report: no profile plot: {}", profile_error);
  }
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
  const std::vector<std::vector<std::string>> quotables =
      Quotables(result, truth, fit_from_truth, truth_error, absorption, limit_error);
  if (!quotables.empty()) {
    md << "\n| quantity | value |\n|---|---|\n";
    for (const auto& row : quotables) md << "| " << row[0] << " | " << row[1] << " |\n";
  }
  md << "\n![each view: input, rendered from the fit, Delta E (0 to 20, viridis)](views.png)\n\n"
     << (sliced ? "![temperature slices](slices.png)\n\n" : "")
     << (profile_plotted ? "![radial profile](profile.png)\n\n" : "")
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
  if (!quotables.empty()) {
    page.Section(truth ? "Uncertainty and the truth" : "Uncertainty");
    page.Table({"quantity", "value"}, quotables);
  }
  page.Section("Views");
  page.Figure("views.png",
              "Each view: its input, the fitted volume rendered through it, and their Delta E "
              "(CIELab, 0 to 20 on viridis; 1 is about the smallest difference a person sees).");
  if (sliced) {
    page.Section("Temperature slices");
    page.Figure("slices.png",
                std::string("Front (x-y) and side (z-y) slices through the box's middle, the "
                            "rig's up at the top; dark grey: no medium. The fitted temperature") +
                    (truth ? ", the truth on the fit's grid and fit - truth (blue too cold, red "
                             "too hot)"
                           : "") +
                    (v.temperature_sigma_k.empty() ? "." : ", and its one-sigma uncertainty."));
  }
  if (profiled) {
    page.Section("Radial profile");
    if (!profile_plotted) page.Warning("No plot: " + profile_error);
    if (profile_plotted)
      page.Figure(
          "profile.png",
          std::string("The axisymmetric fit's rings: temperature against the distance "
                      "from the flame's axis at up to five heights") +
              (result.uncertainty.temperature_sigma_k.empty() ? "" : ", with one-sigma bars") +
              (profile_truth ? "; dashed, the truth's visible voxels averaged over the same rings"
                             : "") +
              ". Every ring's numbers are in profile.csv.");
  }
  page.Section("Error against time");
  if (!plotted) page.Warning("No plot: " + plot_error);
  if (plotted)
    page.Figure("error.png", "Mean Delta E of the fitted views as the fit ran (log time axis).");
  page.Section("Data");
  std::vector<std::pair<std::string, std::string>> files = {
      {"trace.csv", "the fit's energy and Delta E at each step"},
      {"error.dat", "the plot's data; error.gp redraws it with gnuplot"},
      {"report.md", "this report as Markdown"}};
  if (profiled)
    files.push_back({"profile.csv",
                     "the axisymmetric fit's rings: height, radius, temperature and density with "
                     "their sigma" +
                         std::string(profile_truth ? ", and the truth on each ring" : "")});
  page.Files(files);
  page.Write((fs::path(dir) / "index.html").string());
  return scores;
}

}  // namespace flamerig
