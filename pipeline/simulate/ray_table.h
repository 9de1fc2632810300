// The observation ray of every supersample of every pixel, computed once per
// camera: the camera never moves, so all images of a project share it.
//
// Pixel (col, row) spans [col - 1/2, col + 1/2] x [row - 1/2, row + 1/2] (pixel
// centres are integers, mrcal's convention). Its S x S supersamples sit at the
// centres of an S x S grid over that square:
//   q(sx, sy) = (col - 1/2 + (sx + 1/2) / S, row - 1/2 + (sy + 1/2) / S),
// so averaging them integrates the scene over the pixel (a box aperture with
// 100 % fill factor), unbiased about the pixel centre.
//
// Each ray is the normalised direction (x/z, y/z) of the camera-frame point
// that the lens model projects to q: project((x, y, 1)) = q. It is stored as a
// per-pixel base in double (the ray of the pixel's first supersample) plus a
// per-supersample offset in float: the offsets are < 1e-3, so float keeps them
// to ~1e-10 (~1e-7 px), while the memory stays near that of floats (1600 x
// 1200 px, S = 4: 277 MB).
//
// Unprojecting every supersample with mrcal_unproject would take ~1 us each;
// instead a coarse grid is unprojected, each supersample starts from a bicubic
// (Catmull-Rom) interpolation of it (error ~1e-5 px at a 16 px spacing) and
// is refined by the fixed-point step
//   (x, y) += d(x, y)/dq * (q - project((x, y, 1))),
// with d(x, y)/dq the interpolant's own derivative: an approximate inverse of
// the lens's Jacobian (relative error ~1e-4), so each step shrinks the error
// ~1e4-fold. Only plain projections are needed: mrcal 2.2's mrcal_project
// returns wrong dq/dp for batches of points unless dq/dintrinsics is asked
// for too, and that would be far costlier.
#pragma once

#include <cstddef>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/camera.h"

namespace omm {

struct RayTableOptions {
  int supersampling = 4;    // S: S x S supersamples per pixel
  int coarse_step_px = 16;  // spacing of the unprojected coarse grid, px
  int refine_steps = 1;     // refinement steps per supersample
  // Every this many supersample rows the refined rays are projected once more
  // to measure their error (RayTableSummary::max_residual_px).
  int check_every_rows = 16;
  int num_threads = 2;  // the result does not depend on it

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// A rectangle of the image, px: columns [x0, x0 + width), rows [y0, y0 + height).
struct PixelRect {
  int x0 = 0, y0 = 0, width = 0, height = 0;
};

struct RayTable {
  PixelRect rect;         // the pixels covered (the whole image or a crop)
  int supersampling = 0;  // S
  // Base ray of pixel (col, row) of the rect at 2 * ((row - y0) * width + (col - x0)).
  std::vector<double> base_xy;
  // Offset of supersample (sx, sy) of that pixel from the base at
  // 2 * (((row - y0) * width + (col - x0)) * S * S + sy * S + sx): a pixel's
  // samples are contiguous.
  std::vector<float> offset_xy;

  int SamplesPerPixel() const { return supersampling * supersampling; }
  std::size_t PixelIndex(int row_in_rect, int col_in_rect) const {
    return static_cast<std::size_t>(row_in_rect) * rect.width + col_in_rect;
  }
  // The ray (x/z, y/z) of supersample k = sy * S + sx of a pixel of the rect.
  Eigen::Vector2d Ray(int row_in_rect, int col_in_rect, int k) const {
    const std::size_t pixel = PixelIndex(row_in_rect, col_in_rect);
    const std::size_t sample = pixel * SamplesPerPixel() + k;
    return {base_xy[2 * pixel] + offset_xy[2 * sample],
            base_xy[2 * pixel + 1] + offset_xy[2 * sample + 1]};
  }
  // Position of supersample (sx, sy) of pixel (col, row) in the image, px.
  Eigen::Vector2d SamplePixel(int col, int row, int sx, int sy) const {
    return {col - 0.5 + (sx + 0.5) / supersampling, row - 0.5 + (sy + 0.5) / supersampling};
  }
};

struct RayTableSummary {
  bool ok = false;  // false if mrcal refused the model or a point did not converge
  std::size_t num_rays = 0;
  // max |project((x, y, 1)) - q| of the initial (interpolated) rays, px.
  double max_initial_residual_px = 0.0;
  // max |project((x, y, 1)) - q| of the stored rays over the checked rows, px.
  double max_residual_px = 0.0;
};

// Rays of every supersample of `rect` (use the whole image for rendering).
RayTable ComputeRayTable(const CameraModel& camera, const PixelRect& rect,
                         const RayTableOptions& options, RayTableSummary* summary);

}  // namespace omm
