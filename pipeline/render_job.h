// `flamerig render --rig`: a fitted volume (temperature and density) or a reconstruction (an
// emission grid) seen by every camera of a rig, as 8-bit images a camera would record.
#ifndef FLAMERIG_PIPELINE_RENDER_JOB_H_
#define FLAMERIG_PIPELINE_RENDER_JOB_H_

#include <string>
#include <vector>

#include "core/progress.h"
#include "fitting/renderer.h"

namespace flamerig {

struct RenderJob {
  std::string rig_path;
  std::string volume_path;
  std::string out_dir;        // OUT/<camera>.png
  std::string absorption;     // soot | grey; "" = the volume's metadata, else soot
  double exposure = 0;        // 0 = the volume's metadata "exposure", else 1
  RenderOptions render;
};

struct RenderedView {
  std::string path;
  RenderSummary summary;  // empty for an emission volume (the thin-limit projection)
};

// Renders every rig camera. A volume with temperature and density goes through the physical
// renderer; one with only an emission grid (a reconstruction) is projected in the thin limit, as
// the tomography models it. Throws InputError for a volume with neither, DataError for a damaged
// one, IoError for images that cannot be written; Cancelled between cameras when asked.
std::vector<RenderedView> RunRenderJob(const RenderJob& job,
                                       const ProgressCallback& progress = nullptr);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_RENDER_JOB_H_
