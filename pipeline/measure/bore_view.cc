#include "pipeline/measure/bore_view.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "pipeline/core/tile_pixels.h"
#include "pipeline/measure/scene_sensitivity.h"
#include "pipeline/mosaic/orthorectify.h"

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

std::vector<int> TilesSeeingDisc(const LensProjection& lens, const PlaneScene& scene,
                                 const Eigen::Vector2d& centre_mm, double radius_mm, int width_px,
                                 int height_px, double min_border_px) {
  constexpr int kRimPoints = 32;
  const double sagitta_per_radius = 1.0 - std::cos(std::numbers::pi / kRimPoints);
  std::vector<std::pair<double, int>> seeing;  // (-least border distance, tile)
  for (int tile = 0; tile < static_cast<int>(scene.table_pos_mm.size()); ++tile) {
    double least = INFINITY;
    Eigen::Vector2d centre_px = Eigen::Vector2d::Zero();
    for (int m = -1; m < kRimPoints && least >= min_border_px; ++m) {
      const double angle = 2.0 * std::numbers::pi * m / kRimPoints;
      const Eigen::Vector2d p =
          centre_mm + (m < 0 ? 0.0 : radius_mm) * Eigen::Vector2d(std::cos(angle), std::sin(angle));
      const auto q = TilePixelOfPartPoint(lens, scene, tile, p);
      if (!q) {
        least = -INFINITY;
        break;
      }
      if (m < 0) centre_px = *q;
      // The rim between two points bulges beyond their chord by the sagitta.
      const double sagitta = m < 0 ? 0.0 : sagitta_per_radius * (*q - centre_px).norm();
      least = std::min(least, TileBorderDistancePx(*q, width_px, height_px) - sagitta);
    }
    if (least >= min_border_px) seeing.emplace_back(-least, tile);
  }
  std::sort(seeing.begin(), seeing.end());
  std::vector<int> tiles;
  for (const auto& [distance, tile] : seeing) tiles.push_back(tile);
  return tiles;
}

}  // namespace omm
