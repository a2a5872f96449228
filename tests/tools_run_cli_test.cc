// `flamerig run` through the binary: a killed run resumes to the outputs of an uninterrupted one, and
// two MPI ranks agree with one.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "acquisition/recording.h"
#include "core/image.h"
#include "pipeline/distributed.h"
#include "tests/run_test_util.h"
#include "tests/shell_util.h"

namespace flamerig {
namespace {

using namespace testing_run;

using flamerig_test::Result;
using flamerig_test::Shell;

std::string RunCommand(const fs::path& sim, const fs::path& out, const std::string& extra = "") {
  return std::string(FLAMERIG_BINARY) + " run --images " + (sim / "frames").string() + " --rig " +
         (sim / "rig.yaml").string() + " --truth " + (sim / "truth").string() + " --out " +
         out.string() + " --resolution 24 --threads 1 " + extra;
}

TEST(RunCli, KilledOrInterruptedRunResumesToTheUninterruptedOutputs) {
  const fs::path dir = TempDir("resume");
  SimulateDataset(dir / "sim", 5);
  const Result whole = Shell(RunCommand(dir / "sim", dir / "whole"));
  ASSERT_EQ(whole.status, 0) << whole.output;
  EXPECT_NE(whole.output.find("5 computed"), std::string::npos) << whole.output;

  // Start again elsewhere and kill it (SIGKILL) once two frames are complete.
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    const std::string command = RunCommand(dir / "sim", dir / "killed") + " > /dev/null 2>&1";
    ::execl("/bin/sh", "sh", "-c", ("exec " + command).c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
  while (!fs::exists(dir / "killed" / "frames" / "frame_000001.yaml") &&
         std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  ::kill(child, SIGKILL);
  int status = 0;
  ::waitpid(child, &status, 0);
  ASSERT_TRUE(fs::exists(dir / "killed" / "frames" / "frame_000001.yaml"));
  // Every volume under a final name is whole.
  for (const auto& e : fs::directory_iterator(dir / "killed"))
    if (e.path().extension() == ".vdb") {
      EXPECT_NO_THROW(ReadVdb(e.path().string())) << e.path();
    }

  const Result resumed = Shell(RunCommand(dir / "sim", dir / "killed"));
  ASSERT_EQ(resumed.status, 0) << resumed.output;
  EXPECT_NE(resumed.output.find("already done"), std::string::npos) << resumed.output;
  for (int i = 0; i < 5; ++i) {
    SCOPED_TRACE(i);
    ExpectSameVolume(dir / "whole" / (FrameName(i) + ".vdb"),
                     dir / "killed" / (FrameName(i) + ".vdb"));
  }
  EXPECT_TRUE(fs::exists(dir / "killed" / "report" / "index.html"));

  // Ctrl-C (SIGINT) in the middle of a frame: the run stops at the next safe point inside that
  // frame (its solve or fit), commits nothing of it, says so and exits 130; started again, it
  // computes the rest to the uninterrupted outputs.
  const fs::path log = dir / "interrupted.log";
  const pid_t run = ::fork();
  ASSERT_GE(run, 0);
  if (run == 0) {
    const std::string command =
        RunCommand(dir / "sim", dir / "interrupted") + " > " + log.string() + " 2>&1";
    ::execl("/bin/sh", "sh", "-c", ("exec " + command).c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(120);
  while (!fs::exists(dir / "interrupted" / "frames" / "frame_000001.yaml") &&
         std::chrono::steady_clock::now() < until)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  std::this_thread::sleep_for(std::chrono::milliseconds(150));  // into frame 2's work
  ::kill(run, SIGINT);
  ::waitpid(run, &status, 0);
  std::ifstream in(log);
  const std::string said((std::istreambuf_iterator<char>(in)), {});
  ASSERT_TRUE(WIFEXITED(status)) << said;
  EXPECT_EQ(WEXITSTATUS(status), 130) << said;
  EXPECT_NE(said.find("stopped; run the same command again"), std::string::npos) << said;
  int complete = 0;
  while (fs::exists(dir / "interrupted" / "frames" / (FrameName(complete) + ".yaml"))) ++complete;
  EXPECT_GE(complete, 2);
  EXPECT_LT(complete, 5) << "the interrupt came after the last frame";
  for (const auto& e : fs::recursive_directory_iterator(dir / "interrupted"))
    EXPECT_EQ(e.path().string().find(".tmp"), std::string::npos) << e.path();
  EXPECT_FALSE(fs::exists(dir / "interrupted" / (FrameName(complete) + ".vdb")));
  const Result again = Shell(RunCommand(dir / "sim", dir / "interrupted"));
  ASSERT_EQ(again.status, 0) << again.output;
  for (int i = 0; i < 5; ++i) {
    SCOPED_TRACE(i);
    ExpectSameVolume(dir / "whole" / (FrameName(i) + ".vdb"),
                     dir / "interrupted" / (FrameName(i) + ".vdb"));
  }
  fs::remove_all(dir);
}

TEST(RunCli, TwoMpiRanksMatchOneRank) {
  if (!MpiSession::BuiltWithMpi() || Shell("command -v mpirun").status != 0)
    GTEST_SKIP() << "built without MPI, or no mpirun (install openmpi-bin)";
  const fs::path dir = TempDir("mpi");
  SimulateDataset(dir / "sim", 4);
  const Result one = Shell(RunCommand(dir / "sim", dir / "one"));
  ASSERT_EQ(one.status, 0) << one.output;
  // Root may run mpirun only when it says so; --oversubscribe: two ranks whatever the cores.
  const Result two = Shell(
      "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_btl=self,vader "
      "mpirun -n 2 --oversubscribe " +
      RunCommand(dir / "sim", dir / "two"));
  ASSERT_EQ(two.status, 0) << two.output;
  EXPECT_NE(two.output.find("[rank 1] run: frames 2..3"), std::string::npos) << two.output;
  // Rank 0's frames chain exactly as in the one-rank run; rank 1's first frame starts cold, so its
  // frames agree to the fit's accuracy.
  ExpectSameVolume(dir / "one" / "frame_000000.vdb", dir / "two" / "frame_000000.vdb");
  ExpectSameVolume(dir / "one" / "frame_000001.vdb", dir / "two" / "frame_000001.vdb");
  const auto a = ReadFrameSummaries((dir / "one").string(), 0, 4);
  const auto b = ReadFrameSummaries((dir / "two").string(), 0, 4);
  ASSERT_EQ(a.size(), 4u);
  ASSERT_EQ(b.size(), 4u);
  for (int i = 2; i < 4; ++i) {
    EXPECT_NEAR(a[i].MeanFittedDeltaE(), b[i].MeanFittedDeltaE(), 0.15) << i;
    EXPECT_NEAR(a[i].truth_rms_k, b[i].truth_rms_k, 30) << i;
  }
  // One report, written by rank 0, with every frame.
  std::ifstream csv(dir / "two" / "frames.csv");
  int lines = 0;
  for (std::string line; std::getline(csv, line);) ++lines;
  EXPECT_EQ(lines, 5);
  EXPECT_TRUE(fs::exists(dir / "two" / "report" / "index.html"));
  fs::remove_all(dir);
}

// `run` calibrates first when given board views instead of a rig, into OUT/calibrated, and reuses
// that rig when started again.
TEST(RunCli, CalibratesFirstFromBoardViews) {
  const fs::path dir = TempDir("calibrate");
  SimulateConfig c;
  c.frames = 1;
  c.grid_resolution = 24;
  c.shared_per_pair = 12;
  c.closeups_per_camera = 12;
  c.ring.fill = 0.6;  // as config/sim_rig.yaml: room around the fire for the board
  Simulate(c, (dir / "sim").string());
  const std::string command =
      std::string(FLAMERIG_BINARY) + " run --images " + (dir / "sim" / "frames").string() +
      " --calibration-images " + (dir / "sim" / "calibration").string() + " --board " +
      (dir / "sim" / "calibration" / "board.yaml").string() + " --calibrate-config " +
      FLAMERIG_SOURCE_DIR + "/config/calibrate_sim.yaml --resolution 24 --truth " +
      (dir / "sim" / "truth").string() + " --out " + (dir / "out").string();
  const Result first = Shell(command);
  ASSERT_EQ(first.status, 0) << first.output;
  ASSERT_TRUE(fs::exists(dir / "out" / "calibrated" / "rig.yaml"));
  EXPECT_TRUE(fs::exists(dir / "out" / "calibrated" / "report.md"));
  const auto frames = ReadFrameSummaries((dir / "out").string(), 0, 1);
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0].status, "computed") << frames[0].Line();
  // Through the calibrated rig the temperature is still close to the truth (measured about 160 K;
  // a uniform random start gives about 700 K).
  EXPECT_LT(frames[0].truth_rms_k, 300) << frames[0].Line();
  const auto written = fs::last_write_time(dir / "out" / "calibrated" / "rig.yaml");
  const Result again = Shell(command + " --first 0 --count 1");
  ASSERT_EQ(again.status, 0) << again.output;
  EXPECT_EQ(fs::last_write_time(dir / "out" / "calibrated" / "rig.yaml"), written);
  EXPECT_NE(again.output.find("already done"), std::string::npos) << again.output;
  // The calibration's frame is not the simulator's: given the truth's rig, the truth is moved
  // into the calibrated frame before it is scored, and the report says by how much.
  const Result moved =
      Shell(std::string(FLAMERIG_BINARY) + " run --images " + (dir / "sim" / "frames").string() +
            " --rig " + (dir / "out" / "calibrated" / "rig.yaml").string() +
            " --resolution 24 --truth " + (dir / "sim" / "truth").string() + " --truth-rig " +
            (dir / "sim" / "rig.yaml").string() + " --out " + (dir / "moved").string());
  ASSERT_EQ(moved.status, 0) << moved.output;
  const auto registered = ReadFrameSummaries((dir / "moved").string(), 0, 1);
  ASSERT_EQ(registered.size(), 1u);
  EXPECT_EQ(registered[0].status, "computed") << registered[0].Line();
  EXPECT_GE(registered[0].truth_rms_k, 0) << registered[0].Line();
  // "... lies in this rig's frame 1.91 mm, 4.87 mrad, residual 0.044 mm over 729 points"
  // (measured): the gauge is about a millimetre, the cameras agree on the geometry within a
  // tenth of one, and every grid point of the box is seen by both cameras.
  const std::string said = "lies in this rig's frame ";
  const std::size_t at = moved.output.find(said);
  ASSERT_NE(at, std::string::npos) << moved.output;
  double shift_mm = 0, rotation_mrad = 0, residual_mm = 0;
  int points = 0;
  ASSERT_EQ(std::sscanf(moved.output.c_str() + at + said.size(),
                        "%lf mm, %lf mrad, residual %lf mm over %d points", &shift_mm,
                        &rotation_mrad, &residual_mm, &points),
            4)
      << moved.output;
  EXPECT_GT(shift_mm, 0.1);
  EXPECT_LT(shift_mm, 10);
  EXPECT_LT(residual_mm, 0.1);
  EXPECT_EQ(points, 729);
  std::ifstream page(dir / "moved" / "report" / "index.html");
  const std::string html((std::istreambuf_iterator<char>(page)), {});
  EXPECT_NE(html.find("moved into the rig's frame by "), std::string::npos);
  EXPECT_NE(html.find("blender/frame_NNNNNN.vdb"), std::string::npos);  // written by default
  EXPECT_TRUE(fs::exists(dir / "moved" / "blender" / (FrameName(0) + ".vdb")));
  fs::remove_all(dir);
}

// A 12-bit rig rehearsed end to end: sim cameras replaying a raw 12-bit colour dataset (linear,
// black level 64) send BayerRG12p as an Aravis camera's frames arrive (each code in the words' high
// bits), `capture` records them, and `run` reads them with the rig's 12-bit entry scaled to those
// words; the fit matches the same dataset captured as BayerRG16 (codes in the low bits) to a
// kelvin or two (measured: 117.5 and 118.2 K; 76 and 78 K on the main job's 12-bit twin), where the
// rig's 12-bit entry as it stands fails the frame (its words are above 12 bits).
TEST(RunCli, ATwelveBitRigIsRehearsedWithSimCameras) {
  const fs::path dir = TempDir("twelve_bit_rig");
  SimulateRawTwelveBit(dir / "sim", 2);
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  std::map<std::string, FrameSummary> fitted;
  for (const std::string format : {"BayerRG12p", "BayerRG16"}) {
    std::ofstream yaml(dir / ("capture_" + format + ".yaml"));
    yaml << "data_dir: " << (dir / format).string()
         << "\nsync: hardware-trigger\ntrigger_rate_hz: 10\ncameras:\n";
    for (const auto& cam : rig.cameras)
      yaml << "  - {name: " << cam.name << ", width: 120, height: 90, pixel_format: " << format
           << ", sim: {replay: sim}}\n";
    yaml.close();
    const Result captured =
        Shell(std::string(FLAMERIG_BINARY) + " -q capture --config " +
              (dir / ("capture_" + format + ".yaml")).string() + " --record take --frames 1");
    ASSERT_EQ(captured.status, 0) << captured.output;
    const Result run =
        Shell(std::string(FLAMERIG_BINARY) + " -q run --recording " +
              (dir / format / "take").string() + " --rig " + (dir / "sim" / "rig.yaml").string() +
              " --truth " + (dir / "sim" / "truth").string() + " --out " +
              (dir / ("out_" + format)).string() + " --resolution 24 --threads 1");
    ASSERT_EQ(run.status, 0) << run.output;
    const auto frames = ReadFrameSummaries((dir / ("out_" + format)).string(), 0, 1);
    ASSERT_EQ(frames.size(), 1u);
    EXPECT_EQ(frames[0].status, "computed") << frames[0].Line();
    fitted[format] = frames[0];
  }
  const Recording take = Recording::Open((dir / "BayerRG12p" / "take").string());
  EXPECT_EQ(take.metadata().cameras[0].settings.wire_format, "BayerRG12p");
  const std::optional<Frame> f = take.ReadFrame(0, 0);
  ASSERT_TRUE(f.has_value());
  EXPECT_EQ(f->info.sent_pfnc, WireFormatFromName("BayerRG12p")->pfnc);
  const double packed = fitted["BayerRG12p"].truth_rms_k, words = fitted["BayerRG16"].truth_rms_k;
  std::printf("12-bit rig rehearsed: temperature RMS %.1f K as BayerRG12p, %.1f K as BayerRG16\n",
              packed, words);
  EXPECT_GT(packed, 0);
  EXPECT_LT(packed, 300);
  EXPECT_NEAR(packed, words, 10);
  fs::remove_all(dir);
}

// `run --w-sm` sets the fit's neighbour weight, tied to rings or not, and every frame's volume
// records the weight it was fitted under (metadata w_sm): 1 by default, 0.2 with --axisymmetric,
// the given one with either, each at 64 voxels and scaled to the grid, and its factors by
// direction (w_sm_along_y, w_sm_across_y: 1 and 1 untied, 40 and 0 tied, or the ones
// --w-sm-along-y and --w-sm-across-y give either). A stronger prior gives a smoother temperature
// field in the direction it acts: across the grid untied, along the flame's axis (y) tied, and
// along y rather than x when its pairs along y weigh more.
TEST(RunCli, TheNeighbourWeightIsTheUsersAndEachVolumeRecordsIt) {
  const fs::path dir = TempDir("w_sm");
  SimulateDataset(dir / "sim", 1);
  struct Case {
    std::string name, flags;
    double w_sm, along_y, across_y;
  };
  const std::vector<Case> cases = {
      {"default", "", 1.0, 1, 1},
      {"strong", "--w-sm 10", 10.0, 1, 1},
      {"tied", "--axisymmetric", 0.2, 40, 0},
      {"tied_given", "--axisymmetric --w-sm 2", 2.0, 40, 0},
      {"along_y", "--w-sm-along-y 10 --w-sm-across-y 0.1", 1.0, 10, 0.1},
      {"tied_alike", "--axisymmetric --w-sm-across-y 1", 0.2, 40, 1},
      {"tied_linear", "--axisymmetric --axisymmetric-interpolate", 0.2, 40, 0}};
  std::map<std::string, FireVolume> volumes;
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const Result r = Shell(RunCommand(dir / "sim", dir / c.name, "--no-blender " + c.flags));
    ASSERT_EQ(r.status, 0) << r.output;
    EXPECT_FALSE(fs::exists(dir / c.name / "blender"));  // --no-blender: not even the folder
    FireVolume v = ReadVdb((dir / c.name / (FrameName(0) + ".vdb")).string());
    ASSERT_EQ(v.metadata_numbers.count("w_sm"), 1u);
    // Given at 64 voxels, applied x (64 / N)^2 on a grid of N along its longest side.
    const double n = v.geometry.dims.maxCoeff();
    EXPECT_NE(n, 64);  // so that the rule is seen at work
    EXPECT_DOUBLE_EQ(v.metadata_numbers.at("w_sm"), c.w_sm * (64 / n) * (64 / n));
    EXPECT_EQ(v.metadata_numbers.at("neighbour_weight_resolution"), 64);
    ASSERT_EQ(v.metadata_numbers.count("w_sm_along_y"), 1u);
    EXPECT_EQ(v.metadata_numbers.at("w_sm_along_y"), c.along_y);
    EXPECT_EQ(v.metadata_numbers.at("w_sm_across_y"), c.across_y);
    // A tied fit says whether its field is linear in the radius (--axisymmetric-interpolate).
    const bool tied = c.flags.find("--axisymmetric") != std::string::npos;
    ASSERT_EQ(v.metadata_numbers.count("axisymmetric_interpolate"), tied ? 1u : 0u);
    if (tied) {
      EXPECT_EQ(v.metadata_numbers.at("axisymmetric_interpolate"),
                c.flags.find("-interpolate") != std::string::npos ? 1 : 0);
    }
    volumes[c.name] = std::move(v);
  }
  // Scored against the truth, the report and frames.csv give the determined voxels apart.
  std::ifstream page(dir / "default" / "report" / "index.html");
  const std::string html((std::istreambuf_iterator<char>(page)), {});
  EXPECT_NE(html.find("The voxels the fit calls determined: "), std::string::npos);
  EXPECT_EQ(html.find("blender/frame_"), std::string::npos);  // --no-blender: no link to it
  std::ifstream csv(dir / "default" / "frames.csv");
  std::string header;
  std::getline(csv, header);
  EXPECT_NE(header.find("truth_determined_share,truth_determined_rms_k,truth_undetermined_rms_k,"
                        "truth_weighted_rms_k,truth_weighted_bias_k,truth_visible_soot,"
                        "visible_soot"),
            std::string::npos)
      << header;
  // Roughness: the mean |T difference| between face neighbours along x, or along y, that both
  // hold medium.
  auto roughness = [](const FireVolume& v, bool along_y = false) {
    const Eigen::Vector3i d = v.geometry.dims;
    double sum = 0;
    std::size_t pairs = 0;
    for (int z = 0; z < d.z(); ++z)
      for (int y = 0; y + (along_y ? 1 : 0) < d.y(); ++y)
        for (int x = 0; x + (along_y ? 0 : 1) < d.x(); ++x) {
          const std::size_t i = v.geometry.Flat(x, y, z), j = along_y
                                                                  ? v.geometry.Flat(x, y + 1, z)
                                                                  : v.geometry.Flat(x + 1, y, z);
          if (v.density_per_m3[i] <= 0 || v.density_per_m3[j] <= 0) continue;
          sum += std::abs(double(v.temperature_k[i]) - v.temperature_k[j]);
          ++pairs;
        }
    return pairs ? sum / double(pairs) : 0.0;
  };
  EXPECT_LT(roughness(volumes["strong"]), 0.8 * roughness(volumes["default"]));
  std::printf(
      "roughness: untied %.1f K at w_sm 10, %.1f K at 1 (along x); tied %.1f K at 2, "
      "%.1f K at 0.2 (along y)\n",
      roughness(volumes["strong"]), roughness(volumes["default"]),
      roughness(volumes["tied_given"], true), roughness(volumes["tied"], true));
  EXPECT_LT(roughness(volumes["tied_given"], true), 0.8 * roughness(volumes["tied"], true));
  // The untied field's roughness along y over that along x: the pairs along y weighed 100 times
  // the others make it smaller.
  auto anisotropy = [&roughness](const FireVolume& v) { return roughness(v, true) / roughness(v); };
  std::printf("roughness along y / along x: untied %.2f with the pairs alike, %.2f along y x 100\n",
              anisotropy(volumes["default"]), anisotropy(volumes["along_y"]));
  EXPECT_LT(anisotropy(volumes["along_y"]), 0.8 * anisotropy(volumes["default"]));
  for (const std::string flags :
       {"--w-sm -1", "--w-sm-along-y -1", "--w-sm-across-y nan", "--axisymmetric-interpolate"}) {
    const Result bad = Shell(RunCommand(dir / "sim", dir / "bad", flags));
    EXPECT_EQ(bad.status, 2) << bad.output;
    EXPECT_NE(bad.output.find(flags.substr(0, flags.find(' '))), std::string::npos) << bad.output;
    EXPECT_FALSE(fs::exists(dir / "bad"));
  }
  fs::remove_all(dir);
}

// A frame that fails (images of another size than the rig's cameras) does not stop the others,
// but the run's exit status says that it is not complete: a script must not take it for done.
// A corrupt PNG in the middle of a folder of frames (and, in the frame after it, images of the
// wrong size): those frames fail, the others are computed, the report is written, and the exit
// status says that the run is not complete.
TEST(RunCli, ACorruptFrameFailsAloneAndTheExitStatusSaysSo) {
  const fs::path dir = TempDir("failed_frame");
  SimulateDataset(dir / "sim", 4);
  const fs::path corrupt = dir / "sim" / "frames" / "frame_000001" / "cam1.png";
  std::ofstream(corrupt, std::ios::binary | std::ios::trunc) << "\x89PNG\r\n\x1a\ncut short";
  for (const auto& e : fs::directory_iterator(dir / "sim" / "frames" / "frame_000002"))
    if (e.path().extension() == ".png") WritePng(e.path().string(), ImageU8(16, 12, 3, 0));
  const Result r = Shell(RunCommand(dir / "sim", dir / "out"));
  EXPECT_EQ(r.status, 1) << r.output;
  EXPECT_NE(r.output.find("2 of 4 frame(s) failed"), std::string::npos) << r.output;
  const auto frames = ReadFrameSummaries((dir / "out").string(), 0, 4);
  ASSERT_EQ(frames.size(), 4u);
  EXPECT_EQ(frames[0].status, "computed") << frames[0].Line();
  EXPECT_EQ(frames[1].status.rfind("failed", 0), 0u) << frames[1].Line();
  EXPECT_NE(frames[1].status.find(corrupt.string()), std::string::npos) << frames[1].Line();
  EXPECT_NE(frames[2].status.find("16x12"), std::string::npos) << frames[2].Line();
  EXPECT_EQ(frames[3].status, "computed") << frames[3].Line();
  EXPECT_TRUE(fs::exists(dir / "out" / "report" / "index.html"));
  std::ifstream csv(dir / "out" / "frames.csv");
  const std::string table((std::istreambuf_iterator<char>(csv)), {});
  EXPECT_NE(table.find("fit_termination"), std::string::npos) << table;
  EXPECT_NE(table.find("voxels_at_density_bound"), std::string::npos) << table;
  fs::remove_all(dir);
}

// Blender itself (Debian's, through tools/blender_fire.py) renders the Blender export as a fire: an
// upright flame (our Y-up rig turned to Blender's Z up), orange (red over green over blue), where
// the camera looks; both with the script's material and with the README's Principled Volume
// settings alone.
TEST(RunCli, BlenderRendersTheExportAsAnUprightFire) {
  if (Shell("command -v blender").status != 0)
    GTEST_SKIP() << "no blender (scripts/install-deps.sh installs it)";
  const fs::path dir = TempDir("blender");
  SimulateDataset(dir / "sim", 1);
  const Result run = Shell(RunCommand(dir / "sim", dir / "out"));
  ASSERT_EQ(run.status, 0) << run.output;
  const FireVolume fitted = ReadVdb((dir / "out" / "frame_000000.vdb").string());
  const double exposure = fitted.metadata_numbers.at("exposure");
  for (const std::string mode : {"", "--blackbody"}) {
    SCOPED_TRACE(mode.empty() ? "script material" : "README settings");
    const fs::path png = dir / ("blender" + mode + ".png");
    // The README's route needs more light: Blender's blackbody ignores the soot's amount and is
    // scaled by 1e-6 sigma / pi (notes in pipeline/blender_export.h).
    const double stops = mode.empty() ? 0 : 7;
    const Result b = Shell("blender --background --python " + std::string(FLAMERIG_SOURCE_DIR) +
                           "/tools/blender_fire.py -- " + (dir / "out" / "blender").string() +
                           " --exposure " + std::to_string(exposure * std::exp2(stops)) +
                           " --samples 8 --render " + png.string() + " " + mode);
    ASSERT_EQ(b.status, 0) << b.output;
    const ImageU8 image = ReadImageU8(png.string(), 3);
    // The flame: pixels at least half as red as the reddest (Cycles leaves sparse bright specks on
    // the black background at 8 samples; percentiles of the lit pixels ignore them).
    int peak = 0;
    for (int y = 0; y < image.height; ++y)
      for (int x = 0; x < image.width; ++x) peak = std::max<int>(peak, image.at(x, y, 0));
    std::vector<int> xs, ys;
    double r = 0, g = 0, bl = 0, cx = 0;
    for (int y = 0; y < image.height; ++y)
      for (int x = 0; x < image.width; ++x) {
        if (2 * image.at(x, y, 0) < peak) continue;
        xs.push_back(x);
        ys.push_back(y);
        r += image.at(x, y, 0);
        g += image.at(x, y, 1);
        bl += image.at(x, y, 2);
        cx += x;
      }
    const int lit = static_cast<int>(xs.size());
    ASSERT_GT(lit, 100) << b.output;
    std::sort(xs.begin(), xs.end());
    std::sort(ys.begin(), ys.end());
    const int wide = xs[lit * 95 / 100] - xs[lit * 5 / 100];
    const int tall = ys[lit * 95 / 100] - ys[lit * 5 / 100];
    EXPECT_GT(tall, 1.5 * wide) << "the flame should stand upright: " << wide << " px wide, "
                                << tall << " px tall";
    EXPECT_GT(r, g);
    EXPECT_GT(g, bl);
    EXPECT_NEAR(cx / lit, image.width / 2.0, image.width / 6.0);
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
