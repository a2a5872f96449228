#include "calibration/rig_registration.h"

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <vector>

#include "core/error.h"

namespace flamerig {

std::string RigRegistration::Describe() const {
  char line[160];
  std::snprintf(line, sizeof line, "%.2f mm, %.2f mrad, residual %.3f mm over %d points",
                1e3 * box_center_shift_m, 1e3 * rotation_rad, 1e3 * residual_rms_m, points);
  return line;
}

RigRegistration RegisterRigs(const Rig& from, const Rig& to, int samples_per_axis) {
  if (!from.box.IsValid())
    throw InputError("RegisterRigs: rig '" + from.name + "' has no valid reconstruction box");
  if (samples_per_axis < 2) throw InputError("RegisterRigs: samples_per_axis must be at least 2");
  // Cameras of `from` paired with those of `to` by name.
  std::vector<std::pair<const CameraModel*, const CameraModel*>> pairs;
  for (const RigCamera& c : from.cameras) {
    const int k = to.FindCamera(c.name);
    if (k < 0)
      throw InputError("RegisterRigs: camera '" + c.name + "' of rig '" + from.name +
                       "' is not in rig '" + to.name + "'");
    const CameraModel& m = to.cameras[k].model;
    if (m.width() != c.model.width() || m.height() != c.model.height())
      throw InputError("RegisterRigs: camera '" + c.name + "' images " +
                       std::to_string(c.model.width()) + "x" + std::to_string(c.model.height()) +
                       " in rig '" + from.name + "' but " + std::to_string(m.width()) + "x" +
                       std::to_string(m.height()) + " in rig '" + to.name + "'");
    pairs.emplace_back(&c.model, &m);
  }
  if (pairs.size() < 2)
    throw InputError("RegisterRigs: rig '" + from.name + "' needs at least two cameras");

  std::vector<Eigen::Vector3d> grid, seen;
  const Eigen::Vector3d lo = from.box.min_in_rig, size = from.box.size();
  const int n = samples_per_axis;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d p = lo + size.cwiseProduct(Eigen::Vector3d(i, j, k) / double(n - 1));
        // The point nearest to every ray in the least-squares sense: sum over rays of
        // (I - d d^T) (p - o) = 0.
        Eigen::Matrix3d a = Eigen::Matrix3d::Zero();
        Eigen::Vector3d b = Eigen::Vector3d::Zero();
        std::vector<Eigen::Vector3d> directions;
        for (const auto& [f, t] : pairs) {
          if (!f->InFront(p)) continue;
          const Eigen::Vector2d q = f->Project(p);
          if (!q.allFinite() || q.x() < -0.5 || q.y() < -0.5 || q.x() > f->width() - 0.5 ||
              q.y() > f->height() - 0.5)
            continue;
          const Ray r = t->Unproject(q);
          if (!r.valid) continue;
          const Eigen::Vector3d d = r.direction_in_rig.normalized();
          const Eigen::Matrix3d m = Eigen::Matrix3d::Identity() - d * d.transpose();
          a += m;
          b += m * r.origin_in_rig;
          directions.push_back(d);
        }
        if (directions.size() < 2) continue;
        // Rays that are nearly parallel do not fix a point along them.
        bool crossing = false;
        for (std::size_t u = 1; u < directions.size() && !crossing; ++u)
          crossing = directions[0].cross(directions[u]).norm() > 0.05;  // about 3 degrees
        if (!crossing) continue;
        grid.push_back(p);
        seen.push_back(a.ldlt().solve(b));
      }
  if (grid.size() < 4)
    throw InputError("RegisterRigs: only " + std::to_string(grid.size()) + " points of rig '" +
                     from.name + "''s box are seen by two cameras (at least 4 needed)");

  Eigen::Matrix3Xd src(3, grid.size()), dst(3, grid.size());
  for (std::size_t k = 0; k < grid.size(); ++k) {
    src.col(k) = grid[k];
    dst.col(k) = seen[k];
  }
  const Eigen::Matrix4d m = Eigen::umeyama(src, dst, /*with_scaling=*/false);
  RigRegistration out;
  out.to_from_from = Rigid3(Eigen::Quaterniond(Eigen::Matrix3d(m.topLeftCorner<3, 3>())),
                            m.topRightCorner<3, 1>());
  out.points = static_cast<int>(grid.size());
  double sq = 0;
  for (std::size_t k = 0; k < grid.size(); ++k)
    sq += (out.to_from_from * grid[k] - seen[k]).squaredNorm();
  out.residual_rms_m = std::sqrt(sq / grid.size());
  const Eigen::Vector3d c = from.box.center();
  out.box_center_shift_m = (out.to_from_from * c - c).norm();
  out.rotation_rad = Eigen::AngleAxisd(out.to_from_from.rotation).angle();
  return out;
}

}  // namespace flamerig
