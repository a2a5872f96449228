#include "pipeline/run.h"

#include <fcntl.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "core/error.h"
#include "acquisition/recording.h"
#include "fitting/renderer.h"
#include "tomography/vdb_io.h"
#include "pipeline/blender_export.h"
#include "pipeline/fit_report.h"
#include "pipeline/simulate.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

using SteadyClock = std::chrono::steady_clock;
double Ms(SteadyClock::time_point since) {
  return std::chrono::duration<double, std::milli>(SteadyClock::now() - since).count();
}

// Writes `text` to `path` through a temporary file, flushed to disk before the rename, so that a
// file under its final name is always whole.
void WriteFileAtomically(const fs::path& path, const std::string& text) {
  const fs::path tmp = path.string() + ".tmp";
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw IoError(path.string() + ": cannot write");
  std::size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n <= 0) {
      ::close(fd);
      fs::remove(tmp);
      throw IoError(path.string() + ": write failed (disk full?)");
    }
    done += static_cast<std::size_t>(n);
  }
  ::fdatasync(fd);
  ::close(fd);
  fs::rename(tmp, path);
}

// Flushes a file that is already complete (written by a library) to disk.
void SyncFile(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd >= 0) {
    ::fdatasync(fd);
    ::close(fd);
  }
}

// Copies a file under a temporary name, then renames it.
void CopyAtomically(const fs::path& from, const fs::path& to) {
  const fs::path tmp = to.string() + ".tmp";
  fs::copy_file(from, tmp, fs::copy_options::overwrite_existing);
  SyncFile(tmp);
  fs::rename(tmp, to);
}

// WriteVdb writes and renames; this makes the result durable before anything refers to it.
void WriteVolume(const fs::path& path, const FireVolume& volume) {
  WriteVdb(path.string(), volume);
  SyncFile(path);
}

struct Paths {
  fs::path out;
  fs::path Volume(std::size_t i) const { return out / (FrameName(i) + ".vdb"); }
  fs::path Summary(std::size_t i) const { return out / "frames" / (FrameName(i) + ".yaml"); }
  fs::path Picture(std::size_t i) const { return out / "frames" / (FrameName(i) + ".png"); }
  fs::path Tomography(std::size_t i) const { return out / "tomography" / (FrameName(i) + ".vdb"); }
  fs::path Blender(std::size_t i) const { return out / "blender" / (FrameName(i) + ".vdb"); }
  fs::path StateYaml(std::size_t i) const { return out / "state" / (FrameName(i) + ".yaml"); }
  fs::path StateBin(std::size_t i) const { return out / "state" / (FrameName(i) + ".state"); }
  bool Complete(std::size_t i) const { return fs::exists(Summary(i)); }
};

// What the next frame starts from, saved after every frame (state/frame_NNNNNN.yaml).
struct ChainState {
  long long previous_result = -1;  // frame whose .vdb warm-starts the fit; -1 = cold
  long long last_computed = -1;    // frame whose tomography and images were computed last
};

std::string ChainYaml(const ChainState& s) {
  std::ostringstream o;
  o << "previous_result: " << s.previous_result << "\nlast_computed: " << s.last_computed << "\n";
  return o.str();
}

ChainState ReadChain(const fs::path& path) {
  try {
    const YAML::Node n = YAML::LoadFile(path.string());
    ChainState s;
    s.previous_result = n["previous_result"].as<long long>();
    s.last_computed = n["last_computed"].as<long long>();
    return s;
  } catch (const YAML::Exception& e) {
    throw DataError(path.string() + ": cannot resume from this state file: " + e.what());
  }
}

// The truth volumes DIR/frame_NNNNNN.vdb, counted from 0 up to the first gap.
std::size_t CountTruth(const std::string& dir) {
  if (dir.empty()) return 0;
  std::size_t n = 0;
  while (fs::exists(fs::path(dir) / (FrameName(n) + ".vdb"))) ++n;
  if (n == 0) throw InputError("--truth " + dir + ": no frame_000000.vdb there");
  return n;
}

FitResult ResultFromVolume(const fs::path& path) {
  FitResult r;
  r.volume = ReadVdb(path.string());
  auto it = r.volume.metadata_numbers.find("exposure");
  if (r.volume.temperature_k.empty() || r.volume.density_per_m3.empty() ||
      it == r.volume.metadata_numbers.end())
    throw DataError(path.string() +
                             ": not a flamerig run output (temperature, density, exposure)");
  r.exposure = it->second;
  return r;
}

}  // namespace

std::string FrameName(std::size_t i) {
  char name[32];
  std::snprintf(name, sizeof name, "frame_%06zu", i);
  return name;
}

bool DatasetExposure(const std::string& rig_path, double* exposure) {
  const fs::path dataset = fs::path(rig_path).parent_path() / "dataset.yaml";
  if (!fs::exists(dataset)) return false;
  try {
    const YAML::Node root = YAML::LoadFile(dataset.string());
    if (root["dataset"] && root["dataset"]["exposure"]) {
      *exposure = root["dataset"]["exposure"].as<double>();
      return true;
    }
  } catch (const YAML::Exception& e) {
    throw InputError(dataset.string() + ": " + e.what());
  }
  return false;
}

std::string DatasetAbsorption(const std::string& rig_path) {
  const fs::path dataset = fs::path(rig_path).parent_path() / "dataset.yaml";
  if (!fs::exists(dataset)) return "soot";
  try {
    const YAML::Node root = YAML::LoadFile(dataset.string());
    if (root["dataset"] && root["dataset"]["absorption"])
      return root["dataset"]["absorption"].as<std::string>();
  } catch (const YAML::Exception& e) {
    throw InputError(dataset.string() + ": " + e.what());
  }
  return "soot";
}

void RunOptions::Validate() const {
  source.Validate();
  if (rig_path.empty() && calibration.images_dir.empty() && calibration.recording_dir.empty())
    throw InputError("run: give a rig (--rig) or a calibration to make one");
  if (out_dir.empty()) throw InputError("run: give an output folder (--out)");
  if (count == 0) throw InputError("run: count must be >= 1");
  if (!(exposure >= 0) || !std::isfinite(exposure))
    throw InputError("run: exposure must be finite and >= 0 (0 = from the dataset)");
  if (!absorption.empty() && absorption != "soot" && absorption != "grey")
    throw InputError("run: absorption '" + absorption + "': use soot or grey");
  ReconstructOptions r = reconstruct;
  r.exposure = 1;
  r.Validate();
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
  if (status == "computed" || status.rfind("unchanged", 0) == 0) {
    s << ", " << cameras_used << " camera(s), " << total_ms << " ms (read " << read_ms
      << ", tomography " << reconstruct_ms << ", fit " << fit_ms << ", write " << write_ms << ")";
    s.precision(3);
    s << ", Delta E";
    for (const auto& d : delta_e) s << " " << d.camera << (d.held_out ? "*" : "") << " " << d.fire;
    s << ", " << active_voxels << " active voxels";
    if (!matrix_source.empty()) s << ", matrix " << matrix_source;
    s.precision(1);
    if (truth_rms_k >= 0) s << ", T error " << truth_rms_k << " K RMS on visible voxels";
  }
  for (const auto& n : notes) s << "; " << n;
  return s.str();
}

std::string FrameSummary::ToYaml() const {
  YAML::Emitter e;
  e.SetDoublePrecision(9);
  e << YAML::BeginMap;
  e << YAML::Key << "frame" << YAML::Value << frame;
  e << YAML::Key << "status" << YAML::Value << status;
  e << YAML::Key << "notes" << YAML::Value << YAML::Flow << notes;
  e << YAML::Key << "cameras_used" << YAML::Value << cameras_used;
  e << YAML::Key << "read_ms" << YAML::Value << read_ms;
  e << YAML::Key << "reconstruct_ms" << YAML::Value << reconstruct_ms;
  e << YAML::Key << "fit_ms" << YAML::Value << fit_ms;
  e << YAML::Key << "write_ms" << YAML::Value << write_ms;
  e << YAML::Key << "total_ms" << YAML::Value << total_ms;
  e << YAML::Key << "matrix_source" << YAML::Value << matrix_source;
  e << YAML::Key << "hull_fraction" << YAML::Value << hull_fraction;
  e << YAML::Key << "active_voxels" << YAML::Value << active_voxels;
  e << YAML::Key << "fit_evaluations" << YAML::Value << fit_evaluations;
  e << YAML::Key << "exposure" << YAML::Value << exposure;
  e << YAML::Key << "energy" << YAML::Value << energy;
  e << YAML::Key << "delta_e" << YAML::Value << YAML::BeginSeq;
  for (const auto& d : delta_e) {
    e << YAML::Flow << YAML::BeginMap << YAML::Key << "camera" << YAML::Value << d.camera
      << YAML::Key << "held_out" << YAML::Value << d.held_out << YAML::Key << "mean" << YAML::Value
      << d.mean << YAML::Key << "fire" << YAML::Value << d.fire << YAML::EndMap;
  }
  e << YAML::EndSeq;
  e << YAML::Key << "truth_rms_k" << YAML::Value << truth_rms_k;
  e << YAML::Key << "truth_bias_k" << YAML::Value << truth_bias_k;
  e << YAML::Key << "truth_voxels" << YAML::Value << truth_voxels;
  e << YAML::Key << "truth_visible" << YAML::Value << truth_visible;
  e << YAML::Key << "truth_frame" << YAML::Value << truth_frame;
  e << YAML::EndMap;
  return std::string(e.c_str()) + "\n";
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
    s.energy = n["energy"].as<double>();
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
    s.truth_voxels = n["truth_voxels"].as<std::size_t>();
    s.truth_visible = n["truth_visible"].as<std::size_t>();
    s.truth_frame = n["truth_frame"].as<int>();
    return s;
  } catch (const YAML::Exception& e) {
    throw DataError(where + ": not a frame summary: " + e.what());
  }
}

std::string RunSummary::BriefReport() const {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(1);
  std::size_t failed = 0;
  double fit_ms = 0, tomo_ms = 0, de = 0;
  int de_n = 0;
  for (const auto& f : frames) {
    if (f.status.rfind("failed", 0) == 0) ++failed;
    fit_ms += f.fit_ms;
    tomo_ms += f.reconstruct_ms;
    if (!f.delta_e.empty()) {
      de += f.MeanFittedDeltaE();
      ++de_n;
    }
  }
  s << "frames " << begin << ".." << (end ? end - 1 : 0) << ": " << computed << " computed, "
    << unchanged << " unchanged (reused), " << resumed << " already done, " << failed << " failed; "
    << seconds << " s";
  if (computed > 0)
    s << " (" << 60.0 * computed / std::max(seconds, 1e-9) << " computed frames/min; tomography "
      << tomo_ms / 1000 << " s, fit " << fit_ms / 1000 << " s)";
  s.precision(3);
  if (de_n) s << "; mean Delta E of the fitted views " << de / de_n;
  return s.str();
}

std::string PrepareRig(const RunOptions& options, const CalibrationProgress& progress) {
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
                                options.source.Describe() + " has " + std::to_string(n) +
                                " frame sets");
  *begin = options.first;
  *end = options.first + std::min(options.count, n - options.first);
}

std::vector<FrameSummary> ReadFrameSummaries(const std::string& out_dir, std::size_t begin,
                                             std::size_t end) {
  Paths paths{out_dir};
  std::vector<FrameSummary> out;
  for (std::size_t i = begin; i < end; ++i) {
    const fs::path p = paths.Summary(i);
    if (!fs::exists(p)) continue;
    std::ifstream in(p);
    std::stringstream text;
    text << in.rdbuf();
    out.push_back(FrameSummary::FromYaml(text.str(), p.string()));
  }
  return out;
}

RunSummary RunFrames(const RunOptions& options_in, const std::string& rig_path, std::size_t begin,
                     std::size_t end, const RunProgressCallback& progress) {
  const auto start = SteadyClock::now();
  RunOptions options = options_in;
  options.Validate();
  const Rig rig = Rig::Load(rig_path);
  FrameSource source(options.source, rig);
  {
    std::size_t range_begin, range_end;
    RunRange(options, source, &range_begin, &range_end);
    if (begin < range_begin || end > range_end || begin > end)
      throw InputError("run: frames " + std::to_string(begin) + ".." +
                                  std::to_string(end) + " are outside the range");
  }
  double exposure = options.exposure;
  if (!(exposure > 0) && !DatasetExposure(rig_path, &exposure)) exposure = 1.0;
  const std::string absorption_name =
      options.absorption.empty() ? DatasetAbsorption(rig_path) : options.absorption;
  const AbsorptionModel absorption = AbsorptionModel::FromName(absorption_name);
  int holdout = -1;
  if (!options.holdout_camera.empty()) {
    holdout = rig.FindCamera(options.holdout_camera);
    if (holdout < 0)
      throw InputError("run: held-out camera '" + options.holdout_camera +
                                  "' is not in " + rig_path);
  }
  ReconstructOptions ro = options.reconstruct;
  ro.exposure = exposure;
  ro.holdout_camera.clear();  // the held-out camera stays out of the tomography too
  if (ro.cache_dir.empty()) ro.cache_dir = (fs::path(options.out_dir) / "cache").string();
  Reconstructor reconstructor(rig, ro);
  std::vector<std::unique_ptr<CameraRays>> rays;
  for (const auto& c : rig.cameras) rays.push_back(std::make_unique<CameraRays>(c.model));
  const std::size_t truth_count = CountTruth(options.truth_dir);

  const Paths paths{options.out_dir};
  for (const char* sub : {"frames", "tomography", "state", "blender"})
    fs::create_directories(paths.out / sub);

  RunSummary run;
  run.begin = begin;
  run.end = end;
  run.rig_path = rig_path;

  // Resume: the first frame without a complete output, with the state saved after the one before.
  std::size_t next = begin;
  while (next < end && paths.Complete(next)) ++next;
  run.frames = ReadFrameSummaries(options.out_dir, begin, next);
  run.resumed = next - begin;
  ChainState chain;
  FitResult previous;
  FireVolume last_tomography;
  std::vector<ImageU8> last_images;
  if (next > begin) {
    chain = ReadChain(paths.StateYaml(next - 1));
    if (chain.previous_result >= 0) {
      previous = ResultFromVolume(paths.Volume(chain.previous_result));
      // The grid as the reconstructor has it, not as the file's transform rounds it.
      if (previous.volume.geometry.SameVoxels(reconstructor.grid()))
        previous.volume.geometry = reconstructor.grid();
    }
    if (chain.last_computed >= 0) {
      last_tomography = ReadVdb(paths.Tomography(chain.last_computed).string());
      last_images = source.Read(static_cast<std::size_t>(chain.last_computed), exposure).images;
      reconstructor.LoadState(paths.StateBin(next - 1).string());
    }
  }

  for (std::size_t i = next; i < end; ++i) {
    const auto frame_start = SteadyClock::now();
    FrameSummary s;
    s.frame = i;
    auto t0 = SteadyClock::now();
    SourceFrameSet set;
    std::string failure;
    try {
      set = source.Read(i, exposure);
    } catch (const RecordingError& e) {
      failure = e.what();
    } catch (const InputError& e) {
      failure = e.what();
    }
    s.read_ms = Ms(t0);
    s.notes = set.notes;
    s.cameras_used = set.present();
    if (holdout >= 0 && failure.empty() && set.images[holdout].empty())
      s.notes.push_back("held-out camera " + options.holdout_camera + " has no frame");
    if (truth_count && failure.empty())
      s.truth_frame = static_cast<int>(set.frame_id % truth_count);

    // Did anything change since the last computed frame?
    bool unchanged = false;
    if (failure.empty() && options.skip_unchanged && chain.last_computed >= 0 &&
        chain.previous_result >= 0 && last_images.size() == set.images.size()) {
      unchanged = true;
      for (std::size_t c = 0; unchanged && c < set.images.size(); ++c) {
        if (set.images[c].empty() != last_images[c].empty()) unchanged = false;
        if (!unchanged || set.images[c].empty()) continue;
        const ImageChange change = CompareImages(set.images[c], last_images[c], options.unchanged);
        unchanged = change.changed_fraction <= options.unchanged.max_changed_fraction;
      }
    }

    FireVolume fitted;
    bool have_output = false;
    if (!failure.empty()) {
      s.status = "failed: " + failure;
    } else if (unchanged) {
      t0 = SteadyClock::now();
      const std::size_t from = static_cast<std::size_t>(chain.previous_result);
      CopyAtomically(paths.Volume(from), paths.Volume(i));
      if (options.blender && fs::exists(paths.Blender(from)))
        CopyAtomically(paths.Blender(from), paths.Blender(i));
      if (options.pictures && fs::exists(paths.Picture(from)))
        CopyAtomically(paths.Picture(from), paths.Picture(i));
      s.write_ms = Ms(t0);
      const std::vector<FrameSummary> reused = ReadFrameSummaries(options.out_dir, from, from + 1);
      if (!reused.empty()) {
        s.delta_e = reused[0].delta_e;
        s.active_voxels = reused[0].active_voxels;
        s.exposure = reused[0].exposure;
        s.energy = reused[0].energy;
      }
      s.status = "unchanged (reused frame " + std::to_string(chain.last_computed) + ")";
      if (truth_count) fitted = previous.volume;  // what was just copied
      have_output = true;
    } else {
      // Tomography from the fitted views.
      std::vector<LinearFrame> linear = set.linear;
      if (holdout >= 0) linear[holdout] = LinearFrame();
      t0 = SteadyClock::now();
      FireVolume tomography;
      ReconstructSummary rs;
      try {
        tomography = reconstructor.Reconstruct(
            linear, &rs, chain.last_computed >= 0 ? &last_tomography : nullptr);
      } catch (const InputError& e) {
        failure = std::string("tomography: ") + e.what();
      }
      s.reconstruct_ms = Ms(t0);
      s.matrix_source = rs.matrix_source;
      s.hull_fraction = rs.voxel_fraction_in_hull;
      if (rs.fire_pixels_outside_envelope)
        s.notes.push_back(std::to_string(rs.fire_pixels_outside_envelope) +
                          " fire pixels outside the matrix's envelope left out");
      // The fit, warm-started from the previous result.
      std::vector<FitView> views, held;
      for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
        if (set.images[c].empty()) continue;
        FitView v;
        v.name = rig.cameras[c].name;
        v.rays = rays[c].get();
        v.image = set.images[c];
        (static_cast<int>(c) == holdout ? held : views).push_back(std::move(v));
      }
      FitResult result;
      t0 = SteadyClock::now();
      if (failure.empty()) {
        try {
          result = FastFit(reconstructor.grid(), tomography, views, absorption, options.fit,
                           chain.previous_result >= 0 && options.warm_start ? &previous : nullptr);
        } catch (const InputError& e) {
          failure = std::string("fit: ") + e.what();
        }
      }
      s.fit_ms = Ms(t0);
      if (!failure.empty()) {
        s.status = "failed: " + failure;
      } else {
        t0 = SteadyClock::now();
        std::vector<ImageU8> rendered;
        const std::vector<ViewScore> scores =
            WriteFitReport("", result, views, held, absorption, options.fit.render, "", &rendered);
        for (const auto& sc : scores)
          s.delta_e.push_back(ViewDeltaE{sc.name, sc.held_out, sc.mean_delta_e, sc.fire_delta_e});
        result.volume.metadata_text["absorption_model"] = absorption.name();
        result.volume.metadata_numbers["frame"] = static_cast<double>(i);
        result.volume.metadata_numbers["source_frame_id"] = static_cast<double>(set.frame_id);
        WriteVolume(paths.Volume(i), result.volume);
        WriteVolume(paths.Tomography(i), tomography);
        if (options.blender) WriteBlenderVdb(paths.Blender(i).string(), result.volume, absorption);
        if (options.pictures) {
          // Input over rendered, camera by camera (fitted views, then the held-out one).
          std::vector<ImageU8> inputs;
          for (const auto& v : views) inputs.push_back(v.image);
          for (const auto& v : held) inputs.push_back(v.image);
          const ImageU8 top = ContactSheet(inputs, 180), bottom = ContactSheet(rendered, 180);
          ImageU8 picture(std::max(top.width, bottom.width), top.height + bottom.height + 4, 3, 16);
          for (int y = 0; y < top.height; ++y)
            for (int x = 0; x < top.width; ++x)
              for (int c = 0; c < 3; ++c) picture.at(x, y, c) = top.at(x, y, c);
          for (int y = 0; y < bottom.height; ++y)
            for (int x = 0; x < bottom.width; ++x)
              for (int c = 0; c < 3; ++c) picture.at(x, top.height + 4 + y, c) = bottom.at(x, y, c);
          const fs::path tmp = paths.Picture(i).string() + ".tmp.png";
          WritePng(tmp.string(), picture);
          fs::rename(tmp, paths.Picture(i));
        }
        s.write_ms = Ms(t0);
        s.status = "computed";
        s.active_voxels = result.active_voxels;
        s.fit_evaluations = result.evaluations;
        s.exposure = result.exposure;
        s.energy = result.final_terms.exact_energy();
        fitted = std::move(result.volume);
        have_output = true;
        previous = std::move(result);
        previous.volume = fitted;
        last_tomography = std::move(tomography);
        last_images = set.images;
        chain.last_computed = static_cast<long long>(i);
        chain.previous_result = static_cast<long long>(i);
      }
    }
    if (unchanged) chain.previous_result = static_cast<long long>(i);
    if (!failure.empty()) {
      // The next frame starts cold: a failed frame has no output to start from.
      chain.previous_result = -1;
    }
    if (have_output && truth_count) {
      const FireVolume truth =
          ReadVdb((fs::path(options.truth_dir) / (FrameName(s.truth_frame) + ".vdb")).string());
      const TruthError t = CompareWithTruth(truth, fitted);
      if (t.compared && t.counted) {
        s.truth_rms_k = t.rms_k;
        s.truth_bias_k = t.mean_k;
      } else if (!t.compared) {
        s.notes.push_back("truth not compared: " + t.why_not);
      }
      s.truth_voxels = t.counted;
      s.truth_visible = t.visible;
    }
    s.total_ms = Ms(frame_start);
    // Commit: the state for the next frame, then the summary (the mark of a complete frame).
    WriteFileAtomically(paths.StateYaml(i), ChainYaml(chain));
    if (chain.last_computed >= 0) reconstructor.SaveState(paths.StateBin(i).string());
    WriteFileAtomically(paths.Summary(i), s.ToYaml());
    if (i > begin) {
      std::error_code ec;
      fs::remove(paths.StateYaml(i - 1), ec);
      fs::remove(paths.StateBin(i - 1), ec);
    }
    if (unchanged) {
      ++run.unchanged;
    } else if (have_output) {
      ++run.computed;
    }
    run.frames.push_back(std::move(s));
    if (progress) {
      RunProgress p;
      p.done = i + 1 - begin;
      p.total = end - begin;
      p.elapsed_s = std::chrono::duration<double>(SteadyClock::now() - start).count();
      const std::size_t done_here = i + 1 - next;
      p.eta_s = p.elapsed_s / done_here * (end - i - 1);
      p.last = &run.frames.back();
      progress(p);
    }
  }
  run.seconds = std::chrono::duration<double>(SteadyClock::now() - start).count();
  return run;
}

}  // namespace flamerig
