#include "tomography/system_matrix.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
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

struct Fnv {
  std::uint64_t h = 1469598103934665603ULL;
  void Bytes(const void* data, std::size_t n) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < n; ++i) {
      h ^= p[i];
      h *= 1099511628211ULL;
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
  f.Bytes("flamerig system matrix v1", 25);
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
                                 const SystemMatrixOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  options.Validate();
  grid.Validate();
  if (pixel_used.size() != cameras.size())
    throw InputError("SystemMatrix: one pixel mask per camera");
  if (voxel_used.size() != grid.num_voxels())
    throw InputError("SystemMatrix: voxel mask size");
  SystemMatrix m;
  m.key_ = Key(grid, cameras, pixel_used, voxel_used, options);

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
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nblocks, 1),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      std::vector<double> accumulator(ncols, 0.0);
                      std::vector<std::uint32_t> touched;
                      for (std::size_t b = r.begin(); b < r.end(); ++b) {
                        Block& out = blocks[b];
                        for (std::size_t i = b * block;
                             i < std::min(candidates.size(), (b + 1) * block); ++i) {
                          const auto [cam, pix] = candidates[i];
                          RayMarch march;
                          if (!RayMarch::Make(grid, cameras[cam]->rays()[pix], step_m, &march))
                            continue;
                          touched.clear();
                          for (std::int64_t k = 0; k < march.n_steps; ++k) {
                            double length;
                            Eigen::Vector3d p;
                            march.Step(k, &length, &p);
                            TrilinearStencil<double> s(grid.dims, p.x(), p.y(), p.z());
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
                          std::sort(touched.begin(), touched.end());
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
  std::size_t total_rows = 0, total_nnz = 0;
  for (const Block& b : blocks) {
    total_rows += b.camera.size();
    total_nnz += b.cols.size();
  }
  m.row_ptr_.reserve(total_rows + 1);
  m.row_ptr_.push_back(0);
  m.cols_.reserve(total_nnz);
  m.values_.reserve(total_nnz);
  for (Block& b : blocks) {
    for (std::size_t r = 0; r < b.camera.size(); ++r) {
      m.row_camera_.push_back(b.camera[r]);
      m.row_pixel_.push_back(b.pixel[r]);
      m.row_ptr_.push_back(m.row_ptr_.back() + b.lengths[r]);
    }
    m.cols_.insert(m.cols_.end(), b.cols.begin(), b.cols.end());
    m.values_.insert(m.values_.end(), b.values.begin(), b.values.end());
    b = Block();
  }
  m.BuildTranspose();
  m.build_ms_ =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return m;
}

void SystemMatrix::BuildTranspose() {
  const std::size_t nrows = rows(), ncols = cols(), stride = ncols + 1;
  row_sums_.assign(nrows, 0.0f);
  for (std::size_t r = 0; r < nrows; ++r) {
    double s = 0;
    for (std::int64_t e = row_ptr_[r]; e < row_ptr_[r + 1]; ++e) s += values_[e];
    row_sums_[r] = static_cast<float>(s);
  }
  // Camera row ranges (rows are built camera by camera; anything else gets no ranges).
  camera_ranges_.clear();
  for (std::size_t r = 0; r < nrows; ++r) {
    if (r == 0 || row_camera_[r] != row_camera_[r - 1]) {
      if (r > 0 && row_camera_[r] < row_camera_[r - 1]) {
        camera_ranges_.clear();
        break;
      }
      camera_ranges_.emplace_back(r, r);
    }
    camera_ranges_.back().second = r + 1;
  }
  subsets_ = camera_ranges_;
  if (subsets_.empty()) subsets_.emplace_back(0, nrows);
  // Counting sort by (subset, column); rows ascend within each run because they are visited in
  // order.
  const std::size_t ns = subsets_.size();
  t_ptr_.assign(ns * stride, 0);
  for (std::size_t s = 0; s < ns; ++s)
    for (std::size_t r = subsets_[s].first; r < subsets_[s].second; ++r)
      for (std::int64_t e = row_ptr_[r]; e < row_ptr_[r + 1]; ++e)
        ++t_ptr_[s * stride + cols_[e] + 1];
  std::int64_t total = 0;
  for (std::size_t s = 0; s < ns; ++s) {
    t_ptr_[s * stride] = total;
    for (std::size_t c = 0; c < ncols; ++c) {
      total += t_ptr_[s * stride + c + 1];
      t_ptr_[s * stride + c + 1] = total;
    }
  }
  t_entries_.resize(values_.size());
  std::vector<std::int64_t> fill(stride);
  for (std::size_t s = 0; s < ns; ++s) {
    std::copy(t_ptr_.begin() + s * stride, t_ptr_.begin() + (s + 1) * stride, fill.begin());
    for (std::size_t r = subsets_[s].first; r < subsets_[s].second; ++r)
      for (std::int64_t e = row_ptr_[r]; e < row_ptr_[r + 1]; ++e)
        t_entries_[fill[cols_[e]]++] = Entry{static_cast<std::uint32_t>(r), values_[e]};
  }
  col_sums_.assign(ncols, 0.0f);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, ncols, 1024),
                    [&](const tbb::blocked_range<std::size_t>& range) {
                      for (std::size_t c = range.begin(); c < range.end(); ++c) {
                        double sum = 0;
                        for (std::size_t s = 0; s < ns; ++s)
                          for (std::int64_t e = t_ptr_[s * stride + c];
                               e < t_ptr_[s * stride + c + 1]; ++e)
                            sum += t_entries_[e].value;
                        col_sums_[c] = static_cast<float>(sum);
                      }
                    });
}

void SystemMatrix::ParallelColumns(const std::function<void(std::size_t, std::size_t)>& fn) const {
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cols(), 1024),
                    [&](const tbb::blocked_range<std::size_t>& r) { fn(r.begin(), r.end()); });
}

namespace {

template <int kC>
void MultiplyRowsKernel(const std::int64_t* row_ptr, const std::uint32_t* cols, const float* values,
                        std::size_t first, std::size_t last, const float* x, float* y,
                        int channels) {
  const int nc = kC > 0 ? kC : channels;
  tbb::parallel_for(tbb::blocked_range<std::size_t>(first, last, 256),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t i = r.begin(); i < r.end(); ++i) {
                        float acc[4] = {0, 0, 0, 0};
                        for (std::int64_t e = row_ptr[i]; e < row_ptr[i + 1]; ++e) {
                          const float v = values[e];
                          const float* xc = x + static_cast<std::size_t>(cols[e]) * nc;
                          for (int ch = 0; ch < (kC > 0 ? kC : nc); ++ch) acc[ch] += v * xc[ch];
                        }
                        for (int ch = 0; ch < (kC > 0 ? kC : nc); ++ch) y[i * nc + ch] = acc[ch];
                      }
                    });
}

}  // namespace

void SystemMatrix::MultiplyRows(std::size_t first, std::size_t last, const float* x, float* y,
                                int channels) const {
  if (channels < 1 || channels > 4)
    throw InputError("SystemMatrix: 1 to 4 channels, not " + std::to_string(channels));
  last = std::min(last, rows());
  if (first >= last) return;
  if (channels == 3) {
    MultiplyRowsKernel<3>(row_ptr_.data(), cols_.data(), values_.data(), first, last, x, y, 3);
  } else if (channels == 1) {
    MultiplyRowsKernel<1>(row_ptr_.data(), cols_.data(), values_.data(), first, last, x, y, 1);
  } else {
    MultiplyRowsKernel<0>(row_ptr_.data(), cols_.data(), values_.data(), first, last, x, y,
                          channels);
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
  return row_ptr_.size() * 8 + cols_.size() * 4 + values_.size() * 4 + t_ptr_.size() * 8 +
         t_entries_.size() * sizeof(Entry) + row_camera_.size() * 8 + col_voxel_.size() * 4 +
         row_sums_.size() * 4 + col_sums_.size() * 4;
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

constexpr char kMagic[8] = {'F', 'L', 'R', 'G', 'S', 'M', '0', '1'};

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
  WriteVector(out, row_ptr_);
  WriteVector(out, cols_);
  WriteVector(out, values_);
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
  if (!ReadVector(in, &m.row_ptr_, size) || !ReadVector(in, &m.cols_, size) ||
      !ReadVector(in, &m.values_, size) || !ReadVector(in, &m.row_camera_, size) ||
      !ReadVector(in, &m.row_pixel_, size) || !ReadVector(in, &m.col_voxel_, size)) {
    return false;
  }
  // Structural checks, so a corrupt file can never cause out-of-range access.
  const std::size_t nrows = m.row_camera_.size();
  if (m.row_pixel_.size() != nrows || m.row_ptr_.size() != nrows + 1 || m.row_ptr_.front() != 0 ||
      m.row_ptr_.back() != static_cast<std::int64_t>(m.cols_.size()) ||
      m.cols_.size() != m.values_.size()) {
    return false;
  }
  for (std::size_t r = 0; r < nrows; ++r)
    if (m.row_ptr_[r + 1] < m.row_ptr_[r]) return false;
  for (std::uint32_t c : m.cols_)
    if (c >= m.col_voxel_.size()) return false;
  m.BuildTranspose();
  *this = std::move(m);
  return true;
}

}  // namespace flamerig
