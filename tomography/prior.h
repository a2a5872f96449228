// Smoothness priors for the tomography's solve (solvers.h, SolveOptions::prior): an energy U(x)
// over the six face neighbours of the solve's columns, for each of its channels (three, or one for
// grey data). With
// N the grid's voxels along its longest side and L > 0 the channel's scale (the solve's uniform
// emission level), a neighbour pair's difference is read as a gradient across the grid,
// g = N (x_j - x_k) / L, and U is a mean over the N^3 voxels of a cube of that side:
//
//  - "quadratic" (a Laplacian, or Gaussian Markov random field): U = sum over pairs g^2 / 2 / N^3,
//  - "tv" (total variation, anisotropic, smoothed so that it has a gradient everywhere):
//        U = sum over pairs sqrt(g^2 + edge^2) / N^3.
//
// So U is unit-free and does not change with the grid's resolution for a given smooth field (the
// discrete sums approximate the integrals of |grad x|^2 and |grad x|), and one weight suits any
// exposure, voxel size, unit of radiance or grid. The quadratic prior smooths everything; TV
// smooths gradients below `edge` (the level's change across the grid) quadratically and larger
// ones (edges) by a bounded force: |dU/dx_j| <= 6 / (N^2 L).
//
// Pairs are counted between columns of the solve, and between a column and a voxel of the grid
// that is not one (outside the envelope the matrix was built for), valued 0: space outside the
// hull is empty. Columns the solve pins at zero (outside this frame's hull, inside the envelope)
// are zero too, so the hull's edge is drawn towards empty space the same way whatever the
// envelope's margin. Pairs off the grid do not count.
#ifndef FLAMERIG_TOMOGRAPHY_PRIOR_H_
#define FLAMERIG_TOMOGRAPHY_PRIOR_H_

#include <cstdint>
#include <string>
#include <vector>

#include "tomography/volume.h"

namespace flamerig {

enum class PriorKind { kNone, kQuadratic, kTotalVariation };
// "none" | "quadratic" | "tv"; throws InputError listing the names.
PriorKind ParsePriorKind(const std::string& name);
const char* ToString(PriorKind kind);

// The weight a prior has by default (SolveOptions::prior_weight -1): tv 3e-4, quadratic 1e-5.
double DefaultPriorWeight(PriorKind kind);

class GridPrior {
 public:
  // The columns' voxels (flat indices on `grid`, SystemMatrix::col_voxels()); `edge` > 0 is TV's
  // smoothing (a gradient, as g above).
  GridPrior(PriorKind kind, const GridGeometry& grid, const std::vector<std::uint32_t>& col_voxels,
            double edge);

  PriorKind kind() const { return kind_; }
  std::size_t cols() const { return cols_; }
  // The number of a column's neighbours that are columns too (0..6).
  int NeighbourCount(std::size_t col) const;

  // U(x) for x of cols * channels values (interleaved channels, 1 to 3) and a scale per channel
  // (> 0).
  double Energy(const float* x, int channels, const float* scale) const;
  // dU/dx into g (cols * channels values). Multithreaded over columns; each g_j is written once.
  void Gradient(const float* x, int channels, const float* scale, float* g) const;

  // A separable quadratic majoriser of U at x0, for a MAP update that cannot overshoot (osem.cc):
  //     Q(x) = sum over columns and channels of (k_j x_j^2 / 2 - m_j x_j), plus a constant,
  // with Q(x) - Q(x0) >= U(x) - U(x0) for every x >= 0 and grad Q(x0) = grad U(x0). TV's pair
  // term is first bounded by a quadratic in the pair's difference (sqrt(t + edge^2) is concave in
  // t = g^2: a pair weighs 1 / sqrt(g0^2 + edge^2), the half-quadratic or IRLS bound; the
  // quadratic prior's weight is 1), then each pair of columns is split between its two ends by
  // convexity (De Pierro 1995): (x_j - x_k)^2 <= ((2 x_j - x0_j - x0_k)^2 + (2 x_k - x0_j -
  // x0_k)^2) / 2; a pair with an empty voxel is exact. Writes column `col`'s k and m (`channels`
  // values each; k >= 0; in double: they scale as 1 / scale^2 and 1 / scale). One column at a
  // time, as the solve needs it only where the one-step-late step would overshoot.
  void MajoriserAt(std::size_t col, const float* x0, int channels, const float* scale, double* k,
                   double* m) const;

 private:
  PriorKind kind_;
  std::size_t cols_ = 0;
  double edge_ = 0;
  double n_ = 1;  // voxels along the grid's longest side
  // Per column, its six neighbours' columns (-x, +x, -y, +y, -z, +z); kOffGrid where there is no
  // voxel, kEmpty where the voxel is not a column (valued 0).
  static constexpr std::int32_t kOffGrid = -1, kEmpty = -2;
  std::vector<std::int32_t> neighbours_;
};

}  // namespace flamerig

#endif  // FLAMERIG_TOMOGRAPHY_PRIOR_H_
