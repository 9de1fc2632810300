#include "pipeline/measure/hole_views.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <utility>

#include "pipeline/core/statistics.h"
#include "pipeline/core/tile_pixels.h"
#include "pipeline/measure/bore_view.h"
#include "pipeline/measure/ortho_patch.h"

namespace omm {
namespace {

// A hole is one tile's picture where the other tiles' blend weights sum to
// less than this: their ghost bottom rim is under the mosaic's noise.
constexpr double kMaxOtherTileWeight = 0.01;

// How far from the expected centre a fit of a hole of radius_px, searched
// for within search_px, reads pixels (two more for rounding).
double PixelsReachPx(double radius_px, double search_px, const CircleMeasureOptions& options) {
  return radius_px * (1.0 + options.max_radius_deviation) + search_px + options.ReachPx() + 2.0;
}

// A fit that failed for its rim's saturated pixels (CircleMeasureOptions::max_saturated_fraction).
bool RimSaturated(const CircleMeasurement& circle, const CircleMeasureOptions& options) {
  return !circle.ok && circle.num_saturated > options.max_saturated_fraction * circle.num_wedges;
}

// The mosaic's pixels that stand for clipped ones, within `reach_px` of
// `centre_px`: those at its full scale (1: where every tile that sees the
// pixel read a clipped sample, or one was lifted beyond it by its exposure;
// orthorectify.h), and their neighbours within 2 px, whose blend may be
// near a clipped sample's support (ortho_patch.h). An empty mask where
// there are none, as RenderTilePatch gives.
ImageMask SaturatedInMosaic(const ImageF& mosaic, const Eigen::Vector2d& centre_px,
                            double reach_px) {
  constexpr int kSupportPx = 2;
  const auto clamp_to = [](double v, Eigen::Index size) {
    return static_cast<int>(std::clamp<double>(v, 0.0, static_cast<double>(size)));
  };
  const int x0 = clamp_to(std::floor(centre_px.x() - reach_px), mosaic.cols());
  const int x1 = clamp_to(std::ceil(centre_px.x() + reach_px) + 1, mosaic.cols());
  const int y0 = clamp_to(std::floor(centre_px.y() - reach_px), mosaic.rows());
  const int y1 = clamp_to(std::ceil(centre_px.y() + reach_px) + 1, mosaic.rows());
  ImageMask mask;
  for (int y = y0; y < y1; ++y) {
    for (int x = x0; x < x1; ++x) {
      if (mosaic(y, x) < 1.0f) continue;
      if (mask.size() == 0) mask = ImageMask::Zero(mosaic.rows(), mosaic.cols());
      const int ya = std::max(y - kSupportPx, 0), xa = std::max(x - kSupportPx, 0);
      const int yb = std::min<int>(y + kSupportPx, static_cast<int>(mosaic.rows()) - 1);
      const int xb = std::min<int>(x + kSupportPx, static_cast<int>(mosaic.cols()) - 1);
      mask.block(ya, xa, yb - ya + 1, xb - xa + 1).setOnes();
    }
  }
  return mask;
}

CircleMeasureOptions FitOptions(const HoleViewInputs& in) {
  CircleMeasureOptions options;
  options.source_px = in.source_px;
  return options;
}

// The hole in tile `tile` alone, looked for within `search_px` of expected_px:
// a patch reaching that far plus the fit's reach, then the fit with that
// tile's nadir, shifted back to mosaic px.
HoleFit FitInTile(const HoleViewInputs& in, int tile, const Eigen::Vector2d& expected_px,
                  double radius_px, CircleMeasureOptions options, double search_px) {
  options.search_fraction = 0.0;
  options.search_margin_px = search_px;
  const double reach = PixelsReachPx(radius_px, search_px, options);
  const Eigen::Vector2i min_px = (expected_px.array() - reach).floor().cast<int>();
  const int size = static_cast<int>(std::ceil(2.0 * reach)) + 1;
  const OrthoPatch patch =
      RenderTilePatch(in.geometry, tile, in.tiles[tile], in.exposure[tile],
                      OrthoOptions{}.interpolator, min_px, Eigen::Vector2i::Constant(size));
  const Eigen::Vector2d origin = patch.origin_px.cast<double>();
  const Eigen::Vector2d nadir_px =
      in.geometry.grid.MosaicFromPart(TileNadirMm(in.scene, tile)) - origin;
  HoleFit fit{tile, {}, tile};
  if (patch.pixels.size() == 0) {
    fit.circle.error = "not seen by the tile";
    return fit;
  }
  fit.circle = MeasureCircle(patch.pixels, expected_px - origin, radius_px, options, nadir_px,
                             in.bore_prior, patch.saturated.size() ? &patch.saturated : nullptr);
  fit.circle.centre_px += origin;
  fit.circle.coarse_centre_px += origin;
  return fit;
}

// Where every tile that sees the hole whole clipped its rim: the other
// tiles that see its centre, each fitted on the wedges it covers; the fits
// that succeed.
std::vector<HoleFit> FitPartialViews(const HoleViewInputs& in, const Eigen::Vector2d& near_part_mm,
                                     double radius_px, const std::vector<int>& whole,
                                     CircleMeasureOptions options, double search_px) {
  options.max_uncovered_fraction = kPartialViewMaxUncovered;
  const OrthoGrid& grid = in.geometry.grid;
  const Eigen::Vector2d expected_px = grid.MosaicFromPart(near_part_mm);
  std::vector<HoleFit> fits;
  for (const int t : TilesSeeingDisc(in.lens, in.scene, near_part_mm, 0.0, in.camera.width_px,
                                     in.camera.height_px, 0.0)) {
    if (std::find(whole.begin(), whole.end(), t) != whole.end()) continue;
    HoleFit fit = FitInTile(in, t, expected_px, radius_px, options, search_px);
    // Uncovered and saturated wedges together: at most what either may be
    // alone, so that half the rim or more gives the circle.
    const CircleMeasurement& c = fit.circle;
    if (c.ok && c.num_uncovered + c.num_saturated <= kPartialViewMaxUncovered * c.num_wedges)
      fits.push_back(std::move(fit));
  }
  return fits;
}

}  // namespace

// The bore's bottom rim shows scaled about the nadir of the tile the mosaic
// takes the hole from (bore_view.h); where tiles blend there are two such
// rims and the kernel fits one free circle. RenderingTile follows the seam
// rule, not the features the mosaic keeps whole (orthorectify.h): those are
// seen whole by a tile, so they reach this fit only when that tile's fit
// failed.
HoleFit FitHoleInMosaic(const HoleViewInputs& in, const Eigen::Vector2d& centre_mm,
                        double radius_mm) {
  const OrthoGrid& grid = in.mosaic_grid ? *in.mosaic_grid : in.geometry.grid;
  HoleFit fit;
  fit.nadir_tile =
      RenderingTile(in.lens, in.scene, centre_mm, radius_mm, in.camera.width_px,
                    in.camera.height_px, OrthoOptions{}.blend_band_px, kMaxOtherTileWeight);
  std::optional<Eigen::Vector2d> nadir_px;
  if (fit.nadir_tile) nadir_px = grid.MosaicFromPart(TileNadirMm(in.scene, *fit.nadir_tile));
  CircleMeasureOptions options = FitOptions(in);
  if (in.mosaic_grid) options.source_px = in.mosaic_source_px;
  const Eigen::Vector2d expected_px = grid.MosaicFromPart(centre_mm);
  const double radius_px = radius_mm / grid.gsd_mm;
  const ImageMask saturated = SaturatedInMosaic(
      *in.mosaic, expected_px, PixelsReachPx(radius_px, options.SearchPx(radius_px), options));
  fit.circle = MeasureCircle(*in.mosaic, expected_px, radius_px, options, nadir_px, in.bore_prior,
                             saturated.size() ? &saturated : nullptr);
  if (in.mosaic_grid) {
    // To the views' grid: both grids run x along columns and y against rows.
    const OrthoGrid& to = in.geometry.grid;
    const double s = grid.gsd_mm / to.gsd_mm;
    CircleMeasurement& c = fit.circle;
    c.centre_px = to.MosaicFromPart(grid.PartFromMosaic(c.centre_px));
    c.coarse_centre_px = to.MosaicFromPart(grid.PartFromMosaic(c.coarse_centre_px));
    c.radius_px *= s;
    c.covariance_px2 *= s * s;
    c.rms_px *= s;
    c.edge_sigma_px *= s;
    c.correlation_px *= s;
  }
  return fit;
}

HoleViews FitHoleViews(const HoleViewInputs& in, const Eigen::Vector2d& near_part_mm,
                       double radius_mm) {
  HoleViews result;
  const OrthoGrid& grid = in.geometry.grid;
  const CircleMeasureOptions options = FitOptions(in);
  const double radius_px = radius_mm / grid.gsd_mm;
  const double reach_mm = options.ReachPx() * grid.gsd_mm;
  const int width_px = in.camera.width_px, height_px = in.camera.height_px;
  const double search_px = options.SearchPx(radius_px);
  const Eigen::Vector2d expected_px = grid.MosaicFromPart(near_part_mm);
  const std::vector<int> first = TilesSeeingDisc(in.lens, in.scene, near_part_mm,
                                                 radius_mm + reach_mm, width_px, height_px, 0.0);
  std::optional<HoleFit> found;
  for (const int t : first) {
    HoleFit fit = FitInTile(in, t, expected_px, radius_px, options, search_px);
    if (fit.circle.ok) {
      found = std::move(fit);
      break;
    }
    result.failed.push_back(std::move(fit));
  }
  if (!found && result.SaturatedFit()) {
    result.num_seeing = static_cast<int>(first.size());
    result.fits = FitPartialViews(in, near_part_mm, radius_px, first, options, search_px);
    result.partial = !result.fits.empty();
    return result;
  }
  if (!found && in.mosaic != nullptr) {
    result.mosaic_fit = FitHoleInMosaic(in, near_part_mm, radius_mm);
    if (result.mosaic_fit->circle.ok) found = *result.mosaic_fit;
  }
  if (!found) {
    result.num_seeing = static_cast<int>(first.size());
    return result;
  }
  // Centres agree to well within a pixel: a small search about it, in every
  // tile again (one that failed the wide search may find it there).
  result.failed.clear();
  const Eigen::Vector2d centre_px = found->circle.centre_px;
  const double fitted_mm = found->circle.radius_px * grid.gsd_mm;
  for (const int t : TilesSeeingDisc(in.lens, in.scene, grid.PartFromMosaic(centre_px),
                                     fitted_mm + reach_mm, width_px, height_px, 0.0)) {
    ++result.num_seeing;
    HoleFit fit = found->tile == t
                      ? std::move(*found)
                      : FitInTile(in, t, centre_px, radius_px, options, options.search_margin_px);
    (fit.circle.ok ? result.fits : result.failed).push_back(std::move(fit));
  }
  return result;
}

std::vector<HoleFit> FitCutViews(const HoleViewInputs& in, const HoleViews& views, double radius_mm,
                                 double max_uncovered) {
  std::vector<HoleFit> cut;
  if (views.fits.empty()) return cut;
  const OrthoGrid& grid = in.geometry.grid;
  const CircleMeasurement& first = views.fits.front().circle;
  const Eigen::Vector2d centre_mm = grid.PartFromMosaic(first.centre_px);
  const double fitted_mm = first.radius_px * grid.gsd_mm;
  std::vector<int> done;
  for (const std::vector<HoleFit>* fits : {&views.fits, &views.failed}) {
    for (const HoleFit& fit : *fits)
      if (fit.tile) done.push_back(*fit.tile);
  }
  CircleMeasureOptions options = FitOptions(in);
  options.max_uncovered_fraction = max_uncovered;
  const double radius_px = radius_mm / grid.gsd_mm;
  constexpr int kRimPoints = 32;
  for (int t = 0; t < static_cast<int>(in.tiles.size()); ++t) {
    if (std::find(done.begin(), done.end(), t) != done.end()) continue;
    // Some of the rim in the image: a tile beside it fits nothing.
    bool sees_rim = false;
    for (int m = 0; m < kRimPoints && !sees_rim; ++m) {
      const double angle = 2.0 * std::numbers::pi * m / kRimPoints;
      const auto q = TilePixelOfPartPoint(
          in.lens, in.scene, t,
          centre_mm + fitted_mm * Eigen::Vector2d(std::cos(angle), std::sin(angle)));
      sees_rim = q && TileBorderDistancePx(*q, in.camera.width_px, in.camera.height_px) >= 0.0;
    }
    if (!sees_rim) continue;
    HoleFit fit = FitInTile(in, t, first.centre_px, radius_px, options, options.search_margin_px);
    const CircleMeasurement& c = fit.circle;
    if (c.ok && c.num_uncovered + c.num_saturated <= max_uncovered * c.num_wedges)
      cut.push_back(std::move(fit));
  }
  return cut;
}

const HoleFit* HoleViews::SaturatedFit() const {
  for (const HoleFit& fit : failed)
    if (RimSaturated(fit.circle, CircleMeasureOptions{})) return &fit;
  return nullptr;
}

std::optional<OrthoGeometry> MeasurementGeometry(const CameraModel& camera,
                                                 const PlaneScene& scene,
                                                 const OrthoGeometry& mosaic,
                                                 double max_ratio) {
  const double tile_px_per_px = TilePxPerMosaicPx(mosaic);
  if (!(tile_px_per_px > 0.0) ||
      (tile_px_per_px <= max_ratio && tile_px_per_px * max_ratio >= 1.0))
    return std::nullopt;
  OrthoOptions options;
  options.gsd_mm = mosaic.grid.gsd_mm / tile_px_per_px;
  return ComputeOrthoGeometry(camera, scene, options);
}

BoreEvidence BoreEvidenceOf(const std::vector<HoleFit>& fits) {
  BoreEvidence evidence;
  for (const HoleFit& fit : fits) {
    const CircleMeasurement& circle = fit.circle;
    if (circle.bottom_rim_scale > 0.0 && !circle.bore_prior_used)
      evidence.bottom_rim_scales.push_back(circle.bottom_rim_scale);
    if (circle.wall_contrast > 0.0) evidence.wall_contrasts.push_back(circle.wall_contrast);
    // A wall narrower than min_wall_blurs on most of the rim (by the view's
    // own k) is not resolved either: a BorePrior ties it (MeasureCircle).
    const bool narrow = 2 * circle.num_narrow_wall > circle.num_wedges;
    evidence.unresolved |= fit.nadir_tile.has_value() && (!circle.bottom_rim_modelled || narrow);
  }
  return evidence;
}

std::optional<BorePrior> PoolBorePrior(const std::vector<BoreEvidence>& holes, size_t min_views) {
  std::vector<double> scales, walls;
  bool unresolved = false;
  for (const BoreEvidence& hole : holes) {
    scales.insert(scales.end(), hole.bottom_rim_scales.begin(), hole.bottom_rim_scales.end());
    walls.insert(walls.end(), hole.wall_contrasts.begin(), hole.wall_contrasts.end());
    unresolved |= hole.unresolved;
  }
  if (!unresolved || scales.size() < min_views || walls.size() < min_views) return std::nullopt;
  const double wall = Median(walls);
  std::vector<double> deviations;
  for (const double w : walls) deviations.push_back(std::abs(w - wall));
  return BorePrior{Median(std::move(scales)), wall, 1.4826 * Median(std::move(deviations))};
}

}  // namespace omm
