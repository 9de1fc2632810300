#include "pipeline/core/tile_pixels.h"

#include <cmath>

#include <Eigen/LU>

namespace omm {

Eigen::Vector3d CameraPointOfPartPoint(const Eigen::Vector3d& cam_from_part_r,
                                       const PlaneScene& scene, int tile,
                                       const Eigen::Vector2d& part_mm) {
  const Eigen::Vector2d on_table = part_mm + scene.table_pos_mm[tile];
  return RotationFromAngleAxis(cam_from_part_r) * Eigen::Vector3d(on_table.x(), on_table.y(), 0.0) +
         scene.cam_from_part_t_mm;
}

std::optional<Eigen::Vector2d> TilePixelOfPartPoint(const LensProjection& lens,
                                                    const PlaneScene& scene, int tile,
                                                    const Eigen::Vector2d& part_mm) {
  Eigen::Vector2d q;
  const Eigen::Vector3d p = CameraPointOfPartPoint(scene.cam_from_part_r, scene, tile, part_mm);
  if (!lens.Project(p, scene.intrinsics.data(), &q, nullptr, nullptr)) return std::nullopt;
  // The unprojection converges to 1e-9 px: its point is within ~1e-9 mm of
  // P where q is P's own pixel, tens of mm away where the lens folded.
  constexpr double kRoundTripMm = 1e-6;
  const std::optional<Eigen::Vector2d> back = PartPointOfTilePixel(lens, scene, tile, q);
  if (!back || (*back - part_mm).norm() > kRoundTripMm) return std::nullopt;
  return q;
}

std::optional<Eigen::Vector2d> PartPointOfTilePixel(const LensProjection& lens,
                                                    const PlaneScene& scene, int tile,
                                                    const Eigen::Vector2d& q_px) {
  // Pinhole start (mrcal's fx, fy, cx, cy lead every model's intrinsics).
  const Eigen::VectorXd& k = scene.intrinsics;
  const Eigen::Vector3d ray((q_px.x() - k[2]) / k[0], (q_px.y() - k[3]) / k[1], 1.0);
  const Eigen::Matrix3d rot = RotationFromAngleAxis(scene.cam_from_part_r);
  const Eigen::Vector3d normal = rot.col(2);
  const Eigen::Vector2d table = scene.table_pos_mm[tile];
  const Eigen::Vector3d on_plane =
      rot * Eigen::Vector3d(table.x(), table.y(), 0.0) + scene.cam_from_part_t_mm;
  const double along = normal.dot(ray);
  if (std::abs(along) < 1e-12) return std::nullopt;
  const double depth = normal.dot(on_plane) / along;
  if (!(depth > 0.0)) return std::nullopt;
  Eigen::Vector2d part =
      (rot.transpose() * (depth * ray - scene.cam_from_part_t_mm)).head<2>() - table;

  constexpr int kMaxIterations = 20;
  constexpr double kTolerancePx = 1e-9;
  for (int iteration = 0; iteration < kMaxIterations; ++iteration) {
    Eigen::Vector2d q;
    Matrix23d dq_dp;
    const Eigen::Vector3d p = CameraPointOfPartPoint(scene.cam_from_part_r, scene, tile, part);
    if (!lens.Project(p, k.data(), &q, &dq_dp, nullptr)) return std::nullopt;
    const Eigen::Vector2d error = q_px - q;
    if (error.norm() < kTolerancePx) return part;
    const Eigen::Matrix2d dq_dpart = dq_dp * rot.leftCols<2>();
    part += dq_dpart.lu().solve(error);
  }
  return std::nullopt;
}

}  // namespace omm
