#include "pipeline/measure/bore_view.h"

#include <cmath>
#include <numbers>

#include "pipeline/measure/scene_sensitivity.h"

namespace omm {

Eigen::Vector2d TileNadirMm(const PlaneScene& scene, int tile) {
  const Eigen::Vector3d centre =
      -RotationFromAngleAxis(scene.cam_from_part_r).transpose() * scene.cam_from_part_t_mm;
  return centre.head<2>() - scene.table_pos_mm[tile];
}

std::optional<int> RenderingTile(const LensProjection& lens, const PlaneScene& scene,
                                 const Eigen::Vector2d& centre_mm, double radius_mm, int width_px,
                                 int height_px, double band_px, double max_other_weight) {
  constexpr int kRimPoints = 16;
  std::optional<int> rendering;
  for (int m = -1; m < kRimPoints; ++m) {
    const double angle = 2.0 * std::numbers::pi * m / kRimPoints;
    const Eigen::Vector2d p =
        centre_mm + (m < 0 ? 0.0 : radius_mm) * Eigen::Vector2d(std::cos(angle), std::sin(angle));
    bool dominated = false;
    for (const auto& [tile, weight] : MosaicBlendAt(lens, scene, p, width_px, height_px, band_px)) {
      if (weight < 1.0 - max_other_weight) continue;
      if (rendering && *rendering != tile) return std::nullopt;
      rendering = tile;
      dominated = true;
    }
    if (!dominated) return std::nullopt;
  }
  return rendering;
}

}  // namespace omm
