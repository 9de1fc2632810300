#include "pipeline/measure/overlap_ties.h"

#include <algorithm>
#include <cmath>
#include <optional>

#include <Eigen/Cholesky>

#include "pipeline/core/error.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/core/statistics.h"
#include "pipeline/measure/ortho_patch.h"

namespace omm {
namespace {

OverlapTie AlignPair(const OrthoGeometry& geometry, const std::vector<ImageF>& tiles, int tile_a,
                     int tile_b, const std::vector<TieHole>& holes, double table_sigma_mm,
                     const OverlapTieOptions& options) {
  OverlapTie tie;
  tie.tile_a = tile_a;
  tie.tile_b = tile_b;
  const TileOrthoMap& map_a = geometry.tiles[tile_a];
  const TileOrthoMap& map_b = geometry.tiles[tile_b];
  const Eigen::Vector2i lo = map_a.min_px.cwiseMax(map_b.min_px);
  const Eigen::Vector2i hi = map_a.max_px.cwiseMin(map_b.max_px);
  const Eigen::Vector2i size = hi - lo + Eigen::Vector2i::Ones();
  const TileExposure unit;  // the alignment fits the gain field itself
  const OrthoInterpolator interpolator = OrthoInterpolator::kCubicBSpline;
  const OrthoPatch a =
      RenderTilePatch(geometry, tile_a, tiles[tile_a], unit, interpolator, lo, size);
  const OrthoPatch b =
      RenderTilePatch(geometry, tile_b, tiles[tile_b], unit, interpolator, lo, size);
  if (a.pixels.size() == 0 || b.pixels.size() == 0 || a.origin_px != b.origin_px) {
    tie.why = "the footprints do not overlap";
    return tie;
  }
  const int rows = static_cast<int>(a.pixels.rows()), cols = static_cast<int>(a.pixels.cols());
  ImageF mask = ImageF::Ones(rows, cols);
  const double gsd = geometry.grid.gsd_mm;
  for (const TieHole& hole : holes) {
    const Eigen::Vector2d centre =
        geometry.grid.MosaicFromPart(hole.near_part_mm) - a.origin_px.cast<double>();
    // near_px is within a quarter of the diameter (project-format.md).
    const double radius = 1.5 * hole.radius_mm / gsd + options.hole_margin_px;
    const int r0 = std::max(0, static_cast<int>(std::floor(centre.y() - radius)));
    const int r1 = std::min(rows - 1, static_cast<int>(std::ceil(centre.y() + radius)));
    const int c0 = std::max(0, static_cast<int>(std::floor(centre.x() - radius)));
    const int c1 = std::min(cols - 1, static_cast<int>(std::ceil(centre.x() + radius)));
    for (int r = r0; r <= r1; ++r)
      for (int c = c0; c <= c1; ++c)
        if ((Eigen::Vector2d(c, r) - centre).squaredNorm() <= radius * radius) mask(r, c) = 0.0f;
  }
  tie.alignment = AlignOverlap(a.pixels, b.pixels, mask, options.alignment);
  if (!tie.alignment.usable) {
    tie.why = tie.alignment.why;
    return tie;
  }
  const Eigen::Vector2d s = tie.alignment.shift_px;
  // Relative table positions: 2 sigma^2 per axis, in grid px^2.
  const double prior_px = table_sigma_mm / gsd;
  const Eigen::Matrix2d total =
      tie.alignment.covariance_px2 + 2.0 * prior_px * prior_px * Eigen::Matrix2d::Identity();
  tie.prior_chi2 = s.dot(total.ldlt().solve(s));
  if (!(tie.prior_chi2 <= ChiSquareQuantile(options.consistency_probability, 2))) {
    tie.why = "its shift contradicts the table prior";
    return tie;
  }
  // The track's point: the centroid of what both see.
  Eigen::Vector2d sum = Eigen::Vector2d::Zero();
  double count = 0.0;
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      if (a.pixels(r, c) > 0.0f && b.pixels(r, c) > 0.0f && mask(r, c) > 0.0f) {
        sum += Eigen::Vector2d(c, r);
        count += 1.0;
      }
    }
  }
  const Eigen::Vector2d x = sum / count + a.origin_px.cast<double>();
  const auto pixel_of = [&geometry](int tile) {
    return [&geometry, tile](const Eigen::Vector2d& mosaic_px) -> std::optional<Eigen::Vector2d> {
      Eigen::Vector2d q;
      if (!geometry.TilePixel(tile, mosaic_px.x(), mosaic_px.y(), &q)) return std::nullopt;
      return q;
    };
  };
  if (!CarryToTile(pixel_of(tile_a), x, Eigen::Matrix2d::Zero(), options.min_sigma_px, &tie.q_a_px,
                   &tie.covariance_a_px2) ||
      !CarryToTile(pixel_of(tile_b), x + s, tie.alignment.covariance_px2, options.min_sigma_px,
                   &tie.q_b_px, &tie.covariance_b_px2)) {
    tie.why = "the overlap's centre is outside the lens table";
    return tie;
  }
  tie.point_mm = geometry.grid.PartFromMosaic(x);
  tie.used = true;
  return tie;
}

}  // namespace

std::string OverlapTieOptions::Check() const {
  if (const std::string why = alignment.Check(); !why.empty()) return "alignment: " + why;
  if (!(hole_margin_px >= 0.0)) return "hole_margin_px must be >= 0";
  if (!(min_sigma_px > 0.0)) return "min_sigma_px must be > 0";
  if (!(consistency_probability > 0.0 && consistency_probability < 1.0))
    return "consistency_probability must be in (0, 1)";
  if (num_threads < 1) return "num_threads must be at least 1";
  return "";
}

std::vector<std::pair<int, int>> OverlapsToAlign(const OrthoGeometry& geometry,
                                                 const std::vector<int>& held,
                                                 const std::vector<std::pair<int, int>>& links) {
  const int num_tiles = static_cast<int>(geometry.tiles.size());
  const auto is_held = [&held](int tile) {
    return std::find(held.begin(), held.end(), tile) != held.end();
  };
  const auto linked = [&links](int a, int b) {
    return std::find(links.begin(), links.end(), std::pair(std::min(a, b), std::max(a, b))) !=
           links.end();
  };
  std::vector<bool> weak(num_tiles, false);
  for (int b = 0; b < num_tiles; ++b) {
    int num_linked = 0;
    for (int a = 0; a < num_tiles; ++a) num_linked += a != b && linked(a, b) ? 1 : 0;
    weak[b] = !is_held(b) && num_linked <= 1;
  }
  std::vector<std::pair<int, int>> pairs;
  for (int b = 0; b < num_tiles; ++b) {
    if (!is_held(b) && !weak[b]) continue;
    for (int a = 0; a < num_tiles; ++a) {
      // Two weak tiles' overlap once.
      if (a == b || is_held(a) || linked(a, b) || (weak[a] && weak[b] && a > b)) continue;
      const TileOrthoMap& map_a = geometry.tiles[a];
      const TileOrthoMap& map_b = geometry.tiles[b];
      const Eigen::Vector2i size =
          map_a.max_px.cwiseMin(map_b.max_px) - map_a.min_px.cwiseMax(map_b.min_px);
      if ((size.array() > 0).all()) pairs.emplace_back(a, b);
    }
  }
  return pairs;
}

std::vector<OverlapTie> FindOverlapTies(const OrthoGeometry& geometry,
                                        const std::vector<ImageF>& tiles,
                                        const std::vector<std::pair<int, int>>& pairs,
                                        const std::vector<TieHole>& holes, double table_sigma_mm,
                                        const OverlapTieOptions& options) {
  if (const std::string why = options.Check(); !why.empty())
    throw InputError("OverlapTieOptions", why);
  std::vector<OverlapTie> ties(pairs.size());
  ParallelFor(static_cast<int>(pairs.size()), options.num_threads, [&](int i) {
    ties[i] =
        AlignPair(geometry, tiles, pairs[i].first, pairs[i].second, holes, table_sigma_mm, options);
  });
  return ties;
}

void AddOverlapTieTracks(const std::vector<OverlapTie>& ties, PlaneBundleInput* input,
                         PlaneScene* scene) {
  for (const OverlapTie& tie : ties) {
    if (!tie.used) continue;
    AppendTieTrack(tie.point_mm, {tie.tile_a, tie.tile_b}, {tie.q_a_px, tie.q_b_px},
                   {tie.covariance_a_px2, tie.covariance_b_px2}, input, scene);
  }
}

}  // namespace omm
