#include "pipeline/run.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>

#include "acquisition/recording.h"
#include "acquisition/sim_camera.h"
#include "core/error.h"
#include "core/json_yaml.h"
#include "core/log.h"
#include "core/read_file.h"
#include "fitting/absorption.h"
#include "fitting/renderer.h"
#include "pipeline/blender_export.h"
#include "pipeline/fit_report.h"
#include "pipeline/frame_stages.h"
#include "pipeline/simulate.h"
#include "tomography/vdb_io.h"

namespace flamerig {

namespace fs = std::filesystem;

std::string FrameName(std::size_t i) {
  char name[32];
  std::snprintf(name, sizeof name, "frame_%06zu", i);
  return name;
}

namespace {

// `dataset.KEY` of the dataset.yaml beside `rig_path` into *value; false when the file or the
// key is not there (or the key is empty). *file is the dataset's path, for messages. InputError
// when the file is not YAML.
bool DatasetKey(const std::string& rig_path, const char* key, std::string* file,
                YAML::Node* value) {
  const fs::path dataset = fs::path(rig_path).parent_path() / "dataset.yaml";
  *file = dataset.string();
  if (!fs::exists(dataset)) return false;
  try {
    const YAML::Node root = YAML::LoadFile(*file);
    if (!root["dataset"] || !root["dataset"][key] || root["dataset"][key].IsNull()) return false;
    *value = root["dataset"][key];
    return true;
  } catch (const YAML::Exception& e) {
    throw InputError(*file + ": " + e.what());
  }
}

}  // namespace

bool DatasetExposure(const std::string& rig_path, double* exposure) {
  const DatasetExposureStatement stated =
      ReadDatasetExposure(fs::path(rig_path).parent_path().string());
  if (!(stated.exposure > 0)) return false;
  *exposure = stated.exposure;
  return true;
}

ImagesExposure ResolveExposure(double given, const std::string& rig_path,
                               const std::string& images_dir) {
  ImagesExposure e;
  if (given > 0) {
    e.value = given;
    e.known = e.given = true;
    e.from = "--exposure";
    return e;
  }
  // The dataset beside the rig, else DATASET/frames or DATASET/frames/frame_NNNNNN's.
  std::vector<fs::path> datasets = {fs::path(rig_path).parent_path()};
  if (!images_dir.empty()) {
    std::error_code ec;
    const fs::path images = fs::weakly_canonical(images_dir, ec);
    for (const fs::path& frames : {images, images.parent_path()})
      if (!ec && frames.filename() == "frames") datasets.push_back(frames.parent_path());
  }
  for (const fs::path& dataset : datasets) {
    const DatasetExposureStatement stated = ReadDatasetExposure(dataset.string());
    if (!(stated.exposure > 0)) continue;
    e.known = true;
    e.value = stated.exposure;
    e.from = stated.path;
    e.unit_us = stated.unit_us;
    break;
  }
  if (!e.known) e.value = 1;
  return e;
}

void ExposureFromReference(const std::function<std::optional<ExposureReference>()>& reference,
                           const Rig& rig, const std::string& rig_path, ImagesExposure* exposure) {
  if (exposure->given) return;
  const double unit = exposure->known ? exposure->unit_us : rig.exposure_unit_us;
  if (!(unit > 0)) return;
  const std::optional<ExposureReference> ref = reference();
  if (!ref) return;
  const double value = ref->exposure_us_at_0db() / unit;
  exposure->from = fmt::format(
      "{}'s settings at the recording's start ({:g} us{}{}) over {}'s exposure unit ({:g} us)",
      ref->camera, ref->exposure_us,
      ref->gain_in_db ? fmt::format(", {:g} dB", ref->gain_db)
                      : std::string(", its gain in the device's units taken as calibrated"),
      ref->where.empty() ? std::string() : ", as " + ref->where + " gives them",
      exposure->known ? exposure->from : rig_path, unit);
  exposure->value = value;
  exposure->known = true;
}

double HeldExposure(const ImagesExposure& exposure, const FitOptions& fit, const std::string& job) {
  if (!(exposure.value >= fit.exposure_min && exposure.value <= fit.exposure_max))
    throw InputError(job + ": the images' exposure " + std::to_string(exposure.value) + " (" +
                     (exposure.from.empty() ? std::string("unknown") : exposure.from) +
                     ") is outside the fit's range [" + std::to_string(fit.exposure_min) + ", " +
                     std::to_string(fit.exposure_max) + "]");
  return exposure.value;
}

std::string DatasetAbsorption(const std::string& rig_path) {
  std::string file;
  YAML::Node node;
  if (!DatasetKey(rig_path, "absorption", &file, &node)) return "soot";
  try {
    const std::string name = node.as<std::string>();
    AbsorptionModel::FromName(name);
    return name;
  } catch (const YAML::Exception& e) {
    throw InputError(file + ": dataset.absorption: " + e.what());
  } catch (const InputError& e) {
    throw InputError(file + ": dataset.absorption: " + e.what());
  }
}

void RunOptions::Validate() const {
  source.Validate();
  if (rig_path.empty() && calibration.images_dir.empty() && calibration.recording_dir.empty())
    throw InputError("run: give a rig (--rig) or a calibration to make one");
  if (!rig_path.empty() && !(calibration.images_dir.empty() && calibration.recording_dir.empty()))
    throw InputError("run: give a rig (--rig) or a calibration to make one, not both");
  if (out_dir.empty()) throw InputError("run: give an output folder (--out)");
  if (count == 0) throw InputError("run: count must be >= 1");
  if (!truth_rig.empty() && truth_dir.empty())
    throw InputError("run: a truth rig (--truth-rig) without a truth (--truth) to move");
  if (!(exposure >= 0) || !std::isfinite(exposure))
    throw InputError("run: exposure must be finite and >= 0 (0 = from the dataset)");
  if (!absorption.empty() && absorption != "soot" && absorption != "grey")
    throw InputError("run: absorption '" + absorption + "': use soot or grey");
  ReconstructOptions r = reconstruct;
  r.exposure = 1;
  r.Validate();
  if (!input_transfer.empty()) {
    TransferFunction transfer;
    double gamma;
    ParseTransferSpec(input_transfer, &transfer, &gamma);
  }
  fit.Validate();
  unchanged.Validate();
}

double FrameSummary::MeanFittedDeltaE() const {
  double sum = 0;
  int n = 0;
  for (const auto& d : delta_e)
    if (!d.held_out) {
      sum += d.fire;
      ++n;
    }
  return n ? sum / n : 0.0;
}

std::string FrameSummary::Line() const {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(0);
  s << FrameName(frame) << ": " << status;
  if (status == "no fire") {
    s << ", " << cameras_used << " camera(s), " << total_ms << " ms (read " << read_ms
      << ", tomography " << reconstruct_ms << ", write " << write_ms << ")";
  } else if (status == "computed" || status.rfind("unchanged", 0) == 0) {
    s << ", " << cameras_used << " camera(s), " << total_ms << " ms (read " << read_ms
      << ", tomography " << reconstruct_ms << ", fit " << fit_ms << ", write " << write_ms << ")";
    s.precision(3);
    s << ", Delta E";
    for (const auto& d : delta_e) s << " " << d.camera << (d.held_out ? "*" : "") << " " << d.fire;
    s << ", " << active_voxels << " active voxels";
    if (!matrix_source.empty()) s << ", matrix " << matrix_source;
    if (!fit_termination.empty()) s << ", fit " << fit_termination << " after " << fit_iterations;
    if (voxels_at_temperature_bound + voxels_at_density_bound > 0)
      s << ", " << voxels_at_temperature_bound << " voxel(s) at the temperature bound and "
        << voxels_at_density_bound << " at the density bound";
    s.precision(4);
    if (!exposure_from.empty()) s << ", exposure " << exposure << " (" << exposure_from << ")";
    s.precision(1);
    if (truth_rms_k >= 0)
      s << ", T error " << truth_rms_k << " K RMS, bias " << truth_bias_k << " K on visible voxels";
    if (truth_spread_k >= 0) s << " (a constant: " << truth_spread_k << " K)";
    if (truth_within_1_sigma >= 0)
      s << " (" << 100 * truth_within_1_sigma << "% within 1 sigma, " << 100 * truth_within_2_sigma
        << "% within 2; median sigma " << truth_median_sigma_k << " K)";
    if (truth_determined_share >= 0) {
      s << ", " << 100 * truth_determined_share << "% determined";
      if (truth_determined_rms_k >= 0) s << " at " << truth_determined_rms_k << " K RMS";
    }
    if (truth_weighted_rms_k >= 0) {
      s << ", emission-weighted RMS " << truth_weighted_rms_k << " K";
      if (std::isfinite(truth_weighted_bias_k))
        s << " (bias " << std::showpos << truth_weighted_bias_k << std::noshowpos << " K)";
    }
  }
  for (const auto& n : notes) s << "; " << n;
  return s.str();
}

namespace {

// Every field of a summary, in one place (JSON and the state YAML are made from it).
nlohmann::json SummaryJson(const FrameSummary& f) {
  nlohmann::json j;
  j["frame"] = f.frame;
  j["status"] = f.status;
  j["notes"] = f.notes;
  j["cameras_used"] = f.cameras_used;
  j["read_ms"] = f.read_ms;
  j["reconstruct_ms"] = f.reconstruct_ms;
  j["fit_ms"] = f.fit_ms;
  j["write_ms"] = f.write_ms;
  j["total_ms"] = f.total_ms;
  j["matrix_source"] = f.matrix_source;
  j["hull_fraction"] = f.hull_fraction;
  j["active_voxels"] = f.active_voxels;
  j["fit_evaluations"] = f.fit_evaluations;
  j["exposure"] = f.exposure;
  j["exposure_from"] = f.exposure_from;
  j["soot"] = f.soot;
  j["soot_volume_m3"] = f.soot_volume_m3;
  j["energy"] = f.energy;
  j["fit_termination"] = f.fit_termination;
  j["fit_message"] = f.fit_message;
  j["fit_iterations"] = f.fit_iterations;
  j["initial_energy"] = f.initial_energy;
  j["voxels_at_temperature_bound"] = f.voxels_at_temperature_bound;
  j["voxels_at_density_bound"] = f.voxels_at_density_bound;
  j["delta_e"] = nlohmann::json::array();
  for (const auto& d : f.delta_e)
    j["delta_e"].push_back(
        {{"camera", d.camera}, {"held_out", d.held_out}, {"mean", d.mean}, {"fire", d.fire}});
  j["truth_rms_k"] = f.truth_rms_k;
  j["truth_bias_k"] = f.truth_bias_k;
  j["truth_spread_k"] = f.truth_spread_k;
  j["truth_weighted_rms_k"] = f.truth_weighted_rms_k;
  j["truth_weighted_bias_k"] = f.truth_weighted_bias_k;
  j["truth_voxels"] = f.truth_voxels;
  j["truth_visible"] = f.truth_visible;
  j["truth_frame"] = f.truth_frame;
  j["truth_soot"] = f.truth_soot;
  j["truth_visible_soot"] = f.truth_visible_soot;
  j["visible_soot"] = f.visible_soot;
  j["limit_rms_k"] = f.limit_rms_k;
  j["limit_bias_k"] = f.limit_bias_k;
  j["limit_visible_soot"] = f.limit_visible_soot;
  j["limit_soot"] = f.limit_soot;
  j["truth_within_1_sigma"] = f.truth_within_1_sigma;
  j["truth_within_2_sigma"] = f.truth_within_2_sigma;
  j["truth_median_sigma_k"] = f.truth_median_sigma_k;
  j["truth_determined_share"] = f.truth_determined_share;
  j["truth_determined_rms_k"] = f.truth_determined_rms_k;
  j["truth_undetermined_rms_k"] = f.truth_undetermined_rms_k;
  return j;
}

}  // namespace

std::string FrameSummary::ToJson() const {
  // Text that is not UTF-8 (a path in another encoding in a note) is replaced, not thrown on;
  // JSON has no NaN or infinity: they are written as null.
  return SummaryJson(*this).dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
}

std::string FrameSummary::ToYaml() const {
  // From the JSON value, not its text: NaN and infinities stay numbers (.nan, .inf).
  return JsonAsYaml(SummaryJson(*this));
}

FrameSummary FrameSummary::FromYaml(const std::string& text, const std::string& where) {
  try {
    const YAML::Node n = YAML::Load(text);
    FrameSummary s;
    s.frame = n["frame"].as<std::size_t>();
    s.status = n["status"].as<std::string>();
    s.notes = n["notes"].as<std::vector<std::string>>();
    s.cameras_used = n["cameras_used"].as<int>();
    s.read_ms = n["read_ms"].as<double>();
    s.reconstruct_ms = n["reconstruct_ms"].as<double>();
    s.fit_ms = n["fit_ms"].as<double>();
    s.write_ms = n["write_ms"].as<double>();
    s.total_ms = n["total_ms"].as<double>();
    s.matrix_source = n["matrix_source"].as<std::string>();
    s.hull_fraction = n["hull_fraction"].as<double>();
    s.active_voxels = n["active_voxels"].as<std::size_t>();
    s.fit_evaluations = n["fit_evaluations"].as<int>();
    s.exposure = n["exposure"].as<double>();
    // Summaries written before the exposure was held have neither.
    s.exposure_from = n["exposure_from"].as<std::string>("");
    s.soot = n["soot"].as<double>(0.0);
    s.soot_volume_m3 = n["soot_volume_m3"].as<double>(0.0);  // 0 in summaries from before it
    s.energy = n["energy"].as<double>();
    // Summaries written before the fit reported why it stopped have none of these.
    s.fit_termination = n["fit_termination"].as<std::string>("");
    s.fit_message = n["fit_message"].as<std::string>("");
    s.fit_iterations = n["fit_iterations"].as<int>(0);
    s.initial_energy = n["initial_energy"].as<double>(0.0);
    // Summaries written before the voxels at the bounds were counted have none.
    s.voxels_at_temperature_bound = n["voxels_at_temperature_bound"].as<std::size_t>(0);
    s.voxels_at_density_bound = n["voxels_at_density_bound"].as<std::size_t>(0);
    for (const auto& d : n["delta_e"]) {
      ViewDeltaE v;
      v.camera = d["camera"].as<std::string>();
      v.held_out = d["held_out"].as<bool>();
      v.mean = d["mean"].as<double>();
      v.fire = d["fire"].as<double>();
      s.delta_e.push_back(v);
    }
    s.truth_rms_k = n["truth_rms_k"].as<double>();
    s.truth_bias_k = n["truth_bias_k"].as<double>();
    s.truth_spread_k = n["truth_spread_k"].as<double>(-1.0);              // none in older summaries
    s.truth_weighted_rms_k = n["truth_weighted_rms_k"].as<double>(-1.0);  // nor this
    s.truth_weighted_bias_k =  // nor this, which no sentinel can stand for: NaN, not 0
        n["truth_weighted_bias_k"].as<double>(std::numeric_limits<double>::quiet_NaN());
    s.truth_voxels = n["truth_voxels"].as<std::size_t>();
    s.truth_visible = n["truth_visible"].as<std::size_t>();
    s.truth_frame = n["truth_frame"].as<int>();
    s.truth_soot = n["truth_soot"].as<double>(0.0);
    s.truth_visible_soot = n["truth_visible_soot"].as<double>(0.0);
    s.visible_soot = n["visible_soot"].as<double>(0.0);
    s.limit_rms_k = n["limit_rms_k"].as<double>(-1.0);  // none before 2026-12-05
    s.limit_bias_k = n["limit_bias_k"].as<double>(0.0);
    s.limit_visible_soot = n["limit_visible_soot"].as<double>(0.0);
    s.limit_soot = n["limit_soot"].as<double>(0.0);
    // Summaries written before the sigma was scored have none.
    s.truth_within_1_sigma = n["truth_within_1_sigma"].as<double>(-1.0);
    s.truth_within_2_sigma = n["truth_within_2_sigma"].as<double>(-1.0);
    s.truth_median_sigma_k = n["truth_median_sigma_k"].as<double>(-1.0);
    // Summaries written before the determined voxels were scored apart have none.
    s.truth_determined_share = n["truth_determined_share"].as<double>(-1.0);
    s.truth_determined_rms_k = n["truth_determined_rms_k"].as<double>(-1.0);
    s.truth_undetermined_rms_k = n["truth_undetermined_rms_k"].as<double>(-1.0);
    return s;
  } catch (const YAML::Exception& e) {
    throw DataError(where + ": not a frame summary: " + e.what());
  }
}

std::string RunSummary::BriefReport() const {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(1);
  std::size_t failed_here = 0;
  double fit_ms = 0, tomo_ms = 0, de = 0;
  int de_n = 0;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const FrameSummary& f = frames[i];
    if (f.status.rfind("failed", 0) == 0) ++failed_here;
    if (i >= resumed) {  // the times of this call's frames, as `seconds` is this call's
      fit_ms += f.fit_ms;
      tomo_ms += f.reconstruct_ms;
    }
    if (!f.delta_e.empty()) {
      de += f.MeanFittedDeltaE();
      ++de_n;
    }
  }
  s << "frames " << begin << ".." << (end ? end - 1 : 0) << ": " << computed << " computed, "
    << unchanged << " unchanged (reused), " << resumed << " already done, " << failed_here
    << " failed";
  if (no_fire) s << ", " << no_fire << " without fire";
  s << (cancelled ? ", cancelled" : "") << "; " << seconds << " s";
  if (computed > 0)
    s << " (" << 60.0 * computed / std::max(seconds, 1e-9) << " computed frames/min; tomography "
      << tomo_ms / 1000 << " s, fit " << fit_ms / 1000 << " s)";
  s.precision(3);
  if (de_n) s << "; mean Delta E of the fitted views " << de / de_n;
  return s.str();
}

std::string PrepareRig(const RunOptions& options, const ProgressCallback& progress) {
  if (!options.rig_path.empty()) return options.rig_path;
  const fs::path dir = fs::path(options.out_dir) / "calibrated";
  const fs::path rig = dir / "rig.yaml";
  if (fs::exists(rig)) return rig.string();
  RunCalibration(options.calibrate, options.calibration, dir.string(), progress);
  return rig.string();
}

void RunRange(const RunOptions& options, const FrameSource& source, std::size_t* begin,
              std::size_t* end) {
  const std::size_t n = source.num_sets();
  if (options.first >= n)
    throw InputError("run: --first " + std::to_string(options.first) + " but " +
                     options.source.Describe() + " has " + std::to_string(n) + " frame sets");
  *begin = options.first;
  *end = options.first + std::min(options.count, n - options.first);
}

std::vector<FrameSummary> ReadFrameSummaries(const std::string& out_dir, std::size_t begin,
                                             std::size_t end) {
  const RunPaths paths{out_dir};
  std::vector<FrameSummary> out;
  for (std::size_t i = begin; i < end; ++i) {
    const fs::path p = paths.Summary(i);
    if (!fs::exists(p)) continue;
    out.push_back(FrameSummary::FromYaml(ReadFile(p.string()), p.string()));
  }
  return out;
}

RunSummary RunFrames(const RunOptions& options, const std::string& rig_path, std::size_t begin,
                     std::size_t end, const ProgressCallback& progress, FrameStages* stages_in) {
  using SteadyClock = std::chrono::steady_clock;
  const auto start = SteadyClock::now();
  options.Validate();
  std::unique_ptr<FrameStages> own;
  if (!stages_in) own = std::make_unique<FrameStages>(options, rig_path, begin);
  FrameStages& stages = stages_in ? *stages_in : *own;
  {
    std::size_t range_begin, range_end;
    RunRange(options, stages.source(), &range_begin, &range_end);
    if (begin < range_begin || end > range_end || begin > end)
      throw InputError("run: frames " + std::to_string(begin) + ".." + std::to_string(end) +
                       " are outside the range");
  }
  RunSummary run;
  run.begin = begin;
  run.end = end;
  run.rig_path = rig_path;

  // Resume: the first frame without a complete output, with the state saved after the one before.
  std::size_t next = begin;
  while (next < end && stages.paths().Complete(next)) ++next;
  run.frames = ReadFrameSummaries(options.out_dir, begin, next);
  run.resumed = next - begin;
  for (const auto& f : run.frames) {
    run.failed += f.status.rfind("failed", 0) == 0;
    run.no_fire += f.status == "no fire";
  }
  stages.Resume(next);

  // The inner stages report their own progress through the run's callback; a cancel there (or at
  // a frame's end) stops the run.
  bool cancelled = false;
  const ProgressCallback inner = [&](const Progress& p) {
    if (ReportProgress(progress, p)) cancelled = true;
    return cancelled ? ProgressAction::kCancel : ProgressAction::kContinue;
  };
  for (std::size_t i = next; i < end && !cancelled; ++i) {
    FrameWork w;
    w.index = i;
    w.start = SteadyClock::now();
    w.summary.frame = i;
    try {
      stages.Read(&w);
      if (stages.SkipUnchanged(&w)) {
        stages.Reuse(&w);
      } else {
        stages.Reconstruct(&w, inner);
        stages.Fit(&w, inner);
        stages.Write(&w);
      }
      stages.Score(&w);
    } catch (const DataError& e) {
      stages.Fail(&w, e.what());
    } catch (const Cancelled&) {
      cancelled = true;  // nothing of this frame is committed: a resumed run computes it
      break;
    }
    stages.Commit(&w);
    if (w.unchanged) {
      ++run.unchanged;
    } else if (w.no_fire && w.have_output) {
      ++run.no_fire;
    } else if (w.have_output) {
      ++run.computed;
    } else {
      ++run.failed;
    }
    run.frames.push_back(std::move(w.summary));
    Progress p;
    p.stage = "frames";
    p.unit = "frames";
    p.done = static_cast<std::int64_t>(i + 1 - begin);
    p.total = static_cast<std::int64_t>(end - begin);
    p.message = run.frames.back().Line();
    if (ReportProgress(progress, p)) cancelled = true;
  }
  run.cancelled = cancelled;
  run.seconds = std::chrono::duration<double>(SteadyClock::now() - start).count();
  return run;
}

}  // namespace flamerig
