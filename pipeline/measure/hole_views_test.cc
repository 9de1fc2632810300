#include "pipeline/measure/hole_views.h"

#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/mrcal/mrcal_lens_projection.h"
#include "pipeline/measure/synthetic_hole.h"
#include "pipeline/mosaic/orthorectify.h"
#include "pipeline/simulate/simulation.h"

namespace omm {
namespace {

// The simulator's default scene (its truth) and lens.
struct DefaultScene {
  SimulationPlan plan = PlanSimulation(SimulationOptions{});
  PlaneScene scene = TruthPlaneScene(plan.truth);
  const CameraModel& camera = plan.truth.camera.model;
  MrcalLensProjection lens{camera};

  OrthoGeometry Mosaic(double gsd_mm) const {
    OrthoOptions options;
    options.gsd_mm = gsd_mm;
    return ComputeOrthoGeometry(camera, scene, options);
  }
};

// Where the holes below lie: in tile 4, 47 mm from its centre.
Eigen::Vector2d HoleCentreMm(const OrthoGeometry& mosaic) {
  return mosaic.tiles[4].footprint_mm.rowwise().mean() + Eigen::Vector2d(40.0, 25.0);
}

// A hole of radius_mm there (flat, no wall) on `mosaic`'s whole grid.
testing::SyntheticHole HoleOnMosaic(const OrthoGeometry& mosaic, double radius_mm) {
  testing::SyntheticHole hole;
  hole.width_px = mosaic.grid.size_px.x();
  hole.height_px = mosaic.grid.size_px.y();
  hole.centre_px = mosaic.grid.MosaicFromPart(HoleCentreMm(mosaic));
  hole.radius_px = hole.bottom_radius_px = radius_mm / mosaic.grid.gsd_mm;
  return hole;
}

// A hole found only in the blended mosaic, when the views are on a finer
// grid than the mosaic's (MeasurementGeometry): the fit is made on the
// mosaic's pixels and handed back in the views' px, where the truth is.
TEST(HoleViews, AFitInACoarserMosaicComesBackOnTheViewsGrid) {
  const DefaultScene d;
  const PlaneScene& scene = d.scene;
  const CameraModel& camera = d.camera;
  const MrcalLensProjection& lens = d.lens;
  const OrthoGeometry mosaic = d.Mosaic(0.3), views = d.Mosaic(0.15);

  // A 20 mm hole.
  const Eigen::Vector2d centre_mm = HoleCentreMm(mosaic);
  const double radius_mm = 10.0;
  testing::SyntheticHole hole = HoleOnMosaic(mosaic, radius_mm);
  hole.noise_sigma = 0.01;
  const ImageF image = testing::RenderSyntheticHole(hole);

  const std::vector<ImageF> no_tiles;
  const double source_px = 1.0 / TilePxPerMosaicPx(mosaic);
  const HoleViewInputs on_mosaic{scene, lens, mosaic, camera, no_tiles, {}, source_px, &image};
  HoleViewInputs on_views{scene, lens, views, camera, no_tiles, {}, 1.0, &image};
  on_views.mosaic_grid = &mosaic.grid;
  on_views.mosaic_source_px = source_px;
  const HoleFit direct = FitHoleInMosaic(on_mosaic, centre_mm, radius_mm);
  const HoleFit handed = FitHoleInMosaic(on_views, centre_mm, radius_mm);
  ASSERT_TRUE(direct.circle.ok) << direct.circle.error;
  ASSERT_TRUE(handed.circle.ok) << handed.circle.error;

  // The same fit, in the views' px (half the mosaic's).
  const Eigen::Vector2d direct_mm = mosaic.grid.PartFromMosaic(direct.circle.centre_px);
  EXPECT_LT((views.grid.PartFromMosaic(handed.circle.centre_px) - direct_mm).norm(), 1e-9);
  EXPECT_NEAR(handed.circle.radius_px, 2.0 * direct.circle.radius_px, 1e-9);
  EXPECT_LT((handed.circle.covariance_px2 - 4.0 * direct.circle.covariance_px2).norm(),
            1e-12 + 1e-9 * direct.circle.covariance_px2.norm());
  // ... near the truth there (the fit's own accuracy is circle_measure_test's:
  // here 0.009 mosaic px off centre, 0.001 in radius).
  EXPECT_LT((handed.circle.centre_px - views.grid.MosaicFromPart(centre_mm)).norm(), 0.05);
  EXPECT_NEAR(handed.circle.radius_px, radius_mm / views.grid.gsd_mm, 0.05);
}

// A hole found only in the blended mosaic, where the surface beside part of
// its rim is at full scale: those wedges are left out, and a rim mostly so is
// refused, as in a tile's patch (the mosaic's pixels at 1 stand for clipped
// ones).
TEST(HoleViews, AFitInTheMosaicLeavesOutItsPixelsAtFullScale) {
  const DefaultScene d;
  const OrthoGeometry mosaic = d.Mosaic(0.15);
  const Eigen::Vector2d centre_mm = HoleCentreMm(mosaic);
  const double radius_mm = 5.0;
  testing::SyntheticHole hole = HoleOnMosaic(mosaic, radius_mm);
  hole.texture_seed = 7;
  hole.psf_sigma_px = 0.75;
  hole.noise_sigma = 0.003;
  const ImageF rendered = testing::RenderSyntheticHole(hole);
  const std::vector<ImageF> no_tiles;
  const double source_px = 1.0 / TilePxPerMosaicPx(mosaic);

  // The surface right of the centre overexposed: of the third of the rim
  // beyond x = centre + r / 2, the wedges next to pixels at 1.
  ImageF image = rendered;
  const int x_clip = static_cast<int>(hole.centre_px.x() + 0.5 * hole.radius_px);
  image.rightCols(image.cols() - x_clip) =
      (image.rightCols(image.cols() - x_clip).array() * 2.2f).min(1.0f);
  HoleViewInputs in{d.scene, d.lens, mosaic, d.camera, no_tiles, {}, source_px, &image};
  const HoleFit partly = FitHoleInMosaic(in, centre_mm, radius_mm);
  ASSERT_TRUE(partly.circle.ok) << partly.circle.error;
  std::printf("partly clipped: %s\n", partly.circle.Brief().c_str());
  EXPECT_GT(partly.circle.num_saturated, partly.circle.num_wedges / 10);
  EXPECT_LT(partly.circle.num_saturated, partly.circle.num_wedges / 3);
  EXPECT_LT((partly.circle.centre_px - hole.centre_px).norm(), 0.05);

  // Clipped all round: refused.
  image = (rendered.array() * 2.2f).min(1.0f);
  const HoleFit clipped = FitHoleInMosaic(in, centre_mm, radius_mm);
  EXPECT_FALSE(clipped.circle.ok);
  EXPECT_EQ(clipped.circle.error.rfind("rim saturated", 0), 0u) << clipped.circle.error;
}

// The views' own grid only when the mosaic's pixel is far from the tiles'.
TEST(HoleViews, MeasurementGeometryOnlyForAMosaicFarFromTheTilesPixel) {
  const DefaultScene d;
  for (const double gsd_mm : {0.1, 0.15, 0.3}) {
    const OrthoGeometry mosaic = d.Mosaic(gsd_mm);
    const double ratio = TilePxPerMosaicPx(mosaic);
    const std::optional<OrthoGeometry> views = MeasurementGeometry(d.camera, d.scene, mosaic);
    EXPECT_EQ(views.has_value(), ratio > 1.25 || ratio < 0.8) << gsd_mm << " mm: " << ratio;
    if (views) {
      EXPECT_NEAR(TilePxPerMosaicPx(*views), 1.0, 0.01) << gsd_mm;
    }
  }
}

}  // namespace
}  // namespace omm
