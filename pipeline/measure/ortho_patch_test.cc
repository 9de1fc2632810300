#include "pipeline/measure/ortho_patch.h"

#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "pipeline/mosaic/synthetic_plane.h"

namespace omm {
namespace {

// Random texture (the prefilter's hardest input: every frequency) per tile.
std::vector<ImageF> RandomTiles(const CameraModel& camera, int num_tiles) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> value(0.05f, 0.95f);
  std::vector<ImageF> tiles(num_tiles);
  for (ImageF& tile : tiles) {
    tile.resize(camera.height_px, camera.width_px);
    for (Eigen::Index i = 0; i < tile.size(); ++i) tile.data()[i] = value(rng);
  }
  return tiles;
}

// A window over a corner tile's outer corner, where it meets the grid's
// pixels no tile sees and, inwards, the tiles beside it: the patch is what the mosaic of
// that tile alone holds there, and what the 9-tile mosaic holds where no
// other tile sees. Float rounding only (values ~0.5: ulp 6e-8).
TEST(OrthoPatch, IsTheMosaicOfThatTileAlone) {
  const SyntheticPlane s = MakeSyntheticPlane(SyntheticPlaneOptions{});
  PlaneScene scene = s.truth;
  scene.intrinsics = s.camera.intrinsics;
  OrthoOptions options;
  options.gsd_mm = 0.25;
  const OrthoGeometry geometry = ComputeOrthoGeometry(s.camera, scene, options);
  const std::vector<ImageF> tiles = RandomTiles(s.camera, 9);
  std::vector<TileExposure> exposure(9);
  for (int i = 0; i < 9; ++i) exposure[i] = {0.8 + 0.02 * i, 0.05 + 0.01 * i};
  const ImageF mosaic = ResampleMosaic(geometry, tiles, exposure, options);

  constexpr int kTile = 0;  // a corner tile
  OrthoGeometry alone = geometry;
  alone.tiles = {geometry.tiles[kTile]};
  const ImageF alone_mosaic = ResampleMosaic(alone, {tiles[kTile]}, {exposure[kTile]}, options);

  // 300 x 200 px about the footprint's outermost vertex (from the centre
  // tile's footprint), off the row nodes' phase.
  const Eigen::Matrix2Xd& footprint = geometry.tiles[kTile].footprint_mm;
  Eigen::Index outermost = 0;
  (footprint.colwise() - geometry.tiles[4].footprint_mm.rowwise().mean())
      .colwise()
      .squaredNorm()
      .maxCoeff(&outermost);
  const Eigen::Vector2d corner = geometry.grid.MosaicFromPart(footprint.col(outermost));
  const Eigen::Vector2i min_px = corner.cast<int>() - Eigen::Vector2i(147, 93);
  const Eigen::Vector2i size_px(300, 200);
  const OrthoPatch patch = RenderTilePatch(geometry, kTile, tiles[kTile], exposure[kTile],
                                           options.interpolator, min_px, size_px);
  // Clipped to the grid (the vertex is on its edge).
  const Eigen::Vector2i lo = min_px.cwiseMax(0);
  const Eigen::Vector2i hi = (min_px + size_px).cwiseMin(geometry.grid.size_px);
  ASSERT_EQ(patch.origin_px, lo);
  ASSERT_EQ(patch.pixels.cols(), hi.x() - lo.x());
  ASSERT_EQ(patch.pixels.rows(), hi.y() - lo.y());
  int num_seen = 0, num_unseen = 0, num_only = 0;
  for (int r = 0; r < patch.pixels.rows(); ++r) {
    for (int c = 0; c < patch.pixels.cols(); ++c) {
      const int col = lo.x() + c, row = lo.y() + r;
      const float v = patch.pixels(r, c);
      ASSERT_NEAR(v, alone_mosaic(row, col), 2e-7) << col << ", " << row;
      (v > 0.0f ? num_seen : num_unseen)++;
      if (v == 0.0f) continue;
      // No other tile within 1 px of seeing this pixel: the full mosaic is this tile's.
      bool others = false;
      for (int t = 0; t < 9; ++t) {
        Eigen::Vector2d q;
        if (t != kTile && geometry.TilePixel(t, col, row, &q) &&
            geometry.BorderDistancePx(q) > -1.0)
          others = true;
      }
      if (others) continue;
      ++num_only;
      ASSERT_NEAR(v, mosaic(row, col), 2e-7) << col << ", " << row;
    }
  }
  // The window holds all three kinds of pixels.
  EXPECT_GT(num_seen, 10000);
  EXPECT_GT(num_unseen, 10000);
  EXPECT_GT(num_only, 1000);
}

}  // namespace
}  // namespace omm
