// The valid-intrinsics region's plumbing (pipeline/valid_region.h): what happens to models mrcal
// cannot compute a region for, and reading the region as mrcal's Python writer spells it. The
// region itself is compared with mrcal-calibrate-cameras's in pipeline_calibrate_rigs_test, and
// written by `flamerig calibrate` in pipeline_calibrate_job_test.
#include "pipeline/valid_region.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include "calibration/camera_model.h"
#include "core/error.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

fs::path TempDir() {
  const fs::path d =
      fs::temp_directory_path() / ("flamerig_valid_region_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

std::string ReadText(const fs::path& path) {
  std::ifstream in(path);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// A model without the solve's optimization_inputs (one not from a calibration) and a path that is
// not there: each gets its reason, the model is not changed, and nothing is left beside it.
TEST(ValidRegion, AModelWithoutTheSolveIsLeftAsItIsWithTheReason) {
  const fs::path dir = TempDir();
  const std::string model = (dir / "cam0.cameramodel").string();
  CameraModel::Pinhole(500, 500, 319.5, 239.5, Rigid3(), 640, 480).Save(model);
  const std::string before = ReadText(model);
  const std::string missing = (dir / "nowhere.cameramodel").string();
  const std::vector<ValidRegion> regions = AddValidIntrinsicsRegions({model, missing});
  ASSERT_EQ(regions.size(), 2u);
  for (const ValidRegion& r : regions) {
    EXPECT_FALSE(r.computed);
    EXPECT_TRUE(r.contour.empty());
    EXPECT_FALSE(r.error.empty());
  }
  EXPECT_EQ(regions[0].model_path, model);
  EXPECT_NE(regions[0].error.find("no optimization_inputs"), std::string::npos) << regions[0].error;
  EXPECT_NE(regions[1].error.find("nowhere.cameramodel"), std::string::npos) << regions[1].error;
  EXPECT_EQ(ReadText(model), before);
  EXPECT_FALSE(fs::exists(model + ".region"));
  EXPECT_FALSE(fs::exists(missing));
  EXPECT_FALSE(fs::exists(missing + ".region"));
  EXPECT_TRUE(AddValidIntrinsicsRegions({}).empty());
  fs::remove_all(dir);
}

// mrcal's Python writer (mrcal/cameramodel.py) spells the points as floats, "[ 12, 34 ],"; an
// empty region is "[\n]"; a model without one has no key.
TEST(ValidRegion, ReadsTheRegionAsMrcalWritesIt) {
  const fs::path dir = TempDir();
  const std::string model = (dir / "cam0.cameramodel").string();
  CameraModel::Pinhole(500, 500, 319.5, 239.5, Rigid3(), 640, 480).Save(model);
  EXPECT_TRUE(ReadValidIntrinsicsRegion(model).empty());
  const std::string plain = ReadText(model);
  const std::size_t brace = plain.rfind('}');
  ASSERT_NE(brace, std::string::npos);
  auto with = [&](const std::string& field) {
    std::string text = plain;
    text.insert(brace, field);
    std::ofstream(model) << text;
  };
  with(
      "    'valid_intrinsics_region': [\n    [ 10, 20 ],\n    [ 300.4, 20 ],\n    [ 299.6, 200 ],"
      "\n    [ 10, 20 ],\n],\n\n");
  const std::vector<Eigen::Vector2i> contour = ReadValidIntrinsicsRegion(model);
  ASSERT_EQ(contour.size(), 4u);
  EXPECT_EQ(contour[0], Eigen::Vector2i(10, 20));
  EXPECT_EQ(contour[1], Eigen::Vector2i(300, 20));
  EXPECT_EQ(contour[2], Eigen::Vector2i(300, 200));
  EXPECT_EQ(contour.front(), contour.back());
  // mrcal's C reader (CameraModel::Load) takes the key, as mrcal's tools do.
  EXPECT_NO_THROW(CameraModel::Load(model));
  with("    'valid_intrinsics_region': [\n],\n");
  EXPECT_TRUE(ReadValidIntrinsicsRegion(model).empty());
  with("    'valid_intrinsics_region': [\n    [ 10, x ],\n],\n");
  EXPECT_THROW(ReadValidIntrinsicsRegion(model), DataError);
  with("    'valid_intrinsics_region': [\n    [ 10, 20 ],\n");
  EXPECT_THROW(ReadValidIntrinsicsRegion(model), DataError);
  EXPECT_THROW(ReadValidIntrinsicsRegion((dir / "none.cameramodel").string()), IoError);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
