#include "pipeline/fit_job.h"

#include <filesystem>
#include <memory>

#include "core/error.h"
#include "core/format.h"
#include "core/log.h"
#include "pipeline/band_tomography.h"
#include "pipeline/frame_source.h"
#include "pipeline/run.h"
#include "tomography/vdb_io.h"

namespace flamerig {

namespace fs = std::filesystem;

const char* ToString(FitMethod method) {
  switch (method) {
    case FitMethod::kFast:
      return "fast";
    case FitMethod::kAlgorithm1:
      return "alg1";
    case FitMethod::kAlgorithm2:
      return "alg2";
  }
  return "?";
}

FitJobResult RunFitJob(const FitJob& job, const ProgressCallback& progress) {
  // Files needed at the end are checked before the work.
  for (const auto& [path, option] :
       {std::pair{job.truth_path, "--truth"}, std::pair{job.tomography_path, "--tomography"}})
    if (!path.empty() && !fs::is_regular_file(path))
      throw InputError(path + " (" + option + "): no such file");
  if (!job.truth_rig.empty() && job.truth_path.empty())
    throw InputError("fit: a truth rig (--truth-rig) without a truth (--truth) to move");
  const Rig rig = WithInputTransfer(Rig::Load(job.rig_path), job.input_transfer);
  const RigRegistration truth_frame = RegisterTruth(job.truth_rig, rig);
  ImagesExposure images_exposure = ResolveExposure(job.exposure, job.rig_path, job.images_dir);
  ExposureFromReference([&] { return ReadExportedReference(job.images_dir); }, rig, job.rig_path,
                        &images_exposure);
  const double exposure = images_exposure.value;
  // The fast fit holds a known exposure: checked before any work.
  FitOptions fit = job.fit;
  fit.estimate_uncertainty = fit.estimate_uncertainty || job.uncertainty;
  if (job.method == FitMethod::kFast && images_exposure.known && !job.fit_exposure)
    fit.known_exposure = HeldExposure(images_exposure, fit, "fit");
  if (job.method == FitMethod::kFast && !images_exposure.known)
    Log().warn(
        "fit: the images' exposure is unknown (no --exposure, no recorded settings through a rig "
        "that knows its exposure unit, and no dataset.yaml beside the rig "
        "or the images): the fit finds one, and the densities are relative to it, not absolute");
  else if (images_exposure.known)
    Log().info("fit: the images' exposure {} ({}){}", FormatNumber(images_exposure.value, 6),
               images_exposure.from, fit.known_exposure > 0 ? ", held" : ", a start; fitted");
  const AbsorptionModel absorption = AbsorptionModel::FromName(
      job.absorption.empty() ? DatasetAbsorption(job.rig_path) : job.absorption);
  const SourceFrameSet set = ReadFrameFolder(rig, job.images_dir, exposure);

  // Views: the job's, else every camera with an image but the held-out one.
  std::vector<std::string> names = job.views;
  auto camera_index = [&](const std::string& name) {
    const int c = rig.FindCamera(name);
    if (c < 0) throw InputError(job.rig_path + ": no camera named '" + name + "'");
    return c;
  };
  if (names.empty())
    for (std::size_t c = 0; c < rig.cameras.size(); ++c)
      if (!set.images[c].empty() && rig.cameras[c].name != job.holdout)
        names.push_back(rig.cameras[c].name);
  for (std::size_t i = 0; i < names.size(); ++i) {
    if (names[i] == job.holdout)
      throw UsageError("--views and --holdout both name '" + job.holdout +
                       "': a view is fitted or held out");
    for (std::size_t j = 0; j < i; ++j)
      if (names[j] == names[i]) throw UsageError("--views names '" + names[i] + "' twice");
  }
  std::vector<std::unique_ptr<CameraRays>> rays(rig.cameras.size());
  auto make_view = [&](const std::string& name) {
    const int c = camera_index(name);
    if (set.images[c].empty())
      throw InputError("fit: camera '" + name + "' has no image in " + job.images_dir);
    if (!rays[c]) rays[c] = std::make_unique<CameraRays>(rig.cameras[c].model);
    FitView v;
    v.name = name;
    v.rays = rays[c].get();
    v.image = set.images[c];
    v.signal = set.signal[c];
    // At the frame's own exposure, as the set's linear frames were decoded (an exported set of a
    // take whose camera was re-exposed: frame_source.h).
    v.response = ChannelResponse::Exposed(ChannelResponse::ForCamera(rig.cameras[c].radiometry),
                                          set.exposure_ratio.at(c));
    if (set.exposure_unknown.at(c))
      Log().warn(
          "fit: camera '{}' changed its exposure by a factor its record does not give: its "
          "densities are not on the take's scale",
          name);
    if (job.fit.objective.model_mosaic)
      v.mosaic = MakeBayerRecord(set.mosaic[c], set.radiometry[c], name, set.bits[c]);
    return v;
  };
  std::vector<FitView> views, held;
  for (const auto& name : names) views.push_back(make_view(name));
  if (!job.holdout.empty()) held.push_back(make_view(job.holdout));
  if (views.empty()) throw InputError("fit: no views to fit");

  FitJobResult out;
  ReconstructOptions ro = job.reconstruct;
  ro.exposure = exposure;
  if (job.resolution > 0) ro.resolution = job.resolution;
  // The tomography: from a file, or reconstructed here from the fitted views only. A mono rig in
  // several bands has one per band for the two-colour start instead (reconstructed also beside a
  // tomography from a file, which holds no bands): the fit reads the bands, and of a tomography
  // of all its cameras together, which mixes bands, only the exposure.
  FireVolume tomography;
  std::vector<BandTomography> bands;
  const Responses responses = ResponsesOf(views);
  const bool band_rig = job.method == FitMethod::kFast && !GroupByBand(responses).empty();
  if (!job.tomography_path.empty()) {
    tomography = ReadVdb(job.tomography_path);
    if (tomography.emission_rgb.empty())
      throw InputError("--tomography " + job.tomography_path +
                       ": has no 'emission' grid (a tomography's; a fitted volume has temperature "
                       "and density instead)");
    out.tomography = "file " + job.tomography_path;
  } else if (!band_rig) {
    std::vector<LinearFrame> used(rig.cameras.size());
    for (const auto& v : views) used[camera_index(v.name)] = set.linear[camera_index(v.name)];
    Reconstructor reconstructor(rig, ro);
    ReconstructSummary rs;
    tomography = reconstructor.Reconstruct(used, &rs, nullptr, progress);
    out.tomography = "from " + std::to_string(views.size()) + " view(s): " + rs.BriefReport();
  }
  if (band_rig) {
    std::vector<int> rig_index;
    for (const auto& v : views) rig_index.push_back(camera_index(v.name));
    std::string report;
    bands =
        BandReconstructor(rig, ro).Reconstruct(responses, rig_index, set.linear, &report, progress);
    if (job.tomography_path.empty()) tomography = bands.front().tomography;
    out.tomography += (out.tomography.empty() ? "" : "\n") + report;
  }
  const GridGeometry grid = GridGeometry::FromBox(rig.box, ro.resolution);
  try {
    if (job.method == FitMethod::kFast) {
      out.result = FastFit(grid, tomography, views, absorption, fit, nullptr, progress, bands);
    } else {
      PaperFitOptions paper = job.paper;
      paper.algorithm = job.method == FitMethod::kAlgorithm1 ? PaperAlgorithm::kPerVoxelDensity
                                                             : PaperAlgorithm::kDensityScale;
      out.result = PaperFit(grid, tomography, views, absorption, job.fit, paper, progress);
    }
  } catch (const NoActiveVoxelsError& e) {
    // A set without fire: nothing to fit, and nothing written (`run` writes such a set of a take
    // as an empty volume, so that its sequence has no gap).
    throw NoActiveVoxelsError(
        (job.tomography_path.empty() ? job.images_dir : job.tomography_path) +
        ": no fire to fit, nothing written to " + job.out_path + " (" + e.what() +
        "; `flamerig run` writes a take's sets without fire as empty volumes)");
  }
  MeasureRingHeights(rig.up_in_rig, &out.result.ring_profile);
  if (fs::path(job.out_path).has_parent_path())
    fs::create_directories(fs::path(job.out_path).parent_path());
  WriteVdb(job.out_path, out.result.volume);
  out.report_dir = !job.report_dir.empty() ? job.report_dir
                                           : (fs::path(job.out_path).parent_path() /
                                              (fs::path(job.out_path).stem().string() + "_report"))
                                                 .string();
  FireVolume truth;
  if (!job.truth_path.empty()) {
    truth = ReadVdb(job.truth_path);
    out.truth_frame = truth_frame;
    out.have_truth = true;
    out.truth = CompareWithTruth(truth, out.result.volume, out.truth_frame.to_from_from);
    out.limit = CompareLimitWithTruth(truth, out.result.volume, absorption, out.result.ring_profile,
                                      out.truth_frame.to_from_from);
  }
  out.scores =
      WriteFitReport(out.report_dir, out.result, views, held, absorption, job.fit.render,
                     std::string("flamerig fit (") + ToString(job.method) + ")", nullptr,
                     out.have_truth ? &truth : nullptr, out.truth_frame.to_from_from, rig.up_in_rig,
                     out.have_truth ? &out.truth : nullptr, out.have_truth ? &out.limit : nullptr);
  return out;
}

}  // namespace flamerig
