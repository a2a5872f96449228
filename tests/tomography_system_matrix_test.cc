// The system matrix against the renderer's optically thin limit, its transpose, and its cache file.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <random>
#include <set>

#include "calibration/synthetic_rig.h"
#include "fitting/renderer.h"
#include "fitting/synthetic_fire.h"
#include "tomography/reconstruct.h"
#include "tomography/system_matrix.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

struct Scene {
  Rig rig;
  GridGeometry grid;
  FireVolume fire;
  std::vector<std::unique_ptr<CameraRays>> rays;
};

Scene MakeScene(int cameras, int resolution, double soot_fraction, int width = 96,
                int height = 72) {
  Scene s;
  const Box3 box{Eigen::Vector3d(-0.015, 0.0, -0.015), Eigen::Vector3d(0.015, 0.07, 0.015)};
  synthetic::RingOptions ring;
  ring.cameras = cameras;
  ring.width = width;
  ring.height = height;
  s.rig = synthetic::MakeRingRig(box, ring);
  s.grid = GridGeometry::FromBox(box, resolution);
  synthetic::FireOptions fire;
  fire.peak_soot_volume_fraction = soot_fraction;
  AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  s.fire = synthetic::MakeFire(s.grid, fire, grey);
  s.fire.emission_rgb = synthetic::ThinEmissionRgb(s.fire, grey);
  for (const auto& c : s.rig.cameras) s.rays.push_back(std::make_unique<CameraRays>(c.model));
  return s;
}

std::vector<const CameraRays*> Pointers(const Scene& s) {
  std::vector<const CameraRays*> p;
  for (const auto& r : s.rays) p.push_back(r.get());
  return p;
}

// Every pixel of every camera of the scene.
std::vector<std::vector<std::uint8_t>> AllPixels(const Scene& s) {
  std::vector<std::vector<std::uint8_t>> pixels;
  for (const auto& r : s.rays) pixels.emplace_back(r->rays().size(), 1);
  return pixels;
}

// A x for a field given per voxel (x_voxel, one channel), by (camera, pixel) of each row.
std::map<std::pair<int, int>, float> ProductByPixel(const SystemMatrix& a,
                                                    const std::vector<float>& x_voxel) {
  std::vector<float> x(a.cols()), y(a.rows());
  for (std::size_t j = 0; j < a.cols(); ++j) x[j] = x_voxel[a.col_voxel(j)];
  a.Multiply(x.data(), y.data(), 1);
  std::map<std::pair<int, int>, float> by_pixel;
  for (std::size_t r = 0; r < a.rows(); ++r) by_pixel[{a.row_camera(r), a.row_pixel(r)}] = y[r];
  return by_pixel;
}

// The matrix over every pixel and every voxel.
SystemMatrix BuildWhole(const Scene& s) {
  return SystemMatrix::Build(s.grid, Pointers(s), AllPixels(s),
                             std::vector<std::uint8_t>(s.grid.num_voxels(), 1),
                             SystemMatrixOptions());
}

// A e equals the renderer's image of an optically thin fire, pixel for pixel: the tomography model
// is the renderer's thin limit.
TEST(SystemMatrix, IsTheRenderersThinLimit) {
  Scene s = MakeScene(2, 24, 1e-9);  // optical depth ~1e-5: thin
  SystemMatrix a = BuildWhole(s);
  ASSERT_EQ(a.cols(), s.grid.num_voxels());
  std::vector<float> y(a.rows() * 3);
  a.Multiply(s.fire.emission_rgb.data(), y.data(), 3);

  FireRenderer renderer(AbsorptionModel::DefaultGrey());
  renderer.SetVolume(s.grid, s.fire.temperature_k, s.fire.density_per_m3);
  double peak = 0;
  std::vector<ImageF> images;
  for (const auto& r : s.rays) {
    images.emplace_back();
    renderer.Render(*r, &images.back());
    for (float v : images.back().pixels) peak = std::max(peak, double(std::abs(v)));
  }
  ASSERT_GT(peak, 0);
  std::size_t checked = 0;
  for (std::size_t r = 0; r < a.rows(); ++r) {
    const ImageF& img = images[a.row_camera(r)];
    for (int c = 0; c < 3; ++c) {
      ASSERT_NEAR(y[r * 3 + c], img.pixels[3 * a.row_pixel(r) + c], 2e-4 * peak) << "row " << r;
      ++checked;
    }
  }
  EXPECT_GT(checked, 1000u);
  // And RenderThinEmission computes the same for every pixel.
  ImageF thin = RenderThinEmission(s.grid, s.fire.emission_rgb, *s.rays[1]);
  for (std::size_t p = 0; p < thin.pixels.size(); ++p)
    ASSERT_NEAR(thin.pixels[p], images[1].pixels[p], 2e-4 * peak);
}

TEST(SystemMatrix, TransposeIsTheAdjoint) {
  Scene s = MakeScene(3, 16, 1e-6);
  std::vector<std::vector<std::uint8_t>> pixels;
  std::mt19937 rng(1);
  for (const auto& r : s.rays) {
    pixels.emplace_back(r->rays().size());
    for (auto& p : pixels.back()) p = rng() % 3 != 0;
  }
  std::vector<std::uint8_t> voxels(s.grid.num_voxels());
  for (auto& v : voxels) v = rng() % 2;
  SystemMatrix a = SystemMatrix::Build(s.grid, Pointers(s), pixels, voxels, SystemMatrixOptions());
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<float> x(a.cols() * 3), y(a.rows() * 3), ax(a.rows() * 3), aty(a.cols() * 3);
  for (auto& v : x) v = u(rng);
  for (auto& v : y) v = u(rng);
  a.Multiply(x.data(), ax.data(), 3);
  a.MultiplyTransposed(y.data(), aty.data(), 3);
  double lhs = 0, rhs = 0;
  for (std::size_t i = 0; i < y.size(); ++i) lhs += double(ax[i]) * y[i];
  for (std::size_t j = 0; j < x.size(); ++j) rhs += double(x[j]) * aty[j];
  EXPECT_NEAR(lhs, rhs, 1e-4 * std::abs(lhs));
  // Sums.
  for (std::size_t r = 0; r < a.rows(); r += 97) {
    double sum = 0;
    std::vector<float> e(a.cols() * 3, 0.0f), out(a.rows() * 3);
    for (auto& v : e) v = 1.0f;
    a.Multiply(e.data(), out.data(), 3);
    sum = out[r * 3];
    EXPECT_NEAR(sum, a.row_sums()[r], 1e-5 * sum);
  }
}

// A x and a camera's rows of it do not depend on the number of threads (a resumed run must give
// exactly what an uninterrupted one gives), and a row range equals the same rows of the whole.
TEST(SystemMatrix, ProductsAreTheSameOnAnyNumberOfThreads) {
  Scene s = MakeScene(3, 20, 1e-6);
  SystemMatrix a = BuildWhole(s);
  ASSERT_EQ(a.camera_row_ranges().size(), 3u);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0, 1);
  std::vector<float> x(a.cols() * 3);
  for (auto& v : x) v = u(rng);
  std::vector<float> one(a.rows() * 3), two(a.rows() * 3), part(a.rows() * 3, -1.0f);
  tbb::task_arena(1).execute([&] { a.Multiply(x.data(), one.data(), 3); });
  tbb::task_arena(2).execute([&] { a.Multiply(x.data(), two.data(), 3); });
  EXPECT_EQ(one, two);
  const auto [first, last] = a.camera_row_ranges()[1];
  a.MultiplyRows(first + 7, last - 5, x.data(), part.data(), 3);
  for (std::size_t i = 0; i < a.rows() * 3; ++i) {
    if (i >= (first + 7) * 3 && i < (last - 5) * 3) {
      ASSERT_EQ(part[i], one[i]) << i;
    } else {
      ASSERT_EQ(part[i], -1.0f) << i;  // rows outside the range untouched
    }
  }
}

// A camera whose fire covers more than 65536 pixels has its rows stored in several blocks (16-bit
// row offsets): its products are still the renderer's thin limit, the adjoint holds, its rows are
// still one camera range for the ordered-subset solvers, and a row range across two blocks equals
// the same rows of the whole product.
TEST(SystemMatrix, ACameraOfMoreThan65536RowsIsStillTheThinLimit) {
  Scene s = MakeScene(2, 12, 1e-9, 960, 720);  // the box covers about 117000 pixels
  SystemMatrix a = BuildWhole(s);
  ASSERT_EQ(a.camera_row_ranges().size(), 2u);
  const auto [first, last] = a.camera_row_ranges()[0];
  ASSERT_GT(last - first, 65536u) << "the test needs a camera of more than 65536 rows";
  std::vector<float> y(a.rows() * 3);
  a.Multiply(s.fire.emission_rgb.data(), y.data(), 3);
  ImageF thin = RenderThinEmission(s.grid, s.fire.emission_rgb, *s.rays[0]);
  double peak = 0;
  for (float v : thin.pixels) peak = std::max(peak, double(v));
  ASSERT_GT(peak, 0);
  for (std::size_t r = first; r < last; ++r)
    for (int c = 0; c < 3; ++c)
      ASSERT_NEAR(y[r * 3 + c], thin.pixels[3 * a.row_pixel(r) + c], 2e-4 * peak) << "row " << r;
  // Rows 65000 to 66000 of the camera cross from its first block to its second.
  std::vector<float> part(a.rows() * 3, -1.0f);
  a.MultiplyRows(first + 65000, first + 66000, s.fire.emission_rgb.data(), part.data(), 3);
  for (std::size_t i = (first + 65000) * 3; i < (first + 66000) * 3; ++i)
    ASSERT_EQ(part[i], y[i]) << i;
  // The adjoint over the camera's rows, and its column sums against A's (weights of both signs,
  // so that a backprojection reading the wrong rows is off by about as much as the sum).
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<float> w(a.rows() * 3), x(a.cols() * 3), col_sums(a.cols());
  for (auto& v : w) v = u(rng);
  a.MultiplyTransposedRows(first, last, w.data(), x.data(), col_sums.data(), 3);
  std::vector<float> ones(a.cols() * 3, 1.0f), a_ones(a.rows() * 3);
  a.Multiply(ones.data(), a_ones.data(), 3);
  double lhs = 0, rhs = 0, sum_rows = 0, sum_cols = 0;
  for (std::size_t i = first * 3; i < last * 3; ++i) lhs += double(a_ones[i]) * w[i];
  for (float v : x) rhs += v;
  for (std::size_t r = first; r < last; ++r) sum_rows += a.row_sums()[r];
  for (float v : col_sums) sum_cols += v;
  EXPECT_NEAR(lhs, rhs, 1e-4 * std::abs(lhs));
  EXPECT_NEAR(sum_rows, sum_cols, 1e-4 * sum_rows);
  // The backprojection of rows 65000 to 66000 (cutting both blocks) is the whole backprojection
  // of weights that are zero outside them, exactly.
  std::vector<float> cut(a.cols() * 3), cut_sums(a.cols()), whole(a.cols() * 3);
  a.MultiplyTransposedRows(first + 65000, first + 66000, w.data(), cut.data(), cut_sums.data(), 3);
  std::vector<float> w_cut(w.size(), 0.0f);
  std::copy(w.begin() + (first + 65000) * 3, w.begin() + (first + 66000) * 3,
            w_cut.begin() + (first + 65000) * 3);
  a.MultiplyTransposed(w_cut.data(), whole.data(), 3);
  EXPECT_EQ(cut, whole);
  double cut_total = 0;
  for (float v : cut) cut_total += std::abs(v);
  EXPECT_GT(cut_total, 0);
}

// The build's threads change nothing: built on one thread and on two, the matrix of a camera
// whose rows span several storage subsets (blocks of rays cut by the subsets' ends) is the same
// file byte for byte.
TEST(SystemMatrix, BuiltTheSameOnAnyNumberOfThreads) {
  Scene s = MakeScene(2, 12, 1e-9, 960, 720);
  SystemMatrix one, two;
  tbb::task_arena(1).execute([&] { one = BuildWhole(s); });
  tbb::task_arena(2).execute([&] { two = BuildWhole(s); });
  ASSERT_GT(one.camera_row_ranges()[0].second - one.camera_row_ranges()[0].first, 65536u);
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_sm_threads_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  one.Save((dir / "one.bin").string());
  two.Save((dir / "two.bin").string());
  auto bytes = [](const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  };
  const std::string a = bytes(dir / "one.bin"), b = bytes(dir / "two.bin");
  fs::remove_all(dir);
  ASSERT_GT(a.size(), 1000u);
  EXPECT_TRUE(a == b) << "sizes " << a.size() << " and " << b.size();
}

// A backprojection told which columns to compute visits those only, once each, with the same
// values as the whole backprojection (the solvers skip the columns outside the hull this way).
TEST(SystemMatrix, BackprojectionOfFlaggedColumnsVisitsThoseOnly) {
  Scene s = MakeScene(3, 16, 1e-9);
  SystemMatrix a = BuildWhole(s);
  ASSERT_EQ(a.camera_row_ranges().size(), 3u);
  const auto [first, last] = a.camera_row_ranges()[1];
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<float> w(a.rows() * 3);
  for (auto& v : w) v = u(rng);
  std::vector<float> whole(a.cols() * 3), whole_sums(a.cols());
  a.MultiplyTransposedRows(first, last, w.data(), whole.data(), whole_sums.data(), 3);
  std::vector<std::uint8_t> flags(a.cols());
  for (auto& f : flags) f = rng() % 3 == 0;
  std::vector<int> visits(a.cols(), 0);
  std::vector<float> g(a.cols() * 3, 0.0f), sums(a.cols(), 0.0f);
  a.BackprojectRows(
      first, last, w.data(), 3,
      [&](std::size_t j, const float* gj, float sum) {
        ++visits[j];
        for (int c = 0; c < 3; ++c) g[j * 3 + c] = gj[c];
        sums[j] = sum;
      },
      flags.data());
  std::size_t flagged = 0, nonzero = 0;
  for (std::size_t j = 0; j < a.cols(); ++j) {
    ASSERT_EQ(visits[j], flags[j] ? 1 : 0) << "column " << j;
    if (!flags[j]) continue;
    ++flagged;
    nonzero += whole_sums[j] > 0;
    EXPECT_EQ(sums[j], whole_sums[j]) << "column " << j;
    for (int c = 0; c < 3; ++c) EXPECT_EQ(g[j * 3 + c], whole[j * 3 + c]) << "column " << j;
  }
  EXPECT_GT(flagged, a.cols() / 5);
  EXPECT_GT(nonzero, flagged / 5);
}

// A matrix built over some voxels (the hull) is the matrix over all voxels with the other columns
// left out: row by row (matched by camera and pixel), A_used x = A_all x when x is zero outside
// the used voxels. The used voxels are scattered singly and in a ball, so that bricks of the
// build's empty-space skipping are flagged from every side (a skipped step that had a used corner
// loses that corner's weight).
TEST(SystemMatrix, BuiltOverSomeVoxelsIsTheWholeMatrixRestricted) {
  Scene s = MakeScene(3, 24, 1e-9);
  const std::vector<std::vector<std::uint8_t>> pixels = AllPixels(s);
  const std::size_t nv = s.grid.num_voxels();
  std::vector<std::uint8_t> all(nv, 1), ball(nv, 0), some(nv, 0);
  std::mt19937 rng(17);
  for (auto& v : some) v = rng() % 40 == 0;
  const Eigen::Vector3i d = s.grid.dims;
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        const Eigen::Vector3d q(i - 0.5 * d.x(), j - 0.4 * d.y(), k - 0.5 * d.z());
        if (q.norm() < 4.5) ball[s.grid.Flat(i, j, k)] = some[s.grid.Flat(i, j, k)] = 1;
      }
  const SystemMatrix a_all =
      SystemMatrix::Build(s.grid, Pointers(s), pixels, all, SystemMatrixOptions());
  std::uniform_real_distribution<float> u(0.5f, 1.5f);
  // Scattered voxels reach every face of the grid; the ball alone is bounded away from them.
  for (const std::vector<std::uint8_t>* mask : {&some, &ball}) {
    SCOPED_TRACE(mask == &ball ? "ball" : "scattered voxels and a ball");
    const SystemMatrix a_some =
        SystemMatrix::Build(s.grid, Pointers(s), pixels, *mask, SystemMatrixOptions());
    ASSERT_LT(a_some.cols(), a_all.cols() / 4);
    std::vector<float> x_voxel(nv, 0.0f);
    for (std::size_t v = 0; v < nv; ++v)
      if ((*mask)[v]) x_voxel[v] = u(rng);
    const auto y_all = ProductByPixel(a_all, x_voxel), y_some = ProductByPixel(a_some, x_voxel);
    double peak = 0;
    for (const auto& [pixel, v] : y_all) peak = std::max(peak, double(v));
    ASSERT_GT(peak, 0);
    std::size_t lit = 0;
    for (const auto& [pixel, v] : y_all) {
      const auto it = y_some.find(pixel);
      const double w = it == y_some.end() ? 0.0 : it->second;
      ASSERT_NEAR(w, v, 1e-5 * peak) << "camera " << pixel.first << ", pixel " << pixel.second;
      lit += v > 0;
    }
    for (const auto& [pixel, v] : y_some) EXPECT_EQ(y_all.count(pixel), 1u);
    EXPECT_GT(lit, y_all.size() / 10);
  }
}

// The build marches a ray only where it passes within a voxel of the used voxels' bounding box:
// rays parallel to an axis at offsets on both sides of each bound, rays that start inside the used
// voxels and inside the grid, and oblique rays that graze the box's widened faces and corners, all
// give the rows of the whole matrix restricted to the used voxels.
TEST(SystemMatrix, TheStepWindowMissesNoUsedVoxel) {
  const Scene s = MakeScene(1, 32, 1e-9);
  const GridGeometry& g = s.grid;
  // The used voxels: a box well inside the grid, and one a voxel from every face (its widened
  // bounds then lie within a step of where rays enter and leave the grid).
  const Eigen::Vector3i one = Eigen::Vector3i::Ones();
  // The third spans x whole (unbounded there) and stops short of y's far face: a ray that
  // crosses its bound on y and leaves the grid through the x face within half a step has a last,
  // shortened step whose midpoint lies before the bound although the step's nominal one does not.
  const std::pair<Eigen::Vector3i, Eigen::Vector3i> boxes[] = {
      {Eigen::Vector3i(4, 9, 5), Eigen::Vector3i(9, 20, 8)},
      {one, g.dims - 2 * one},
      {Eigen::Vector3i(0, 2, 1), Eigen::Vector3i(g.dims.x() - 1, g.dims.y() - 4, g.dims.z() - 2)}};
  for (const auto& [lo, hi] : boxes) {
    SCOPED_TRACE("used voxels from (" + std::to_string(lo.x()) + ", " + std::to_string(lo.y()) +
                 ", " + std::to_string(lo.z()) + ")");
    std::vector<std::uint8_t> used(g.num_voxels(), 0);
    for (int k = lo.z(); k <= hi.z(); ++k)
      for (int j = lo.y(); j <= hi.y(); ++j)
        for (int i = lo.x(); i <= hi.x(); ++i) used[g.Flat(i, j, k)] = 1;
    auto rig_from_index = [&](const Eigen::Vector3d& index) {
      return Eigen::Vector3d(g.VoxelCenter(0, 0, 0) + index.cwiseProduct(g.voxel_size_m));
    };
    std::vector<Ray> rays;
    auto add = [&](const Eigen::Vector3d& origin_index, const Eigen::Vector3d& direction) {
      Ray r;
      r.origin_in_rig = rig_from_index(origin_index);
      r.direction_in_rig = direction.cwiseProduct(g.voxel_size_m).normalized();
      r.valid = true;
      rays.push_back(r);
    };
    // Parallel to each axis, from outside the grid, at offsets around the bounds on the other two.
    const double offsets[] = {-1.2, -1.0, -0.9, -0.5, 0.0, 0.3};
    for (int axis = 0; axis < 3; ++axis) {
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      for (double du : offsets)
        for (double dv : offsets)
          for (int side = 0; side < 2; ++side) {
            Eigen::Vector3d o = 0.5 * (lo + hi).cast<double>();
            o[u] = side ? hi[u] - du : lo[u] + du;
            o[v] = side ? hi[v] - dv : lo[v] + dv;
            o[axis] = -3.0;
            Eigen::Vector3d d = Eigen::Vector3d::Zero();
            d[axis] = 1.0;
            add(o, d);
            o[axis] = g.dims[axis] + 2.0;
            add(o, -d);
          }
    }
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> unit(-1, 1);
    auto random_direction = [&] {
      Eigen::Vector3d d;
      do d = Eigen::Vector3d(unit(rng), unit(rng), unit(rng));
      while (d.norm() < 0.1);
      return d;
    };
    // Starting inside the used voxels, and inside the grid beside them.
    for (int n = 0; n < 40; ++n) {
      const Eigen::Vector3d inside = lo.cast<double>() + 0.5 * (hi - lo).cast<double>() +
                                     Eigen::Vector3d(unit(rng), unit(rng), unit(rng)) * 2.0;
      add(inside, random_direction());
      add(Eigen::Vector3d(2.0, 3.0, 2.5) + Eigen::Vector3d(unit(rng), unit(rng), 0),
          random_direction());
    }
    // Rays at 45 degrees in x and y that cross y's far bound just before the x face where they
    // leave, at 200 phases of their steps.
    for (int n = 0; n < 200; ++n) {
      const double e = 0.3 * (n + 0.5) / 200;  // how far before the x face (index units)
      const Eigen::Vector3d d = Eigen::Vector3d(1, 1, 0).normalized();
      const Eigen::Vector3d p(g.dims.x() - 0.5 - e, hi.y() + 1.0, 0.5 * (lo.z() + hi.z()));
      add(p - (40.0 + 0.01 * n) * d, d);
    }
    // Oblique rays through points on the widened box's faces, edges and corners (within a voxel
    // of the used ones, or just beyond), from outside the grid.
    for (int n = 0; n < 400; ++n) {
      Eigen::Vector3d p;
      for (int a = 0; a < 3; ++a) {
        const double r = unit(rng);
        p[a] = r < -0.3  ? lo[a] - 1.0 + 0.2 * unit(rng)
               : r > 0.3 ? hi[a] + 1.0 + 0.2 * unit(rng)
                         : lo[a] + (hi[a] - lo[a]) * 0.5;
      }
      const Eigen::Vector3d d = random_direction().normalized();
      add(p - 40.0 * d, d);
    }
    const int width = static_cast<int>(rays.size());
    const CameraRays camera(width, 1, rays);
    const std::vector<std::vector<std::uint8_t>> pixels = {std::vector<std::uint8_t>(width, 1)};
    const SystemMatrix whole = SystemMatrix::Build(
        g, {&camera}, pixels, std::vector<std::uint8_t>(g.num_voxels(), 1), SystemMatrixOptions());
    const SystemMatrix some =
        SystemMatrix::Build(g, {&camera}, pixels, used, SystemMatrixOptions());
    std::uniform_real_distribution<float> value(0.5f, 1.5f);
    std::vector<float> x_voxel(g.num_voxels(), 0.0f);
    for (std::size_t v = 0; v < used.size(); ++v)
      if (used[v]) x_voxel[v] = value(rng);
    // Per ray (a pixel of the one camera); a ray with no row sees nothing.
    auto by_ray = [&](const SystemMatrix& a) {
      std::vector<double> y(width, 0.0);
      for (const auto& [pixel, v] : ProductByPixel(a, x_voxel)) y[pixel.second] = v;
      return y;
    };
    const std::vector<double> y_whole = by_ray(whole), y_some = by_ray(some);
    const double peak = *std::max_element(y_whole.begin(), y_whole.end());
    ASSERT_GT(peak, 0);
    int lit = 0, faint = 0;
    for (int p = 0; p < width; ++p) {
      ASSERT_NEAR(y_some[p], y_whole[p], 1e-5 * peak) << "ray " << p;
      lit += y_whole[p] > 0;
      faint += y_whole[p] > 0 && y_whole[p] < 0.05 * peak;
    }
    // Most rays see the used voxels, and some only faintly (a corner's weight at their edge).
    EXPECT_GT(lit, width / 2);
    EXPECT_GT(faint, 10);
  }
}

// The cache key changes with any byte of what it hashes: each voxel of the mask flipped in turn
// (at every offset within the hash's 8-byte words and in the tail), and a ray moved by one ulp.
TEST(SystemMatrix, TheKeyChangesWithEveryByte) {
  Scene s = MakeScene(2, 12, 1e-9);
  const std::vector<std::vector<std::uint8_t>> pixels = AllPixels(s);
  std::vector<std::uint8_t> voxels(s.grid.num_voxels(), 1);
  ASSERT_NE(voxels.size() % 8, 0u) << "the test needs a tail shorter than a word";
  const SystemMatrixOptions options;
  const std::uint64_t key = SystemMatrix::Key(s.grid, Pointers(s), pixels, voxels, options);
  std::set<std::uint64_t> keys = {key};
  for (std::size_t v = 0; v < voxels.size(); ++v) {
    voxels[v] = 0;
    keys.insert(SystemMatrix::Key(s.grid, Pointers(s), pixels, voxels, options));
    voxels[v] = 1;
  }
  EXPECT_EQ(keys.size(), voxels.size() + 1);
  CameraRays moved = *s.rays[1];
  Ray& ray = const_cast<Ray&>(moved.rays()[moved.rays().size() / 2]);
  ray.direction_in_rig.x() = std::nextafter(ray.direction_in_rig.x(), 2.0);
  std::vector<const CameraRays*> rays = {s.rays[0].get(), &moved};
  EXPECT_NE(SystemMatrix::Key(s.grid, rays, pixels, voxels, options), key);
}

TEST(SystemMatrix, CacheRoundTripAndCorruptFiles) {
  Scene s = MakeScene(2, 16, 1e-6);
  const std::vector<std::vector<std::uint8_t>> pixels = AllPixels(s);
  std::vector<std::uint8_t> voxels(s.grid.num_voxels(), 1);
  SystemMatrix a = SystemMatrix::Build(s.grid, Pointers(s), pixels, voxels, SystemMatrixOptions());
  EXPECT_EQ(a.key(), SystemMatrix::Key(s.grid, Pointers(s), pixels, voxels, SystemMatrixOptions()));
  fs::path dir = fs::temp_directory_path() / ("flamerig_sm_test_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string path = (dir / "a.bin").string();
  a.Save(path);
  SystemMatrix b;
  ASSERT_TRUE(b.Load(path, a.key()));
  EXPECT_EQ(b.nnz(), a.nnz());
  std::vector<float> x(a.cols() * 3, 1.0f), ya(a.rows() * 3), yb(a.rows() * 3);
  a.Multiply(x.data(), ya.data(), 3);
  b.Multiply(x.data(), yb.data(), 3);
  EXPECT_EQ(ya, yb);
  SystemMatrix c;
  EXPECT_FALSE(c.Load(path, a.key() + 1));  // another rig or grid
  EXPECT_FALSE(c.Load((dir / "missing.bin").string(), a.key()));
  fs::resize_file(path, fs::file_size(path) / 2);  // truncated
  EXPECT_FALSE(c.Load(path, a.key()));
  std::ofstream(path, std::ios::trunc) << "garbage";
  EXPECT_FALSE(c.Load(path, a.key()));
  EXPECT_EQ(c.rows(), 0u);
  // A cache file with one byte changed anywhere (a disk or copy fault) is either rejected or
  // loads a matrix whose every index is in range: the products never read out of bounds
  // (AddressSanitizer's run of this test checks that).
  a.Save(path);
  std::string bytes;
  {
    std::ifstream in(path, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  std::mt19937 rng(9);
  int rejected = 0;
  for (int trial = 0; trial < 300; ++trial) {
    std::string broken = bytes;
    broken[rng() % broken.size()] ^= static_cast<char>(1 + rng() % 255);
    std::ofstream(path, std::ios::binary | std::ios::trunc) << broken;
    SystemMatrix d;
    if (!d.Load(path, a.key())) {
      ++rejected;
      continue;
    }
    std::vector<float> xd(d.cols() * 3, 1.0f), yd(d.rows() * 3), back(d.cols() * 3);
    std::vector<float> sums(d.cols());
    d.Multiply(xd.data(), yd.data(), 3);
    d.MultiplyTransposed(yd.data(), back.data(), 3);
    // Ranges that cut a camera's rows (the searches in its runs).
    for (const auto& [r0, r1] : d.camera_row_ranges()) {
      if (r1 - r0 < 20) continue;
      d.MultiplyRows(r0 + 7, r1 - 5, xd.data(), yd.data(), 3);
      d.MultiplyTransposedRows(r0 + 7, r1 - 5, yd.data(), back.data(), sums.data(), 3);
    }
  }
  EXPECT_GT(rejected, 0);
  // A row offset past its block's rows (the first stored entry's, set to 65535) is rejected. The
  // file: magic and key, then length-prefixed arrays: the blocks' row ranges (two per camera
  // here), the column pointers (32-bit, a block's columns + 1), the blocks' first entries, the
  // entries (16-bit row offset, 16-bit value).
  ASSERT_EQ(a.camera_row_ranges().size(), 2u);
  ASSERT_LT(a.rows(), 65535u);
  const std::size_t entries_at =
      16 + (8 + 2 * 2 * 8) + (8 + 2 * (a.cols() + 1) * 4) + (8 + 3 * 8) + 8;
  std::string bad_row = bytes;
  bad_row[entries_at] = bad_row[entries_at + 1] = static_cast<char>(0xff);
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bad_row;
  SystemMatrix e;
  EXPECT_FALSE(e.Load(path, a.key()));
  // The same file unchanged loads (the offset above is the entries' start).
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
  EXPECT_TRUE(e.Load(path, a.key()));
  // A different mask gives a different key.
  voxels[5] = 0;
  EXPECT_NE(a.key(), SystemMatrix::Key(s.grid, Pointers(s), pixels, voxels, SystemMatrixOptions()));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
