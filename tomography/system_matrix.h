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
// Storage: one copy of A, column-major within blocks of rows ("subsets"; a subset is at most 65536
// rows of one camera, so a camera of more fire pixels has several): for subset s and column j, the
// entries (row, value) sorted by row, 4 bytes per non-zero: the row as a 16-bit offset from the
// subset's first row, and the value as a 16-bit fraction of the column's largest value
// (A_ij = q * scale_j, scale_j = max_i A_ij / 65535: a relative error of at most 7.6e-6 of the
// column's largest weight, far below 8-bit pixel noise). A column's pointers are 32-bit offsets
// into its subset's entries. Each column's run in a subset is padded with zero-valued entries to a
// multiple of 4 (about 17% more entries at 128^3 from 8 views) so that the products' inner loops
// run four at a time: the runs hold about four entries, and a loop whose length varies around four
// mispredicts its exit at nearly every column. Measured (issue 24, 128^3 from 8 views, the first
// frame's 47 OS-EM iterations, best of three alternating runs): 8-byte entries 1303 ms, 4-byte
// entries 1144 ms, 4-byte entries in padded runs 926 ms. The products are bound by the work per
// column more than by bandwidth. Before issue 24 an entry took 8 bytes (a 32-bit row, a float)
// and a pointer 8.
// A^T y runs over columns in parallel without atomics, and the backprojection of one camera's rows
// (ordered-subset solvers) streams through contiguous blocks; A x scatters each subset's entries
// column block by column block into a buffer of that subset's rows and sums the blocks in order
// (the same result whatever the number of threads and whichever rows are asked for). A matrix
// held twice (rows and columns) needed twice the memory: 16 bytes per non-zero, 1.6 GB for a
// 72x108x72 grid seen by four 640x360 cameras (issue 20). Three colour channels have specialised
// kernels. A matrix can be saved to and loaded from a binary cache file; the file starts with a
// key (a hash of everything the matrix depends on) and is rejected if it differs.
#ifndef FLAMERIG_TOMOGRAPHY_SYSTEM_MATRIX_H_
#define FLAMERIG_TOMOGRAPHY_SYSTEM_MATRIX_H_

#include <algorithm>
#include <cstdint>
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "calibration/camera_rays.h"
#include "core/error.h"
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
  // used voxel are dropped. Multithreaded. `key`: Key() of these same arguments when the caller has
  // computed it already (to look for a cached file): it hashes every ray, tens of milliseconds for
  // a rig of 640x360 cameras; computed here when absent.
  static SystemMatrix Build(const GridGeometry& grid, const std::vector<const CameraRays*>& cameras,
                            const std::vector<std::vector<std::uint8_t>>& pixel_used,
                            const std::vector<std::uint8_t>& voxel_used,
                            const SystemMatrixOptions& options,
                            std::optional<std::uint64_t> key = std::nullopt);

  std::size_t rows() const { return row_camera_.size(); }
  std::size_t cols() const { return col_voxel_.size(); }
  std::size_t nnz() const { return nonzeros_; }  // the entries of A, not counting padding
  std::size_t stored_entries() const { return t_entries_.size(); }  // with the padding
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
  // parallel, each exactly once; `visit` must only touch data of column j. With `columns` (one flag
  // per column), only the flagged columns are computed and visited: a solver whose other columns
  // stay at zero (outside this frame's hull, inside the envelope the matrix was built for) skips
  // their work.
  template <typename Visit>
  void BackprojectRows(std::size_t first, std::size_t last, const float* y, int channels,
                       Visit&& visit, const std::uint8_t* columns = nullptr) const;
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

  // Binary cache file. Save throws IoError naming the path on I/O failure (writes to
  // path.tmp, then renames). Load returns false (and leaves *this untouched) when the file is
  // missing, truncated, corrupt or made for another key; it never throws for a bad cache file.
  void Save(const std::string& path) const;
  bool Load(const std::string& path, std::uint64_t expected_key);
  // Whether every row's camera and pixel and every column's voxel lie in these cameras' images
  // and a grid of num_voxels (columns ascending, as Build makes them). Load checks the matrix's
  // own structure; a caller that indexes images and grids with a loaded matrix checks this too.
  bool IndicesFit(const std::vector<const CameraRays*>& cameras, std::size_t num_voxels) const;

 private:
  // Row and column sums from the entries (after building or loading).
  void ComputeSums();
  // The contiguous row ranges of each camera (empty when a camera's rows are not contiguous).
  static std::vector<std::pair<std::size_t, std::size_t>> CameraRanges(
      const std::vector<std::int32_t>& row_camera);
  // The storage subsets: each range (all `rows` when there are none) cut into pieces of at most
  // kSubsetRows rows.
  static std::vector<std::pair<std::size_t, std::size_t>> SplitRows(
      const std::vector<std::pair<std::size_t, std::size_t>>& ranges, std::size_t rows);
  // Checks a loaded matrix's structure (no index out of range); false when it is broken.
  bool Consistent() const;
  // Runs fn(j0, j1) over blocks of columns in parallel (TBB, kept out of this header).
  void ParallelColumns(const std::function<void(std::size_t, std::size_t)>& fn) const;

  std::uint64_t key_ = 0;
  std::uint64_t nonzeros_ = 0;
  // The entries, subset by subset (a subset is at most kSubsetRows rows of one camera's row range;
  // when the rows are not grouped by camera, the subsets split all rows): entries of subset s,
  // column j are t_entries_[subset_entries_[s] + t_ptr_[s * (cols + 1) + j] .. subset_entries_[s] +
  // t_ptr_[s * (cols + 1) + j + 1]), sorted by row; row = subsets_[s].first + Entry::row, value =
  // Entry::q * col_scale_[j].
  static constexpr std::size_t kSubsetRows = 65536;
  static constexpr std::size_t kRunMultiple = 4;  // a column's run in a subset is padded to this
  struct Entry {
    std::uint16_t row;  // offset from the subset's first row
    std::uint16_t q;    // value / col_scale_[column]
  };
  // Entries [lo, hi) of subset s, column j.
  const Entry* ColumnBegin(std::size_t s, std::size_t j) const {
    return t_entries_.data() + subset_entries_[s] + t_ptr_[s * (col_voxel_.size() + 1) + j];
  }
  const Entry* ColumnEnd(std::size_t s, std::size_t j) const {
    return t_entries_.data() + subset_entries_[s] + t_ptr_[s * (col_voxel_.size() + 1) + j + 1];
  }
  std::vector<std::uint32_t> t_ptr_;
  std::vector<std::uint64_t> subset_entries_;  // first entry of each subset, and the total
  std::vector<Entry> t_entries_;
  std::vector<float> col_scale_;
  std::vector<std::pair<std::size_t, std::size_t>> subsets_;  // row range of each subset
  std::vector<std::int32_t> row_camera_, row_pixel_;
  std::vector<std::uint32_t> col_voxel_;
  std::vector<float> row_sums_, col_sums_;
  std::vector<std::pair<std::size_t, std::size_t>> camera_ranges_;
  double build_ms_ = 0;
};

template <typename Visit>
void SystemMatrix::BackprojectRows(std::size_t first, std::size_t last, const float* y,
                                   int channels, Visit&& visit, const std::uint8_t* columns) const {
  if (channels < 1 || channels > 4)
    throw InputError("SystemMatrix: 1 to 4 channels, not " + std::to_string(channels));
  // Subsets overlapping [first, last); a subset wholly inside needs no row filtering.
  std::vector<std::size_t> parts;
  for (std::size_t s = 0; s < subsets_.size(); ++s)
    if (subsets_[s].first < last && subsets_[s].second > first &&
        subsets_[s].first < subsets_[s].second)
      parts.push_back(s);
  auto run = [&](auto kChannels) {
    constexpr int kC = decltype(kChannels)::value;
    const int nc = kC > 0 ? kC : channels;
    ParallelColumns([&](std::size_t j0, std::size_t j1) {
      for (std::size_t j = j0; j < j1; ++j) {
        if (columns && !columns[j]) continue;
        float acc[4] = {0, 0, 0, 0};
        float sum = 0;
        for (std::size_t s : parts) {
          const Entry* lo = ColumnBegin(s, j);
          const Entry* hi = ColumnEnd(s, j);
          const std::size_t base = subsets_[s].first;
          if (base < first || subsets_[s].second > last) {
            // Offsets within the subset of the range's ends (0 or the subset's size when the
            // range covers that end).
            const std::size_t r0 = std::max(first, base) - base;
            const std::size_t r1 = std::min(last, subsets_[s].second) - base;
            lo = std::lower_bound(lo, hi, r0,
                                  [](const Entry& e, std::size_t r) { return e.row < r; });
            hi = std::lower_bound(lo, hi, r1,
                                  [](const Entry& e, std::size_t r) { return e.row < r; });
          }
          const float* ys = y + base * nc;
          const Entry* e = lo;
          for (; e + 4 <= hi; e += 4) {
            for (int k = 0; k < 4; ++k) {
              const float q = e[k].q;
              const float* yr = ys + static_cast<std::size_t>(e[k].row) * nc;
              for (int ch = 0; ch < (kC > 0 ? kC : nc); ++ch) acc[ch] += q * yr[ch];
              sum += q;
            }
          }
          for (; e < hi; ++e) {
            const float q = e->q;
            const float* yr = ys + static_cast<std::size_t>(e->row) * nc;
            for (int ch = 0; ch < (kC > 0 ? kC : nc); ++ch) acc[ch] += q * yr[ch];
            sum += q;
          }
        }
        const float scale = col_scale_[j];
        for (int ch = 0; ch < (kC > 0 ? kC : nc); ++ch) acc[ch] *= scale;
        sum *= scale;
        visit(j, acc, sum);
      }
    });
  };
  if (channels == 3) {
    run(std::integral_constant<int, 3>());
  } else if (channels == 1) {
    run(std::integral_constant<int, 1>());
  } else {
    run(std::integral_constant<int, 0>());
  }
}

}  // namespace flamerig

#endif  // FLAMERIG_TOMOGRAPHY_SYSTEM_MATRIX_H_
