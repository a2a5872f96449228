#include "pipeline/render_job.h"

#include <cmath>
#include <filesystem>
#include <string>

#include "core/error.h"
#include "core/log.h"
#include "tomography/reconstruct.h"
#include "tomography/vdb_io.h"

namespace flamerig {

namespace fs = std::filesystem;

std::vector<RenderedView> RunRenderJob(const RenderJob& job, const ProgressCallback& progress) {
  const Rig rig = Rig::Load(job.rig_path);
  const FireVolume volume = ReadVdb(job.volume_path);
  const bool physical = !volume.temperature_k.empty() && !volume.density_per_m3.empty();
  if (!physical && volume.emission_rgb.empty())
    throw InputError(job.volume_path +
                     ": needs 'temperature' and 'density' grids, or an 'emission' grid, to render");
  double exposure = job.exposure;
  if (!(exposure > 0)) {
    auto it = volume.metadata_numbers.find("exposure");
    if (it == volume.metadata_numbers.end()) {
      exposure = 1.0;
      Log().info("render: {} states no exposure: rendered at 1", job.volume_path);
    } else if (!(it->second > 0) || !std::isfinite(it->second)) {
      throw InputError(job.volume_path + ": its metadata's exposure " + std::to_string(it->second) +
                       " must be finite and > 0 (give --exposure to render it at another)");
    } else {
      exposure = it->second;
    }
  }
  std::string absorption_name = job.absorption;
  if (absorption_name.empty()) {
    auto it = volume.metadata_text.find("absorption_model");
    absorption_name = it != volume.metadata_text.end() ? it->second : "soot";
  }
  std::unique_ptr<FireRenderer> renderer;
  if (physical) {
    renderer =
        std::make_unique<FireRenderer>(AbsorptionModel::FromName(absorption_name), job.render);
    renderer->SetVolume(volume.geometry, volume.temperature_k, volume.density_per_m3);
  }
  fs::create_directories(job.out_dir);
  std::vector<RenderedView> out;
  for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
    const CameraRays rays(rig.cameras[c].model);
    ImageF linear;
    RenderedView view;
    if (physical)
      view.summary = renderer->Render(rays, &linear);
    else
      linear = RenderThinEmission(volume.geometry, volume.emission_rgb, rays);
    view.path = (fs::path(job.out_dir) / (rig.cameras[c].name + ".png")).string();
    WritePng(view.path, ApplyCameraResponse(linear, exposure));
    out.push_back(view);
    Progress p;
    p.stage = "render";
    p.unit = "cameras";
    p.done = static_cast<std::int64_t>(c + 1);
    p.total = static_cast<std::int64_t>(rig.cameras.size());
    if (ReportProgress(progress, p) && c + 1 < rig.cameras.size())
      throw Cancelled("render: cancelled");
  }
  return out;
}

}  // namespace flamerig
