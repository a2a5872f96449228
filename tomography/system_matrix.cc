#include "tomography/system_matrix.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <stdexcept>

#include "core/atomic_file.h"
#include "core/error.h"
#include "tomography/ray_march.h"

namespace flamerig {

void SystemMatrixOptions::Validate() const {
  if (!(step_voxels >= 0.01) || !(step_voxels <= 0.5)) {
    throw InputError("SystemMatrixOptions.step_voxels = " + std::to_string(step_voxels) +
                     ": must be in [0.01, 0.5] (samples at most half a voxel apart, "
                     "at most 100 per voxel)");
  }
}

namespace {

// FNV-1a's multiply over 8-byte words, each followed by an xor-shift (both steps invertible, so
// inputs that differ in one word always hash apart), the tail byte by byte. A key hashes every ray
// of every camera (about 30 MB for 8 cameras of 320x240): by words it takes a fifth of the time
// FNV-1a byte by byte took (45 ms, once per build and once per look-up).
struct Fnv {
  static constexpr std::uint64_t kPrime = 1099511628211ULL;
  std::uint64_t h = 1469598103934665603ULL;
  void Bytes(const void* data, std::size_t n) {
    const auto* p = static_cast<const unsigned char*>(data);
    std::size_t i = 0;
    for (; i + 8 <= n; i += 8) {
      std::uint64_t w;
      std::memcpy(&w, p + i, 8);
      h = (h ^ w) * kPrime;
      h ^= h >> 29;
    }
    for (; i < n; ++i) {
      h ^= p[i];
      h *= kPrime;
    }
  }
  template <typename T>
  void Value(const T& v) {
    Bytes(&v, sizeof(v));
  }
};

}  // namespace

std::uint64_t SystemMatrix::Key(const GridGeometry& grid,
                                const std::vector<const CameraRays*>& cameras,
                                const std::vector<std::vector<std::uint8_t>>& pixel_used,
                                const std::vector<std::uint8_t>& voxel_used,
                                const SystemMatrixOptions& options) {
  Fnv f;
  f.Bytes("flamerig system matrix v2", 25);
  f.Value(grid.dims.x());
  f.Value(grid.dims.y());
  f.Value(grid.dims.z());
  for (int a = 0; a < 3; ++a) {
    f.Value(grid.origin_in_rig[a]);
    f.Value(grid.voxel_size_m[a]);
  }
  f.Value(options.step_voxels);
  for (std::size_t c = 0; c < cameras.size(); ++c) {
    f.Value(cameras[c]->width());
    f.Value(cameras[c]->height());
    for (const Ray& r : cameras[c]->rays()) {
      f.Bytes(r.origin_in_rig.data(), 3 * sizeof(double));
      f.Bytes(r.direction_in_rig.data(), 3 * sizeof(double));
      f.Value(r.valid);
    }
    f.Bytes(pixel_used[c].data(), pixel_used[c].size());
  }
  f.Bytes(voxel_used.data(), voxel_used.size());
  return f.h;
}

SystemMatrix SystemMatrix::Build(const GridGeometry& grid,
                                 const std::vector<const CameraRays*>& cameras,
                                 const std::vector<std::vector<std::uint8_t>>& pixel_used,
                                 const std::vector<std::uint8_t>& voxel_used,
                                 const SystemMatrixOptions& options,
                                 std::optional<std::uint64_t> key) {
  const auto start = std::chrono::steady_clock::now();
  options.Validate();
  grid.Validate();
  if (pixel_used.size() != cameras.size())
    throw InputError("SystemMatrix: one pixel mask per camera");
  if (voxel_used.size() != grid.num_voxels()) throw InputError("SystemMatrix: voxel mask size");
  SystemMatrix m;
  m.key_ = key ? *key : Key(grid, cameras, pixel_used, voxel_used, options);

  std::vector<std::int32_t> voxel_to_col(grid.num_voxels(), -1);
  for (std::size_t v = 0; v < voxel_used.size(); ++v) {
    if (voxel_used[v]) {
      voxel_to_col[v] = static_cast<std::int32_t>(m.col_voxel_.size());
      m.col_voxel_.push_back(static_cast<std::uint32_t>(v));
    }
  }
  // Candidate rows.
  std::vector<std::pair<std::int32_t, std::int32_t>> candidates;
  for (std::size_t c = 0; c < cameras.size(); ++c) {
    const std::size_t n = static_cast<std::size_t>(cameras[c]->width()) * cameras[c]->height();
    if (pixel_used[c].size() != n)
      throw InputError("SystemMatrix: pixel mask size of camera " + std::to_string(c));
    for (std::size_t p = 0; p < n; ++p)
      if (pixel_used[c][p])
        candidates.emplace_back(static_cast<std::int32_t>(c), static_cast<std::int32_t>(p));
  }
  const double step_m = options.step_voxels * grid.voxel_size_m.minCoeff();
  const std::size_t nx = grid.dims.x(), nxy = nx * grid.dims.y();
  // Bricks of 4^3 stencil cells (a cell: the 2^3 voxels of a trilinear stencil, named by its lowest
  // corner), flagged when some cell in them has a used corner: a step whose cell lies in an
  // unflagged brick adds nothing, and is passed over without reading its 8 corners' columns (most
  // of a ray lies outside the hull). A cell's corners lie in [4B, 4B + 4] along an axis for brick
  // B, so a used voxel at index i flags bricks i / 4 and, when i is a positive multiple of 4,
  // i / 4 - 1.
  constexpr int kBrickShift = 2;
  Eigen::Vector3i used_lo = grid.dims, used_hi(-1, -1, -1);
  const Eigen::Vector3i bricks_dims((grid.dims.array() + 3) / 4);
  std::vector<std::uint8_t> brick_used(
      static_cast<std::size_t>(bricks_dims.x()) * bricks_dims.y() * bricks_dims.z(), 0);
  for (int k = 0; k < grid.dims.z(); ++k)
    for (int j = 0; j < grid.dims.y(); ++j)
      for (int i = 0; i < grid.dims.x(); ++i) {
        if (!voxel_used[i + nx * j + nxy * k]) continue;
        used_lo = used_lo.cwiseMin(Eigen::Vector3i(i, j, k));
        used_hi = used_hi.cwiseMax(Eigen::Vector3i(i, j, k));
        const int bi[2] = {i >> kBrickShift, (i & 3) == 0 && i > 0 ? (i >> kBrickShift) - 1 : -1};
        const int bj[2] = {j >> kBrickShift, (j & 3) == 0 && j > 0 ? (j >> kBrickShift) - 1 : -1};
        const int bk[2] = {k >> kBrickShift, (k & 3) == 0 && k > 0 ? (k >> kBrickShift) - 1 : -1};
        for (int c : bk)
          for (int b : bj)
            for (int a : bi)
              if (a >= 0 && b >= 0 && c >= 0)
                brick_used[a + static_cast<std::size_t>(bricks_dims.x()) *
                                   (b + static_cast<std::size_t>(bricks_dims.y()) * c)] = 1;
      }
  // The used voxels' bounds along each axis (found with the bricks above), widened by a voxel: a
  // step whose clamped midpoint lies outside the open interval (lo - 1, hi + 1) on some axis has no
  // used corner. An axis whose used voxels reach the grid's edge is unbounded there (midpoints
  // beyond it clamp onto the edge).
  Eigen::Vector3d bound_lo, bound_hi;
  for (int a = 0; a < 3; ++a) {
    const double inf = std::numeric_limits<double>::infinity();
    bound_lo[a] = used_lo[a] == 0 ? -inf : used_lo[a] - 1.0;
    bound_hi[a] = used_hi[a] == grid.dims[a] - 1 ? inf : used_hi[a] + 1.0;
  }
  // The steps [*first, *end) of a march that may have a used corner: those whose midpoint lies in
  // the bounds, give or take a step (the last step's midpoint is nearer than the others').
  auto used_steps = [&](const RayMarch& march, std::int64_t* first, std::int64_t* end) {
    double t0, t1;
    const bool beside =
        !SlabInterval(march.origin_index, march.direction_index, bound_lo, bound_hi, &t0, &t1);
    // A ray that misses the bounds by less than a step (a corner grazed, or rounding) keeps the
    // steps around the near miss: the window below is a step wider on each side anyway.
    if (beside || !(t1 > t0 - march.step_m)) {
      *first = *end = 0;
      return;
    }
    *first = std::max<std::int64_t>(0, march.FirstStepAfter(t0) - 1);
    *end = std::min<std::int64_t>(march.n_steps, march.FirstStepAfter(t1) + 1);
  };
  auto cell_may_be_used = [&](const TrilinearStencil<double>& s) {
    return brick_used[(s.i0 >> kBrickShift) +
                      static_cast<std::size_t>(bricks_dims.x()) *
                          ((s.j0 >> kBrickShift) +
                           static_cast<std::size_t>(bricks_dims.y()) * (s.k0 >> kBrickShift))] != 0;
  };
  const std::size_t block = 512;
  const std::size_t nblocks = (candidates.size() + block - 1) / block;
  struct Block {
    std::vector<std::int32_t> camera, pixel;
    std::vector<std::int64_t> lengths;
    std::vector<std::uint32_t> cols;
    std::vector<float> values;
  };
  std::vector<Block> blocks(nblocks);
  const std::size_t ncols = m.col_voxel_.size();
  // Each thread's sums over a ray's steps, one per column (zero between rays), and the columns a
  // ray touched, in the order it touched them: the order of a row's entries does not matter, since
  // the counting sort below places each by its column.
  struct Scratch {
    std::vector<double> accumulator;
    std::vector<std::uint32_t> touched;
  };
  tbb::enumerable_thread_specific<Scratch> scratch([&] {
    return Scratch{std::vector<double>(ncols, 0.0), {}};
  });
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nblocks, 1),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      auto& [accumulator, touched] = scratch.local();
                      for (std::size_t b = r.begin(); b < r.end(); ++b) {
                        Block& out = blocks[b];
                        for (std::size_t i = b * block;
                             i < std::min(candidates.size(), (b + 1) * block); ++i) {
                          const auto [cam, pix] = candidates[i];
                          RayMarch march;
                          if (!RayMarch::Make(grid, cameras[cam]->rays()[pix], step_m, &march))
                            continue;
                          touched.clear();
                          std::int64_t first, end;
                          used_steps(march, &first, &end);
                          for (std::int64_t k = first; k < end; ++k) {
                            double length;
                            Eigen::Vector3d p;
                            march.Step(k, &length, &p);
                            TrilinearStencil<double> s(grid.dims, p.x(), p.y(), p.z());
                            if (!cell_may_be_used(s)) continue;
                            std::size_t flat[8];
                            double weight[8];
                            s.Corners(nx, nxy, flat, weight);
                            for (int n = 0; n < 8; ++n) {
                              const std::int32_t col = voxel_to_col[flat[n]];
                              if (col < 0 || weight[n] <= 0) continue;
                              if (accumulator[col] == 0.0)
                                touched.push_back(static_cast<std::uint32_t>(col));
                              accumulator[col] += weight[n] * length;
                            }
                          }
                          if (touched.empty()) continue;
                          for (std::uint32_t col : touched) {
                            out.cols.push_back(col);
                            out.values.push_back(static_cast<float>(accumulator[col]));
                            accumulator[col] = 0.0;
                          }
                          out.camera.push_back(cam);
                          out.pixel.push_back(pix);
                          out.lengths.push_back(static_cast<std::int64_t>(touched.size()));
                        }
                      }
                    });
  scratch.clear();  // the accumulators' memory goes before the sort's
  // Rows, in candidate order (camera by camera).
  std::size_t total_rows = 0;
  for (const Block& b : blocks) total_rows += b.camera.size();
  m.row_camera_.reserve(total_rows);
  m.row_pixel_.reserve(total_rows);
  for (const Block& b : blocks) {
    m.row_camera_.insert(m.row_camera_.end(), b.camera.begin(), b.camera.end());
    m.row_pixel_.insert(m.row_pixel_.end(), b.pixel.begin(), b.pixel.end());
  }
  m.camera_ranges_ = CameraRanges(m.row_camera_);
  m.subsets_ = SplitRows(m.camera_ranges_, total_rows);
  // Counting sort of the blocks' entries by (subset, column), straight into the column-major
  // storage, the subsets in parallel (each writes only its own counts and entries); rows ascend
  // within each run because a subset visits its blocks in row order. A block is freed once every
  // subset holding some of its rows has placed them.
  const std::size_t ns = m.subsets_.size(), stride = ncols + 1;
  std::vector<std::size_t> block_first_row(blocks.size() + 1, 0);
  for (std::size_t b = 0; b < blocks.size(); ++b)
    block_first_row[b + 1] = block_first_row[b] + blocks[b].camera.size();
  // The blocks holding subset s's rows: [subset_blocks[s].first, subset_blocks[s].second).
  std::vector<std::pair<std::size_t, std::size_t>> subset_blocks(ns);
  std::vector<std::atomic<int>> block_users(blocks.size());
  for (std::size_t s = 0, b = 0; s < ns; ++s) {
    const auto [r0, r1] = m.subsets_[s];
    while (b < blocks.size() && block_first_row[b + 1] <= r0) ++b;
    std::size_t e = b;
    while (e < blocks.size() && block_first_row[e] < r1) ++e;
    subset_blocks[s] = {b, e};
    for (std::size_t i = b; i < e; ++i) block_users[i].fetch_add(1, std::memory_order_relaxed);
  }
  // Visits subset s's entries in row order (a row's in the order its ray touched their columns).
  auto for_each_entry = [&](std::size_t s, bool release, auto&& visit) {
    const auto [r0, r1] = m.subsets_[s];
    for (std::size_t b = subset_blocks[s].first; b < subset_blocks[s].second; ++b) {
      const Block& blk = blocks[b];
      std::size_t e = 0;
      for (std::size_t r = 0; r < blk.camera.size(); ++r) {
        const std::size_t row = block_first_row[b] + r;
        const std::size_t end = e + static_cast<std::size_t>(blk.lengths[r]);
        if (row >= r0 && row < r1)
          for (; e < end; ++e) visit(row, blk.cols[e], blk.values[e]);
        e = end;
      }
      if (release && block_users[b].fetch_sub(1, std::memory_order_acq_rel) == 1)
        blocks[b] = Block();
    }
  };
  // Counts per (subset, column), kept in t_ptr_ and turned into run offsets in place, and each
  // column's largest value (its 16-bit scale); the runs are padded to a multiple of kRunMultiple.
  m.t_ptr_.assign(ns * stride, 0);
  m.subset_entries_.assign(ns + 1, 0);
  tbb::enumerable_thread_specific<std::vector<float>> thread_col_max(
      [&] { return std::vector<float>(ncols, 0.0f); });
  std::vector<std::uint64_t> subset_total(ns, 0);
  tbb::parallel_for(std::size_t(0), ns, [&](std::size_t s) {
    std::vector<float>& col_max = thread_col_max.local();
    std::uint32_t* ptr = m.t_ptr_.data() + s * stride;
    for_each_entry(s, false, [&](std::size_t, std::uint32_t col, float value) {
      ++ptr[col + 1];
      col_max[col] = std::max(col_max[col], value);
    });
    std::uint64_t total = 0;
    for (std::size_t c = 0; c < ncols; ++c) {
      total += (ptr[c + 1] + kRunMultiple - 1) / kRunMultiple * kRunMultiple;
      if (total > std::numeric_limits<std::uint32_t>::max()) {
        subset_total[s] = total;
        return;
      }
      ptr[c + 1] = static_cast<std::uint32_t>(total);
    }
    subset_total[s] = total;
  });
  std::size_t total_nnz = 0;
  for (const Block& b : blocks) total_nnz += b.cols.size();
  for (std::size_t s = 0; s < ns; ++s) {
    if (subset_total[s] > std::numeric_limits<std::uint32_t>::max())
      throw InputError("SystemMatrix: more than 2^32 non-zeros in the rows " +
                       std::to_string(m.subsets_[s].first) + " to " +
                       std::to_string(m.subsets_[s].second) +
                       " of one camera; use a coarser grid or fewer pixels");
    m.subset_entries_[s + 1] = m.subset_entries_[s] + subset_total[s];
  }
  std::vector<float> col_max(ncols, 0.0f);
  for (const std::vector<float>& local : thread_col_max)
    for (std::size_t c = 0; c < ncols; ++c) col_max[c] = std::max(col_max[c], local[c]);
  thread_col_max.clear();
  m.col_scale_.resize(ncols);
  std::vector<double> inverse(ncols);
  for (std::size_t c = 0; c < ncols; ++c) {
    m.col_scale_[c] = col_max[c] / 65535.0f;
    inverse[c] = col_max[c] > 0 ? 65535.0 / col_max[c] : 0.0;
  }
  m.t_entries_.resize(m.subset_entries_[ns]);
  m.nonzeros_ = total_nnz;
  tbb::parallel_for(std::size_t(0), ns, [&](std::size_t s) {
    const std::uint32_t* ptr = m.t_ptr_.data() + s * stride;
    Entry* entries = m.t_entries_.data() + m.subset_entries_[s];
    std::vector<std::uint32_t> fill(ptr, ptr + ncols);
    const std::size_t r0 = m.subsets_[s].first;
    for_each_entry(s, true, [&](std::size_t row, std::uint32_t col, float value) {
      const double q = std::min(65535.0, std::nearbyint(value * inverse[col]));
      entries[fill[col]++] =
          Entry{static_cast<std::uint16_t>(row - r0), static_cast<std::uint16_t>(q)};
    });
    // Padding: the run's last row again (the run stays sorted), with a value of zero.
    for (std::size_t c = 0; c < ncols; ++c)
      for (std::uint32_t f = fill[c]; f < ptr[c + 1]; ++f)
        entries[f] = Entry{entries[f - 1].row, 0};
  });
  m.ComputeSums();
  m.build_ms_ =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return m;
}

void SystemMatrix::ComputeSums() {
  const std::size_t nrows = rows(), ncols = cols(), ns = subsets_.size();
  col_sums_.assign(ncols, 0.0f);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, ncols, 1024),
                    [&](const tbb::blocked_range<std::size_t>& range) {
                      for (std::size_t c = range.begin(); c < range.end(); ++c) {
                        double sum = 0;
                        for (std::size_t s = 0; s < ns; ++s)
                          for (const Entry* e = ColumnBegin(s, c); e < ColumnEnd(s, c); ++e)
                            sum += e->q;
                        col_sums_[c] = static_cast<float>(sum * col_scale_[c]);
                      }
                    });
  // Row sums: subsets hold disjoint rows, so they run in parallel.
  std::vector<double> row_sums(nrows, 0.0);
  tbb::parallel_for(std::size_t(0), ns, [&](std::size_t s) {
    double* out = row_sums.data() + subsets_[s].first;
    for (std::size_t c = 0; c < ncols; ++c)
      for (const Entry* e = ColumnBegin(s, c); e < ColumnEnd(s, c); ++e)
        out[e->row] += double(e->q) * col_scale_[c];
  });
  row_sums_.assign(row_sums.begin(), row_sums.end());
}

std::vector<std::pair<std::size_t, std::size_t>> SystemMatrix::CameraRanges(
    const std::vector<std::int32_t>& row_camera) {
  std::vector<std::pair<std::size_t, std::size_t>> ranges;
  for (std::size_t r = 0; r < row_camera.size(); ++r) {
    if (r == 0 || row_camera[r] != row_camera[r - 1]) {
      if (r > 0 && row_camera[r] < row_camera[r - 1]) return {};
      ranges.emplace_back(r, r);
    }
    ranges.back().second = r + 1;
  }
  return ranges;
}

std::vector<std::pair<std::size_t, std::size_t>> SystemMatrix::SplitRows(
    const std::vector<std::pair<std::size_t, std::size_t>>& ranges, std::size_t rows) {
  std::vector<std::pair<std::size_t, std::size_t>> subsets;
  auto split = [&](std::size_t first, std::size_t last) {
    for (std::size_t r = first; r < last; r += kSubsetRows)
      subsets.emplace_back(r, std::min(last, r + kSubsetRows));
  };
  if (ranges.empty()) {
    split(0, rows);
  } else {
    for (const auto& [first, last] : ranges) split(first, last);
  }
  if (subsets.empty()) subsets.emplace_back(0, 0);
  return subsets;
}

bool SystemMatrix::Consistent() const {
  const std::size_t nrows = row_camera_.size(), ncols = col_voxel_.size(), stride = ncols + 1;
  const std::size_t ns = subsets_.size();
  if (row_pixel_.size() != nrows || subsets_.empty()) return false;
  std::size_t expect = 0;
  for (const auto& [first, last] : subsets_) {
    if (first != expect || last < first || last > nrows || last - first > kSubsetRows) return false;
    expect = last;
  }
  if (expect != nrows || t_ptr_.size() != ns * stride || subset_entries_.size() != ns + 1 ||
      col_scale_.size() != ncols || subset_entries_[0] != 0 ||
      subset_entries_[ns] != t_entries_.size())
    return false;
  for (float scale : col_scale_)
    if (!std::isfinite(scale) || scale < 0) return false;
  // Every subset's entries within the array before any is read.
  for (std::size_t s = 0; s < ns; ++s)
    if (subset_entries_[s + 1] < subset_entries_[s]) return false;
  for (std::size_t s = 0; s < ns; ++s) {
    if (t_ptr_[s * stride] != 0 ||
        t_ptr_[s * stride + ncols] != subset_entries_[s + 1] - subset_entries_[s])
      return false;
    for (std::size_t c = 0; c < ncols; ++c)
      if (t_ptr_[s * stride + c + 1] < t_ptr_[s * stride + c]) return false;
    // Rows inside the subset and ascending within each run (the products' range cuts search
    // them, and an unsorted run would place an entry outside a cut range's buffer).
    const std::size_t size = subsets_[s].second - subsets_[s].first;
    for (std::size_t c = 0; c < ncols; ++c)
      for (const Entry* e = ColumnBegin(s, c); e < ColumnEnd(s, c); ++e)
        if (e->row >= size || (e > ColumnBegin(s, c) && e->row < e[-1].row)) return false;
  }
  return true;
}

bool SystemMatrix::IndicesFit(const std::vector<const CameraRays*>& cameras,
                              std::size_t num_voxels) const {
  for (std::size_t r = 0; r < rows(); ++r) {
    const std::int32_t c = row_camera_[r];
    if (c < 0 || static_cast<std::size_t>(c) >= cameras.size()) return false;
    const std::size_t pixels = static_cast<std::size_t>(cameras[c]->width()) *
                               static_cast<std::size_t>(cameras[c]->height());
    if (row_pixel_[r] < 0 || static_cast<std::size_t>(row_pixel_[r]) >= pixels) return false;
  }
  for (std::size_t j = 0; j < cols(); ++j)
    if (col_voxel_[j] >= num_voxels || (j > 0 && col_voxel_[j] <= col_voxel_[j - 1])) return false;
  return true;
}

void SystemMatrix::ParallelColumns(const std::function<void(std::size_t, std::size_t)>& fn) const {
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cols(), 1024),
                    [&](const tbb::blocked_range<std::size_t>& r) { fn(r.begin(), r.end()); });
}

void SystemMatrix::MultiplyRows(std::size_t first, std::size_t last, const float* x, float* y,
                                int channels) const {
  if (channels < 1 || channels > 4)
    throw InputError("SystemMatrix: 1 to 4 channels, not " + std::to_string(channels));
  last = std::min(last, rows());
  if (first >= last) return;
  const std::size_t nc = static_cast<std::size_t>(channels);
  const std::size_t ncols = cols();
  // Each subset's rows in [first, last) are summed the same way whatever the range and the
  // threads: the columns fall in a fixed number of blocks (set by the column count alone), each
  // block's entries are summed into a buffer of the subset's rows in ascending column order, and
  // a row is the blocks' sums in block order. So a row is the same in a camera's rows (one
  // subset: its blocks run in parallel) as in the whole product (several subsets: they run in
  // parallel, each block after block in a buffer that stays in cache). Nothing searches for its
  // rows but at the ends of a range that cuts a subset (row blocks that each walked every column
  // and found their rows by binary search cost as much in searches as in arithmetic: a column
  // holds about four entries of one camera's rows).
  const std::size_t blocks = ncols >= 4 * 4096 ? 4 : 1;
  struct Part {
    std::size_t subset, r0, r1;
  };
  std::vector<Part> parts;
  for (std::size_t s = 0; s < subsets_.size(); ++s) {
    const std::size_t r0 = std::max(first, subsets_[s].first);
    const std::size_t r1 = std::min(last, subsets_[s].second);
    if (r0 < r1) parts.push_back({s, r0, r1});
  }
  auto run = [&](auto kChannels) {
    constexpr int kC = decltype(kChannels)::value;
    const std::size_t nch = kC > 0 ? std::size_t(kC) : nc;
    // Block b of part p's sums into `out` (indexed from the part's first row), zeroed first.
    auto block_sums = [&](const Part& p, std::size_t b, float* out) {
      std::fill(out, out + (p.r1 - p.r0) * nch, 0.0f);
      const std::size_t s = p.subset;
      const bool cut_front = subsets_[s].first<p.r0, cut_back = subsets_[s].second> p.r1;
      const std::size_t j0 = ncols * b / blocks, j1 = ncols * (b + 1) / blocks;
      // Offsets within the subset of the part's rows; `out` is indexed from the part's first row.
      const std::size_t o0 = p.r0 - subsets_[s].first, o1 = p.r1 - subsets_[s].first;
      for (std::size_t j = j0; j < j1; ++j) {
        const float* xj = x + j * nch;
        bool zero = true;
        for (std::size_t ch = 0; ch < nch; ++ch) zero = zero && xj[ch] == 0.0f;
        if (zero) continue;
        float xs[4];
        for (std::size_t ch = 0; ch < nch; ++ch) xs[ch] = xj[ch] * col_scale_[j];
        const Entry* lo = ColumnBegin(s, j);
        const Entry* hi = ColumnEnd(s, j);
        if (cut_front)
          lo =
              std::lower_bound(lo, hi, o0, [](const Entry& e, std::size_t r) { return e.row < r; });
        if (cut_back)
          hi =
              std::lower_bound(lo, hi, o1, [](const Entry& e, std::size_t r) { return e.row < r; });
        const Entry* e = lo;
        for (; e + 4 <= hi; e += 4) {
          for (int k = 0; k < 4; ++k) {
            const float q = e[k].q;
            float* yr = out + (static_cast<std::size_t>(e[k].row) - o0) * nch;
            for (std::size_t ch = 0; ch < nch; ++ch) yr[ch] += q * xs[ch];
          }
        }
        for (; e < hi; ++e) {
          const float q = e->q;
          float* yr = out + (static_cast<std::size_t>(e->row) - o0) * nch;
          for (std::size_t ch = 0; ch < nch; ++ch) yr[ch] += q * xs[ch];
        }
      }
    };
    // y over the part's rows: the blocks' buffers summed in block order.
    auto combine = [&](const Part& p, const float* buffers, std::size_t k0, std::size_t k1) {
      const std::size_t n = (p.r1 - p.r0) * nch;
      for (std::size_t k = k0; k < k1; ++k) {
        float sum = buffers[k];
        for (std::size_t b = 1; b < blocks; ++b) sum += buffers[b * n + k];
        y[p.r0 * nch + k] = sum;
      }
    };
    if (parts.size() == 1) {
      const Part& p = parts[0];
      const std::size_t n = (p.r1 - p.r0) * nch;
      std::vector<float> buffers(blocks * n);
      tbb::parallel_for(std::size_t(0), blocks,
                        [&](std::size_t b) { block_sums(p, b, buffers.data() + b * n); });
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 16384),
                        [&](const tbb::blocked_range<std::size_t>& r) {
                          combine(p, buffers.data(), r.begin(), r.end());
                        });
      return;
    }
    tbb::parallel_for(std::size_t(0), parts.size(), [&](std::size_t i) {
      const Part& p = parts[i];
      const std::size_t n = (p.r1 - p.r0) * nch;
      std::vector<float> buffers(blocks * n);
      for (std::size_t b = 0; b < blocks; ++b) block_sums(p, b, buffers.data() + b * n);
      combine(p, buffers.data(), 0, n);
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

void SystemMatrix::MultiplyTransposedRows(std::size_t first, std::size_t last, const float* y,
                                          float* x, float* col_sums, int channels) const {
  BackprojectRows(first, last, y, channels, [&](std::size_t j, const float* g, float sum) {
    for (int ch = 0; ch < channels; ++ch) x[j * channels + ch] = g[ch];
    col_sums[j] = sum;
  });
}

std::size_t SystemMatrix::bytes() const {
  return t_ptr_.size() * sizeof(std::uint32_t) + subset_entries_.size() * 8 +
         t_entries_.size() * sizeof(Entry) + row_camera_.size() * 8 + col_voxel_.size() * 4 +
         col_scale_.size() * 4 + row_sums_.size() * 4 + col_sums_.size() * 4;
}

void SystemMatrix::Multiply(const float* x, float* y, int channels) const {
  MultiplyRows(0, rows(), x, y, channels);
}

void SystemMatrix::MultiplyTransposed(const float* y, float* x, int channels) const {
  BackprojectRows(0, rows(), y, channels, [&](std::size_t j, const float* g, float) {
    for (int ch = 0; ch < channels; ++ch) x[j * channels + ch] = g[ch];
  });
}

namespace {

// 03: 16-bit entries in subsets of at most 65536 rows (02: 32-bit row and float value; 01 held
// rows and columns).
constexpr char kMagic[8] = {'F', 'L', 'R', 'G', 'S', 'M', '0', '3'};

template <typename T>
void WriteVector(std::ofstream& out, const std::vector<T>& v) {
  const std::uint64_t n = v.size();
  out.write(reinterpret_cast<const char*>(&n), sizeof(n));
  out.write(reinterpret_cast<const char*>(v.data()), static_cast<std::streamsize>(n * sizeof(T)));
}

template <typename T>
bool ReadVector(std::ifstream& in, std::vector<T>* v, std::uint64_t remaining_bytes) {
  std::uint64_t n = 0;
  if (!in.read(reinterpret_cast<char*>(&n), sizeof(n))) return false;
  if (n > remaining_bytes / sizeof(T)) return false;  // corrupt length
  v->resize(n);
  return static_cast<bool>(
      in.read(reinterpret_cast<char*>(v->data()), static_cast<std::streamsize>(n * sizeof(T))));
}

}  // namespace

void SystemMatrix::Save(const std::string& path) const {
  AtomicFile file(path);
  std::ofstream out(file.temp_path(), std::ios::binary | std::ios::trunc);
  if (!out) throw IoError(path + ": cannot write the system matrix cache");
  out.write(kMagic, sizeof(kMagic));
  out.write(reinterpret_cast<const char*>(&key_), sizeof(key_));
  std::vector<std::uint64_t> subsets;
  for (const auto& [first, last] : subsets_) {
    subsets.push_back(first);
    subsets.push_back(last);
  }
  WriteVector(out, subsets);
  WriteVector(out, t_ptr_);
  WriteVector(out, subset_entries_);
  WriteVector(out, t_entries_);
  WriteVector(out, col_scale_);
  WriteVector(out, std::vector<std::uint64_t>{nonzeros_});
  WriteVector(out, row_camera_);
  WriteVector(out, row_pixel_);
  WriteVector(out, col_voxel_);
  out.close();
  if (!out) throw IoError(path + ": writing the system matrix cache failed (disk full?)");
  file.Commit();
}

bool SystemMatrix::Load(const std::string& path, std::uint64_t expected_key) {
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  if (ec) return false;
  std::ifstream in(path, std::ios::binary);
  if (!in) return false;
  char magic[8];
  std::uint64_t key = 0;
  if (!in.read(magic, 8) || std::memcmp(magic, kMagic, 8) != 0) return false;
  if (!in.read(reinterpret_cast<char*>(&key), sizeof(key)) || key != expected_key) return false;
  SystemMatrix m;
  m.key_ = key;
  std::vector<std::uint64_t> subsets, nonzeros;
  if (!ReadVector(in, &subsets, size) || !ReadVector(in, &m.t_ptr_, size) ||
      !ReadVector(in, &m.subset_entries_, size) || !ReadVector(in, &m.t_entries_, size) ||
      !ReadVector(in, &m.col_scale_, size) || !ReadVector(in, &nonzeros, size) ||
      nonzeros.size() != 1 || nonzeros[0] > m.t_entries_.size() ||
      !ReadVector(in, &m.row_camera_, size) || !ReadVector(in, &m.row_pixel_, size) ||
      !ReadVector(in, &m.col_voxel_, size) || subsets.size() % 2 != 0) {
    return false;
  }
  m.nonzeros_ = nonzeros[0];
  for (std::size_t i = 0; i < subsets.size(); i += 2)
    m.subsets_.emplace_back(subsets[i], subsets[i + 1]);
  // Structural checks, so a corrupt file can never cause out-of-range access.
  if (!m.Consistent()) return false;
  // Camera ranges from the rows; the subsets must be those ranges split as Build splits them.
  m.camera_ranges_ = CameraRanges(m.row_camera_);
  if (m.subsets_ != SplitRows(m.camera_ranges_, m.rows())) return false;
  m.ComputeSums();
  *this = std::move(m);
  return true;
}

}  // namespace flamerig
