// The tomography's linear model. With negligible self-absorption a pixel is a line integral of the
// per-voxel emission e (linear RGB radiance per metre), so each colour channel satisfies A e = b:
//
//   b_i = sum_j A_ij e_j,
//   A_ij = sum over the steps of ray i of (step length) * (trilinear weight of voxel j at the step's
//          midpoint),
//
// exactly the renderer's optically thin limit (the same ray march, ray_march.h). Rows are the
// pixels used (camera, pixel); columns are the voxels used (inside the visual hull). Weights of
// voxels outside the columns are dropped: those voxels are taken as empty.
//
// Storage: CSR for A and for its transpose (so A x and A^T y both run in parallel without atomics),
// float values, 32-bit column indices. A matrix can be saved to and loaded from a binary cache
// file; the file starts with a key (a hash of everything the matrix depends on) and is rejected if
// it differs.
#ifndef FLAMERIG_TOMOGRAPHY_SYSTEM_MATRIX_H_
#define FLAMERIG_TOMOGRAPHY_SYSTEM_MATRIX_H_

#include <algorithm>
#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "calibration/camera_rays.h"
#include "tomography/volume.h"

namespace flamerig {

struct SystemMatrixOptions {
  double step_voxels = 0.5;  // march step in units of the smallest voxel edge; (0, 0.5] keeps
                             // samples at most half a voxel apart
  void Validate() const;
};

class SystemMatrix {
 public:
  SystemMatrix() = default;

  // Builds A for the pixels with pixel_used[camera][pixel] != 0 and the voxels with voxel_used !=
  // 0. `cameras` are the rays of each camera; pixel_used is parallel to it. Rows whose ray meets no
  // used voxel are dropped. Multithreaded.
  static SystemMatrix Build(const GridGeometry& grid, const std::vector<const CameraRays*>& cameras,
                            const std::vector<std::vector<std::uint8_t>>& pixel_used,
                            const std::vector<std::uint8_t>& voxel_used,
                            const SystemMatrixOptions& options);

  std::size_t rows() const { return row_camera_.size(); }
  std::size_t cols() const { return col_voxel_.size(); }
  std::size_t nnz() const { return values_.size(); }
  std::size_t bytes() const;
  double build_ms() const { return build_ms_; }

  int row_camera(std::size_t r) const { return row_camera_[r]; }
  int row_pixel(std::size_t r) const { return row_pixel_[r]; }
  std::size_t col_voxel(std::size_t c) const { return col_voxel_[c]; }
  const std::vector<std::uint32_t>& col_voxels() const { return col_voxel_; }

  // y = A x and x = A^T y for `channels` interleaved channels (x: cols * channels, y: rows *
  // channels).
  void Multiply(const float* x, float* y, int channels) const;
  void MultiplyTransposed(const float* y, float* x, int channels) const;
  // Rows of one camera form a contiguous range [first, last); subsets of rows for ordered-subset
  // solvers. Empty when the rows are not grouped by camera.
  const std::vector<std::pair<std::size_t, std::size_t>>& camera_row_ranges() const {
    return camera_ranges_;
  }
  // Backprojection restricted to the rows [first, last): x = A_sub^T y (y indexed by global row) and the
  // restricted column sums, in one pass.
  void MultiplyTransposedRows(std::size_t first, std::size_t last, const float* y, float* x,
                              float* col_sums, int channels) const;
  // The same backprojection handed column by column to `visit(j, g_j, col_sum_j)` (g_j: `channels`
  // values), so that a solver can update x_j in the same pass over memory. Columns are visited in
  // parallel, each exactly once; `visit` must only touch data of column j.
  template <typename Visit>
  void BackprojectRows(std::size_t first, std::size_t last, const float* y, int channels,
                       Visit&& visit) const;
  // Forward projection of the rows [first, last) only (y indexed by global row).
  void MultiplyRows(std::size_t first, std::size_t last, const float* x, float* y,
                    int channels) const;
  // Row sums (sum_j A_ij) and column sums (sum_i A_ij).
  const std::vector<float>& row_sums() const { return row_sums_; }
  const std::vector<float>& col_sums() const { return col_sums_; }

  // A key for caching: a hash of the grid, the cameras' rays, the masks and the options.
  static std::uint64_t Key(const GridGeometry& grid, const std::vector<const CameraRays*>& cameras,
                           const std::vector<std::vector<std::uint8_t>>& pixel_used,
                           const std::vector<std::uint8_t>& voxel_used,
                           const SystemMatrixOptions& options);
  std::uint64_t key() const { return key_; }

  // Binary cache file. Save throws std::runtime_error naming the path on I/O failure (writes to
  // path.tmp, then renames). Load returns false (and leaves *this untouched) when the file is
  // missing, truncated, corrupt or made for another key; it never throws for a bad cache file.
  void Save(const std::string& path) const;
  bool Load(const std::string& path, std::uint64_t expected_key);

 private:
  void BuildTranspose();
  // Runs fn(j0, j1) over blocks of columns in parallel (TBB, kept out of this header).
  void ParallelColumns(const std::function<void(std::size_t, std::size_t)>& fn) const;

  std::uint64_t key_ = 0;
  std::vector<std::int64_t> row_ptr_;  // rows + 1
  std::vector<std::uint32_t> cols_;    // nnz
  std::vector<float> values_;          // nnz
  std::vector<std::int64_t> t_ptr_;    // transpose: cols + 1
  std::vector<std::uint32_t> t_rows_;
  std::vector<float> t_values_;
  std::vector<std::int32_t> row_camera_, row_pixel_;
  std::vector<std::uint32_t> col_voxel_;
  std::vector<float> row_sums_, col_sums_;
  std::vector<std::pair<std::size_t, std::size_t>> camera_ranges_;
  // For each column, where each camera's entries start in its transposed run (relative offsets,
  // cameras + 1 per column), so that a subset backprojection needs no search.
  std::vector<std::uint32_t> t_camera_offsets_;
  double build_ms_ = 0;
};

template <typename Visit>
void SystemMatrix::BackprojectRows(std::size_t first, std::size_t last, const float* y,
                                   int channels, Visit&& visit) const {
  int subset = -1;
  const std::size_t ns = camera_ranges_.size() + 1;
  if (t_camera_offsets_.size() == cols() * ns) {
    for (std::size_t c = 0; c < camera_ranges_.size(); ++c) {
      if (camera_ranges_[c].first == first && camera_ranges_[c].second == last)
        subset = static_cast<int>(c);
    }
  }
  ParallelColumns([&](std::size_t j0, std::size_t j1) {
    for (std::size_t j = j0; j < j1; ++j) {
      const std::uint32_t* begin = t_rows_.data() + t_ptr_[j];
      const std::uint32_t* end = t_rows_.data() + t_ptr_[j + 1];
      const std::uint32_t* lo;
      const std::uint32_t* hi;
      if (subset >= 0) {
        lo = begin + t_camera_offsets_[j * ns + subset];
        hi = begin + t_camera_offsets_[j * ns + subset + 1];
      } else {
        lo = std::lower_bound(begin, end, static_cast<std::uint32_t>(first));
        hi = std::lower_bound(lo, end, static_cast<std::uint32_t>(last));
      }
      float acc[4] = {0, 0, 0, 0};
      float sum = 0;
      for (const std::uint32_t* it = lo; it < hi; ++it) {
        const float v = t_values_[it - t_rows_.data()];
        const float* yr = y + static_cast<std::size_t>(*it) * channels;
        for (int ch = 0; ch < channels; ++ch) acc[ch] += v * yr[ch];
        sum += v;
      }
      visit(j, acc, sum);
    }
  });
}

}  // namespace flamerig

#endif  // FLAMERIG_TOMOGRAPHY_SYSTEM_MATRIX_H_
