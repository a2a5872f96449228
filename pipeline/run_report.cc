#include "pipeline/run_report.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <set>
#include <sstream>

#include "core/atomic_file.h"
#include "core/error.h"
#include "core/image.h"
#include "core/log.h"
#include "pipeline/fit_report.h"
#include "pipeline/picture.h"
#include "pipeline/plot.h"
#include "pipeline/report_page.h"
#include "pipeline/simulate.h"
#include "pipeline/truth.h"
#include "tomography/vdb_io.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

// The colour of a temperature on the report's scale.
Rgb ColourOf(double t, double t_lo, double t_hi) {
  return InfernoColour((t - t_lo) / std::max(1e-9, t_hi - t_lo));
}

// A slice of any per-voxel field: `colour` of each voxel where `shown` says, dark grey elsewhere;
// the plane and orientation of TemperatureSlice.
ImageU8 FieldSlice(const GridGeometry& g, int axis, int index, int scale,
                   const std::function<bool(std::size_t)>& shown,
                   const std::function<Rgb(std::size_t)>& colour, bool minus_y_up = false) {
  const int across = axis == 2 ? g.dims.x() : g.dims.z();
  const int up = g.dims.y();
  const int depth = axis == 2 ? g.dims.z() : g.dims.x();
  index = std::clamp(index, 0, depth - 1);
  scale = std::max(1, scale);
  ImageU8 out(across * scale, up * scale, 3, 40);
  for (int j = 0; j < up; ++j)
    for (int a = 0; a < across; ++a) {
      const std::size_t v = axis == 2 ? g.Flat(a, j, index) : g.Flat(index, j, a);
      if (!shown(v)) continue;
      const Rgb c = colour(v);
      const int row = minus_y_up ? j : up - 1 - j;
      for (int y = row * scale; y < (row + 1) * scale; ++y)
        for (int x = a * scale; x < (a + 1) * scale; ++x)
          for (int ch = 0; ch < 3; ++ch) out.at(x, y, ch) = c[ch];
    }
  return out;
}

void WritePicture(const fs::path& path, const ImageU8& image) { WritePng(path.string(), image); }

bool Computed(const FrameSummary& f) { return f.status == "computed"; }

}  // namespace

ImageU8 TemperatureSlice(const FireVolume& volume, int axis, int index, double t_lo, double t_hi,
                         int scale) {
  const GridGeometry& g = volume.geometry;
  if (volume.temperature_k.size() != g.num_voxels())
    throw InputError("TemperatureSlice: the volume has no temperature grid");
  if (axis != 0 && axis != 2) throw InputError("TemperatureSlice: axis must be 0 or 2");
  const bool have_density = volume.density_per_m3.size() == g.num_voxels();
  return FieldSlice(
      g, axis, index, scale,
      [&](std::size_t v) { return !have_density || volume.density_per_m3[v] > 0; },
      [&](std::size_t v) { return ColourOf(volume.temperature_k[v], t_lo, t_hi); });
}

ImageU8 SlicesPicture(const FireVolume& v, const FireVolume* truth_volume,
                      const Rigid3& fit_from_truth, const Eigen::Vector3d& up_in_rig) {
  const bool minus_y_up = up_in_rig.y() < 0;
  const GridGeometry& g = v.geometry;
  if (!v.HasTemperatureAndDensity())
    throw InputError("SlicesPicture: the volume needs temperature and density grids");
  // The truth is usually finer than the fit (the main job's 96 against 64): shown on the fit's
  // grid, each fit voxel with the truth voxel holding its centre, as the scorer pairs them.
  FireVolume truth;
  if (truth_volume) truth = SampleOnGrid(*truth_volume, g, fit_from_truth);
  // The scale spans the truth too: a fit that runs cold would otherwise hide the truth's hot core
  // in the scale's top colour.
  double t_hi = 1500;
  for (std::size_t i = 0; i < v.temperature_k.size(); ++i)
    if (v.density_per_m3[i] > 0) t_hi = std::max(t_hi, double(v.temperature_k[i]));
  for (std::size_t i = 0; i < truth.temperature_k.size(); ++i)
    if (truth.density_per_m3.size() == truth.temperature_k.size() && truth.density_per_m3[i] > 0 &&
        std::isfinite(truth.temperature_k[i]))
      t_hi = std::max(t_hi, double(truth.temperature_k[i]));
  const double t_lo = 300;
  const int scale = std::max(1, 320 / std::max(1, g.dims.y()));
  // One row per field: front (the x-y plane through the middle) and side (z-y), its bar; a
  // scale bar in each front view.
  const double pixels_per_m = scale / g.voxel_size_m.y();
  const double bar_m = ScaleBarLength(pixels_per_m);
  std::vector<ImageU8> rows;
  auto row = [&](const std::string& what, const std::function<bool(std::size_t)>& shown,
                 const std::function<Rgb(std::size_t)>& colour, const ColourScale& bar) {
    ImageU8 front = FieldSlice(g, 2, g.dims.z() / 2, scale, shown, colour, minus_y_up);
    ImageU8 side = FieldSlice(g, 0, g.dims.x() / 2, scale, shown, colour, minus_y_up);
    DrawScaleBar(&front, pixels_per_m, bar_m);
    DrawScaleBar(&side, pixels_per_m, bar_m);
    const std::string up = minus_y_up ? "-y up" : "y up";
    rows.push_back(Labelled(
        Beside({Labelled(front, "front (x right, " + up + ")"),
                Labelled(side, "side (z right, " + up + ")"), ColourBar(bar, front.height + 24)},
               12),
        what));
  };
  auto has_fit = [&](std::size_t i) { return v.density_per_m3[i] > 0; };
  const ColourScale temperature{"temperature", "K", t_lo, t_hi,
                                [&](double t) { return ColourOf(t, t_lo, t_hi); }};
  row(
      "fit (K)", has_fit, [&](std::size_t i) { return ColourOf(v.temperature_k[i], t_lo, t_hi); },
      temperature);
  if (!truth.temperature_k.empty() && truth.density_per_m3.size() == g.num_voxels()) {
    auto has_truth = [&](std::size_t i) { return truth.density_per_m3[i] > 0; };
    row(
        "truth on the fit's grid (K)", has_truth,
        [&](std::size_t i) { return ColourOf(truth.temperature_k[i], t_lo, t_hi); }, temperature);
    const double range = 400;
    row(
        "fit - truth (K)", [&](std::size_t i) { return has_fit(i) && has_truth(i); },
        [&](std::size_t i) {
          return DivergingColour(double(v.temperature_k[i]) - truth.temperature_k[i], range);
        },
        ColourScale{"fit - truth", "K", -range, range,
                    [&](double e) { return DivergingColour(e, range); }, true});
  }
  if (v.temperature_sigma_k.size() == g.num_voxels()) {
    double sigma_hi = 1;
    for (float x : v.temperature_sigma_k) sigma_hi = std::max(sigma_hi, double(x));
    row(
        "temperature sigma (K)", has_fit,
        [&](std::size_t i) { return ViridisColour(v.temperature_sigma_k[i] / sigma_hi); },
        ColourScale{"sigma", "K", 0, sigma_hi,
                    [&](double x) { return ViridisColour(x / sigma_hi); }});
  }
  return Stacked(rows, 16);
}

std::string WriteRunReport(const std::string& out_dir, const std::vector<FrameSummary>& frames,
                           const RunReportInfo& info) {
  const fs::path out(out_dir);
  const fs::path dir = out / "report";
  fs::create_directories(dir);

  // frames.csv: one row per frame.
  {
    std::set<std::string> cameras;
    for (const auto& f : frames)
      for (const auto& d : f.delta_e) cameras.insert(d.camera);
    // A field in double quotes, its quotes doubled (RFC 4180).
    auto quoted = [](const std::string& text) {
      std::string q = "\"";
      for (char c : text) q += c == '"' ? std::string("\"\"") : std::string(1, c);
      return q + "\"";
    };
    std::ostringstream csv;
    csv << "frame,status,cameras_used,total_ms,read_ms,tomography_ms,fit_ms,write_ms,matrix,"
           "active_voxels,exposure,exposure_from,soot,soot_volume_mm3,initial_energy,energy,"
           "fit_termination,"
           "fit_iterations,fit_message,voxels_at_temperature_bound,voxels_at_density_bound,"
           "truth_frame,truth_rms_k,truth_bias_k,truth_spread_k,"
           "truth_soot,truth_within_1_sigma,truth_within_2_sigma,truth_median_sigma_k,"
           "truth_determined_share,truth_determined_rms_k,truth_undetermined_rms_k,"
           "truth_weighted_rms_k,truth_weighted_bias_k,truth_visible_soot,visible_soot,"
           "limit_rms_k,limit_bias_k,limit_visible_soot,limit_soot";
    for (const auto& c : cameras) csv << ",delta_e_fire_" << c << ",delta_e_all_" << c;
    csv << ",notes\n";
    for (const auto& f : frames) {
      csv << f.frame << "," << quoted(f.status) << "," << f.cameras_used << "," << f.total_ms << ","
          << f.read_ms << "," << f.reconstruct_ms << "," << f.fit_ms << "," << f.write_ms << ","
          << f.matrix_source << "," << f.active_voxels << "," << f.exposure << ","
          << quoted(f.exposure_from) << "," << f.soot << "," << f.soot_volume_m3 * 1e9 << ","
          << f.initial_energy << "," << f.energy << "," << f.fit_termination << ","
          << f.fit_iterations << "," << quoted(f.fit_message) << ","
          << f.voxels_at_temperature_bound << "," << f.voxels_at_density_bound << ","
          << f.truth_frame << "," << f.truth_rms_k << "," << f.truth_bias_k << ","
          << f.truth_spread_k << "," << f.truth_soot << "," << f.truth_within_1_sigma << ","
          << f.truth_within_2_sigma << "," << f.truth_median_sigma_k << ","
          << f.truth_determined_share << "," << f.truth_determined_rms_k << ","
          << f.truth_undetermined_rms_k << "," << f.truth_weighted_rms_k << ","
          << f.truth_weighted_bias_k << "," << f.truth_visible_soot << "," << f.visible_soot << ","
          << f.limit_rms_k << "," << f.limit_bias_k << "," << f.limit_visible_soot << ","
          << f.limit_soot;
      for (const auto& c : cameras) {
        auto it = std::find_if(f.delta_e.begin(), f.delta_e.end(),
                               [&](const ViewDeltaE& d) { return d.camera == c; });
        if (it == f.delta_e.end())
          csv << ",,";
        else
          csv << "," << it->fire << "," << it->mean;
      }
      std::string notes;
      for (const auto& n : f.notes) notes += (notes.empty() ? "" : "; ") + n;
      csv << "," << quoted(notes) << "\n";
    }
    WriteFileAtomically((out / "frames.csv").string(), csv.str());
  }
  // Every number of each frame as JSON, for scripts.
  for (const auto& f : frames)
    WriteFileAtomically((dir / (FrameName(f.frame) + ".json")).string(), f.ToJson());

  // Plots.
  std::map<std::string, PlotSeries> per_view;
  PlotSeries truth{"temperature RMS error on visible voxels (K, right axis)", {}, {}, true};
  // The baseline the error is read against: the truth's own spread on the same voxels, the RMS of
  // the best single temperature (drawn dashed in the error's colour).
  PlotSeries constant{
      "a constant temperature's RMS error (the truth's spread; K, right axis)", {}, {}, true};
  // And the fit's limit: the RMS of the truth's light given exactly to each fitted voxel (or ring).
  PlotSeries limit{
      "the fit's limit: the truth's light per fitted voxel or ring (K, right axis)", {}, {}, true};
  PlotSeries tomo{"tomography", {}, {}}, fit{"fit", {}, {}}, total{"whole frame", {}, {}};
  std::size_t computed = 0, unchanged = 0, failed = 0, no_fire = 0;
  double de_sum = 0, t_sum = 0, in1_sum = 0, in2_sum = 0, sigma_sum = 0;
  int de_n = 0, t_n = 0, sigma_n = 0;
  // The determined voxels scored apart: their share, and the RMS over them and over the rest
  // (each averaged over the frames that have such voxels).
  double determined_share_sum = 0, determined_rms_sum = 0, undetermined_rms_sum = 0;
  int determined_n = 0, determined_rms_n = 0, undetermined_rms_n = 0;
  double computed_ms = 0;  // the computed frames' own times, read to write
  for (const auto& f : frames) {
    if (Computed(f)) {
      ++computed;
      computed_ms += f.total_ms;
    }
    if (f.status.rfind("unchanged", 0) == 0) ++unchanged;
    if (f.status.rfind("failed", 0) == 0) ++failed;
    if (f.status == "no fire") ++no_fire;
    for (const auto& d : f.delta_e) {
      PlotSeries& s = per_view[d.camera];
      s.name = d.camera + (d.held_out ? " (held out)" : " (fitted)");
      s.x.push_back(static_cast<double>(f.frame));
      s.y.push_back(d.fire);
    }
    if (!f.delta_e.empty()) {
      de_sum += f.MeanFittedDeltaE();
      ++de_n;
    }
    if (f.truth_rms_k >= 0) {
      truth.x.push_back(static_cast<double>(f.frame));
      truth.y.push_back(f.truth_rms_k);
      if (f.truth_spread_k >= 0) {
        constant.x.push_back(static_cast<double>(f.frame));
        constant.y.push_back(f.truth_spread_k);
      }
      if (f.limit_rms_k >= 0) {
        limit.x.push_back(static_cast<double>(f.frame));
        limit.y.push_back(f.limit_rms_k);
      }
      t_sum += f.truth_rms_k;
      ++t_n;
      if (f.truth_within_1_sigma >= 0) {
        in1_sum += f.truth_within_1_sigma;
        in2_sum += f.truth_within_2_sigma;
        sigma_sum += f.truth_median_sigma_k;
        ++sigma_n;
      }
      if (f.truth_determined_share >= 0) {
        determined_share_sum += f.truth_determined_share;
        ++determined_n;
        if (f.truth_determined_rms_k >= 0) {
          determined_rms_sum += f.truth_determined_rms_k;
          ++determined_rms_n;
        }
        if (f.truth_undetermined_rms_k >= 0) {
          undetermined_rms_sum += f.truth_undetermined_rms_k;
          ++undetermined_rms_n;
        }
      }
    }
    if (Computed(f)) {
      tomo.x.push_back(static_cast<double>(f.frame));
      tomo.y.push_back(f.reconstruct_ms / 1000);
      fit.x.push_back(static_cast<double>(f.frame));
      fit.y.push_back(f.fit_ms / 1000);
    }
    total.x.push_back(static_cast<double>(f.frame));
    total.y.push_back(f.total_ms / 1000);
  }
  std::vector<std::string> plot_errors;
  bool errors_plotted = false, timing_plotted = false;
  {
    PlotSpec errors;
    errors.title = "Error over the frames";
    errors.x_label = "frame";
    errors.y_label = "mean Delta E of the view's fire pixels (CIELab)";
    errors.integer_x = true;
    for (auto& [name, s] : per_view) errors.series.push_back(s);
    if (!truth.x.empty()) {
      errors.y2_label = "temperature RMS error (K)";
      errors.series.push_back(truth);
      if (!constant.x.empty()) {
        constant.reference_of = int(errors.series.size()) - 1;
        errors.series.push_back(constant);
      }
      if (!limit.x.empty()) errors.series.push_back(limit);
    }
    std::string why;
    errors_plotted = WritePlot(errors, (dir / "errors").string(), &why);
    if (!errors_plotted) plot_errors.push_back(why);
    PlotSpec timing;
    timing.title = "Run time per frame by stage";
    timing.x_label = "frame";
    timing.y_label = "time (s)";
    timing.integer_x = true;
    timing.series = {tomo, fit, total};
    timing_plotted = WritePlot(timing, (dir / "timing").string(), &why);
    if (!timing_plotted) plot_errors.push_back(why);
    for (const auto& e : plot_errors) Log().warn("run report: a plot is missing: {}", e);
  }

  // Contact sheet: input over rendered for a few frames, evenly spaced among the computed ones.
  std::vector<const FrameSummary*> shown;
  {
    std::vector<const FrameSummary*> candidates;
    for (const auto& f : frames)
      if (Computed(f) && fs::exists(out / "frames" / (FrameName(f.frame) + ".png")))
        candidates.push_back(&f);
    const int n = std::min<int>(info.contact_frames, static_cast<int>(candidates.size()));
    for (int k = 0; k < n; ++k)
      shown.push_back(candidates[n == 1 ? 0 : k * (candidates.size() - 1) / (n - 1)]);
  }
  if (!shown.empty()) {
    std::vector<ImageU8> columns;
    for (const auto* f : shown)
      columns.push_back(
          Labelled(ReadImageU8((out / "frames" / (FrameName(f->frame) + ".png")).string(), 3),
                   FrameName(f->frame)));
    // At most three frames per row, and a row at most about 2000 px wide.
    const std::size_t per_row =
        std::clamp<std::size_t>(2000 / static_cast<std::size_t>(columns.front().width + 16), 1, 3);
    std::vector<ImageU8> rows;
    for (std::size_t k = 0; k < columns.size(); k += per_row)
      rows.push_back(
          Beside(std::vector<ImageU8>(columns.begin() + k,
                                      columns.begin() + std::min(columns.size(), k + per_row)),
                 16));
    WritePicture(dir / "contact.png", Stacked(rows, 16));
  }

  // Temperature slices of a few computed frames, and their radial profiles when the fit was
  // axisymmetric (the run's OUT/frames/frame_NNNNNN_profile.csv).
  std::vector<std::string> slice_files, profile_files;
  RigRegistration truth_frame;  // identity without a truth rig
  Eigen::Vector3d rig_up = Eigen::Vector3d::UnitY();
  if (!info.rig_path.empty()) {
    const Rig rig = Rig::Load(info.rig_path);
    rig_up = rig.up_in_rig;
    if (!info.truth_dir.empty() && !info.truth_rig.empty())
      truth_frame = RegisterTruth(info.truth_rig, rig);
  }
  {
    std::vector<const FrameSummary*> candidates;
    for (const auto& f : frames)
      if (Computed(f) && fs::exists(out / (FrameName(f.frame) + ".vdb"))) candidates.push_back(&f);
    const int n = std::min<int>(info.slice_frames, static_cast<int>(candidates.size()));
    for (int k = 0; k < n; ++k) {
      const FrameSummary* f = candidates[n == 1 ? 0 : k * (candidates.size() - 1) / (n - 1)];
      const FireVolume v = ReadVdb((out / (FrameName(f->frame) + ".vdb")).string());
      FireVolume truth;
      if (!info.truth_dir.empty() && f->truth_frame >= 0) {
        const fs::path t = fs::path(info.truth_dir) / (FrameName(f->truth_frame) + ".vdb");
        // The truth is finer than the fit (the main job's 96 against 64): shown on the fit's
        // grid, each fit voxel with the truth voxel holding its centre, as the scorer pairs them.
        if (fs::exists(t)) truth = ReadVdb(t.string());
      }
      const std::string name = "slices_" + FrameName(f->frame).substr(6) + ".png";
      WritePicture(dir / name, SlicesPicture(v, truth.temperature_k.empty() ? nullptr : &truth,
                                             truth_frame.to_from_from, rig_up));
      slice_files.push_back(name);
      const fs::path csv = out / "frames" / (FrameName(f->frame) + "_profile.csv");
      if (!fs::exists(csv)) continue;
      std::vector<RingProfilePoint> profile;
      try {
        profile = ReadRingProfileCsv(csv.string());
      } catch (const DataError& e) {  // the report goes on without that picture
        Log().warn("run report: no profile plot of {}: {}", FrameName(f->frame), e.what());
        continue;
      }
      const bool with_truth = !truth.temperature_k.empty() && truth.HasTemperatureAndDensity();
      std::vector<RingTruth> on_rings;
      if (with_truth) on_rings = TruthOnRings(truth, v.geometry, profile, truth_frame.to_from_from);
      const std::string base = "profile_" + FrameName(f->frame).substr(6);
      std::string plot_error;
      if (WriteRingProfilePlot((dir / base).string(), profile, with_truth ? &on_rings : nullptr,
                               FrameName(f->frame), &plot_error))
        profile_files.push_back(base + ".png");
      else
        Log().warn("run report: no profile plot of {}: {}", FrameName(f->frame), plot_error);
    }
  }

  // The page.
  std::vector<std::pair<std::string, std::string>> inputs = {{"source", info.source},
                                                             {"rig", info.rig_path}};
  if (!info.truth_dir.empty()) inputs.emplace_back("truth", info.truth_dir);
  if (!info.truth_dir.empty() && !info.truth_rig.empty())
    inputs.emplace_back("truth's rig", info.truth_rig + ", moved into the rig's frame by " +
                                           truth_frame.Describe());
  if (info.ranks > 1) inputs.emplace_back("MPI ranks", std::to_string(info.ranks));
  ReportPage page(info.title, inputs);
  page.Section("Results");
  std::vector<std::string> results = {fmt::format(
      "{} frame{}: {} computed, {} unchanged (the previous result reused), {} failed{}.",
      frames.size(), frames.size() == 1 ? "" : "s", computed, unchanged, failed,
      no_fire ? fmt::format(", {} without fire (their images hold none: empty "
                            "volumes written)",
                            no_fire)
              : std::string())};
  if (de_n)
    results.push_back(fmt::format(
        "Mean Delta E of the fitted views' fire pixels: <b>{:.3f}</b> (CIELab; 1 is about the "
        "smallest difference a person sees).",
        de_sum / de_n));
  if (t_n)
    results.push_back(fmt::format(
        "Temperature against the known truth on visible voxels: <b>{:.1f} K RMS</b> on average "
        "over the frames.",
        t_sum / t_n));
  if (sigma_n)
    results.push_back(fmt::format(
        "Its sigma: {:.0f}% of those voxels within one sigma, {:.0f}% within two (a calibrated "
        "sigma: 68%, 95%); median sigma {:.0f} K.",
        100 * in1_sum / sigma_n, 100 * in2_sum / sigma_n, sigma_sum / sigma_n));
  if (determined_n) {
    std::string line = fmt::format("The voxels the fit calls determined: {:.0f}% of those voxels",
                                   100 * determined_share_sum / determined_n);
    if (determined_rms_n)
      line += fmt::format(", at {:.1f} K RMS", determined_rms_sum / determined_rms_n);
    if (undetermined_rms_n)
      line += fmt::format(" (the rest at {:.1f} K)", undetermined_rms_sum / undetermined_rms_n);
    results.push_back(line + ".");
  }
  // The rate from the frames' own times: the report covers every frame in OUT, and frames done
  // by an earlier call (a resume) are not in this call's time (which made a resumed run's rate
  // up to 360 frames a minute, 2026-12-02).
  if (computed > 0 && computed_ms > 0)
    results.push_back(fmt::format(
        "The {} computed frame{} took {:.1f} s, read to write: {:.1f} computed frames per minute "
        "one after another.",
        computed, computed == 1 ? "" : "s", computed_ms / 1000, 60e3 * computed / computed_ms));
  if (info.wall_seconds > 0)
    results.push_back(fmt::format("This call of run took {:.1f} s.", info.wall_seconds));
  page.List(results);
  page.Section("Error over the frames");
  for (const auto& e : plot_errors) page.Warning("A plot is missing: " + e);
  if (errors_plotted) {
    std::string caption = "Mean Delta E of each view's fire pixels per frame (left axis)";
    if (truth.x.empty())
      caption += ".";
    else
      caption +=
          "; the temperature RMS error against the truth on visible voxels, in kelvin (right "
          "axis), and dashed beside it the error of the best single temperature on the same "
          "voxels (the truth's spread): a fit above that line tells less than a constant.";
    if (!limit.x.empty())
      caption +=
          " The fit's limit is the error of the truth's light given exactly to each fitted voxel "
          "(to each ring, for a tied fit): what the fit's grid (or rings) can show.";
    page.Figure("errors.png", caption);
  }
  if (!shown.empty()) {
    page.Section("Input against rendered");
    page.Figure("contact.png",
                "A few frames: each camera's input (top row) and the fitted volume rendered "
                "through it (bottom row).");
  }
  if (!slice_files.empty()) {
    page.Section(std::string("Fitted temperature") +
                 (info.truth_dir.empty() ? "" : ", the truth, the error") +
                 " and its sigma, slices through the middle of the box");
    page.Text(
        "Each row a field, front (x-y) and side (z-y) through the box's middle, the rig's up "
        "at the top; dark grey: no medium. The truth is shown on the fit's grid, sampled at each "
        "fit voxel's centre (the error above pairs each visible truth voxel with the fit voxel "
        "holding its centre); fit - truth is blue where the fit is too cold, red where too hot; "
        "the sigma is the fit's one-standard-deviation temperature uncertainty.");
    for (const auto& f : slice_files) page.Figure(f, "Slices of frame " + f.substr(7, 6) + ".");
  }
  if (!profile_files.empty()) {
    page.Section("Radial profiles (axisymmetric fit)");
    page.Text(
        "The same frames' rings: temperature against the distance from the flame's axis at up "
        "to five heights, with one-sigma bars" +
        std::string(info.truth_dir.empty()
                        ? ""
                        : "; dashed, the truth's visible voxels averaged over the same rings") +
        ". Every ring's numbers: frames/frame_NNNNNN_profile.csv beside the frames' summaries.");
    for (const auto& f : profile_files)
      page.Figure(f, "Radial profile of frame " + f.substr(8, 6) + ".");
  }
  page.Section("Run time");
  if (timing_plotted)
    page.Figure("timing.png", "Seconds per frame: tomography, fit and the whole frame.");
  page.Section("Data");
  std::vector<std::pair<std::string, std::string>> files = {
      {"../frames.csv", "every frame's numbers, one row per frame"},
      {"errors.dat", "the error plot's data; errors.gp redraws it with gnuplot"}};
  if (!frames.empty())
    files.emplace_back(FrameName(frames.front().frame) + ".json",
                       "every number of one frame (one file per frame)");
  if (errors_plotted) files.emplace_back("errors.svg", "the error plot, scalable");
  page.Files(files);
  // The Blender-ready sequence is there unless the run was told not to write it (--no-blender).
  const bool blender = fs::exists(fs::path(out_dir) / "blender");
  page.Html(std::string("Volumes: <code>frame_NNNNNN.vdb</code> (temperature in K, density in "
                        "m<sup>-3</sup>, sigma); ") +
            (blender ? "Blender-ready: <code>blender/frame_NNNNNN.vdb</code>; " : "") +
            "as a table: <code>flamerig export-volume</code>.");
  page.Section("Frames");
  std::vector<std::vector<std::string>> rows;
  for (const auto& f : frames) rows.push_back({f.Line()});
  page.Table({"summary"}, rows);
  const fs::path index = dir / "index.html";
  page.Write(index.string());
  return index.string();
}

}  // namespace flamerig
