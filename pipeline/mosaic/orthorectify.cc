#include "pipeline/mosaic/orthorectify.h"

#include <algorithm>
#include <cassert>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <numeric>
#include <optional>
#include <stdexcept>

#include <fmt/format.h>
#include <Eigen/Geometry>

#include "adapters/mrcal/lens.h"
#include "pipeline/core/error.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/core/timing.h"
#include "pipeline/mosaic/ortho_sampling.h"

namespace omm {

std::string OrthoOptions::Check() const {
  if (!(gsd_mm > 0.0)) return "gsd_mm must be > 0";
  if (const std::string e = lens_table.Check(); !e.empty()) return "lens_table: " + e;
  if (!(blend_band_px > 0.0)) return "blend_band_px must be > 0";
  if (!(whole_margin_px >= 0.0 && std::isfinite(whole_margin_px)))
    return "whole_margin_px must be >= 0 and finite";
  if (const std::string e = exposure.Check(); !e.empty()) return "exposure: " + e;
  if (num_threads < 1) return "num_threads must be >= 1";
  if (max_pixels < 1) return "max_pixels must be >= 1";
  if (!(max_tile_px_per_mosaic_px >= 1.0)) return "max_tile_px_per_mosaic_px must be >= 1";
  return "";
}

GsdError::GsdError(const std::string& why, bool is_too_fine, double tile_pixel, double fitting_gsd)
    : InputError("", why),
      too_fine(is_too_fine),
      tile_pixel_mm(tile_pixel),
      fitting_gsd_mm(fitting_gsd) {}

namespace {

using Clock = std::chrono::steady_clock;

// The border of the region a tile is sampled in, [1, W - 2] x [1, H - 2].
Eigen::Matrix2Xd TileBorderPx(const CameraModel& camera) {
  return RectangleBorderPx({1.0, 1.0}, {camera.width_px - 2.0, camera.height_px - 2.0}, 32);
}

// Area of a simple polygon (2 x N vertices in order, either sense).
double PolygonArea(const Eigen::Matrix2Xd& polygon) {
  double twice = 0.0;
  for (Eigen::Index k = 0, n = polygon.cols(); k < n; ++k) {
    const Eigen::Vector2d a = polygon.col(k), b = polygon.col((k + 1) % n);
    twice += a.x() * b.y() - b.x() * a.y();
  }
  return 0.5 * std::abs(twice);
}

// x > 0 rounded up or down to two significant digits.
double RoundTo2Digits(double x, bool up) {
  const double unit = std::pow(10.0, std::floor(std::log10(x)) - 1.0);
  return (up ? std::ceil(x / unit) : std::floor(x / unit)) * unit;
}

// The (2r+1)^2 box mean of `image` (borders replicated) bilinearly
// interpolated at q (q in [0, W - 1) x [0, H - 1)): one (2r+2)^2 stencil
// whose weights along each axis are (1 - f, 1, ..., 1, f) / (2r + 1). Only at
// the sample points: box-filtering whole tiles cost ~30x the work and 140 MB
// of fresh pages on the demo.
double SampleBoxSmoothed(const ImageF& image, const Eigen::Vector2d& q, int r) {
  const int ix = static_cast<int>(q.x()), iy = static_cast<int>(q.y());
  const double fx = q.x() - ix, fy = q.y() - iy;
  const int last_col = static_cast<int>(image.cols()) - 1;
  const int last_row = static_cast<int>(image.rows()) - 1;
  const int taps = 2 * r + 2;
  double sum = 0.0;
  for (int j = 0; j < taps; ++j) {
    const float* row =
        image.data() +
        static_cast<std::ptrdiff_t>(std::clamp(iy - r + j, 0, last_row)) * image.cols();
    const auto at = [&](int i) {
      return static_cast<double>(row[std::clamp(ix - r + i, 0, last_col)]);
    };
    double row_sum = (1 - fx) * at(0) + fx * at(taps - 1);
    for (int i = 1; i + 1 < taps; ++i) row_sum += at(i);
    sum += (j == 0 ? 1 - fy : j + 1 == taps ? fy : 1.0) * row_sum;
  }
  return sum / ((2 * r + 1) * (2 * r + 1));
}

// Observations of the tiles' (smoothed) intensities at every sample_step-th
// mosaic pixel seen by >= 2 tiles, min_border_px inside their borders.
std::vector<ExposureObservation> CollectExposureObservations(const OrthoGeometry& geometry,
                                                             const std::vector<ImageF>& tiles,
                                                             const OrthoOptions& options) {
  const ExposureOptions& eo = options.exposure;
  const int num_tiles = static_cast<int>(tiles.size());
  const VignettingFrame& frame = geometry.vignetting;
  const int step = eo.sample_step_px;
  const int num_rows = (geometry.grid.size_px.y() + step - 1) / step;
  const int num_cols = (geometry.grid.size_px.x() + step - 1) / step;
  const double min_border = std::max(eo.min_border_px, 1.0);
  std::vector<std::vector<ExposureObservation>> per_row(num_rows);
  ParallelFor(num_rows, options.num_threads, [&](int sample_row) {
    const int row = sample_row * step;
    std::vector<ExposureObservation> here;
    for (int sample_col = 0; sample_col < num_cols; ++sample_col) {
      const int col = sample_col * step;
      here.clear();
      for (int i = 0; i < num_tiles; ++i) {
        const TileOrthoMap& map = geometry.tiles[i];
        if (col < map.min_px.x() || col > map.max_px.x() || row < map.min_px.y() ||
            row > map.max_px.y())
          continue;
        Eigen::Vector2d q;
        if (!geometry.TilePixel(i, col, row, &q) || geometry.BorderDistancePx(q) < min_border)
          continue;
        const double value = SampleBoxSmoothed(tiles[i], q, eo.smoothing_radius_px);
        if (value < eo.min_value || value > eo.max_value) continue;
        here.push_back({sample_col, i, value, frame.Rho2(q)});
      }
      if (here.size() >= 2)
        per_row[sample_row].insert(per_row[sample_row].end(), here.begin(), here.end());
    }
  });
  std::vector<ExposureObservation> obs;
  int sample = -1;
  for (const std::vector<ExposureObservation>& row : per_row) {
    for (size_t k = 0; k < row.size(); ++k) {
      if (k == 0 || row[k].sample != row[k - 1].sample) ++sample;
      obs.push_back(row[k]);
      obs.back().sample = sample;
    }
  }
  return obs;
}

}  // namespace

void OrthoGeometry::TileRowPixels(int tile, int row, int col0, int n,
                                  std::vector<Eigen::Vector2d>* q_px,
                                  std::vector<char>* valid) const {
  constexpr int kStep = kRowNodeStep;
  const int num_nodes = (n - 1) / kStep + 4;  // node j at column col0 + (j - 1) kStep
  std::vector<Eigen::Vector2d> nq(num_nodes);
  std::vector<char> nok(num_nodes);
  for (int j = 0; j < num_nodes; ++j) nok[j] = TilePixel(tile, col0 + (j - 1) * kStep, row, &nq[j]);
  q_px->resize(n);
  valid->resize(n);
  double w[kStep][4];
  for (int phase = 0; phase < kStep; ++phase)
    CatmullRomWeights(static_cast<double>(phase) / kStep, w[phase]);
  // Segment by segment: pixel k lies between nodes j and j + 1, j = k / kStep + 1.
  for (int j = 1, k0 = 0; k0 < n; ++j, k0 += kStep) {
    const int k1 = std::min(n, k0 + kStep);
    if (!(nok[j - 1] && nok[j] && nok[j + 1] && nok[j + 2])) {
      // Nodes beyond the lens table's reach (a gsd of many tile pixels puts
      // them far outside the image): each pixel from the table itself.
      for (int k = k0; k < k1; ++k) (*valid)[k] = TilePixel(tile, col0 + k, row, &(*q_px)[k]);
      continue;
    }
    std::fill(valid->begin() + k0, valid->begin() + k1, true);
    for (int k = k0; k < k1; ++k) {
      const double* wk = w[k - k0];
      (*q_px)[k] = wk[0] * nq[j - 1] + wk[1] * nq[j] + wk[2] * nq[j + 1] + wk[3] * nq[j + 2];
    }
  }
}

std::optional<Eigen::Vector2d> FirstUnmappedTileBorderPixel(const CameraModel& camera) {
  return FirstUnmappedPixel(camera, TileBorderPx(camera), 0.01);
}

OrthoGeometry ComputeOrthoGeometry(const CameraModel& camera, const PlaneScene& scene,
                                   const OrthoOptions& options) {
  if (const std::string e = options.Check(); !e.empty()) throw InputError("mosaic options", e);
  if (camera.intrinsics.size() != LensModelNumParams(camera.lens_model))
    throw InputError("camera", "lens model '" + camera.lens_model + "' does not fit its " +
                                   std::to_string(camera.intrinsics.size()) + " intrinsics");
  if (camera.width_px < 4 || camera.height_px < 4)
    throw InputError("camera", "image size must be at least 4 x 4 px");
  if (scene.table_pos_mm.empty()) throw InputError("scene", "no tiles");

  OrthoGeometry geometry;
  geometry.image_width_px = camera.width_px;
  geometry.image_height_px = camera.height_px;
  geometry.lens = BuildLensTable(camera, options.lens_table);
  geometry.vignetting = VignettingFrame::Of(camera);

  // The border of the sampled region, as rays.
  const Eigen::Matrix2Xd border = TileBorderPx(camera);
  if (const std::optional<Eigen::Vector2d> unmapped = FirstUnmappedTileBorderPixel(camera)) {
    char text[256];
    std::snprintf(text, sizeof(text),
                  "the lens model maps no ray to pixel (%.0f, %.0f) of the image border: it does "
                  "not cover the whole image, which the tiles use (calibrate with the plate near "
                  "the image's corners and edges)",
                  unmapped->x(), unmapped->y());
    throw InputError("camera", text);
  }
  Eigen::Matrix3Xd rays;
  if (!UnprojectPixels(camera, border, &rays))
    throw InputError("camera", "cannot unproject the image border");

  // Footprints: X = R^T (lambda v - t) with X_z = 0, then P = X - T_i.
  const Eigen::Matrix3d cam_from_part = RotationFromAngleAxis(scene.cam_from_part_r);
  const Eigen::Vector3d& t = scene.cam_from_part_t_mm;
  const Eigen::Vector3d part_t = cam_from_part.transpose() * t;
  const int num_tiles = static_cast<int>(scene.table_pos_mm.size());
  geometry.tiles.resize(num_tiles);
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(INFINITY), hi = -lo;
  for (int i = 0; i < num_tiles; ++i) {
    Eigen::Matrix2Xd& footprint = geometry.tiles[i].footprint_mm;
    footprint.resize(2, rays.cols());
    for (Eigen::Index k = 0; k < rays.cols(); ++k) {
      const Eigen::Vector3d v = cam_from_part.transpose() * rays.col(k);
      const double lambda = part_t.z() / v.z();
      if (!(lambda > 0.0))
        throw InputError("scene", "tile " + std::to_string(i) +
                                      ": the image border does not meet the part plane");
      footprint.col(k) = (lambda * v - part_t).head<2>() - scene.table_pos_mm[i];
    }
    lo = lo.cwiseMin(footprint.rowwise().minCoeff());
    hi = hi.cwiseMax(footprint.rowwise().maxCoeff());
  }

  OrthoGrid& grid = geometry.grid;
  const double gsd = options.gsd_mm;
  grid.gsd_mm = gsd;
  grid.origin_mm = {std::floor(lo.x() / gsd) * gsd, std::ceil(hi.y() / gsd) * gsd};
  const Eigen::Vector2d size_px(std::ceil((hi.x() - grid.origin_mm.x()) / gsd),
                                std::ceil((grid.origin_mm.y() - lo.y()) / gsd));
  const double tile_pixel_mm = std::sqrt(PolygonArea(geometry.tiles[0].footprint_mm) /
                                         ((camera.width_px - 3.0) * (camera.height_px - 3.0)));
  if (gsd > options.max_tile_px_per_mosaic_px * tile_pixel_mm) {
    const double max_gsd =
        RoundTo2Digits(0.99 * options.max_tile_px_per_mosaic_px * tile_pixel_mm, false);
    throw GsdError(fmt::format("a gsd of {:g} mm makes a mosaic pixel {:.0f} tile pixels wide, "
                               "more than the {:g} it may be; a tile pixel is {:.3g} mm on the "
                               "part: a gsd of {:g} mm or less fits",
                               gsd, gsd / tile_pixel_mm, options.max_tile_px_per_mosaic_px,
                               tile_pixel_mm, max_gsd),
                   false, tile_pixel_mm, max_gsd);
  }
  if (!(size_px.prod() <= static_cast<double>(options.max_pixels))) {
    // The pixel count goes as 1 / gsd^2 (the ceilings add a row and a
    // column at most: 1 % covers them).
    const double min_gsd =
        RoundTo2Digits(1.01 * gsd * std::sqrt(size_px.prod() / options.max_pixels), true);
    throw GsdError(
        fmt::format("a gsd of {:g} mm makes a mosaic of {:.0f} x {:.0f} px ({:.0f} "
                    "Mpx), more than the {:.0f} Mpx it may have; a tile pixel is "
                    "{:.3g} mm on the part: a gsd of {:g} mm or more fits",
                    gsd, size_px.x(), size_px.y(), 1e-6 * size_px.prod(),
                    1e-6 * static_cast<double>(options.max_pixels), tile_pixel_mm, min_gsd),
        true, tile_pixel_mm, min_gsd);
  }
  grid.size_px = size_px.cast<int>();

  for (int i = 0; i < num_tiles; ++i) {
    TileOrthoMap& map = geometry.tiles[i];
    const Eigen::Vector3d table(scene.table_pos_mm[i].x(), scene.table_pos_mm[i].y(), 0.0);
    const Eigen::Vector3d p_first(grid.origin_mm.x() + 0.5 * gsd, grid.origin_mm.y() - 0.5 * gsd,
                                  0.0);
    map.p0_mm = cam_from_part * (p_first + table) + t;
    map.dcol_mm = gsd * cam_from_part.col(0);
    map.drow_mm = -gsd * cam_from_part.col(1);
    Eigen::Vector2d min_px = Eigen::Vector2d::Constant(INFINITY), max_px = -min_px;
    for (Eigen::Index k = 0; k < map.footprint_mm.cols(); ++k) {
      const Eigen::Vector2d m = grid.MosaicFromPart(map.footprint_mm.col(k));
      min_px = min_px.cwiseMin(m);
      max_px = max_px.cwiseMax(m);
    }
    // The border between the footprint's vertices bulges by the distortion's
    // curvature over 1/32 of a side: a few pixels at most.
    constexpr double kMarginPx = 4.0;
    map.min_px = {std::max(0, static_cast<int>(std::floor(min_px.x() - kMarginPx))),
                  std::max(0, static_cast<int>(std::floor(min_px.y() - kMarginPx)))};
    map.max_px = {
        std::min(grid.size_px.x() - 1, static_cast<int>(std::ceil(max_px.x() + kMarginPx))),
        std::min(grid.size_px.y() - 1, static_cast<int>(std::ceil(max_px.y() + kMarginPx)))};
  }
  return geometry;
}

int TileSeeingDiscBest(const OrthoGeometry& geometry, const Eigen::Vector2d& centre_px,
                       double radius_px) {
  // A rim point every ~4 px: the border is straight between them.
  const int num_rim =
      std::max(16, static_cast<int>(std::ceil(2.0 * std::numbers::pi * radius_px / 4.0)));
  int best_tile = -1;
  double best_least = 0.0;
  for (int tile = 0; tile < static_cast<int>(geometry.tiles.size()); ++tile) {
    double least = INFINITY;
    for (int m = -1; m < num_rim && least > best_least; ++m) {
      const double angle = 2.0 * std::numbers::pi * m / num_rim;
      const Eigen::Vector2d p =
          centre_px + (m < 0 ? 0.0 : radius_px) * Eigen::Vector2d(std::cos(angle), std::sin(angle));
      Eigen::Vector2d q;
      least = geometry.TilePixel(tile, p.x(), p.y(), &q)
                  ? std::min(least, geometry.BorderDistancePx(q))
                  : -INFINITY;
    }
    if (least > best_least) {
      best_least = least;
      best_tile = tile;
    }
  }
  return best_tile;
}

std::vector<WholeDisc> WholeDiscs(const OrthoGeometry& geometry,
                                  const std::vector<OrthoDisc>& features,
                                  const OrthoOptions& options) {
  std::vector<WholeDisc> discs;
  for (const OrthoDisc& feature : features) {
    WholeDisc disc;
    disc.centre_px = geometry.grid.MosaicFromPart(feature.centre_mm);
    disc.radius_px = feature.radius_mm / geometry.grid.gsd_mm + options.whole_margin_px;
    disc.band_px = options.blend_band_px;
    disc.tile = TileSeeingDiscBest(geometry, disc.centre_px, disc.radius_px + disc.band_px);
    if (disc.tile >= 0) discs.push_back(disc);
  }
  return discs;
}

std::vector<ImageF> InterpolatorSamples(const std::vector<ImageF>& tiles,
                                        const OrthoOptions& options) {
  std::vector<ImageF> coefficients;
  if (options.interpolator == OrthoInterpolator::kCubicBSpline) {
    coefficients.resize(tiles.size());
    ParallelFor(static_cast<int>(tiles.size()), options.num_threads,
                [&](int i) { coefficients[i] = CubicBSplineCoefficients(tiles[i]); });
  }
  return coefficients;
}

ImageF ResampleMosaic(const OrthoGeometry& geometry, const std::vector<ImageF>& tiles,
                      const std::vector<TileExposure>& exposure, const OrthoOptions& options,
                      const std::vector<WholeDisc>& whole, ResampleCounts* counts,
                      const std::vector<ImageF>* samples) {
  const int num_tiles = static_cast<int>(tiles.size());
  assert(num_tiles == static_cast<int>(geometry.tiles.size()));
  assert(exposure.empty() || static_cast<int>(exposure.size()) == num_tiles);
  const int width = geometry.grid.size_px.x(), height = geometry.grid.size_px.y();
  ImageF mosaic = ImageF::Zero(height, width);
  const VignettingFrame& frame = geometry.vignetting;
  const double band = options.blend_band_px;

  std::vector<ImageF> computed;
  if (samples == nullptr) {
    computed = InterpolatorSamples(tiles, options);
    samples = &computed;
  }
  const std::vector<ImageF>& sampled = samples->empty() ? tiles : *samples;
  // Where each tile's interpolation reads a clipped sample (header).
  std::vector<ImageMask> clipped_support(num_tiles);
  for (int i = 0; i < num_tiles; ++i) clipped_support[i] = ClippedSupport(tiles[i]);

  // Blocks of rows: the per-row buffers are allocated once per block.
  constexpr int kRowsPerBlock = 16;
  const int num_blocks = (height + kRowsPerBlock - 1) / kRowsPerBlock;
  std::vector<std::int64_t> covered(num_blocks, 0), clipped(num_blocks, 0);
  // Tiles whose weight is below exp(-kNegligibleBands) of the best one's are
  // not sampled (they would change the result by < 1e-4 of the intensity).
  constexpr double kNegligibleBands = 10.0;
  ParallelFor(num_blocks, options.num_threads, [&](int block) {
    // Per tile: its tile pixels along the row's span [min_px.x, max_px.x] and
    // their border distances (<= 0: unseen, or a clipped sample read).
    std::vector<std::vector<Eigen::Vector2d>> q(num_tiles);
    std::vector<std::vector<char>> q_ok(num_tiles);
    std::vector<std::vector<float>> dist(num_tiles);
    std::vector<float> best(width);
    std::vector<char> seen(width);  // by a tile, clipped or not
    std::vector<double> sum_w(width), sum_wv(width);
    std::vector<int> active;
    // The whole discs' share of a pixel (1 inside, falling across the band)
    // and their tile; 0 outside every disc.
    std::vector<float> share(width, 0.0f);
    std::vector<int> share_tile(width, -1);
    for (int row = block * kRowsPerBlock; row < std::min(height, (block + 1) * kRowsPerBlock);
         ++row) {
      active.clear();
      std::fill(best.begin(), best.end(), -1.0f);
      std::fill(seen.begin(), seen.end(), 0);
      for (int i = 0; i < num_tiles; ++i) {
        const TileOrthoMap& map = geometry.tiles[i];
        if (row < map.min_px.y() || row > map.max_px.y()) continue;
        active.push_back(i);
        const int n = map.max_px.x() - map.min_px.x() + 1;
        geometry.TileRowPixels(i, row, map.min_px.x(), n, &q[i], &q_ok[i]);
        dist[i].resize(n);
        float* best_span = best.data() + map.min_px.x();
        char* seen_span = seen.data() + map.min_px.x();
        const ImageMask& clipped_at = clipped_support[i];
        for (int k = 0; k < n; ++k) {
          float d = q_ok[i][k] ? static_cast<float>(geometry.BorderDistancePx(q[i][k])) : -1.0f;
          if (d > 0.0f) {
            seen_span[k] = 1;
            const Eigen::Vector2d& qk = q[i][k];
            if (clipped_at.size() > 0 &&
                clipped_at(static_cast<int>(qk.y()), static_cast<int>(qk.x())) != 0)
              d = -1.0f;
          }
          dist[i][k] = d;
          best_span[k] = std::max(best_span[k], d);
        }
      }
      // Tile by tile along its span (in tile order, so the sums add up as a
      // per-pixel loop over the tiles would).
      std::fill(sum_w.begin(), sum_w.end(), 0.0);
      std::fill(sum_wv.begin(), sum_wv.end(), 0.0);
      for (const int i : active) {
        const int col0 = geometry.tiles[i].min_px.x();
        const int n = static_cast<int>(dist[i].size());
        for (int k = 0; k < n; ++k) {
          const double d = dist[i][k], best_d = best[col0 + k];
          if (!(d > 0.0) || d < best_d - kNegligibleBands * band) continue;
          const Eigen::Vector2d& qi = q[i][k];
          double v = SampleCubic(options.interpolator, sampled[i], qi);
          if (!exposure.empty()) v /= exposure[i].Factor(frame.Rho2(qi));
          const double w = TileBlendWeight(d, best_d, band);
          sum_w[col0 + k] += w;
          sum_wv[col0 + k] += w * v;
        }
      }
      std::fill(share.begin(), share.end(), 0.0f);
      for (const WholeDisc& disc : whole) {
        const double reach = disc.radius_px + disc.band_px, dy = row - disc.centre_px.y();
        if (std::abs(dy) >= reach) continue;
        const double half = std::sqrt(reach * reach - dy * dy);
        const int first = std::max(0, static_cast<int>(std::ceil(disc.centre_px.x() - half)));
        const int last =
            std::min(width - 1, static_cast<int>(std::floor(disc.centre_px.x() + half)));
        for (int col = first; col <= last; ++col) {
          const double beyond = std::hypot(col - disc.centre_px.x(), dy) - disc.radius_px;
          // Smoothstep from 1 at the radius to 0 a band beyond.
          const double x = std::clamp(1.0 - beyond / disc.band_px, 0.0, 1.0);
          const float s = static_cast<float>(x * x * (3.0 - 2.0 * x));
          if (s > share[col]) {
            share[col] = s;
            share_tile[col] = disc.tile;
          }
        }
      }
      float* out = mosaic.data() + static_cast<std::ptrdiff_t>(row) * width;
      for (int col = 0; col < width; ++col) {
        if (!seen[col]) continue;
        ++covered[block];
        if (!(best[col] > 0.0f)) {  // every tile that sees it read a clipped sample
          ++clipped[block];
          out[col] = 1.0f;
          continue;
        }
        double v = sum_wv[col] / sum_w[col];
        if (share[col] > 0.0f) {
          const int t = share_tile[col];
          const int k = col - geometry.tiles[t].min_px.x();
          if (std::find(active.begin(), active.end(), t) != active.end() && k >= 0 &&
              k < static_cast<int>(dist[t].size()) && dist[t][k] > 0.0f) {
            double vt = SampleCubic(options.interpolator, sampled[t], q[t][k]);
            if (!exposure.empty()) vt /= exposure[t].Factor(frame.Rho2(q[t][k]));
            v = (1.0 - share[col]) * v + share[col] * vt;
          }
        }
        if (v < 0.0 || v > 1.0) ++clipped[block];
        out[col] = std::clamp(static_cast<float>(v), kDarkestCovered, 1.0f);
      }
    }
  });
  if (counts) {
    counts->covered_px = std::accumulate(covered.begin(), covered.end(), std::int64_t{0});
    counts->clipped_px = std::accumulate(clipped.begin(), clipped.end(), std::int64_t{0});
  }
  return mosaic;
}

double TilePxPerMosaicPx(const OrthoGeometry& geometry) {
  double px_per_px = 0.0;
  int n = 0;
  for (size_t i = 0; i < geometry.tiles.size(); ++i) {
    const Eigen::Vector2d centre =
        geometry.grid.MosaicFromPart(geometry.tiles[i].footprint_mm.rowwise().mean());
    Eigen::Vector2d q0, q1;
    if (geometry.TilePixel(static_cast<int>(i), centre.x(), centre.y(), &q0) &&
        geometry.TilePixel(static_cast<int>(i), centre.x() + 1.0, centre.y(), &q1)) {
      px_per_px += (q1 - q0).norm();
      ++n;
    }
  }
  return n > 0 ? px_per_px / n : 0.0;
}

ExposureSummary EstimateTileExposure(const OrthoGeometry& geometry,
                                     const std::vector<ImageF>& tiles,
                                     const OrthoOptions& options) {
  ExposureOptions exposure_options = options.exposure;
  exposure_options.num_threads = options.num_threads;
  return EstimateExposure(CollectExposureObservations(geometry, tiles, options),
                          static_cast<int>(tiles.size()), exposure_options);
}

OrthoResult Orthorectify(const CameraModel& camera, const PlaneScene& scene,
                         const std::vector<ImageF>& tiles, const OrthoOptions& options,
                         const std::vector<OrthoDisc>& features,
                         const OrthoPrecomputed& precomputed) {
  const Clock::time_point start = Clock::now();
  if (tiles.size() != scene.table_pos_mm.size())
    throw InputError("tiles", std::to_string(tiles.size()) + " images for " +
                                  std::to_string(scene.table_pos_mm.size()) + " tile positions");
  for (size_t i = 0; i < tiles.size(); ++i) {
    if (tiles[i].cols() != camera.width_px || tiles[i].rows() != camera.height_px)
      throw InputError(
          "tiles", "tile " + std::to_string(i) + " is " + std::to_string(tiles[i].cols()) + " x " +
                       std::to_string(tiles[i].rows()) + " px, the camera " +
                       std::to_string(camera.width_px) + " x " + std::to_string(camera.height_px));
  }
  if (const std::vector<ImageF>* samples = precomputed.samples) {
    const bool spline = options.interpolator == OrthoInterpolator::kCubicBSpline;
    bool fit = samples->size() == (spline ? tiles.size() : 0);
    for (size_t i = 0; fit && i < samples->size(); ++i)
      fit = (*samples)[i].rows() == tiles[i].rows() && (*samples)[i].cols() == tiles[i].cols();
    if (!fit) {
      throw std::invalid_argument(
          "Orthorectify: the precomputed samples are not InterpolatorSamples of the tiles");
    }
  }
  OrthoResult result;
  OrthoSummary& summary = result.summary;
  const OrthoGeometry geometry = ComputeOrthoGeometry(camera, scene, options);
  summary.lens_table_max_error_px = geometry.lens.max_error_px();
  summary.lens_table_nodes = geometry.lens.num_nodes();
  summary.tile_px_per_mosaic_px = TilePxPerMosaicPx(geometry);
  summary.geometry_seconds = SecondsSince(start);

  const Clock::time_point exposure_start = Clock::now();
  if (options.compensate_exposure) {
    summary.exposure = precomputed.exposure != nullptr
                           ? *precomputed.exposure
                           : EstimateTileExposure(geometry, tiles, options);
  }
  summary.exposure_seconds = SecondsSince(exposure_start);

  const Clock::time_point resample_start = Clock::now();
  ResampleCounts counts;
  const std::vector<WholeDisc> whole = WholeDiscs(geometry, features, options);
  summary.features_kept_whole = static_cast<int>(whole.size());
  summary.features_blended = static_cast<int>(features.size() - whole.size());
  ImageF pixels = ResampleMosaic(geometry, tiles, summary.exposure.tiles, options, whole, &counts,
                                 precomputed.samples);
  const std::int64_t covered = counts.covered_px, clipped = counts.clipped_px;
  summary.resample_seconds = SecondsSince(resample_start);
  summary.covered_fraction = pixels.size() > 0 ? static_cast<double>(covered) / pixels.size() : 0.0;
  summary.clipped_fraction = covered > 0 ? static_cast<double>(clipped) / covered : 0.0;
  summary.usable = covered > 0 &&
                   summary.lens_table_max_error_px <= options.lens_table.max_error_px &&
                   (!options.compensate_exposure || summary.exposure.usable);

  char line[320];
  std::snprintf(line, sizeof(line),
                "mosaic %d x %d px at %.4g mm (origin %.3f, %.3f mm), %.1f %% covered, "
                "%.2f tile px per mosaic px, map error <= %.1e px%s%s",
                geometry.grid.size_px.x(), geometry.grid.size_px.y(), geometry.grid.gsd_mm,
                geometry.grid.origin_mm.x(), geometry.grid.origin_mm.y(),
                100.0 * summary.covered_fraction, summary.tile_px_per_mosaic_px,
                summary.lens_table_max_error_px, options.compensate_exposure ? "; " : "",
                options.compensate_exposure ? summary.exposure.brief.c_str() : "");
  summary.brief = line;
  if (!features.empty()) {
    summary.brief += "; " + std::to_string(summary.features_kept_whole) + " of " +
                     std::to_string(features.size()) + " features each from one tile";
  }
  result.mosaic.grid = geometry.grid;
  result.mosaic.pixels = std::move(pixels);
  return result;
}

}  // namespace omm
