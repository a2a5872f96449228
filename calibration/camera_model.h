// A calibrated camera: an mrcal lens model (projection between the camera frame and pixels) plus
// the camera's pose in the rig, read and written as mrcal `.cameramodel` files.
//
// Projection and unprojection go through libmrcal, so every lens model mrcal supports (PINHOLE,
// OPENCV4/5/8/12, splined stereographic, ...; CAHVORE projects but cannot unproject) behaves
// exactly as in mrcal's own tools. Pixel coordinates put the centre of the top-left pixel at (0,
// 0).
//
// Files: Load() reads any file mrcal's C reader reads (including files written by mrcal's Python
// tools); Save() writes all numbers with 17 significant digits ("%.17g"), because mrcal 2.2's own C
// writer keeps only 6 decimals. The `extrinsics` of a .cameramodel are rt_cam_from_rig (mrcal's
// rt_cam_ref): the rig is mrcal's reference frame.
//
// Thread safety: const methods are safe to call concurrently.
#ifndef FLAMERIG_CALIBRATION_CAMERA_MODEL_H_
#define FLAMERIG_CALIBRATION_CAMERA_MODEL_H_

#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "calibration/pose.h"

namespace flamerig {

// A ray in the rig frame: origin and unit direction. `valid` is false when unprojection failed
// (a pixel outside the lens model's domain); such rays carry no light.
struct Ray {
  Eigen::Vector3d origin_in_rig = Eigen::Vector3d::Zero();
  Eigen::Vector3d direction_in_rig = Eigen::Vector3d::UnitZ();
  bool valid = false;
};

class CameraModel {
 public:
  // `lensmodel` is an mrcal lens model name ("LENSMODEL_PINHOLE", "LENSMODEL_OPENCV8",
  // "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_fov_x_deg=100", ...). `intrinsics` must
  // have the model's parameter count (fx, fy, cx, cy first for models with a core). Throws
  // InputError naming the problem when the name is unknown, the parameter count is
  // wrong, a value is not finite, or the imager size is not positive.
  CameraModel(const std::string& lensmodel, std::vector<double> intrinsics,
              const Rigid3& cam_from_rig, int width_px, int height_px);

  // Convenience: a pinhole camera.
  static CameraModel Pinhole(double fx, double fy, double cx, double cy, const Rigid3& cam_from_rig,
                             int width_px, int height_px);

  // Reads a .cameramodel file. Throws IoError naming the file when it is missing or
  // mrcal cannot parse it.
  static CameraModel Load(const std::string& path);
  // Writes a .cameramodel file at full precision. Throws IoError naming the file on I/O
  // failure. `comment` lines (optional) are written as '#' comments at the top.
  void Save(const std::string& path, const std::string& comment = "") const;

  // The same camera with its pixels binned `factor` x `factor` (a pixel of the result averages a
  // block of the original's; the imager is width / factor by height / factor, rounded down): the
  // core's fx and fy scale by 1 / factor and cx, cy move with the pixel centres, (c + 0.5) / factor
  // - 0.5. Exact for every mrcal model with a core (PINHOLE, OPENCV*, splined, ...), whose lens
  // acts before the core. Throws InputError for a model without a core, or a factor below 1 or
  // larger than the imager.
  CameraModel Binned(int factor) const;

  // Projects a point in the rig frame to pixel coordinates. Points behind a pinhole-like camera
  // give undefined (but finite or NaN) pixels: check InFront() first.
  Eigen::Vector2d Project(const Eigen::Vector3d& point_in_rig) const;
  // Projects many points at once (one call into mrcal).
  std::vector<Eigen::Vector2d> Project(const std::vector<Eigen::Vector3d>& points_in_rig) const;
  bool InFront(const Eigen::Vector3d& point_in_rig) const {
    return (cam_from_rig_ * point_in_rig).z() > 0;
  }

  // The ray through pixel (x, y), in the rig frame.
  Ray Unproject(const Eigen::Vector2d& pixel) const;
  // Rays through the centres of all pixels, row-major (index y * width + x), or through each
  // pixel's centre moved by `offset` pixels (a point inside the pixel: (-0.5, -0.5) is its
  // top-left corner). One call into mrcal.
  std::vector<Ray> UnprojectAllPixels(
      const Eigen::Vector2d& offset = Eigen::Vector2d::Zero()) const;

  const std::string& lensmodel() const { return lensmodel_; }
  const std::vector<double>& intrinsics() const { return intrinsics_; }
  const Rigid3& cam_from_rig() const { return cam_from_rig_; }
  void set_cam_from_rig(const Rigid3& cam_from_rig) { cam_from_rig_ = cam_from_rig; }
  Eigen::Vector3d center_in_rig() const { return cam_from_rig_.Inverse().translation; }
  int width() const { return width_; }
  int height() const { return height_; }

 private:
  std::string lensmodel_;
  std::vector<double> intrinsics_;
  Rigid3 cam_from_rig_;
  int width_ = 0;
  int height_ = 0;
  std::shared_ptr<const void> mrcal_lensmodel_;  // parsed mrcal_lensmodel_t
};

}  // namespace flamerig

#endif  // FLAMERIG_CALIBRATION_CAMERA_MODEL_H_
