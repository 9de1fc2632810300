// One tile alone, orthorectified on the mosaic's own grid over a window: what
// ResampleMosaic (orthorectify.h) draws there when that tile is the only one,
// with the same map (OrthoGeometry::TileRowPixels), the same support test
// (border distance > 0), the same interpolator and exposure division, and
// the same floor (kDarkestCovered); beside them, which pixels read a
// saturated tile sample (1, the file's full scale) in their 4 x 4
// interpolation support (ClippedSupport): their value is not the scene's
// (the mosaic draws them at 1).
//
// Unlike the mosaic (a file of full scale 1), a patch is not clamped at 1.
// The exposure gauge is the median tile (exposure_compensation.h): darker
// ones are scaled up, above 1 where a brighter tile would have clipped.
// Clamped, their rims lost the bright side of their steps, unmarked: demo
// seed 281 with one tile at 2.2 times the others' gain (then the gauge) read
// the diameters in the other tiles 0.2 raw px small, 4-6 of their sigmas.
// A hole that several tiles see whole is measured in each such patch: each is
// an independent picture, with one bottom rim about that tile's nadir
// (bore_view.h), where the mosaic blends two.
//
// The interpolator's B-spline coefficients are computed on a crop of the tile
// reaching kPrefilterMarginPx beyond the samples' support: the prefilter's
// influence decays as (2 - sqrt(3))^d, 1.4e-9 at 16 px, so the patch matches
// the whole tile's coefficients to float precision (ortho_patch_test.cc).
#pragma once

#include <Eigen/Core>

#include "pipeline/core/image.h"
#include "pipeline/mosaic/exposure_compensation.h"
#include "pipeline/mosaic/orthorectify.h"

namespace omm {

struct OrthoPatch {
  Eigen::Vector2i origin_px = Eigen::Vector2i::Zero();  // mosaic (col, row) of pixel (0, 0)
  ImageF pixels;        // >= kDarkestCovered; 0 where the tile does not see (as in the mosaic)
  ImageMask saturated;  // pixels' size, or empty where no pixel reads a saturated sample
};

// Tile `tile` (its image `tile_image`, gray [0, 1], and its exposure) over
// the mosaic pixels [min_px, min_px + size_px), clipped to the grid. Pure.
OrthoPatch RenderTilePatch(const OrthoGeometry& geometry, int tile, const ImageF& tile_image,
                           const TileExposure& exposure, OrthoInterpolator interpolator,
                           const Eigen::Vector2i& min_px, const Eigen::Vector2i& size_px);

}  // namespace omm
