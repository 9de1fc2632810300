#include "pipeline/measure/ortho_patch.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace omm {
namespace {

constexpr int kPrefilterMarginPx = 16;

}  // namespace

OrthoPatch RenderTilePatch(const OrthoGeometry& geometry, int tile, const ImageF& tile_image,
                           const TileExposure& exposure, OrthoInterpolator interpolator,
                           const Eigen::Vector2i& min_px, const Eigen::Vector2i& size_px) {
  const Eigen::Vector2i lo = min_px.cwiseMax(0);
  const Eigen::Vector2i hi = (min_px + size_px).cwiseMin(geometry.grid.size_px);
  OrthoPatch patch;
  patch.origin_px = lo;
  if ((hi.array() <= lo.array()).any()) return patch;
  const int width = hi.x() - lo.x(), height = hi.y() - lo.y();
  patch.pixels = ImageF::Zero(height, width);

  // The tile pixels of the window, exactly as ResampleMosaic computes them:
  // over the tile's span, with TileRowPixels' nodes where its call puts them.
  const TileOrthoMap& map = geometry.tiles[tile];
  constexpr int kStep = OrthoGeometry::kRowNodeStep;
  std::vector<Eigen::Vector2d> q(static_cast<size_t>(width) * height);
  std::vector<char> seen(q.size(), 0);
  std::vector<Eigen::Vector2d> row_q;
  std::vector<char> row_ok;
  Eigen::Vector2d q_min = Eigen::Vector2d::Constant(INFINITY);
  Eigen::Vector2d q_max = Eigen::Vector2d::Constant(-INFINITY);
  const int col_lo = std::max(lo.x(), map.min_px.x()),
            col_hi = std::min(hi.x() - 1, map.max_px.x());
  const int row_lo = std::max(lo.y(), map.min_px.y()),
            row_hi = std::min(hi.y() - 1, map.max_px.y());
  const int col0 = map.min_px.x() + (col_lo - map.min_px.x()) / kStep * kStep;
  for (int row = row_lo; row <= row_hi && col_lo <= col_hi; ++row) {
    geometry.TileRowPixels(tile, row, col0, col_hi - col0 + 1, &row_q, &row_ok);
    for (int col = col_lo; col <= col_hi; ++col) {
      const Eigen::Vector2d& qk = row_q[col - col0];
      if (!row_ok[col - col0] || !(static_cast<float>(geometry.BorderDistancePx(qk)) > 0.0f))
        continue;
      const size_t i = static_cast<size_t>(row - lo.y()) * width + (col - lo.x());
      q[i] = qk;
      seen[i] = 1;
      q_min = q_min.cwiseMin(qk);
      q_max = q_max.cwiseMax(qk);
    }
  }
  if (!(q_min.x() <= q_max.x())) return patch;

  // A crop wide enough that its coefficients equal the whole tile's (header).
  const int margin = interpolator == OrthoInterpolator::kCubicBSpline ? kPrefilterMarginPx : 0;
  const int x0 = std::max(0, static_cast<int>(std::floor(q_min.x())) - 1 - margin);
  const int y0 = std::max(0, static_cast<int>(std::floor(q_min.y())) - 1 - margin);
  const int x1 = std::min<int>(tile_image.cols(), static_cast<int>(q_max.x()) + 3 + margin);
  const int y1 = std::min<int>(tile_image.rows(), static_cast<int>(q_max.y()) + 3 + margin);
  const ImageF crop = tile_image.block(y0, x0, y1 - y0, x1 - x0);
  const ImageF sampled =
      interpolator == OrthoInterpolator::kCubicBSpline ? CubicBSplineCoefficients(crop) : crop;
  const Eigen::Vector2d shift(x0, y0);  // integers: q - shift keeps q's fraction exactly
  const ImageMask clipped = ClippedSupport(crop);
  if (clipped.size() > 0) patch.saturated = ImageMask::Zero(height, width);
  for (int r = 0; r < height; ++r) {
    for (int c = 0; c < width; ++c) {
      const size_t i = static_cast<size_t>(r) * width + c;
      if (!seen[i]) continue;
      if (clipped.size() > 0) {
        const Eigen::Vector2d in_crop = q[i] - shift;
        patch.saturated(r, c) =
            clipped(static_cast<int>(in_crop.y()), static_cast<int>(in_crop.x()));
      }
      const double v = SampleCubic(interpolator, sampled, q[i] - shift) /
                       exposure.Factor(geometry.vignetting.Rho2(q[i]));
      patch.pixels(r, c) = std::max(static_cast<float>(v), kDarkestCovered);
    }
  }
  return patch;
}

}  // namespace omm
