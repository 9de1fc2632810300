// A hole fitted in each tile that sees it whole, on the mosaic's grid: the
// views the measure stage combines (CombineCircleViews) and the mosaic stage
// ties the tiles with (hole_ties.h).
//
// Each view is one tile alone, orthorectified through the scene over a
// window about the hole (ortho_patch.h), and fitted there (MeasureCircle)
// with the bore's bottom rim about that tile's nadir (bore_view.h): an
// independent picture with its own noise. The first fit is in the tile that
// sees the expected disc best, searched as widely as a feature's near_px
// asks; its circle then says which tiles see the hole whole, and those are
// fitted about it. The blended mosaic is fitted only where no tile finds the
// hole, and only when one is given.
//
// Views near a tile's nadir may resolve no bore wall; the other holes' views
// that do resolve it say what the bore is (BorePrior: one plane, one
// thickness), and those views are fitted again with it (PoolBorePrior).
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/camera.h"
#include "pipeline/core/image.h"
#include "pipeline/core/lens_projection.h"
#include "pipeline/core/plane_scene.h"
#include "pipeline/measure/circle_measure.h"
#include "pipeline/mosaic/exposure_compensation.h"
#include "pipeline/mosaic/orthorectify.h"

namespace omm {

// What the fits read; shared, read only, by concurrent fits.
struct HoleViewInputs {
  const PlaneScene& scene;
  const LensProjection& lens;          // the camera's lens, with scene.intrinsics
  const OrthoGeometry& geometry;       // the scene's mosaic grid (ComputeOrthoGeometry)
  const CameraModel& camera;           // the imager's size
  const std::vector<ImageF>& tiles;    // gray [0, 1], in the scene's tile order
  std::vector<TileExposure> exposure;  // per tile; identity where not compensated
  // Raw tile pixels per mosaic pixel (how far the mosaic's edge noise is correlated).
  double source_px = 1.0;
  const ImageF* mosaic = nullptr;  // the blended mosaic on geometry's grid, or none
  std::optional<BorePrior> bore_prior;
  // When the views are fitted on a finer grid than the mosaic's
  // (MeasurementGeometry): the mosaic's grid and its source_px. Fits in the
  // mosaic are then converted to geometry's grid.
  const OrthoGrid* mosaic_grid = nullptr;
  double mosaic_source_px = 1.0;
};

// The grid to fit the views on when the mosaic's pixels are far from the
// tiles': one at the tiles' own resolution (a raw pixel per grid pixel at the
// footprints' centres) if the mosaic has more than max_ratio tile pixels per
// pixel, or fewer than 1 / max_ratio; else nullopt (the mosaic's grid). The
// circle fit's pixel-sized parameters (wedges, step profiles) are set for
// about a raw pixel per grid pixel. A coarser grid throws away the detail the
// rims are located with: demo seed 241 with mosaic.gsd_mm 0.3 (2.1 tile px
// per mosaic px), hole centres 0.044 raw px RMS from the truth after a
// similarity fit, against 0.0095 at 0.15.
std::optional<OrthoGeometry> MeasurementGeometry(const CameraModel& camera,
                                                 const PlaneScene& scene,
                                                 const OrthoGeometry& mosaic,
                                                 double max_ratio = 1.25);

// One fit, in the mosaic or in one tile's patch; mosaic px.
struct HoleFit {
  std::optional<int> tile;  // none: in the mosaic
  CircleMeasurement circle;
  std::optional<int> nadir_tile;  // the tile whose nadir the bottom rim is about
};

// A partial view (FitHoleViews) may leave this much of the rim's wedges
// uncovered, or uncovered and saturated together: as much as a whole view
// may leave out saturated (CircleMeasureOptions::max_saturated_fraction).
inline constexpr double kPartialViewMaxUncovered = 0.5;

struct HoleViews {
  std::vector<HoleFit> fits;          // the tiles' fits that succeeded
  bool partial = false;               // fits are partial views (FitHoleViews)
  std::vector<HoleFit> failed;        // the tiles' fits that failed, each with its error
  int num_seeing = 0;                 // tiles that see the hole whole
  std::optional<HoleFit> mosaic_fit;  // made when no tile found the hole (and a mosaic is given)
  // The first of `failed` that failed as "rim saturated", if any. The mosaic
  // then is not fitted: it draws the hole from that tile where its samples
  // are not clipped and from the others where they are, a picture of no one
  // view. Fitted so, 11 holes of demo projects with one tile at 2.2 times
  // the others' gain read diameters up to 0.26 raw px and 4.8 sigma off.
  const HoleFit* SaturatedFit() const;
};

// The hole of nominal radius radius_mm near the part point near_part_mm:
// looked for in the tiles that see it whole, one after another, until one
// finds it (or in the mosaic where none does); then fitted about that centre
// in every tile that sees it whole. Where a tile that sees it whole found its
// rim saturated and none other found it (a tile exposed brighter than the
// others may clip it alone), the mosaic is not fitted (SaturatedFit): the
// other tiles that see the hole's centre are, each on the wedges of the rim
// it covers (partial views: at most kPartialViewMaxUncovered of them
// uncovered). Pure.
HoleViews FitHoleViews(const HoleViewInputs& in, const Eigen::Vector2d& near_part_mm,
                       double radius_mm);

// The hole in the tiles that see part of its rim but not all of it (views
// of `views`' tiles, fitted or failed, are not made again), each fitted about
// the first fit of `views` on the wedges that tile covers, and kept where at
// most max_uncovered of them are uncovered or saturated. Such views tie the
// tiles (hole_ties.h); they measure nothing, since each sees its own arc of
// the rim. None if `views` has no fit. Pure.
std::vector<HoleFit> FitCutViews(const HoleViewInputs& in, const HoleViews& views, double radius_mm,
                                 double max_uncovered);

// The hole in the blended mosaic (in.mosaic, which must be set); its pixels
// at full scale (clipped or clamped there) and those within 2 px of them are
// taken for saturated, as a tile patch's are
// (CircleMeasureOptions::max_saturated_fraction).
HoleFit FitHoleInMosaic(const HoleViewInputs& in, const Eigen::Vector2d& centre_mm,
                        double radius_mm);

// What one hole's fits say of the bore: the bottom rim's scale k and the
// wall's level where a view resolved them, and whether a view near a nadir
// resolved no wall, or one narrower than min_wall_blurs on most of its rim
// (such a view is fitted again with a BorePrior).
struct BoreEvidence {
  std::vector<double> bottom_rim_scales, wall_contrasts;
  bool unresolved = false;
};
BoreEvidence BoreEvidenceOf(const std::vector<HoleFit>& fits);

// The project's bore from its holes' evidence: the median k and wall level,
// the level's sigma for one hole the levels' spread (1.4826 MAD, not a
// standard error: walls differ from hole to hole beyond their noise).
// nullopt unless at least min_views views resolved each, and some hole left
// its wall unresolved (nothing would use it).
std::optional<BorePrior> PoolBorePrior(const std::vector<BoreEvidence>& holes, size_t min_views);

}  // namespace omm
