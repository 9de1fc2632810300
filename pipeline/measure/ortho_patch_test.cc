#include "pipeline/measure/ortho_patch.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <utility>
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

// The synthetic plane's 3 x 3 tiles on a mosaic grid of `gsd_mm`.
struct PlaneMosaic {
  SyntheticPlane plane = MakeSyntheticPlane(SyntheticPlaneOptions{});
  OrthoOptions options;
  OrthoGeometry geometry;
  explicit PlaneMosaic(double gsd_mm) {
    PlaneScene scene = plane.truth;
    scene.intrinsics = plane.camera.intrinsics;
    options.gsd_mm = gsd_mm;
    geometry = ComputeOrthoGeometry(plane.camera, scene, options);
  }
};

// A window over a corner tile's outer corner, where it meets the grid's
// pixels no tile sees and, inwards, the tiles beside it: the patch is what the mosaic of
// that tile alone holds there, and what the 9-tile mosaic holds where no
// other tile sees. Float rounding only (values ~0.5: ulp 6e-8). Where the
// exposure division lifts a sample above 1 (gains 0.8-0.96 on samples up to
// 0.95), the mosaic, a file's full scale, clamps; the patch does not.
TEST(OrthoPatch, IsTheMosaicOfThatTileAlone) {
  const PlaneMosaic m(0.25);
  const OrthoGeometry& geometry = m.geometry;
  const OrthoOptions& options = m.options;
  const std::vector<ImageF> tiles = RandomTiles(m.plane.camera, 9);
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
  int num_seen = 0, num_unseen = 0, num_only = 0, num_above_one = 0;
  for (int r = 0; r < patch.pixels.rows(); ++r) {
    for (int c = 0; c < patch.pixels.cols(); ++c) {
      const int col = lo.x() + c, row = lo.y() + r;
      const float v = patch.pixels(r, c);
      ASSERT_NEAR(std::min(v, 1.0f), alone_mosaic(row, col), 2e-7) << col << ", " << row;
      (v > 0.0f ? num_seen : num_unseen)++;
      if (v > 1.0f) ++num_above_one;
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
      ASSERT_NEAR(std::min(v, 1.0f), mosaic(row, col), 2e-7) << col << ", " << row;
    }
  }
  // The window holds all three kinds of pixels, and pixels above 1.
  EXPECT_GT(num_seen, 10000);
  EXPECT_GT(num_unseen, 10000);
  EXPECT_GT(num_only, 1000);
  EXPECT_GT(num_above_one, 1000);
}

// Black pixels that a tile sees (a through-hole over a black table, a clipped
// black level) are not the 0 of pixels no tile sees: in the mosaic and in a
// tile's patch they are kDarkestCovered, exactly where gray tiles draw.
TEST(OrthoPatch, BlackPixelsATileSeesAreNotUnseen) {
  const PlaneMosaic m(0.5);
  const OrthoGeometry& geometry = m.geometry;
  const OrthoOptions& options = m.options;
  const CameraModel& camera = m.plane.camera;
  const std::vector<TileExposure> exposure(9, TileExposure{0.8, 0.1});
  const ImageF black_tile = ImageF::Zero(camera.height_px, camera.width_px);
  const ImageF gray_tile = ImageF::Constant(camera.height_px, camera.width_px, 0.5f);
  const ImageF black =
      ResampleMosaic(geometry, std::vector<ImageF>(9, black_tile), exposure, options);
  const ImageF gray =
      ResampleMosaic(geometry, std::vector<ImageF>(9, gray_tile), exposure, options);
  ASSERT_EQ(black.size(), gray.size());
  const auto seen = (gray.array() > 0.0f).count();
  EXPECT_GT(seen, black.size() / 2);
  EXPECT_LT(seen, black.size());  // the grid's corners are unseen
  EXPECT_EQ(((gray.array() > 0.0f) == (black.array() == kDarkestCovered)).count(), black.size());

  const Eigen::Vector2i min_px(0, 0);
  const OrthoPatch black_patch = RenderTilePatch(
      geometry, 0, black_tile, exposure[0], options.interpolator, min_px, geometry.grid.size_px);
  const OrthoPatch gray_patch = RenderTilePatch(
      geometry, 0, gray_tile, exposure[0], options.interpolator, min_px, geometry.grid.size_px);
  const ImageF& b = black_patch.pixels;
  const ImageF& g = gray_patch.pixels;
  ASSERT_EQ(b.size(), g.size());
  EXPECT_GT((g.array() > 0.0f).count(), b.size() / 20);
  EXPECT_EQ(((g.array() > 0.0f) == (b.array() == kDarkestCovered)).count(), b.size());
}

// The mosaic draws no clipped sample where another tile sees the pixel, and
// 1 (full scale) where none does: of nine gray (0.5) tiles, a corner one
// clipped (1) but for its top quarter. Every pixel is 0.5, the others' value,
// but those that the corner tile alone sees and reads a clipped sample at
// (its patch marks them saturated), which are 1; counted as clipped.
// Catmull-Rom reads the 4 x 4 support alone; the B-spline's prefilter
// spreads each sample's value beyond it (as (2 - sqrt(3))^d), so that pixels
// beside the clipped part would differ from 0.5 by its tail.
TEST(OrthoPatch, TheMosaicDrawsClippedSamplesOnlyWhereNoOtherTileSees) {
  PlaneMosaic m(0.5);
  m.options.interpolator = OrthoInterpolator::kCatmullRom;
  const OrthoGeometry& geometry = m.geometry;
  const CameraModel& camera = m.plane.camera;
  constexpr int kCorner = 0;
  const int quarter = camera.height_px / 4;
  std::vector<ImageF> tiles(9, ImageF::Constant(camera.height_px, camera.width_px, 0.5f));
  tiles[kCorner].bottomRows(camera.height_px - quarter).setOnes();
  ResampleCounts counts;
  const ImageF mosaic = ResampleMosaic(geometry, tiles, {}, m.options, {}, &counts);
  const OrthoPatch patch =
      RenderTilePatch(geometry, kCorner, tiles[kCorner], TileExposure{}, m.options.interpolator,
                      Eigen::Vector2i::Zero(), geometry.grid.size_px);
  ASSERT_EQ(patch.saturated.rows(), mosaic.rows());
  int num_clipped_alone = 0, num_clipped_seen_by_others = 0, num_full_scale = 0;
  for (int row = 0; row < mosaic.rows(); ++row) {
    for (int col = 0; col < mosaic.cols(); ++col) {
      num_full_scale += mosaic(row, col) == 1.0f;
      // Away from the borders' and the clipped half's edges, where the row
      // interpolation of the map (1e-5 px) could tip the tests.
      bool others = false, ambiguous = false;
      for (int t = 0; t < 9; ++t) {
        Eigen::Vector2d q;
        if (!geometry.TilePixel(t, col, row, &q)) continue;
        const double d = geometry.BorderDistancePx(q);
        ambiguous = ambiguous || std::abs(d) < 1e-3 ||
                    (t == kCorner && std::abs(q.y() - std::round(q.y())) < 1e-3);
        others = others || (t != kCorner && d > 0.0);
      }
      if (ambiguous || !(mosaic(row, col) > 0.0f)) continue;
      const bool clipped = patch.saturated(row, col) != 0;
      if (clipped && !others) {
        ++num_clipped_alone;
        ASSERT_EQ(mosaic(row, col), 1.0f) << col << ", " << row;
      } else {
        num_clipped_seen_by_others += clipped;
        ASSERT_NEAR(mosaic(row, col), 0.5f, 1e-6) << col << ", " << row;
      }
    }
  }
  EXPECT_GT(num_clipped_alone, 1000);
  EXPECT_GT(num_clipped_seen_by_others, 1000);
  EXPECT_EQ(counts.clipped_px, num_full_scale);
}

// A patch marks the pixels whose 4 x 4 interpolation support reads a tile
// sample at full scale (the camera clipped it), and only those.
TEST(OrthoPatch, MarksThePixelsThatReadSaturatedSamples) {
  const PlaneMosaic m(0.25);
  const OrthoGeometry& geometry = m.geometry;
  ImageF tile = RandomTiles(m.plane.camera, 1)[0];  // values below 0.95
  const TileExposure exposure{0.9, 0.1};
  const Eigen::Vector2i min_px(0, 0);
  const OrthoPatch clean = RenderTilePatch(geometry, 0, tile, exposure, m.options.interpolator,
                                           min_px, geometry.grid.size_px);
  EXPECT_EQ(clean.saturated.size(), 0);
  for (const auto& [x, y] : {std::pair{400, 300}, {401, 300}, {900, 750}}) tile(y, x) = 1.0f;
  const OrthoPatch patch = RenderTilePatch(geometry, 0, tile, exposure, m.options.interpolator,
                                           min_px, geometry.grid.size_px);
  ASSERT_EQ(patch.saturated.rows(), patch.pixels.rows());
  ASSERT_EQ(patch.saturated.cols(), patch.pixels.cols());
  int marked = 0;
  for (int row = 0; row < patch.pixels.rows(); ++row) {
    for (int col = 0; col < patch.pixels.cols(); ++col) {
      Eigen::Vector2d q;
      bool reads = false;
      if (patch.pixels(row, col) > 0.0f && geometry.TilePixel(0, col, row, &q)) {
        const int x0 = static_cast<int>(std::floor(q.x())) - 1;
        const int y0 = static_cast<int>(std::floor(q.y())) - 1;
        for (const auto& [x, y] : {std::pair{400, 300}, {401, 300}, {900, 750}})
          reads = reads || (x >= x0 && x <= x0 + 3 && y >= y0 && y <= y0 + 3);
      }
      ASSERT_EQ(patch.saturated(row, col) != 0, reads) << col << ", " << row;
      marked += reads ? 1 : 0;
    }
  }
  // Each sample reaches ~4 x 4 tile px: ~(4 x 0.146 / 0.25)^2 mosaic px.
  EXPECT_GT(marked, 10);
  EXPECT_LT(marked, 60);
}

}  // namespace
}  // namespace omm
