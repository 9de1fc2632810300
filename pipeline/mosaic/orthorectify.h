// The orthorectified mosaic: a metric top view of the part's top surface
// (Z = 0) at `gsd_mm` per pixel, resampled from the tiles through the adjusted
// planar scene.
//
// Geometry (pure, no pixels: ComputeOrthoGeometry). The mosaic pixel
// (col, row) has its centre at the part-frame point
//     P(col, row) = (origin_x + (col + 1/2) gsd, origin_y - (row + 1/2) gsd, 0)
// (project-format.md: columns along +X, rows along -Y, not mirrored; origin_mm
// is the outer corner of pixel (0, 0)). With the table at T_i the point is, in
// the camera frame,
//     p_cam = R (P + T_i) + t  =  p0_i + col * dcol + row * drow,
// affine in (col, row) (dcol = gsd R e_x, drow = -gsd R e_y), and its pixel in
// tile i is q = L(p_cam.xy / p_cam.z), L the lens model's projection, taken
// from a LensTable (ortho_lens_table.h; its error bound is in the summary).
// The grid covers the union of the tiles' footprints: the image border
// unprojected onto the plane Z = 0 of each tile's scene.
//
// Pixels (Resample). A tile sees a mosaic pixel when its q lies inside
// [1, W - 2] x [1, H - 2] (the full 4 x 4 support of the cubic interpolator
// that samples it, ortho_sampling.h; bilinear would blur edges and bias them).
// Tiles are blended by a soft choice of the tile that sees the pixel farthest
// from its border: with d_i the distance of q to that border (tile px),
//     w_i = min(d_i / band, 1) exp((d_i - max_j d_j) / band),
// so each pixel comes from essentially one tile except in a smooth band of a
// few `blend_band_px` around the line where two tiles' border distances are
// equal (the middle of their overlap): a flat feature is never cut, and far
// from the seams the mosaic is one tile's pixels, not an average of two
// slightly different blurs. Before blending, each tile's intensity is divided
// by its exposure (exposure_compensation.h: gain and vignetting estimated from
// the overlaps). Pixels no tile sees are 0 (project-format.md); the others
// are clamped to [kDarkestCovered, 1].
//
// Clipped samples. Where a tile's interpolation reads a sample at full scale
// (ClippedSupport), the blend takes that tile for not seeing the pixel (the
// weights above too); where every tile that sees it does, the pixel is 1,
// full scale: its value is not known. Compensated, a clipped sample of a tile exposed
// brighter than the gauge is below 1: blended, demo seed 281 with one tile
// at 2.2 times the others' gain showed that tile's clipped texture as a
// flat gray at 0.49, unmarked, over the 6 % of the mosaic it was drawn in.
//
// Features kept whole. The part's top surface is the same picture in every
// tile, but a through-hole's bore wall is not: each tile sees it from its own
// side. Where a seam crosses a hole (a third of the unseen projects' holes),
// the mosaic showed both walls, or a ghost of one. A feature disc given to
// Orthorectify, grown by whole_margin_px and a blend band, is drawn from one
// tile alone: the one that sees it farthest from its border. The blend
// returns to the rule above across that band, on the top surface outside the
// rim. A disc no tile sees whole is blended by the rule.
//
// Sampling. The cubic interpolators are not low-pass filters: at a gsd
// well above the tiles' ground pixel size (summary.tile_px_per_mosaic_px > ~1.5)
// the mosaic aliases fine texture; edges stay unbiased.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/camera.h"
#include "pipeline/core/error.h"
#include "pipeline/core/image.h"
#include "pipeline/core/plane_scene.h"
#include "pipeline/mosaic/exposure_compensation.h"
#include "pipeline/mosaic/ortho_lens_table.h"
#include "pipeline/mosaic/ortho_sampling.h"

namespace omm {

// Distance of a tile pixel q to the border of the region the tile is sampled
// in, [1, W - 2] x [1, H - 2] (the cubic interpolator's support); > 0 inside, tile px.
inline double TileBorderDistancePx(const Eigen::Vector2d& q_px, int width_px, int height_px) {
  return std::min(std::min(q_px.x() - 1.0, width_px - 2.0 - q_px.x()),
                  std::min(q_px.y() - 1.0, height_px - 2.0 - q_px.y()));
}

// Unnormalised blend weight of a tile that sees a mosaic pixel at border
// distance d_px (> 0) when the best tile's is best_px (the header comment's w_i).
inline double TileBlendWeight(double d_px, double best_px, double band_px) {
  const double ramp = std::min(d_px / band_px, 1.0);
  return d_px < best_px ? ramp * std::exp((d_px - best_px) / band_px) : ramp;
}

// The mosaic's pixel grid on the part plane (project-format.md, out/ table).
struct OrthoGrid {
  double gsd_mm = 0.0;                                  // pixel size, mm
  Eigen::Vector2d origin_mm = Eigen::Vector2d::Zero();  // part-frame outer corner of pixel (0, 0)
  Eigen::Vector2i size_px = Eigen::Vector2i::Zero();    // width (cols), height (rows)

  // Part-frame point (Z = 0) at mosaic position (col, row), pixel centres at
  // integers; and the inverse.
  Eigen::Vector2d PartFromMosaic(const Eigen::Vector2d& col_row) const {
    return {origin_mm.x() + (col_row.x() + 0.5) * gsd_mm,
            origin_mm.y() - (col_row.y() + 0.5) * gsd_mm};
  }
  Eigen::Vector2d MosaicFromPart(const Eigen::Vector2d& part_mm) const {
    return {(part_mm.x() - origin_mm.x()) / gsd_mm - 0.5,
            (origin_mm.y() - part_mm.y()) / gsd_mm - 0.5};
  }
};

struct OrthoOptions {
  double gsd_mm = 0.1;  // mosaic pixel size (project.yaml mosaic.gsd_mm), mm
  LensTableOptions lens_table;
  // Width of the blend between tiles (see the header comment), tile px.
  double blend_band_px = 12.0;
  // How tiles are sampled (ortho_sampling.h): B-spline puts resampled edges
  // within +-0.008 tile px of the analytic ones whatever the sampling phase,
  // Catmull-Rom within +-0.023 (ortho_sampling_test.cc); over 30 rendered
  // projects the diameters' RMS error fell from 0.025 to 0.020 raw px.
  OrthoInterpolator interpolator = OrthoInterpolator::kCubicBSpline;
  // A feature disc kept whole (header) reaches this far beyond its radius,
  // mosaic px: the rim's blur, and the scene's change since the feature was
  // located. Its blend back to the rule spans blend_band_px more.
  double whole_margin_px = 4.0;
  bool compensate_exposure = true;  // false: tiles are blended as recorded
  ExposureOptions exposure;
  // Rows, and the exposure fit's passes (exposure.num_threads is set from
  // this), are split between threads; the result does not depend on it.
  int num_threads = 2;
  // The largest mosaic made, pixels: omm's image readers refuse larger
  // images (kMaxImagePixels), so `omm measure` could not read it back. A
  // caller lowers it to what the machine's memory holds.
  std::int64_t max_pixels = kMaxImagePixels;
  // The coarsest mosaic pixel, in tile pixels. At 16 the demo, lens-mismatch
  // and low-texture-exposure projects measure as at 1; at ~140 the mosaic's
  // rims and overlaps are too few pixels for the measure stage and the
  // exposure fit (pipeline/mosaic/README.md, "The mosaic's pixel size").
  double max_tile_px_per_mosaic_px = 16.0;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// ComputeOrthoGeometry's refusal of options.gsd_mm (project.yaml's
// mosaic.gsd_mm): too fine, a mosaic of more than max_pixels (a gsd far finer
// than the tiles resolve); or too coarse, mosaic pixels of more than
// max_tile_px_per_mosaic_px tile pixels. It says why, and a gsd that fits.
class GsdError : public InputError {
 public:
  GsdError(const std::string& why, bool too_fine, double tile_pixel, double fitting_gsd);
  bool too_fine;
  double tile_pixel_mm;   // a tile pixel's size on the part (the footprint's mean)
  double fitting_gsd_mm;  // the finest (too_fine) or coarsest gsd that fits
};

// Where one tile's scene puts the mosaic's pixels.
struct TileOrthoMap {
  // Camera-frame point of mosaic pixel (col, row): p0 + col dcol + row drow, mm.
  Eigen::Vector3d p0_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d dcol_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d drow_mm = Eigen::Vector3d::Zero();
  // Mosaic pixels that may see the tile: cols [min.x, max.x], rows [min.y, max.y].
  Eigen::Vector2i min_px = Eigen::Vector2i::Zero();
  Eigen::Vector2i max_px = Eigen::Vector2i::Constant(-1);
  // The footprint: the image border unprojected onto the part plane, part mm.
  Eigen::Matrix2Xd footprint_mm;
};

struct OrthoGeometry {
  OrthoGrid grid;
  LensTable lens;
  std::vector<TileOrthoMap> tiles;
  int image_width_px = 0, image_height_px = 0;
  VignettingFrame vignetting;  // where the exposure model's rho is measured from

  // Pixel of tile `tile` at mosaic position (col, row) (fractional allowed).
  // False if the lens table does not cover it (far outside the image).
  bool TilePixel(int tile, double col, double row, Eigen::Vector2d* q_px) const {
    const TileOrthoMap& map = tiles[tile];
    const Eigen::Vector3d p = map.p0_mm + col * map.dcol_mm + row * map.drow_mm;
    if (!(p.z() > 0.0)) return false;
    return lens.Project(Eigen::Vector2d(p.x() / p.z(), p.y() / p.z()), q_px);
  }
  // Tile pixels of the mosaic pixels (col0 + k, row), k < n: the lens table
  // at every kRowNodeStep-th column, 1-D Catmull-Rom between (the map is
  // smooth along a row: its error is below 1e-5 px; orthorectify_test.cc);
  // where the table does not cover one of the four nodes around a pixel,
  // TilePixel itself. valid[k] is false where TilePixel's is.
  static constexpr int kRowNodeStep = 8;
  void TileRowPixels(int tile, int row, int col0, int n, std::vector<Eigen::Vector2d>* q_px,
                     std::vector<char>* valid) const;
  // Distance of q to the border of the region a tile is sampled in,
  // [1, W - 2] x [1, H - 2]; > 0 inside, tile px.
  double BorderDistancePx(const Eigen::Vector2d& q_px) const {
    return TileBorderDistancePx(q_px, image_width_px, image_height_px);
  }
};

// The grid covering every tile's footprint and each tile's map. Pure;
// throws InputError if options are invalid or the scene does not fit the
// camera (intrinsics, a tile whose image border does not meet the plane).
OrthoGeometry ComputeOrthoGeometry(const CameraModel& camera, const PlaneScene& scene,
                                   const OrthoOptions& options);

// The first of the points on the border of the region a tile is sampled in
// ([1, W - 2] x [1, H - 2], 32 a side) that the lens maps to no ray;
// nullopt if every one maps. ComputeOrthoGeometry needs them all: it finds
// the tiles' footprints from their rays.
std::optional<Eigen::Vector2d> FirstUnmappedTileBorderPixel(const CameraModel& camera);

// Mean tile pixels per mosaic pixel along a row, at the tiles' footprint
// centres (0 if none projects).
double TilePxPerMosaicPx(const OrthoGeometry& geometry);

// A part-frame disc (a hole and where it may be) to draw from one tile.
struct OrthoDisc {
  Eigen::Vector2d centre_mm = Eigen::Vector2d::Zero();
  double radius_mm = 0.0;
};

// A disc of mosaic pixels drawn from tile `tile` alone out to radius_px,
// blended back to the rule over band_px beyond.
struct WholeDisc {
  Eigen::Vector2d centre_px = Eigen::Vector2d::Zero();
  double radius_px = 0.0;
  double band_px = 0.0;
  int tile = -1;
};

// The tile that sees the whole mosaic disc (centre_px, radius_px) farthest
// from its border (the least border distance over the centre and the rim,
// sampled every few px), or -1 if none sees it whole. The measure stage
// orders its views by the same rule through the lens (TilesSeeingDisc,
// pipeline/measure/bore_view.h).
int TileSeeingDiscBest(const OrthoGeometry& geometry, const Eigen::Vector2d& centre_px,
                       double radius_px);

// The discs of `features` to draw from one tile (grown by the options'
// whole_margin_px; their tile from TileSeeingDiscBest over that and the
// blend band), in order; those no tile sees whole are left out.
std::vector<WholeDisc> WholeDiscs(const OrthoGeometry& geometry,
                                  const std::vector<OrthoDisc>& features,
                                  const OrthoOptions& options);

struct OrthoMosaic {
  OrthoGrid grid;
  ImageF pixels;  // grid.size_px.y() rows x grid.size_px.x() cols, [0, 1]; 0 where no tile sees
};

struct OrthoSummary {
  bool usable = false;
  std::string brief;  // one line: size, gsd, coverage, exposure fit (no time: reproducible)

  double lens_table_max_error_px = 0.0;  // the map's interpolation error bound, px
  int lens_table_nodes = 0;
  double tile_px_per_mosaic_px = 0.0;  // mean tile pixels per mosaic pixel (along a row)
  double covered_fraction = 0.0;       // of the mosaic's pixels, seen by a tile
  double clipped_fraction = 0.0;       // of the covered ones, clamped to 0 or 1, or clipped
  ExposureSummary exposure;            // empty tiles vector if not compensated
  int features_kept_whole = 0;         // of the feature discs given, drawn from one tile
  int features_blended = 0;            // ... that no tile sees whole
  double geometry_seconds = 0.0;
  double exposure_seconds = 0.0;
  double resample_seconds = 0.0;
};

struct OrthoResult {
  OrthoMosaic mosaic;
  OrthoSummary summary;
};

struct ResampleCounts {
  std::int64_t covered_px = 0;  // mosaic pixels some tile sees
  // ... whose blend fell outside [0, 1] and was clamped, or set to 1 as
  // every tile that sees them read a clipped sample there
  std::int64_t clipped_px = 0;
};

// What options.interpolator samples of each tile: its cubic B-spline
// coefficients (kCubicBSpline), else nothing (the pixels themselves). Pure.
std::vector<ImageF> InterpolatorSamples(const std::vector<ImageF>& tiles,
                                        const OrthoOptions& options);

// Blends the tiles (gray, [0, 1], all camera.width_px x camera.height_px, in
// the scene's tile order) into the mosaic `geometry` describes, each divided
// by its exposure (`exposure` empty: as recorded), the `whole` discs each
// from its tile. `samples`, if given, is InterpolatorSamples(tiles, options).
// Pure.
ImageF ResampleMosaic(const OrthoGeometry& geometry, const std::vector<ImageF>& tiles,
                      const std::vector<TileExposure>& exposure, const OrthoOptions& options,
                      const std::vector<WholeDisc>& whole = {}, ResampleCounts* counts = nullptr,
                      const std::vector<ImageF>* samples = nullptr);

// The tiles' exposure (options.exposure) from their overlaps in `geometry`.
ExposureSummary EstimateTileExposure(const OrthoGeometry& geometry,
                                     const std::vector<ImageF>& tiles, const OrthoOptions& options);

// Work on the tiles that Orthorectify can be given, done beforehand (the
// mosaic stage does it on the core its final adjustment leaves free); each
// one not given is done by Orthorectify.
struct OrthoPrecomputed {
  // EstimateTileExposure on a geometry of the same tiles: gains and
  // vignetting do not move with a scene's hundredths of a pixel.
  const ExposureSummary* exposure = nullptr;
  // InterpolatorSamples(tiles, options).
  const std::vector<ImageF>* samples = nullptr;
};

// Geometry, exposure compensation and resampling, with the `features` discs
// kept whole. Throws InputError for invalid options or tiles that do not fit
// the camera or the scene (count, size), std::invalid_argument for
// precomputed samples that are not those of the tiles (count, size).
OrthoResult Orthorectify(const CameraModel& camera, const PlaneScene& scene,
                         const std::vector<ImageF>& tiles, const OrthoOptions& options,
                         const std::vector<OrthoDisc>& features = {},
                         const OrthoPrecomputed& precomputed = {});

}  // namespace omm
