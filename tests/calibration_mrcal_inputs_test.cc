// mrcal's optimization inputs as we serialise them, read back by numpy and mrcal themselves (the
// oracle): Python's base85 on known vectors, an .npz that numpy.load reads value for value, and a
// camera model whose optimization_inputs mrcal.cameramodel returns with the problem we wrote.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include "calibration/camera_model.h"
#include "calibration/mrcal_inputs.h"
#include "core/error.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() /
                       ("flamerig_mrcal_inputs_" + std::to_string(::getpid()) + "_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

bool HavePythonMrcal() {
  return std::system("/usr/bin/python3 -c 'import mrcal, numpy' > /dev/null 2>&1") == 0;
}

std::string Slurp(const fs::path& f) {
  std::ifstream in(f);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// Python's base64.b85encode on the same bytes (printed by Python 3.11).
TEST(MrcalInputs, Base85IsPythons) {
  EXPECT_EQ(internal::Base85Encode(""), "");
  EXPECT_EQ(internal::Base85Encode("h"), "Xa");
  EXPECT_EQ(internal::Base85Encode("hello"), "Xk~0{Zv");
  EXPECT_EQ(internal::Base85Encode(std::string(4, '\0')), "00000");
  EXPECT_EQ(internal::Base85Encode(std::string(5, '\xff')), "|NsC0{{");
}

// A small two-camera problem with every kind of member.
MrcalProblem SmallProblem() {
  MrcalProblem p;
  p.lensmodel = "LENSMODEL_PINHOLE";
  p.num_cameras = 2;
  p.num_params = 4;
  p.intrinsics = {500, 501, 160, 120, 510, 511, 161, 121};
  p.extrinsics = {{0.1, -0.2, 0.3, -0.05, 0.01, 0.002}};
  p.frames = {{0, 0, 0, 0, 0, 0.5}, {0.01, 0.02, 0.03, 0.1, 0.2, 0.6}};
  p.calobject_warp = {1e-4, -2e-4};
  p.indices = {{0, 0, -1}, {0, 1, 0}, {1, 1, 0}};
  p.board_width = 3;
  p.board_height = 2;
  for (int i = 0; i < 3 * 2 * 3; ++i)
    p.observations.insert(p.observations.end(), {10.0 + i, 20.0 + i, i == 4 ? -1.0 : 1.0});
  p.imagersizes = {{320, 240}, {640, 480}};
  p.spacing_m = 0.012;
  p.optimize_calobject_warp = false;
  return p;
}

TEST(MrcalInputs, NumpyAndMrcalReadWhatWeWrite) {
  if (!HavePythonMrcal()) GTEST_SKIP() << "python3-mrcal and numpy are not installed";
  const fs::path dir = TempDir("read");
  const MrcalProblem p = SmallProblem();
  CameraModel::Pinhole(510, 511, 161, 121, Rigid3(), 640, 480)
      .Save((dir / "cam1.cameramodel").string(), "test");
  AddMrcalOptimizationInputs((dir / "cam1.cameramodel").string(),
                             SerializeMrcalOptimizationInputs(p), 1);
  // Our own reader (mrcal's C parser) still reads the model.
  const CameraModel back = CameraModel::Load((dir / "cam1.cameramodel").string());
  EXPECT_EQ(back.intrinsics()[0], 510);
  const std::string script =
      "import mrcal, numpy as np\n"
      "m = mrcal.cameramodel('" +
      (dir / "cam1.cameramodel").string() +
      "')\n"
      "o = m.optimization_inputs()\n"
      "print(m.icam_intrinsics())\n"
      "print(o['lensmodel'])\n"
      "print(o['intrinsics'].shape, o['intrinsics'][1, 0], o['intrinsics'].dtype)\n"
      "print(o['extrinsics_rt_fromref'].shape, o['extrinsics_rt_fromref'][0, 2])\n"
      "print(o['frames_rt_toref'].shape, o['frames_rt_toref'][1, 5])\n"
      "print(o['observations_board'].shape, o['observations_board'][0, 1, 1, 2],"
      " o['observations_board'][2, 1, 2, 0])\n"
      "print(o['indices_frame_camintrinsics_camextrinsics'].dtype,"
      " o['indices_frame_camintrinsics_camextrinsics'][0].tolist())\n"
      "print(o['imagersizes'].tolist(), o['calibration_object_spacing'], o['calobject_warp'][1])\n"
      "print(o['points'], o['observations_point'], o['do_optimize_calobject_warp'],"
      " o['do_optimize_frames'], o['verbose'])\n";
  std::ofstream(dir / "read.py") << script;
  ASSERT_EQ(std::system(("/usr/bin/python3 " + (dir / "read.py").string() + " > " +
                         (dir / "out.txt").string() + " 2>&1")
                            .c_str()),
            0)
      << Slurp(dir / "out.txt");
  EXPECT_EQ(Slurp(dir / "out.txt"),
            "1\n"
            "LENSMODEL_PINHOLE\n"
            "(2, 4) 510.0 float64\n"
            "(1, 6) 0.3\n"
            "(2, 6) 0.6\n"
            "(3, 2, 3, 3) -1.0 27.0\n"  // point 17 = 2 * 6 + 1 * 3 + 2: x 10 + 17
            "int32 [0, 0, -1]\n"
            "[[320, 240], [640, 480]] 0.012 -0.0002\n"
            "None None False True False\n");
  fs::remove_all(dir);
}

TEST(MrcalInputs, InconsistentSizesAndAFileThatIsNotAModelAreRefused) {
  MrcalProblem p = SmallProblem();
  p.observations.pop_back();
  EXPECT_THROW(SerializeMrcalOptimizationInputs(p), DataError);
  const fs::path dir = TempDir("bad");
  std::ofstream(dir / "x.cameramodel") << "not a model";
  EXPECT_THROW(AddMrcalOptimizationInputs((dir / "x.cameramodel").string(), "abc", 0), DataError);
  EXPECT_THROW(AddMrcalOptimizationInputs((dir / "none.cameramodel").string(), "abc", 0), IoError);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
