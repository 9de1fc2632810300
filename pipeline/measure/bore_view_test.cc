#include "pipeline/measure/bore_view.h"

#include <cmath>

#include <gtest/gtest.h>

#include "adapters/mrcal/mrcal_lens_projection.h"
#include "pipeline/measure/scene_sensitivity.h"
#include "pipeline/mosaic/synthetic_plane.h"

namespace omm {
namespace {

constexpr double kBandPx = 12.0;

// The nadir lies on the camera's perpendicular to the plane: seen from the
// camera it is straight along the plane's normal (tilted 3 degrees from the
// optical axis here), for every tile.
TEST(BoreView, NadirIsTheFootOfThePerpendicular) {
  const SyntheticPlane s = MakeSyntheticPlane(SyntheticPlaneOptions{});
  const Eigen::Matrix3d rot = RotationFromAngleAxis(s.truth.cam_from_part_r);
  for (int tile = 0; tile < 9; ++tile) {
    const Eigen::Vector2d nadir = TileNadirMm(s.truth, tile);
    const Eigen::Vector2d on_table = nadir + s.truth.table_pos_mm[tile];
    const Eigen::Vector3d seen =
        rot * Eigen::Vector3d(on_table.x(), on_table.y(), 0.0) + s.truth.cam_from_part_t_mm;
    EXPECT_LT(seen.normalized().cross(rot.col(2)).norm(), 1e-12) << tile;
  }
}

// A hole well inside the centre tile is rendered by it; moved onto the seam
// with the next tile, where both weigh, by none.
TEST(BoreView, RenderingTileOnlyAwayFromSeams) {
  const SyntheticPlane s = MakeSyntheticPlane(SyntheticPlaneOptions{});
  PlaneScene scene = s.truth;
  scene.intrinsics = s.camera.intrinsics;
  const MrcalLensProjection lens(s.camera);
  const Eigen::Vector2d inside(-17.0, 23.0);  // seen by tile 4 only
  EXPECT_EQ(RenderingTile(lens, scene, inside, 5.0, 1600, 1200, kBandPx, 0.01), 4);
  // Walk along +x until two tiles weigh more than 1/4 each: the seam.
  Eigen::Vector2d seam = inside;
  for (double x = 0.0; x < 200.0; x += 0.5) {
    const Eigen::Vector2d p = inside + Eigen::Vector2d(x, 0.0);
    int weighing = 0;
    for (const auto& entry : MosaicBlendAt(lens, scene, p, 1600, 1200, kBandPx))
      weighing += entry.second > 0.25 ? 1 : 0;
    if (weighing == 2) {
      seam = p;
      break;
    }
  }
  ASSERT_NE(seam, inside);
  EXPECT_FALSE(RenderingTile(lens, scene, seam, 5.0, 1600, 1200, kBandPx, 0.01).has_value());
}

}  // namespace
}  // namespace omm
