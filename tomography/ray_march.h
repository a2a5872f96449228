// Ray marching through a voxel grid: the discretisation shared by the renderer (fitting/renderer.h)
// and the tomography's system matrix (tomography/system_matrix.h), so that the matrix is exactly
// the renderer's optically thin limit.
//
// A ray enters the grid's box at t_enter and leaves at t_exit (metres along the unit direction;
// rays starting inside the box enter at 0). It is cut into steps of step_m from t_enter, the last
// step shortened to end at t_exit; step k spans [t_enter + k step_m, min(t_enter + (k+1) step_m,
// t_exit)] and the medium is sampled at the step's midpoint. Samples are trilinear in index
// coordinates (voxel centres at integers, see volume.h), clamped to the grid, so values outside the
// outermost voxel centres repeat the border voxels.
#ifndef FLAMERIG_TOMOGRAPHY_RAY_MARCH_H_
#define FLAMERIG_TOMOGRAPHY_RAY_MARCH_H_

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

#include "calibration/camera_model.h"
#include "tomography/volume.h"

namespace flamerig {

// The slabs of the axis-aligned box [lo, hi] (bounds may be infinite) along a whole line: the
// line lies between them for t in [*t0, *t1], which is empty (*t1 <= *t0) when it passes beside
// the box; false only when the line is parallel to an axis and outside that axis's slab.
inline bool SlabInterval(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                         const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, double* t0,
                         double* t1) {
  *t0 = -std::numeric_limits<double>::infinity();
  *t1 = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    if (std::abs(direction[a]) < 1e-300) {
      if (origin[a] < lo[a] || origin[a] > hi[a]) return false;
      continue;
    }
    const double inv = 1.0 / direction[a];
    double ta = (lo[a] - origin[a]) * inv, tb = (hi[a] - origin[a]) * inv;
    if (ta > tb) std::swap(ta, tb);
    *t0 = std::max(*t0, ta);
    *t1 = std::min(*t1, tb);
  }
  return true;
}

// Entry and exit distances (t >= 0) of a ray with the axis-aligned box [lo, hi]; false when it
// misses or only touches it.
inline bool IntersectBox(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                         const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, double* t_enter,
                         double* t_exit) {
  double t0, t1;
  if (!SlabInterval(origin, direction, lo, hi, &t0, &t1)) return false;
  t0 = std::max(t0, 0.0);
  if (!(t1 > t0)) return false;
  *t_enter = t0;
  *t_exit = t1;
  return true;
}

// The steps of one ray through one grid.
struct RayMarch {
  double t_enter = 0, t_exit = 0, step_m = 0;
  std::int64_t n_steps = 0;
  Eigen::Vector3d origin_index = Eigen::Vector3d::Zero();     // ray origin in index coordinates
  Eigen::Vector3d direction_index = Eigen::Vector3d::Zero();  // index units per metre along the ray

  // False when the ray is invalid or misses the grid's box.
  static bool Make(const GridGeometry& grid, const Ray& ray, double step_m, RayMarch* march) {
    if (!ray.valid) return false;
    const Box3 box = grid.box();
    if (!IntersectBox(ray.origin_in_rig, ray.direction_in_rig, box.min_in_rig, box.max_in_rig,
                      &march->t_enter, &march->t_exit)) {
      return false;
    }
    march->step_m = step_m;
    march->n_steps = std::max<std::int64_t>(
        1, static_cast<std::int64_t>(std::ceil((march->t_exit - march->t_enter) / step_m - 1e-9)));
    march->origin_index = grid.IndexFromRig(ray.origin_in_rig);
    march->direction_index = ray.direction_in_rig.cwiseQuotient(grid.voxel_size_m);
    return true;
  }
  // Step k: its length (metres) and its midpoint in index coordinates.
  void Step(std::int64_t k, double* length_m, Eigen::Vector3d* midpoint_index) const {
    const double ta = t_enter + k * step_m;
    const double tb = std::min(ta + step_m, t_exit);
    *length_m = tb - ta;
    *midpoint_index = origin_index + (0.5 * (ta + tb)) * direction_index;
  }
  // The first step whose midpoint lies at or beyond distance t (for skipping), clamped to n_steps.
  std::int64_t FirstStepAfter(double t) const {
    const double k = std::ceil((t - t_enter) / step_m - 0.5);
    if (!(k > 0)) return 0;
    return k >= double(n_steps) ? n_steps : static_cast<std::int64_t>(k);
  }
};

// The trilinear stencil at a point in index coordinates, clamped to the grid: 8 corners (with
// repeats on grids one voxel thick) and their weights.
template <typename Real>
struct TrilinearStencil {
  int i0, j0, k0, i1, j1, k1;
  Real fx, fy, fz;

  TrilinearStencil(const Eigen::Vector3i& dims, Real x, Real y, Real z) {
    Setup(dims.x(), x, &i0, &i1, &fx);
    Setup(dims.y(), y, &j0, &j1, &fy);
    Setup(dims.z(), z, &k0, &k1, &fz);
  }
  static void Setup(int n, Real c, int* a, int* b, Real* f) {
    c = std::clamp(c, Real(0), Real(n - 1));
    const int lo = std::min(static_cast<int>(c), std::max(n - 2, 0));
    *a = lo;
    *b = std::min(lo + 1, n - 1);
    *f = c - Real(lo);
  }
  // Interpolated value of a scalar field flattened as in volume.h.
  Real Sample(const float* field, std::size_t nx, std::size_t nxy) const {
    auto at = [&](int i, int j, int k) { return Real(field[i + nx * j + nxy * k]); };
    const Real c00 = at(i0, j0, k0) + fx * (at(i1, j0, k0) - at(i0, j0, k0));
    const Real c10 = at(i0, j1, k0) + fx * (at(i1, j1, k0) - at(i0, j1, k0));
    const Real c01 = at(i0, j0, k1) + fx * (at(i1, j0, k1) - at(i0, j0, k1));
    const Real c11 = at(i0, j1, k1) + fx * (at(i1, j1, k1) - at(i0, j1, k1));
    const Real c0 = c00 + fy * (c10 - c00);
    const Real c1 = c01 + fy * (c11 - c01);
    return c0 + fz * (c1 - c0);
  }
  // The 8 corners' flat indices and weights (summing to 1): Sample() == sum weight[c] *
  // field[flat[c]].
  void Corners(std::size_t nx, std::size_t nxy, std::size_t flat[8], Real weight[8]) const {
    const int is[2] = {i0, i1}, js[2] = {j0, j1}, ks[2] = {k0, k1};
    const Real wx[2] = {Real(1) - fx, fx}, wy[2] = {Real(1) - fy, fy}, wz[2] = {Real(1) - fz, fz};
    int n = 0;
    for (int c = 0; c < 2; ++c)
      for (int b = 0; b < 2; ++b)
        for (int a = 0; a < 2; ++a, ++n) {
          flat[n] = is[a] + nx * js[b] + nxy * ks[c];
          weight[n] = wx[a] * wy[b] * wz[c];
        }
  }
};

}  // namespace flamerig

#endif  // FLAMERIG_TOMOGRAPHY_RAY_MARCH_H_
