#include "pipeline/measure/bore_view.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/mrcal/mrcal_lens_projection.h"
#include "pipeline/core/tile_pixels.h"
#include "pipeline/measure/scene_sensitivity.h"
#include "pipeline/mosaic/orthorectify.h"
#include "pipeline/mosaic/synthetic_plane.h"

namespace omm {
namespace {

constexpr double kBandPx = 12.0;

// The synthetic plane's scene with its camera's intrinsics, and its lens.
struct PlaneAndLens {
  SyntheticPlane plane = MakeSyntheticPlane(SyntheticPlaneOptions{});
  PlaneScene scene = SceneWithIntrinsics(plane);
  MrcalLensProjection lens{plane.camera};

  static PlaneScene SceneWithIntrinsics(const SyntheticPlane& plane) {
    PlaneScene scene = plane.truth;
    scene.intrinsics = plane.camera.intrinsics;
    return scene;
  }
};

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
  const PlaneAndLens d;
  const PlaneScene& scene = d.scene;
  const MrcalLensProjection& lens = d.lens;
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

// The tiles that see a disc whole, against the least border distance over
// the disc's centre and 360 rim points: a tile clearly inside (>= 1 px) is
// listed, one clearly outside (< -1 px) is not, best first; a margin no
// tile has leaves none. Discs inside the centre tile and in overlaps.
TEST(BoreView, TilesSeeingDiscWholeBestFirst) {
  const PlaneAndLens d;
  const PlaneScene& scene = d.scene;
  const MrcalLensProjection& lens = d.lens;
  size_t most = 0;
  // Where the centre tile sees its middle, a side and two corners.
  for (const Eigen::Vector2d& q :
       {Eigen::Vector2d(800.0, 600.0), Eigen::Vector2d(1400.0, 600.0),
        Eigen::Vector2d(1400.0, 1000.0), Eigen::Vector2d(200.0, 200.0)}) {
    const Eigen::Vector2d centre = *PartPointOfTilePixel(lens, scene, 4, q);
    for (const double radius : {5.0, 30.0}) {
      const std::vector<int> tiles = TilesSeeingDisc(lens, scene, centre, radius, 1600, 1200, 0.0);
      std::vector<double> least(9, INFINITY);
      for (int tile = 0; tile < 9; ++tile) {
        for (int m = -1; m < 360; ++m) {
          const double a = m * std::numbers::pi / 180.0;
          const Eigen::Vector2d p =
              centre + (m < 0 ? 0.0 : radius) * Eigen::Vector2d(std::cos(a), std::sin(a));
          least[tile] = std::min(
              least[tile],
              TileBorderDistancePx(*TilePixelOfPartPoint(lens, scene, tile, p), 1600, 1200));
        }
        const bool listed = std::find(tiles.begin(), tiles.end(), tile) != tiles.end();
        if (least[tile] >= 1.0) {
          EXPECT_TRUE(listed) << tile;
        }
        if (least[tile] < -1.0) {
          EXPECT_FALSE(listed) << tile;
        }
      }
      for (size_t i = 1; i < tiles.size(); ++i)
        EXPECT_GE(least[tiles[i - 1]], least[tiles[i]] - 0.5);
      ASSERT_FALSE(tiles.empty());
      EXPECT_TRUE(
          TilesSeeingDisc(lens, scene, centre, radius, 1600, 1200, least[tiles[0]] + 1.0).empty());
      most = std::max(most, tiles.size());
    }
  }
  EXPECT_GE(most, 3u);  // some disc lies where three tiles overlap
}

// Between its 32 rim points the rim bulges beyond their polygon (1 px at
// 200 px radius): a disc walked towards the centre tile's right border, in
// 0.05 px steps over 6 px about where its rim meets it, is never listed
// while the rim (720 points) crosses the border, and is listed up to
// within 1 px of it.
TEST(BoreView, TilesSeeingDiscNeverListsATileTheRimLeaves) {
  const PlaneAndLens d;
  const PlaneScene& scene = d.scene;
  const MrcalLensProjection& lens = d.lens;
  constexpr int kTile = 4;
  const double radius = 30.0;
  const auto centre_at = [&](double x) {
    return *PartPointOfTilePixel(lens, scene, kTile, Eigen::Vector2d(x, 600.0));
  };
  const Eigen::Vector2d middle = centre_at(800.0);
  const double radius_px =
      (*TilePixelOfPartPoint(lens, scene, kTile, middle + Eigen::Vector2d(radius, 0.0)) -
       Eigen::Vector2d(800.0, 600.0))
          .norm();
  int num_near_listed = 0;
  for (double x = 1598.0 - radius_px - 3.0; x < 1598.0 - radius_px + 3.0; x += 0.05) {
    const Eigen::Vector2d centre = centre_at(x);
    double least = INFINITY;
    for (int m = 0; m < 720; ++m) {
      const double a = m * std::numbers::pi / 360.0;
      const Eigen::Vector2d p = centre + radius * Eigen::Vector2d(std::cos(a), std::sin(a));
      least = std::min(
          least, TileBorderDistancePx(*TilePixelOfPartPoint(lens, scene, kTile, p), 1600, 1200));
    }
    const std::vector<int> tiles = TilesSeeingDisc(lens, scene, centre, radius, 1600, 1200, 0.0);
    const bool listed = std::find(tiles.begin(), tiles.end(), kTile) != tiles.end();
    if (listed) {
      EXPECT_GE(least, -0.005) << x;  // the 720 points' own sagitta: 0.002 px
      if (least < 1.0) ++num_near_listed;
    }
  }
  EXPECT_GT(num_near_listed, 0);
}

}  // namespace
}  // namespace omm
