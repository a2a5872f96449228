#include "calibration/camera_model.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <stdexcept>

extern "C" {
#include <mrcal/mrcal.h>
}

#include "core/atomic_file.h"
#include "core/error.h"
#include "core/format.h"

namespace flamerig {
namespace {

const mrcal_lensmodel_t& Lens(const std::shared_ptr<const void>& p) {
  return *static_cast<const mrcal_lensmodel_t*>(p.get());
}

}  // namespace

CameraModel::CameraModel(const std::string& lensmodel, std::vector<double> intrinsics,
                         const Rigid3& cam_from_rig, int width_px, int height_px)
    : lensmodel_(lensmodel),
      intrinsics_(std::move(intrinsics)),
      cam_from_rig_(cam_from_rig),
      width_(width_px),
      height_(height_px) {
  auto parsed = std::make_shared<mrcal_lensmodel_t>();
  if (!mrcal_lensmodel_from_name(parsed.get(), lensmodel.c_str()) ||
      !mrcal_lensmodel_type_is_valid(parsed->type)) {
    throw InputError("lens model '" + lensmodel + "' is not a valid mrcal lens model name");
  }
  int expected = mrcal_lensmodel_num_params(parsed.get());
  if (static_cast<int>(intrinsics_.size()) != expected) {
    throw InputError("lens model " + lensmodel + " needs " + std::to_string(expected) +
                     " intrinsics, got " + std::to_string(intrinsics_.size()));
  }
  for (std::size_t i = 0; i < intrinsics_.size(); ++i) {
    if (!std::isfinite(intrinsics_[i])) {
      throw InputError("intrinsics[" + std::to_string(i) + "] of " + lensmodel + " is not finite");
    }
  }
  if (width_px <= 0 || height_px <= 0) {
    throw InputError("imager size " + std::to_string(width_px) + "x" + std::to_string(height_px) +
                     " must be positive");
  }
  // ToRt maps a rotation that is not finite to none, so the pose is checked as it is held.
  if (!cam_from_rig.rotation.coeffs().allFinite() || !cam_from_rig.translation.allFinite())
    throw InputError("camera pose is not finite");
  if (mrcal_lensmodel_metadata(parsed.get()).has_core &&
      (!(intrinsics_[0] > 0) || !(intrinsics_[1] > 0)))
    throw InputError("focal lengths fx = " + FormatNumber(intrinsics_[0], 17) +
                     ", fy = " + FormatNumber(intrinsics_[1], 17) + " of " + lensmodel +
                     " must be > 0 (pixels)");
  mrcal_lensmodel_ = parsed;
}

CameraModel CameraModel::Binned(int factor) const {
  if (factor < 1 || factor > width_ || factor > height_)
    throw InputError("binning " + std::to_string(factor) + "x" + std::to_string(factor) +
                     " needs a factor from 1 to the imager's smaller side (" +
                     std::to_string(std::min(width_, height_)) + " px)");
  if (!mrcal_lensmodel_metadata(&Lens(mrcal_lensmodel_)).has_core)
    throw InputError("lens model " + lensmodel_ + " has no core (fx, fy, cx, cy) to bin");
  std::vector<double> intrinsics = intrinsics_;
  intrinsics[0] /= factor;
  intrinsics[1] /= factor;
  intrinsics[2] = (intrinsics[2] + 0.5) / factor - 0.5;
  intrinsics[3] = (intrinsics[3] + 0.5) / factor - 0.5;
  return CameraModel(lensmodel_, std::move(intrinsics), cam_from_rig_, width_ / factor,
                     height_ / factor);
}

CameraModel CameraModel::Pinhole(double fx, double fy, double cx, double cy,
                                 const Rigid3& cam_from_rig, int width_px, int height_px) {
  return CameraModel("LENSMODEL_PINHOLE", {fx, fy, cx, cy}, cam_from_rig, width_px, height_px);
}

CameraModel CameraModel::Load(const std::string& path) {
  {
    std::ifstream probe(path);
    if (!probe) throw IoError(path + ": cannot open camera model file");
  }
  mrcal_cameramodel_t* model = mrcal_read_cameramodel_file(path.c_str());
  if (model == nullptr) {
    throw InputError(path + ": mrcal could not parse this .cameramodel file");
  }
  char name[1024];
  if (!mrcal_lensmodel_name(name, sizeof(name), &model->lensmodel)) {
    mrcal_free_cameramodel(&model);
    throw InputError(path + ": lens model name too long");
  }
  int n = mrcal_lensmodel_num_params(&model->lensmodel);
  std::vector<double> intrinsics(model->intrinsics, model->intrinsics + n);
  std::array<double, 6> rt;
  std::copy(model->rt_cam_ref, model->rt_cam_ref + 6, rt.begin());
  int w = static_cast<int>(model->imagersize[0]);
  int h = static_cast<int>(model->imagersize[1]);
  mrcal_free_cameramodel(&model);
  try {
    return CameraModel(name, std::move(intrinsics), Rigid3::FromRt(rt), w, h);
  } catch (const InputError& e) {
    throw InputError(path + ": " + e.what());
  }
}

void CameraModel::Save(const std::string& path, const std::string& comment) const {
  std::ostringstream out;
  if (!comment.empty()) {
    std::istringstream lines(comment);
    std::string line;
    while (std::getline(lines, line)) out << "# " << line << "\n";
  }
  out << "{\n";
  out << "    'lensmodel':  '" << lensmodel_ << "',\n";
  out << "    # intrinsics are fx,fy,cx,cy,distortion0,distortion1,....\n";
  out << "    'intrinsics': [";
  for (std::size_t i = 0; i < intrinsics_.size(); ++i) {
    out << (i ? ", " : " ") << FormatNumber(intrinsics_[i], 17);
  }
  out << " ],\n";
  out << "    # extrinsics are rt_cam_from_rig (mrcal's rt_fromref): rotation (Rodrigues), "
         "translation (m)\n";
  out << "    'extrinsics': [";
  auto rt = cam_from_rig_.ToRt();
  for (std::size_t i = 0; i < rt.size(); ++i) out << (i ? ", " : " ") << FormatNumber(rt[i], 17);
  out << " ],\n";
  out << "    'imagersize': [ " << width_ << ", " << height_ << " ],\n";
  out << "}\n";
  WriteFileAtomically(path, out.str());
}

Eigen::Vector2d CameraModel::Project(const Eigen::Vector3d& point_in_rig) const {
  Eigen::Vector3d p = cam_from_rig_ * point_in_rig;
  mrcal_point3_t in{{p.x(), p.y(), p.z()}};
  mrcal_point2_t q;
  if (!mrcal_project(&q, nullptr, nullptr, &in, 1, &Lens(mrcal_lensmodel_), intrinsics_.data())) {
    return Eigen::Vector2d::Constant(std::nan(""));
  }
  return Eigen::Vector2d(q.x, q.y);
}

std::vector<Eigen::Vector2d> CameraModel::Project(
    const std::vector<Eigen::Vector3d>& points_in_rig) const {
  std::vector<mrcal_point3_t> in(points_in_rig.size());
  for (std::size_t i = 0; i < in.size(); ++i) {
    Eigen::Vector3d p = cam_from_rig_ * points_in_rig[i];
    in[i] = mrcal_point3_t{{p.x(), p.y(), p.z()}};
  }
  std::vector<mrcal_point2_t> q(in.size());
  std::vector<Eigen::Vector2d> out(in.size(), Eigen::Vector2d::Constant(std::nan("")));
  if (in.empty()) return out;
  if (mrcal_project(q.data(), nullptr, nullptr, in.data(), static_cast<int>(in.size()),
                    &Lens(mrcal_lensmodel_), intrinsics_.data())) {
    for (std::size_t i = 0; i < q.size(); ++i) out[i] = Eigen::Vector2d(q[i].x, q[i].y);
  }
  return out;
}

Ray CameraModel::Unproject(const Eigen::Vector2d& pixel) const {
  mrcal_point2_t q{{pixel.x(), pixel.y()}};
  mrcal_point3_t v;
  Ray ray;
  Rigid3 rig_from_cam = cam_from_rig_.Inverse();
  ray.origin_in_rig = rig_from_cam.translation;
  if (!mrcal_unproject(&v, &q, 1, &Lens(mrcal_lensmodel_), intrinsics_.data())) return ray;
  Eigen::Vector3d d(v.x, v.y, v.z);
  if (!d.allFinite() || d.norm() == 0) return ray;
  ray.direction_in_rig = (rig_from_cam.rotation * d).normalized();
  ray.valid = true;
  return ray;
}

std::vector<Ray> CameraModel::UnprojectAllPixels(const Eigen::Vector2d& offset) const {
  const int n = width_ * height_;
  std::vector<mrcal_point2_t> q(n);
  for (int y = 0; y < height_; ++y) {
    for (int x = 0; x < width_; ++x)
      q[y * width_ + x] = mrcal_point2_t{{x + offset.x(), y + offset.y()}};
  }
  std::vector<mrcal_point3_t> v(n);
  Rigid3 rig_from_cam = cam_from_rig_.Inverse();
  std::vector<Ray> rays(n);
  bool all_ok = mrcal_unproject(v.data(), q.data(), n, &Lens(mrcal_lensmodel_), intrinsics_.data());
  for (int i = 0; i < n; ++i) {
    Ray& ray = rays[i];
    ray.origin_in_rig = rig_from_cam.translation;
    if (!all_ok) {
      // mrcal reports failure for the batch as a whole; retry one pixel at a time.
      ray = Unproject(Eigen::Vector2d(q[i].x, q[i].y));
      continue;
    }
    Eigen::Vector3d d(v[i].x, v[i].y, v[i].z);
    if (!d.allFinite() || d.norm() == 0) continue;
    ray.direction_in_rig = (rig_from_cam.rotation * d).normalized();
    ray.valid = true;
  }
  return rays;
}

}  // namespace flamerig
