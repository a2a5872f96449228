#include "pipeline/frame_stages.h"

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <sstream>
#include <string>

#include "core/atomic_file.h"
#include "core/error.h"
#include "core/format.h"
#include "core/log.h"
#include "pipeline/blender_export.h"
#include "pipeline/fit_report.h"
#include "pipeline/picture.h"
#include "pipeline/truth.h"
#include "tomography/vdb_io.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

using SteadyClock = std::chrono::steady_clock;
double Ms(SteadyClock::time_point since) {
  return std::chrono::duration<double, std::milli>(SteadyClock::now() - since).count();
}

std::string In(const std::string& out, const char* sub, std::size_t i, const char* ext) {
  return (fs::path(out) / sub / (FrameName(i) + ext)).string();
}

// WriteVdb writes and renames; this makes the result durable before anything refers to it.
void WriteVolume(const std::string& path, const FireVolume& volume) {
  WriteVdb(path, volume);
  SyncFile(path);
}

// The truth volumes DIR/frame_NNNNNN.vdb, counted from 0 up to the first gap.
std::size_t CountTruth(const std::string& dir) {
  if (dir.empty()) return 0;
  std::size_t n = 0;
  while (fs::exists(fs::path(dir) / (FrameName(n) + ".vdb"))) ++n;
  if (n == 0) throw InputError("--truth " + dir + ": no frame_000000.vdb there");
  return n;
}

FitResult ResultFromVolume(const std::string& path) {
  FitResult r;
  r.volume = ReadVdb(path);
  auto it = r.volume.metadata_numbers.find("exposure");
  if (r.volume.temperature_k.empty() || r.volume.density_per_m3.empty() ||
      it == r.volume.metadata_numbers.end())
    throw DataError(path + ": not a flamerig run output (temperature, density, exposure)");
  r.exposure = it->second;
  return r;
}

// Input over rendered, camera by camera, each column named.
ImageU8 InputOverRendered(const std::vector<std::string>& names, const std::vector<ImageU8>& inputs,
                          const std::vector<ImageU8>& rendered) {
  PictureGrid grid;
  grid.column_labels = names;
  grid.row_labels = {"input", "rendered from the fit"};
  grid.rows = {inputs, rendered};
  grid.tile_height = names.size() > 4 ? 120 : 180;  // eight cameras stay under 2000 px wide
  return DrawPictureGrid(grid);
}

}  // namespace

std::string RunPaths::Volume(std::size_t i) const {
  return (fs::path(out) / (FrameName(i) + ".vdb")).string();
}
std::string RunPaths::Summary(std::size_t i) const { return In(out, "frames", i, ".yaml"); }
std::string RunPaths::Picture(std::size_t i) const { return In(out, "frames", i, ".png"); }
std::string RunPaths::Profile(std::size_t i) const { return In(out, "frames", i, "_profile.csv"); }
std::string RunPaths::Tomography(std::size_t i) const { return In(out, "tomography", i, ".vdb"); }
std::string RunPaths::Blender(std::size_t i) const { return In(out, "blender", i, ".vdb"); }
std::string RunPaths::StateYaml(std::size_t i) const { return In(out, "state", i, ".yaml"); }
std::string RunPaths::StateBin(std::size_t i) const { return In(out, "state", i, ".state"); }
bool RunPaths::Complete(std::size_t i) const {
  std::error_code ec;
  if (!fs::exists(Summary(i), ec)) return false;
  const auto size = fs::file_size(Volume(i), ec);
  if (!ec && size > 0) return true;
  try {  // no volume: complete only as a failed frame's record
    return ReadFrameSummaries(out, i, i + 1).at(0).status.rfind("failed", 0) == 0;
  } catch (const std::exception&) {
    return false;  // a summary that does not read: the frame is computed again
  }
}

FrameStages::FrameStages(const RunOptions& options, const std::string& rig_path, std::size_t begin)
    : options_(options),
      begin_(begin),
      rig_(WithInputTransfer(Rig::Load(rig_path), options.input_transfer)),
      source_(options.source, rig_),
      paths_{options.out_dir},
      absorption_(AbsorptionModel::FromName(options.absorption.empty() ? DatasetAbsorption(rig_path)
                                                                       : options.absorption)) {
  options_.Validate();
  ImagesExposure exposure =
      ResolveExposure(options_.exposure, rig_path, options_.source.images_dir);
  // A recording (or its export) through a rig whose radiometric calibration gave its exposure
  // unit, or of a dataset that states one: from the reference camera's settings at the start.
  ExposureFromReference([&] { return source_.exposure_reference(); }, rig_, rig_path, &exposure);
  exposure_ = exposure.value;
  exposure_known_ = exposure.known;
  if (exposure_known_ && !options_.fit_exposure) HeldExposure(exposure, options_.fit, "run");
  if (exposure_known_)
    Log().info("run: the take's exposure {} ({}){}", FormatNumber(exposure_, 6), exposure.from,
               options_.fit_exposure ? ", a start; fitted" : ", held");
  if (!options_.holdout_camera.empty()) {
    holdout_ = rig_.FindCamera(options_.holdout_camera);
    if (holdout_ < 0)
      throw InputError("run: held-out camera '" + options_.holdout_camera + "' is not in " +
                       rig_path);
  }
  ReconstructOptions ro = options_.reconstruct;
  if (!ro.stop_camera.empty() && ro.stop_camera == options_.holdout_camera)
    throw InputError("run: camera '" + ro.stop_camera +
                     "' cannot both stop the tomography and be held out (give another stop "
                     "camera)");
  ro.exposure = exposure_;
  ro.holdout_camera.clear();  // the held-out camera stays out of the tomography too
  if (ro.cache_dir.empty()) ro.cache_dir = (fs::path(options_.out_dir) / "cache").string();
  reconstructor_ = std::make_unique<Reconstructor>(rig_, ro);
  for (const auto& c : rig_.cameras) {
    rays_.push_back(std::make_unique<CameraRays>(c.model));
    responses_.push_back(ChannelResponse::ForCamera(c.radiometry));
  }
  // Mono cameras in several bands (two-colour pyrometry): a tomography per band as well.
  Responses fitted;
  for (std::size_t c = 0; c < rig_.cameras.size(); ++c)
    if (static_cast<int>(c) != holdout_) fitted.push_back(responses_[c]);
  if (!GroupByBand(fitted).empty())
    band_reconstructor_ = std::make_unique<BandReconstructor>(rig_, ro);
  truth_count_ = CountTruth(options_.truth_dir);
  if (truth_count_ && !options_.truth_rig.empty()) {
    const RigRegistration r = RegisterTruth(options_.truth_rig, rig_);
    fit_from_truth_ = r.to_from_from;
    Log().info("run: the truth's rig {} lies in this rig's frame {}", options_.truth_rig,
               r.Describe());
  }
  {
    const FitOptions& f = options_.fit;
    std::ostringstream key;
    key.precision(17);
    key << "absorption " << absorption_.name() << ", exposure " << exposure_
        << (exposure_known_ ? " known" : " unknown") << (options_.fit_exposure ? " fitted" : "")
        << ", held out '" << options_.holdout_camera << "', warm_start " << options_.warm_start
        << ", sigma " << options_.sigma << ", input_transfer '" << options_.input_transfer
        << "', per-frame exposure against the first camera's start; " << f.Key();
    fit_key_ = key.str();
  }
  for (const char* sub : {"frames", "tomography", "state"})
    fs::create_directories(fs::path(options_.out_dir) / sub);
  if (options_.blender) fs::create_directories(fs::path(options_.out_dir) / "blender");
}

FrameStages::~FrameStages() = default;

void FrameStages::Resume(std::size_t next) {
  // Every state file in OUT (the last frame of each range a run committed) says the options its
  // frames were fitted with; absent from a run before 2026-12-01, taken as this run's.
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(fs::path(options_.out_dir) / "state", ec)) {
    if (entry.path().extension() != ".yaml") continue;
    std::string saved = fit_key_;
    try {
      saved = YAML::LoadFile(entry.path().string())["fit_options"].as<std::string>(fit_key_);
    } catch (const YAML::Exception&) {
      continue;  // one that does not read is refused below if this run needs it
    }
    if (saved != fit_key_)
      throw InputError(options_.out_dir + " holds frames fitted with other options (" +
                       entry.path().string() + ": " + saved + "; this run: " + fit_key_ +
                       "): give another --out, or remove it to fit them again");
  }
  if (next <= begin_) return;
  const std::string state = paths_.StateYaml(next - 1);
  if (!fs::exists(state)) {
    // Only the last committed frame keeps its state: a frame before it whose volume has gone
    // since starts cold, as after a failed frame.
    Log().warn("run: {} is computed again (its volume is gone) and starts cold", FrameName(next));
    return;
  }
  try {
    const YAML::Node n = YAML::LoadFile(state);
    chain_.previous_result = n["previous_result"].as<long long>();
    chain_.last_computed = n["last_computed"].as<long long>();
    take_exposure_ = n["take_exposure"].as<double>(0.0);
    take_exposure_frame_ = n["take_exposure_frame"].as<long long>(-1);
  } catch (const YAML::Exception& e) {
    throw DataError(state + ": cannot resume from this state file: " + e.what());
  }
  if (chain_.previous_result >= 0) {
    previous_ = ResultFromVolume(paths_.Volume(chain_.previous_result));
    // The grid as the reconstructor has it, not as the file's transform rounds it.
    if (previous_.volume.geometry.SameVoxels(reconstructor_->grid()))
      previous_.volume.geometry = reconstructor_->grid();
  }
  if (chain_.last_computed >= 0) {
    last_tomography_ = ReadVdb(paths_.Tomography(chain_.last_computed));
    last_images_ = source_.Read(static_cast<std::size_t>(chain_.last_computed), exposure_).images;
    reconstructor_->LoadState(paths_.StateBin(next - 1));
  }
}

void FrameStages::Read(FrameWork* w) {
  const auto t0 = SteadyClock::now();
  FrameSummary& s = w->summary;
  try {
    w->set = source_.Read(w->index, exposure_);
  } catch (...) {
    s.read_ms = Ms(t0);
    throw;
  }
  s.read_ms = Ms(t0);
  s.notes = w->set.notes;
  s.cameras_used = w->set.present();
  if (s.cameras_used < static_cast<int>(rig_.cameras.size())) {
    std::string why;
    for (const std::string& n : s.notes) why += "; " + n;
    Log().warn("run: {}: {} of the rig's {} cameras have an image{}", FrameName(w->index),
               s.cameras_used, rig_.cameras.size(), why);
  }
  // A frame's own change against its camera's start (a camera started at other settings than
  // the take's reference is said once, in the source's notes).
  for (std::size_t c = 0; c < w->set.exposure_ratio.size(); ++c) {
    const double start =
        c < w->set.exposure_start_ratio.size() ? w->set.exposure_start_ratio[c] : 1.0;
    if (std::abs(w->set.exposure_ratio[c] / start - 1) > kExposureChange)
      Log().info("run: {}: {} exposed at {:.3g} times its start: fitted so", FrameName(w->index),
                 rig_.cameras[c].name, w->set.exposure_ratio[c] / start);
  }
  for (std::size_t c = 0; c < w->set.exposure_unknown.size(); ++c)
    if (w->set.exposure_unknown[c])
      Log().warn(
          "run: {}: {}'s exposure changed by a factor its record does not give: this set's "
          "densities are not on the take's scale (its note says why)",
          FrameName(w->index), rig_.cameras[c].name);
  if (holdout_ >= 0 && w->set.images[holdout_].empty())
    s.notes.push_back("held-out camera " + options_.holdout_camera + " has no frame");
  if (truth_count_) s.truth_frame = static_cast<int>(w->set.frame_id % truth_count_);
}

bool FrameStages::SkipUnchanged(FrameWork* w) {
  if (!options_.skip_unchanged || chain_.last_computed < 0 || chain_.previous_result < 0 ||
      last_images_.size() != w->set.images.size())
    return false;
  for (std::size_t c = 0; c < w->set.images.size(); ++c) {
    if (w->set.images[c].empty() != last_images_[c].empty()) return false;
    if (w->set.images[c].empty()) continue;
    const ImageChange change = CompareImages(w->set.images[c], last_images_[c], options_.unchanged);
    if (change.changed_fraction > options_.unchanged.max_changed_fraction) return false;
  }
  w->unchanged = true;
  return true;
}

void FrameStages::Reuse(FrameWork* w) {
  const auto t0 = SteadyClock::now();
  FrameSummary& s = w->summary;
  const std::size_t from = static_cast<std::size_t>(chain_.previous_result);
  // The volume it reuses, under this frame's own number and set id, and the frame it came from
  // (a byte copy said it was that frame, 2026-12-02).
  FireVolume volume = ReadVdb(paths_.Volume(from));
  volume.metadata_numbers["frame"] = static_cast<double>(w->index);
  volume.metadata_numbers["source_frame_id"] = static_cast<double>(w->set.frame_id);
  volume.metadata_numbers["reused_from_frame"] = static_cast<double>(from);
  WriteVolume(paths_.Volume(w->index), volume);
  if (options_.blender)
    WriteBlenderVdb(paths_.Blender(w->index), volume, absorption_, rig_.up_in_rig);
  if (options_.pictures && fs::exists(paths_.Picture(from)))
    CopyFileAtomically(paths_.Picture(from), paths_.Picture(w->index));
  if (options_.fit.axisymmetric && fs::exists(paths_.Profile(from)))
    CopyFileAtomically(paths_.Profile(from), paths_.Profile(w->index));
  else
    fs::remove(paths_.Profile(w->index));  // none from an earlier run into the same OUT
  s.write_ms = Ms(t0);
  std::vector<FrameSummary> reused;
  try {
    reused = ReadFrameSummaries(options_.out_dir, from, from + 1);
  } catch (const DataError& e) {  // the copies are made: a note, not a failed frame
    s.notes.push_back(std::string("figures of frame ") + std::to_string(from) +
                      " not copied: " + e.what());
  }
  if (!reused.empty()) {
    const FrameSummary& r = reused[0];
    s.delta_e = r.delta_e;
    s.active_voxels = r.active_voxels;
    s.exposure = r.exposure;
    s.exposure_from = r.exposure_from;
    s.soot = r.soot;
    s.soot_volume_m3 = r.soot_volume_m3;
    s.energy = r.energy;
    s.fit_termination = r.fit_termination;
    s.fit_message = r.fit_message;
    s.fit_iterations = r.fit_iterations;
    s.initial_energy = r.initial_energy;
    s.voxels_at_temperature_bound = r.voxels_at_temperature_bound;
    s.voxels_at_density_bound = r.voxels_at_density_bound;
  }
  s.status = "unchanged (reused frame " + std::to_string(chain_.last_computed) + ")";
  scored_ = previous_.volume;  // what was just copied
  w->have_output = true;
  chain_.previous_result = static_cast<long long>(w->index);
}

bool FrameStages::WarmStart() const {
  // An axisymmetric fit starts cold (RunOptions::warm_start says why).
  return options_.warm_start && !options_.fit.axisymmetric;
}

std::shared_ptr<const ChannelResponse> FrameStages::ResponseOf(const SourceFrameSet& set,
                                                               std::size_t c) const {
  return ChannelResponse::Exposed(responses_[c],
                                  c < set.exposure_ratio.size() ? set.exposure_ratio[c] : 1.0);
}

void FrameStages::Reconstruct(FrameWork* w, const ProgressCallback& progress) {
  std::vector<LinearFrame> linear = w->set.linear;
  if (holdout_ >= 0) linear[holdout_] = LinearFrame();
  const auto t0 = SteadyClock::now();
  ReconstructSummary rs;
  FrameSummary& s = w->summary;
  // A black tomography (the last computed frame held no fire) is no start.
  const bool warm = WarmStart() && chain_.last_computed >= 0 &&
                    std::any_of(last_tomography_.emission_rgb.begin(),
                                last_tomography_.emission_rgb.end(), [](float e) { return e > 0; });
  try {
    w->tomography =
        reconstructor_->Reconstruct(linear, &rs, warm ? &last_tomography_ : nullptr, progress);
  } catch (const DataError& e) {
    s.reconstruct_ms = Ms(t0);
    throw DataError(std::string("tomography: ") + e.what());
  }
  if (band_reconstructor_) {
    Responses responses;
    std::vector<int> rig_index;
    for (std::size_t c = 0; c < rig_.cameras.size(); ++c)
      if (!linear[c].radiance.empty()) {
        responses.push_back(ResponseOf(w->set, c));
        rig_index.push_back(static_cast<int>(c));
      }
    std::string report;
    try {
      w->bands = band_reconstructor_->Reconstruct(responses, rig_index, linear, &report, progress);
    } catch (const DataError& e) {
      s.reconstruct_ms = Ms(t0);
      throw DataError(std::string("tomography of a band: ") + e.what());
    }
    if (!w->bands.empty())
      s.notes.push_back("two-colour start from " + std::to_string(w->bands.size()) +
                        " bands' tomographies");
  }
  s.reconstruct_ms = Ms(t0);
  for (const CameraMaskSummary& m : rs.masks)
    if (!m.held_out) w->fire_pixels.emplace_back(m.camera, m.fire_pixels);
  s.matrix_source = rs.matrix_source;
  s.hull_fraction = rs.voxel_fraction_in_hull;
  if (!rs.stop_camera.empty() && !rs.solves.empty()) {
    const SolveSummary& fine = rs.solves.back();
    s.notes.push_back("tomography stopped on " + rs.stop_camera + " (best iterate " +
                      std::to_string(fine.best_iteration) + " of " +
                      std::to_string(fine.iterations) + ")");
  }
  if (rs.fire_pixels_outside_envelope)
    s.notes.push_back(std::to_string(rs.fire_pixels_outside_envelope) +
                      " fire pixels outside the matrix's envelope left out");
  if (rs.box_face_light_share > ReconstructSummary::kBoxFaceWarning)
    s.notes.push_back(std::to_string(std::lround(100 * rs.box_face_light_share)) +
                      "% of the light on the box's faces (" + rs.box_faces_lit +
                      "): the box cuts the fire");
}

void FrameStages::Fit(FrameWork* w, const ProgressCallback& progress) {
  for (std::size_t c = 0; c < rig_.cameras.size(); ++c) {
    if (w->set.images[c].empty()) continue;
    FitView v;
    v.name = rig_.cameras[c].name;
    v.rays = rays_[c].get();
    v.image = w->set.images[c];
    v.signal = w->set.signal[c];
    v.response = ResponseOf(w->set, c);
    if (options_.fit.objective.model_mosaic)
      v.mosaic = MakeBayerRecord(w->set.mosaic[c], w->set.radiometry[c], v.name, w->set.bits[c]);
    (static_cast<int>(c) == holdout_ ? w->held : w->views).push_back(std::move(v));
  }
  // The exposure: known, the take's, or fitted here (and the take's from here on).
  FitOptions fit = options_.fit;
  fit.estimate_uncertainty = fit.estimate_uncertainty || options_.sigma;
  std::string& from = w->summary.exposure_from;
  if (options_.fit_exposure) {
    from = "fitted (free)";
  } else if (exposure_known_) {
    fit.known_exposure = exposure_;
    from = "known";
  } else if (take_exposure_ > 0) {
    fit.known_exposure = take_exposure_;
    from = "held from frame " + std::to_string(take_exposure_frame_);
  } else {
    from = "fitted";
  }
  const auto t0 = SteadyClock::now();
  bool nothing = false;  // FastFit found no active voxel: the images hold no fire (or a fault)
  try {
    w->result = FastFit(reconstructor_->grid(), w->tomography, w->views, absorption_, fit,
                        WarmStart() && chain_.previous_result >= 0 ? &previous_ : nullptr, progress,
                        w->bands);
  } catch (const NoActiveVoxelsError&) {
    nothing = true;
  } catch (const DataError& e) {
    w->summary.fit_ms = Ms(t0);
    throw DataError(std::string("fit: ") + e.what());
  }
  w->summary.fit_ms = Ms(t0);
  if (nothing) {
    // Which cameras see fire, and how much of it.
    std::string seen, dark;
    int seeing = 0;
    for (const auto& [camera, pixels] : w->fire_pixels)
      if (pixels > 0) {
        seen += (seeing++ ? ", " : "") + camera + " (" + std::to_string(pixels) + " pixels)";
      } else {
        dark += (dark.empty() ? "" : ", ") + camera;
      }
    const int min_views =
        std::min<int>(options_.reconstruct.hull.min_views, static_cast<int>(w->fire_pixels.size()));
    if (seeing >= std::max(min_views, 1))
      throw DataError("fit: the tomography is black although " + seen +
                      " see fire: their views of it do not meet inside the box (is the rig or "
                      "the box wrong" +
                      (dark.empty()
                           ? std::string()
                           : ", or is the fire hidden from " + dark + ", which sees none") +
                      "?)");
    w->no_fire = true;
    if (seeing == 0) {
      w->summary.notes.push_back("no camera sees fire");
    } else {
      // One camera's fire alone may be a fault of the others (a lens cap, a dead sensor): said.
      w->summary.notes.push_back("only " + seen + " sees fire, where " + std::to_string(min_views) +
                                 " cameras must (the visual hull's min_views)");
      Log().warn("run: {}: {}", FrameName(w->index), w->summary.notes.back());
    }
    // The exposure as a fit would hold it; none fitted. Not known yet: a placeholder, said so.
    if (fit.known_exposure <= 0) from = fmt::format("none (no fire; {:g} written)", exposure_);
    w->result = NoFireResult(reconstructor_->grid(), absorption_, fit,
                             fit.known_exposure > 0 ? fit.known_exposure : exposure_);
    return;
  }
  MeasureRingHeights(rig_.up_in_rig, &w->result.ring_profile);
  if (w->result.termination == FitTermination::kCancelled) throw Cancelled("run: cancelled");
}

void FrameStages::Write(FrameWork* w) {
  const auto t0 = SteadyClock::now();
  FrameSummary& s = w->summary;
  FitResult& result = w->result;
  std::vector<ImageU8> rendered;
  if (w->no_fire) {  // nothing rendered: black, and no Delta E (there are no fire pixels)
    for (const std::vector<FitView>* views : {&w->views, &w->held})
      for (const FitView& v : *views) rendered.emplace_back(v.image.width, v.image.height, 3);
  } else {
    const std::vector<ViewScore> scores = WriteFitReport("", result, w->views, w->held, absorption_,
                                                         options_.fit.render, "", &rendered);
    for (const auto& sc : scores)
      s.delta_e.push_back(ViewDeltaE{sc.name, sc.held_out, sc.mean_delta_e, sc.fire_delta_e});
  }
  result.volume.metadata_numbers["frame"] = static_cast<double>(w->index);
  result.volume.metadata_numbers["source_frame_id"] = static_cast<double>(w->set.frame_id);
  WriteVolume(paths_.Volume(w->index), result.volume);
  WriteVolume(paths_.Tomography(w->index), w->tomography);
  if (options_.blender)
    WriteBlenderVdb(paths_.Blender(w->index), result.volume, absorption_, rig_.up_in_rig);
  if (!result.ring_profile.empty())
    WriteRingProfileCsv(paths_.Profile(w->index), result.ring_profile);
  else
    fs::remove(paths_.Profile(w->index));  // none from an earlier run into the same OUT
  if (options_.pictures) {
    // Input over rendered, camera by camera (fitted views, then the held-out one).
    std::vector<ImageU8> inputs;
    std::vector<std::string> names;
    for (const auto& v : w->views) {
      inputs.push_back(v.image);
      names.push_back(v.name + " (fitted)");
    }
    for (const auto& v : w->held) {
      inputs.push_back(v.image);
      names.push_back(v.name + " (held out)");
    }
    AtomicFile picture(paths_.Picture(w->index));
    WritePng(picture.temp_path(), InputOverRendered(names, inputs, rendered));
    picture.Commit();
  }
  s.write_ms = Ms(t0);
  s.status = w->no_fire ? "no fire" : "computed";
  s.active_voxels = result.active_voxels;
  s.fit_evaluations = result.evaluations;
  s.exposure = result.exposure;
  s.soot = TotalSoot(result.volume);
  if (const auto it = result.volume.metadata_numbers.find("soot_volume_m3");
      it != result.volume.metadata_numbers.end())
    s.soot_volume_m3 = it->second;
  // The take's exposure from here on (not a failed fit's).
  if (s.exposure_from == "fitted" && result.termination != FitTermination::kFailed) {
    take_exposure_ = result.exposure;
    take_exposure_frame_ = static_cast<long long>(w->index);
  }
  s.energy = result.final_terms.exact_energy();
  s.fit_termination = ToString(result.termination);
  s.fit_message = result.message;
  s.fit_iterations = result.iterations;
  s.initial_energy = result.initial_energy;
  s.voxels_at_temperature_bound = result.voxels_at_temperature_bound;
  s.voxels_at_density_bound = result.voxels_at_density_bound;
  w->have_output = true;
  scored_ = result.volume;
  previous_ = std::move(result);
  last_tomography_ = std::move(w->tomography);
  last_images_ = w->set.images;
  chain_.last_computed = static_cast<long long>(w->index);
  // No fire: the next frame's fit starts cold (and its tomography too: Reconstruct).
  chain_.previous_result = w->no_fire ? -1 : static_cast<long long>(w->index);
}

void FrameStages::Score(FrameWork* w) {
  if (!w->have_output || !truth_count_) return;
  FrameSummary& s = w->summary;
  if (w->no_fire) {
    s.notes.push_back("no fire: not compared with the truth");
    return;
  }
  // The frame's output is written: a truth that cannot be read is a note, not a failed frame.
  FireVolume truth;
  try {
    truth = ReadVdb((fs::path(options_.truth_dir) / (FrameName(s.truth_frame) + ".vdb")).string());
  } catch (const DataError& e) {
    s.notes.push_back(std::string("truth not compared: ") + e.what());
    return;
  }
  const TruthError t = CompareWithTruth(truth, scored_, fit_from_truth_);
  if (t.compared && t.counted) {
    s.truth_rms_k = t.rms_k;
    s.truth_bias_k = t.mean_k;
    s.truth_spread_k = t.truth_spread_k;
    s.truth_weighted_rms_k = t.weighted_rms_k;
    s.truth_weighted_bias_k = t.weighted_mean_k;
    s.truth_soot = t.truth_soot;
    s.truth_visible_soot = t.truth_visible_soot;
    s.visible_soot = t.fit_visible_soot;
    if (t.have_sigma) {
      s.truth_within_1_sigma = t.within_1_sigma;
      s.truth_within_2_sigma = t.within_2_sigma;
      s.truth_median_sigma_k = t.median_sigma_k;
      if (t.have_determined) {
        s.truth_determined_share = t.determined_share;
        s.truth_determined_rms_k = t.determined_rms_k;
        s.truth_undetermined_rms_k = t.undetermined_rms_k;
      }
    }
  } else if (!t.compared) {
    s.notes.push_back("truth not compared: " + t.why_not);
  }
  s.truth_voxels = t.counted;
  s.truth_visible = t.visible;
  // A tied frame's profile gains the truth's ring means, as `fit --truth`'s does.
  const std::string profile = paths_.Profile(w->index);
  std::vector<RingProfilePoint> rings;
  bool rings_read = true;
  if (t.compared && truth.HasTemperatureAndDensity() && fs::exists(profile)) {
    try {
      rings = ReadRingProfileCsv(profile);
      const std::vector<RingTruth> on_rings =
          TruthOnRings(truth, scored_.geometry, rings, fit_from_truth_);
      WriteRingProfileCsv(profile, rings, &on_rings);
    } catch (const DataError& e) {
      s.notes.push_back(std::string("truth not put on the profile, nor the rings' limit scored: ") +
                        e.what());
      rings_read = false;
    }
  }
  // The fit's limit: the truth as its grid (or its rings) could at best show it.
  if (rings_read && t.compared && t.counted) {
    const TruthError limit =
        CompareLimitWithTruth(truth, scored_, absorption_, rings, fit_from_truth_);
    if (limit.compared && limit.counted) {
      s.limit_rms_k = limit.rms_k;
      s.limit_bias_k = limit.mean_k;
      s.limit_visible_soot = limit.fit_visible_soot;
      s.limit_soot = limit.fit_soot;
    }
  }
}

void FrameStages::Fail(FrameWork* w, const std::string& what) {
  w->summary.status = "failed: " + what;
  // At error level, so that `run -q` says why beside its count of failed frames.
  Log().error("run: {}: failed: {}", FrameName(w->index), what);
  w->summary.exposure_from.clear();  // no output, no exposure
  w->have_output = false;
  chain_.previous_result = -1;  // a failed frame has no output to start from
}

void FrameStages::Commit(FrameWork* w) {
  const std::size_t i = w->index;
  w->summary.total_ms = Ms(w->start);
  std::ostringstream chain;
  chain.precision(17);
  chain << "previous_result: " << chain_.previous_result
        << "\nlast_computed: " << chain_.last_computed << "\ntake_exposure: " << take_exposure_
        << "\ntake_exposure_frame: " << take_exposure_frame_ << "\nfit_options: \"" << fit_key_
        << "\"\n";
  WriteFileAtomically(paths_.StateYaml(i), chain.str());
  if (chain_.last_computed >= 0) reconstructor_->SaveState(paths_.StateBin(i));
  WriteFileAtomically(paths_.Summary(i), w->summary.ToYaml());
  if (i > begin_) {
    std::error_code ec;
    fs::remove(paths_.StateYaml(i - 1), ec);
    fs::remove(paths_.StateBin(i - 1), ec);
  }
}

}  // namespace flamerig
