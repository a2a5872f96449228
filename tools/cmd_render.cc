// `flamerig render`: a volume through a rig's cameras (pipeline/render_job.h), or fires lighting a
// scene (pipeline/scene_job.h).
#include <tbb/global_control.h>

#include <cstdio>
#include <memory>

#include "core/error.h"
#include "pipeline/render_job.h"
#include "pipeline/scene_job.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddRender(CLI::App* command) {
  struct Options {
    std::string rig, volume, out, exposure = "auto", absorption;
    double step = 0;
    std::string scene, lighting;
    int samples = 0, threads = 0;
    std::int64_t seed = -1;
  };
  auto o = std::make_shared<Options>();
  command->footer(
      "Render every rig camera's view of a volume to OUT/<camera>.png: a fit's temperature and\n"
      "density through the renderer, or a reconstruction's emission in the thin limit.\n"
      "With --scene: fitted fires lighting a virtual scene (config/scene_candle.yaml); the fire's\n"
      "own emission lights the surfaces. OUT/fire.exr (linear HDR), fire.png (Reinhard 2002 tone\n"
      "mapping), fire_linear.png; --lighting compare adds point and sphere lights (compare.png).");
  command->add_option("--rig", o->rig, "Rig file (rig.yaml)")->type_name("RIG.yaml");
  command
      ->add_option("--volume", o->volume,
                   "Volume to render (.vdb); with --scene, replaces the "
                   "scene's fire volume")
      ->type_name("V.vdb");
  command->add_option("--out", o->out, "Output folder")->required()->type_name("DIR");
  command->add_option("--exposure", o->exposure, "Camera exposure, or auto (the volume's)")
      ->type_name("S|auto")
      ->check(ExposureRange(/*or_auto=*/true));
  command->add_option("--absorption", o->absorption, "Absorption model (default: the volume's)")
      ->check(CLI::IsMember({"soot", "grey"}));
  command->add_option("--step", o->step, "Ray-marching step in voxels (default 0.5)")
      ->type_name("VOXELS")
      ->check(kPositive & CLI::Range(0.01, 4.0));
  command->add_option("--scene", o->scene, "Scene file: render fires lighting it")
      ->type_name("SCENE.yaml");
  command
      ->add_option("--samples", o->samples,
                   "Scene: light samples per pixel (default: the scene file's, or 64)")
      ->type_name("N")
      ->check(Whole(1, 1 << 20));
  command->add_option("--seed", o->seed, "Scene: random seed (default: the scene file's, or 1)")
      ->type_name("N")
      ->check(Whole(0, std::int64_t(1) << 53));
  command->add_option("--lighting", o->lighting, "Scene: what lights it")
      ->check(CLI::IsMember({"fire", "point", "sphere", "compare"}));
  command->add_option("--threads", o->threads, "Scene: threads (default: all cores)")
      ->type_name("N")
      ->check(Whole(1, 4096));
  return [o](Context& context) {
    context.StopOnSignals();
    if (!o->scene.empty()) {
      if (!o->rig.empty()) throw UsageError("--scene and --rig: give one");
      SceneJob job = SceneJob::Load(o->scene, o->volume);
      if (o->samples > 0) {
        job.render.samples_per_pixel = o->samples;
        job.render.Validate();
      }
      if (o->seed >= 0) job.render.seed = static_cast<std::uint64_t>(o->seed);
      if (!o->lighting.empty()) {
        job.compare = o->lighting == "compare";
        if (!job.compare) job.render.lighting = SceneLightingFromName(o->lighting);
      }
      std::unique_ptr<tbb::global_control> limit;
      if (o->threads > 0)
        limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                      static_cast<std::size_t>(o->threads));
      const SceneJobResult r = RunSceneJob(job, o->out, context.Progress());
      for (const auto& summary : r.renders)
        std::printf("render: %s\n", summary.BriefReport().c_str());
      for (const auto& f : r.files) std::printf("  %s\n", f.c_str());
      return kExitOk;
    }
    if (o->rig.empty() || o->volume.empty())
      throw UsageError("give --rig and --volume (or --scene)");
    if (o->samples || o->seed >= 0 || !o->lighting.empty() || o->threads)
      throw UsageError("--samples, --seed, --lighting and --threads are for --scene");
    RenderJob job;
    job.rig_path = o->rig;
    job.volume_path = o->volume;
    job.out_dir = o->out;
    job.absorption = o->absorption;
    job.exposure = o->exposure == "auto" ? 0 : std::stod(o->exposure);
    if (o->step > 0) job.render.step_voxels = o->step;
    for (const RenderedView& v : RunRenderJob(job, context.Progress()))
      std::printf("%s: %s\n", v.path.c_str(),
                  v.summary.rays > 0 ? v.summary.BriefReport().c_str() : "emission, thin limit");
    return kExitOk;
  };
}

}  // namespace flamerig::cli
