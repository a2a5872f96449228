#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include "calibration/calibrate.h"
#include "tools/benchmark.h"
#include "pipeline/simulate.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

// The worst error of the cameras' poses relative to the first camera (frame independent).
struct PoseError {
  double rotation_deg = 0, translation_mm = 0;
};
PoseError CompareRelativePoses(const std::vector<CameraModel>& got, const Rig& truth) {
  PoseError e;
  const Rigid3 g0 = got[0].cam_from_rig(), t0 = truth.cameras[0].model.cam_from_rig();
  for (std::size_t c = 1; c < got.size(); ++c) {
    const Rigid3 g = got[c].cam_from_rig() * g0.Inverse();
    const Rigid3 t = truth.cameras[c].model.cam_from_rig() * t0.Inverse();
    e.rotation_deg = std::max(
        e.rotation_deg, Eigen::AngleAxisd(g.rotation.inverse() * t.rotation).angle() * 180 / M_PI);
    e.translation_mm = std::max(e.translation_mm, 1e3 * (g.translation - t.translation).norm());
  }
  return e;
}

}  // namespace

std::string RunCalibrationBenchmark(const CalibrationBenchmarkOptions& options,
                                    const std::function<void(const std::string&)>& log) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_calibration_benchmark_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  SimulateConfig c;
  c.seed = 21;
  c.frames = 1;
  c.grid_resolution = 12;
  c.ring.cameras = options.cameras;
  c.ring.width = options.width;
  c.ring.height = options.height;
  c.ring.fill = 0.45;
  c.board.square_m = 0.012;
  c.board.marker_m = 0.009;
  c.shared_per_pair = options.quick ? 8 : options.views_per_pair;
  c.closeups_per_camera = options.quick ? 8 : options.views_per_camera;
  log("rendering the calibration views");
  auto t0 = std::chrono::steady_clock::now();
  const SimulateSummary sim = Simulate(c, dir.string());
  const double render_s = Seconds(t0);
  const Rig truth = Rig::Load((dir / "rig.yaml").string());
  const BoardSpec board = LoadBoardSpec((dir / "calibration" / "board.yaml").string());

  log("ours: detection");
  const std::string cache = (dir / "detections.cache").string();
  const CalibrationData data =
      DetectViewsInFolder((dir / "calibration").string(), board, {}, cache);
  t0 = std::chrono::steady_clock::now();
  const CalibrationData cached =
      DetectViewsInFolder((dir / "calibration").string(), board, {}, cache);
  const double cached_s = Seconds(t0);
  log("ours: solve");
  CalibrationOptions copt;
  const CalibrationSummary ours = Calibrate(data, copt);
  std::vector<CameraModel> our_models;
  for (const auto& cam : ours.rig.cameras) our_models.push_back(cam.model);
  const PoseError our_error = CompareRelativePoses(our_models, truth);

  // mrcal's tool on the same detections, whole boards only (with partial ChArUco views it solves,
  // then fails computing its valid-intrinsics region and writes no models); ours again on those.
  CalibrationData whole = data;
  std::erase_if(whole.observations, [&](const BoardObservation& o) {
    return static_cast<int>(o.detection.corner_ids.size()) < board.num_corners();
  });
  const CalibrationSummary ours_whole = Calibrate(whole, copt);
  std::vector<CameraModel> whole_models;
  for (const auto& cam : ours_whole.rig.cameras) whole_models.push_back(cam.model);
  const PoseError whole_error = CompareRelativePoses(whole_models, truth);
  // mrcal's tool on the same detections. It needs a focal length to seed from (ours estimates one
  // from the board homographies); it is given the true one and guesses 10% under and 15% over.
  std::vector<std::string> tool_lines;
  if (std::system("command -v mrcal-calibrate-cameras > /dev/null 2>&1") != 0) {
    tool_lines.push_back("| `mrcal-calibrate-cameras` | - | - | not installed | | | |");
  } else {
    const fs::path work = dir / "mrcal";
    fs::create_directories(work);
    WriteMrcalCorners(whole, (work / "corners.vnl").string(), "views");
    const double f_true = truth.cameras[0].model.intrinsics()[0];
    for (double factor : {1.0, 0.9, 1.15}) {
      log("mrcal-calibrate-cameras --focal " + Fixed(factor * f_true, 0));
      for (const auto& e : fs::directory_iterator(work))
        if (e.path().extension() == ".cameramodel") fs::remove(e.path());
      std::ostringstream cmd;
      cmd << "cd " << work << " && mrcal-calibrate-cameras --corners-cache corners.vnl --lensmodel "
          << copt.lensmodel << " --focal " << factor * f_true << " --imagersize " << options.width
          << " " << options.height << " --object-spacing " << board.square_m << " --object-width-n "
          << board.corners_x() << " --object-height-n " << board.corners_y() << " --outdir "
          << work;
      for (const auto& name : data.camera_names) cmd << " 'views/*/" << name << ".png'";
      cmd << " > tool.log 2>&1";
      t0 = std::chrono::steady_clock::now();
      const int status = std::system(cmd.str().c_str());
      const double tool_s = Seconds(t0);
      std::ifstream in(work / "tool.log");
      const std::string text((std::istreambuf_iterator<char>(in)),
                             std::istreambuf_iterator<char>());
      double tool_rms = -1;
      const std::regex stage_rms("## RMS error: ([0-9.eE+-]+)");
      for (auto it = std::sregex_iterator(text.begin(), text.end(), stage_rms);
           it != std::sregex_iterator(); ++it)
        tool_rms = std::stod((*it)[1]);
      std::vector<fs::path> files;
      for (const auto& e : fs::directory_iterator(work))
        if (e.path().extension() == ".cameramodel") files.push_back(e.path());
      std::sort(files.begin(), files.end());
      const std::string label = "| `mrcal-calibrate-cameras --focal " + Fixed(factor * f_true, 0) +
                                "` (" + (factor == 1.0 ? "the true focal" : "a guess") +
                                ") | - | - | ";
      if (status == 0 && files.size() == data.camera_names.size()) {
        std::vector<CameraModel> models;
        for (const auto& f : files) models.push_back(CameraModel::Load(f.string()));
        const PoseError e = CompareRelativePoses(models, truth);
        tool_lines.push_back(label + Fixed(tool_s, 2) + " | " + Fixed(tool_rms, 4) + " | " +
                             Fixed(e.rotation_deg, 4) + " | " + Fixed(e.translation_mm, 3) + " |");
      } else {
        tool_lines.push_back(label + "failed (status " + std::to_string(status) + ") | | | |");
      }
    }
  }
  fs::remove_all(dir);

  std::ostringstream md;
  md << "Machine: " << MachineDescription() << ".\n\n";
  md << "A ring of " << options.cameras << " cameras (" << options.width << "x" << options.height
     << ", LENSMODEL_OPENCV8 with mild distortion) 90 degrees apart from `flamerig simulate`: "
     << sim.calibration_views << " board views (ChArUco " << board.squares_x << "x"
     << board.squares_y << ", " << board.square_m * 1e3
     << " mm squares) shared by neighbours only, plus close-ups, " << sim.calibration_images
     << " rendered images with sensor noise (rendering took " << Fixed(render_s, 1)
     << " s, not counted). Errors are the worst over cameras of each camera's rotation and "
        "translation relative to the first camera, against the true rig. RMS is per coordinate "
        "(mrcal's convention).\n\n";
  md << "| solver | detection s (" << data.detected
     << " images) | detection from cache s | solve s | RMS px | rotation error deg | translation "
        "error mm |\n";
  md << "|---|---|---|---|---|---|---|\n";
  md << "| flamerig (OpenCV ChArUco, `mrcal_optimize` in process) | "
     << Fixed(data.detect_time_s, 2) << " | " << Fixed(cached_s, 2) << " (" << cached.from_cache
     << " cached) | " << Fixed(ours.solve_time_s, 2) << " | "
     << Fixed(ours.rms_px_per_coordinate, 4) << " | " << Fixed(our_error.rotation_deg, 4) << " | "
     << Fixed(our_error.translation_mm, 3) << " |\n";
  md << "| flamerig, whole boards only (" << whole.observations.size() << " of "
     << data.observations.size() << " observations) | - | - | " << Fixed(ours_whole.solve_time_s, 2)
     << " | " << Fixed(ours_whole.rms_px_per_coordinate, 4) << " | "
     << Fixed(whole_error.rotation_deg, 4) << " | " << Fixed(whole_error.translation_mm, 3)
     << " |\n";
  for (const auto& line : tool_lines) md << line << "\n";
  md << "\n";
  md << "The tool's time is the whole command (Python start-up, seeding, its staged solves) on our "
        "detections of whole boards (the row above solves the same problem), without its "
        "board-warp solve; it is "
        "seeded with the true focal length and with guesses 10% under and 15% over (ours seeds "
        "intrinsics from the board homographies and needs none). It cannot detect "
        "ChArUco boards itself (mrgingham finds square chessboards "
        "only), so detection is ours in both rows. "
     << ours.points << " corners, " << ours.outliers << " rejected as outliers by our solve.\n";
  return md.str();
}

}  // namespace flamerig
