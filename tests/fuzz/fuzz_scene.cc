// The scene file of `flamerig render --scene` (pipeline/scene_job.h), read and built (Embree) but not
// rendered: errors are flamerig::Error (core/error.h) naming the file and key, or a volume or mesh
// file. Next to the scene file the seeds refer to: fire.vdb (a small fire) and
// mesh.obj (a triangle), written once.
#include "tests/fuzz/fuzz_util.h"
#include "tests/fuzz/small_fire.h"
#include "tomography/vdb_io.h"
#include "pipeline/scene_job.h"

namespace {

void WriteNeighbours() {
  const flamerig::FireVolume v = flamerig_fuzz::SmallFire(Eigen::Vector3i(4, 4, 4), 21);
  flamerig::WriteVdb((flamerig_fuzz::Dir() / "fire.vdb").string(), v);
  const std::string obj = "v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nf 1 2 3\n";
  flamerig_fuzz::WriteFile("mesh.obj", reinterpret_cast<const std::uint8_t*>(obj.data()),
                           obj.size());
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const bool ready = (WriteNeighbours(), true);
  (void)ready;
  const std::string path = flamerig_fuzz::WriteFile("scene.yaml", data, size);
  try {
    flamerig::SceneJob::Load(path);
  } catch (const std::runtime_error&) {
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
