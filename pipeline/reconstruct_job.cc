#include "pipeline/reconstruct_job.h"

#include <fmt/format.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>

#include "core/error.h"
#include "fitting/renderer.h"
#include "pipeline/frame_source.h"
#include "pipeline/picture.h"
#include "pipeline/report_page.h"
#include "pipeline/run.h"
#include "pipeline/truth.h"
#include "tomography/vdb_io.h"

namespace flamerig {

namespace fs = std::filesystem;

ReconstructJobResult RunReconstructJob(const ReconstructJob& job,
                                       const ProgressCallback& progress) {
  if (!job.truth_path.empty() && !fs::is_regular_file(job.truth_path))
    throw InputError(job.truth_path + " (--truth): no such file");
  ReconstructJobResult out;
  ReconstructOptions options = job.reconstruct;
  out.exposure_source = "default 1";
  if (job.exposure > 0) {
    options.exposure = job.exposure;
    out.exposure_source = "--exposure";
  } else if (DatasetExposure(job.rig_path, &options.exposure)) {
    out.exposure_source = "dataset.yaml";
  } else {
    options.exposure = 1;
  }
  out.exposure = options.exposure;
  const Rig rig = Rig::Load(job.rig_path);
  const SourceFrameSet set = ReadFrameFolder(rig, job.images_dir, options.exposure);
  out.notes = set.notes;
  if (!options.holdout_camera.empty()) {
    const int h = rig.FindCamera(options.holdout_camera);
    if (h >= 0 && set.images[h].empty())
      throw InputError("held-out camera '" + options.holdout_camera + "' has no image in " +
                       job.images_dir + ": nothing to score on");
  }
  Reconstructor reconstructor(rig, options);
  FireVolume volume = reconstructor.Reconstruct(set.linear, &out.summary, nullptr, progress);
  volume.metadata_text["exposure_source"] = out.exposure_source;
  if (fs::path(job.out_path).has_parent_path())
    fs::create_directories(fs::path(job.out_path).parent_path());
  WriteVdb(job.out_path, volume);
  ImageU8 views;
  if (!job.preview_path.empty() || !job.report_dir.empty()) {
    // Each camera: its input, the reconstruction rendered back through it, and 4x their difference.
    PictureGrid grid;
    grid.column_labels = {"input", "reconstruction rendered back", "|difference| x 4"};
    for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
      const ImageU8& input = set.images[c];
      if (input.empty()) continue;
      const ImageU8 rendered =
          ApplyCameraResponse(RenderThinEmission(volume.geometry, volume.emission_rgb,
                                                 CameraRays(rig.cameras[c].model)),
                              options.exposure);
      ImageU8 difference(rendered.width, rendered.height, 3);
      for (std::size_t p = 0; p < difference.pixels.size(); ++p)
        difference.pixels[p] = static_cast<std::uint8_t>(
            std::min(255, 4 * std::abs(int(input.pixels[p]) - int(rendered.pixels[p]))));
      grid.row_labels.push_back(rig.cameras[c].name);
      grid.rows.push_back({input, rendered, difference});
    }
    views = DrawPictureGrid(grid);
    if (!job.preview_path.empty()) WritePng(job.preview_path, views);
  }
  if (!job.truth_path.empty())
    out.truth_error = EmissionError(volume, ReadVdb(job.truth_path), job.truth_path);
  if (!job.report_dir.empty()) {
    fs::create_directories(job.report_dir);
    WritePng((fs::path(job.report_dir) / "views.png").string(), views);
    ReportPage page("flamerig reconstruct",
                    {{"rig", job.rig_path}, {"images", job.images_dir}, {"volume", job.out_path}});
    page.Section("Tomography");
    page.Text(out.summary.BriefReport());
    std::vector<std::string> facts = {"Exposure " + std::to_string(out.exposure) + " (" +
                                      HtmlEscape(out.exposure_source) + ")."};
    for (const auto& n : out.notes) facts.push_back(HtmlEscape(n));
    if (out.truth_error >= 0) {
      facts.push_back(fmt::format(
          "Relative L2 error of the emission against the truth (<code>{}</code>): <b>{:.4f}</b>.",
          HtmlEscape(job.truth_path), out.truth_error));
    }
    page.List(facts);
    page.Section("Views");
    page.Figure("views.png",
                "Each camera: its input, the reconstructed emission rendered back through it (thin "
                "limit), and their absolute difference times 4.");
    page.Write((fs::path(job.report_dir) / "index.html").string());
  }
  return out;
}

}  // namespace flamerig
