// The rays of every pixel of a camera, in the rig frame: what the renderer marches and what the
// tomography's system matrix is built from. Unprojecting a distorted lens model costs about 1 us
// per pixel, so rays are computed once per camera and reused for every frame.
//
// Rays are stored row-major (index y * width + x), one per pixel centre (or one per pixel through
// the same point inside every pixel). A CameraRays can also be
// made from explicit rays, for cameras mrcal has no lens model for (an orthographic test camera,
// say).
#ifndef FLAMERIG_CALIBRATION_CAMERA_RAYS_H_
#define FLAMERIG_CALIBRATION_CAMERA_RAYS_H_

#include <stdexcept>
#include <string>
#include <vector>

#include "calibration/camera_model.h"
#include "core/error.h"

namespace flamerig {

class CameraRays {
 public:
  explicit CameraRays(const CameraModel& camera)
      : width_(camera.width()), height_(camera.height()), rays_(camera.UnprojectAllPixels()) {}
  // The rays through one point inside every pixel: its centre moved by `offset` pixels (a
  // renderer averaging several such sets integrates over the pixel's area, as a sensor does).
  CameraRays(const CameraModel& camera, const Eigen::Vector2d& offset)
      : width_(camera.width()),
        height_(camera.height()),
        rays_(camera.UnprojectAllPixels(offset)) {}
  // Throws InputError unless rays.size() == width * height and every valid ray has a
  // finite origin and a finite, non-zero direction (a zero direction would march forever).
  CameraRays(int width, int height, std::vector<Ray> rays)
      : width_(width), height_(height), rays_(std::move(rays)) {
    if (width <= 0 || height <= 0 || rays_.size() != static_cast<std::size_t>(width) * height) {
      throw InputError("CameraRays: need width * height rays");
    }
    for (std::size_t i = 0; i < rays_.size(); ++i) {
      const Ray& r = rays_[i];
      if (r.valid && (!r.origin_in_rig.allFinite() || !r.direction_in_rig.allFinite() ||
                      !(r.direction_in_rig.squaredNorm() > 0))) {
        throw InputError("CameraRays: the ray of pixel (" + std::to_string(i % width) + ", " +
                         std::to_string(i / width) +
                         ") is valid but its origin or direction is not finite, or "
                         "its direction is zero");
      }
    }
  }
  int width() const { return width_; }
  int height() const { return height_; }
  const std::vector<Ray>& rays() const { return rays_; }
  const Ray& at(int x, int y) const { return rays_[static_cast<std::size_t>(y) * width_ + x]; }

 private:
  int width_, height_;
  std::vector<Ray> rays_;
};

}  // namespace flamerig

#endif  // FLAMERIG_CALIBRATION_CAMERA_RAYS_H_
