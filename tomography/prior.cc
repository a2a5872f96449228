#include "tomography/prior.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "core/error.h"

namespace flamerig {

PriorKind ParsePriorKind(const std::string& name) {
  if (name == "none") return PriorKind::kNone;
  if (name == "quadratic") return PriorKind::kQuadratic;
  if (name == "tv") return PriorKind::kTotalVariation;
  throw InputError("prior '" + name + "' is unknown; use one of none, quadratic, tv");
}

const char* ToString(PriorKind kind) {
  switch (kind) {
    case PriorKind::kNone:
      return "none";
    case PriorKind::kQuadratic:
      return "quadratic";
    case PriorKind::kTotalVariation:
      return "tv";
  }
  return "?";
}

double DefaultPriorWeight(PriorKind kind) {
  switch (kind) {
    case PriorKind::kQuadratic:
      return 1e-5;
    case PriorKind::kTotalVariation:
      return 3e-4;
    case PriorKind::kNone:
      break;
  }
  return 0.0;
}

GridPrior::GridPrior(PriorKind kind, const GridGeometry& grid,
                     const std::vector<std::uint32_t>& col_voxels, double edge)
    : kind_(kind), cols_(col_voxels.size()), edge_(edge) {
  if (!(edge > 0) || !std::isfinite(edge))
    throw InputError("GridPrior: the edge must be finite and > 0");
  const std::size_t voxels = grid.num_voxels();
  std::vector<std::int32_t> column_of(voxels, -1);
  for (std::size_t c = 0; c < cols_; ++c) {
    if (col_voxels[c] >= voxels) throw InputError("GridPrior: a column's voxel is off the grid");
    column_of[col_voxels[c]] = static_cast<std::int32_t>(c);
  }
  const int nx = grid.dims.x(), ny = grid.dims.y(), nz = grid.dims.z();
  n_ = std::max(1, grid.dims.maxCoeff());
  neighbours_.assign(cols_ * 6, kOffGrid);
  for (std::size_t c = 0; c < cols_; ++c) {
    const std::size_t v = col_voxels[c];
    const int i = static_cast<int>(v % nx), j = static_cast<int>((v / nx) % ny),
              k = static_cast<int>(v / (static_cast<std::size_t>(nx) * ny));
    const int at[6][3] = {{i - 1, j, k}, {i + 1, j, k}, {i, j - 1, k},
                          {i, j + 1, k}, {i, j, k - 1}, {i, j, k + 1}};
    for (int n = 0; n < 6; ++n) {
      const int a = at[n][0], b = at[n][1], d = at[n][2];
      if (a < 0 || b < 0 || d < 0 || a >= nx || b >= ny || d >= nz) continue;
      const std::int32_t k = column_of[grid.Flat(a, b, d)];
      neighbours_[c * 6 + n] = k >= 0 ? k : kEmpty;
    }
  }
}

int GridPrior::NeighbourCount(std::size_t col) const {
  int n = 0;
  for (int q = 0; q < 6; ++q) n += neighbours_[col * 6 + q] != kOffGrid;
  return n;
}

double GridPrior::Energy(const float* x, int channels, const float* scale) const {
  if (kind_ == PriorKind::kNone) return 0.0;
  double u = 0;
  for (std::size_t c = 0; c < cols_; ++c)
    for (int q = 0; q < 6; ++q) {
      // Each pair once: a pair of columns from its -x, -y or -z side; an empty voxel's pair from
      // the column's.
      const std::int32_t k = neighbours_[c * 6 + q];
      if (k == kOffGrid || (k >= 0 && q % 2 == 0)) continue;
      for (int ch = 0; ch < channels; ++ch) {
        const double other = k >= 0 ? x[std::size_t(k) * channels + ch] : 0.0;
        const double d = n_ * (double(x[c * channels + ch]) - other) / scale[ch];
        u += kind_ == PriorKind::kQuadratic ? 0.5 * d * d : std::sqrt(d * d + edge_ * edge_);
      }
    }
  return u / (n_ * n_ * n_);
}

void GridPrior::Gradient(const float* x, int channels, const float* scale, float* g) const {
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, cols_, 4096),
      [&](const tbb::blocked_range<std::size_t>& range) {
        for (std::size_t c = range.begin(); c < range.end(); ++c)
          for (int ch = 0; ch < channels; ++ch) {
            double sum = 0;
            if (kind_ != PriorKind::kNone)
              for (int q = 0; q < 6; ++q) {
                const std::int32_t k = neighbours_[c * 6 + q];
                if (k == kOffGrid) continue;
                const double other = k >= 0 ? x[std::size_t(k) * channels + ch] : 0.0;
                const double d = n_ * (double(x[c * channels + ch]) - other) / scale[ch];
                sum += kind_ == PriorKind::kQuadratic ? d : d / std::sqrt(d * d + edge_ * edge_);
              }
            // dg/dx_j = N / L, over N^3.
            g[c * channels + ch] = static_cast<float>(sum / (n_ * n_ * scale[ch]));
          }
      });
}

void GridPrior::MajoriserAt(std::size_t col, const float* x0, int channels, const float* scale,
                            double* k, double* m) const {
  for (int ch = 0; ch < channels; ++ch) {
    // U's pair term as a_jk (x_j - x_k)^2 about x0: rho(g) over N^3 with g = N dx / L is
    // bounded by psi(g0) / 2 g^2 (plus a constant), so a = psi / (2 N L^2).
    const double xj = x0[col * channels + ch], l = scale[ch];
    double kk = 0, mm = 0;
    if (kind_ != PriorKind::kNone)
      for (int q = 0; q < 6; ++q) {
        const std::int32_t o = neighbours_[col * 6 + q];
        if (o == kOffGrid) continue;
        const double other = o >= 0 ? x0[std::size_t(o) * channels + ch] : 0.0;
        const double g0 = n_ * (xj - other) / l;
        const double psi =
            kind_ == PriorKind::kQuadratic ? 1.0 : 1.0 / std::sqrt(g0 * g0 + edge_ * edge_);
        const double a = psi / (2 * n_ * l * l);
        if (o >= 0) {  // a (2 x_j - x0_j - x0_k)^2 / 2: k += 4a, m += 2a (x0_j + x0_k)
          kk += 4 * a;
          mm += 2 * a * (xj + other);
        } else {  // a x_j^2, exact
          kk += 2 * a;
        }
      }
    k[ch] = kk;
    m[ch] = mm;
  }
}

}  // namespace flamerig
