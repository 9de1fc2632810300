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
// 1200 px, S = 4: 277 MB). The rays of each pixel's 2 x 2 Gauss-Legendre
// points, q = (col +- g, row +- g) with g = 1/(2 sqrt 3), are stored the same
// way (render.h integrates smooth regions with them).
//
// Unprojecting every supersample with mrcal_unproject would take ~1 us each,
// and even one projection each (~0.3 us through a splined model) dominates,
// so rays are interpolated at two levels. A coarse grid (coarse_step_px) is
// unprojected; the nodes of a fine grid (fine_step_px) start from a bicubic
// (Catmull-Rom) interpolation of it (error 1e-5..1e-4 px at a 16 px spacing) and
// are refined by the fixed-point step
//   (x, y) += d(x, y)/dq * (q - project((x, y, 1))),
// with d(x, y)/dq the interpolant's own derivative: an approximate inverse of
// the lens's Jacobian (relative error ~1e-4), so each step shrinks the error
// ~1e4-fold. Every supersample is then interpolated in the fine grid: the
// error is O(step^3), ~1e-7 px at a 2 px spacing, and only the fine nodes and
// the check rows are projected (a 2 px grid has 1/64 of the rays of S = 4).
// Only plain projections are needed: mrcal 2.2's mrcal_project returns wrong
// dq/dp for batches of points unless dq/dintrinsics is asked for too, and
// that would be far costlier.
#pragma once

#include <cstddef>
#include <numbers>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/camera.h"

namespace omm {

struct RayTableOptions {
  int supersampling = 4;      // S: S x S supersamples per pixel
  int coarse_step_px = 16;    // spacing of the unprojected coarse grid, px
  double fine_step_px = 2.0;  // spacing of the refined fine grid, px
  int refine_steps = 1;       // refinement steps per fine-grid node
  // Every this many pixel rows the stored rays are projected once more to
  // measure their error (RayTableSummary::max_residual_px).
  int check_every_rows = 16;
  int num_threads = 2;  // the result does not depend on it

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// A rectangle of the image, px: columns [x0, x0 + width), rows [y0, y0 + height).
struct PixelRect {
  int x0 = 0, y0 = 0, width = 0, height = 0;
};

// The affine map (u, v) -> ray (x/z, y/z) of one pixel, (u, v) the offset
// from the pixel centre in px: the least-squares fit to the pixel's S x S rays
// (over a pixel the lens map departs from affine by < 1e-4 px).
struct PixelRayMap {
  Eigen::Vector2d centre, d_du, d_dv;
  Eigen::Vector2d operator()(double u, double v) const { return centre + u * d_du + v * d_dv; }
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
  // Offset of Gauss point k = 2 j + i, at (col + (i - 1/2) / sqrt 3, row +
  // (j - 1/2) / sqrt 3), from the base at 2 * (pixel * 4 + k).
  std::vector<float> gauss_offset_xy;
  static constexpr double kGaussPx = 0.5 / std::numbers::sqrt3;  // g

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
  // The ray of Gauss point k of a pixel of the rect.
  Eigen::Vector2d GaussRay(int row_in_rect, int col_in_rect, int k) const {
    const std::size_t pixel = PixelIndex(row_in_rect, col_in_rect);
    return {base_xy[2 * pixel] + gauss_offset_xy[8 * pixel + 2 * k],
            base_xy[2 * pixel + 1] + gauss_offset_xy[8 * pixel + 2 * k + 1]};
  }
  // The affine ray map of a pixel of the rect; needs S >= 2. The rays form a
  // symmetric grid, so the fit separates into a mean and two moments.
  PixelRayMap PixelMap(int row_in_rect, int col_in_rect) const {
    const std::size_t pixel = PixelIndex(row_in_rect, col_in_rect);
    const float* offset = offset_xy.data() + 2 * pixel * SamplesPerPixel();
    const int s = supersampling;
    Eigen::Vector2d sum = Eigen::Vector2d::Zero(), sum_u = sum, sum_v = sum;
    double uu = 0;
    for (int sy = 0; sy < s; ++sy) {
      Eigen::Vector2d row = Eigen::Vector2d::Zero();
      for (int sx = 0; sx < s; ++sx, offset += 2) {
        const Eigen::Vector2d o(offset[0], offset[1]);
        const double u = (sx + 0.5) / s - 0.5;
        row += o;
        sum_u += u * o;
        if (sy == 0) uu += u * u;
      }
      sum += row;
      sum_v += ((sy + 0.5) / s - 0.5) * row;
    }
    uu *= s;  // sum of u^2 over all S x S rays (= sum of v^2)
    return {Eigen::Vector2d(base_xy[2 * pixel], base_xy[2 * pixel + 1]) + sum / (s * s), sum_u / uu,
            sum_v / uu};
  }
  // Position of supersample (sx, sy) of pixel (col, row) in the image, px.
  Eigen::Vector2d SamplePixel(int col, int row, int sx, int sy) const {
    return {col - 0.5 + (sx + 0.5) / supersampling, row - 0.5 + (sy + 0.5) / supersampling};
  }
  // Position of Gauss point k of pixel (col, row) in the image, px.
  static Eigen::Vector2d GaussPixel(int col, int row, int k) {
    return {col + (k % 2 ? kGaussPx : -kGaussPx), row + (k / 2 ? kGaussPx : -kGaussPx)};
  }
};

struct RayTableSummary {
  bool ok = false;  // false if mrcal refused the model or a point did not converge
  std::size_t num_rays = 0;
  // max |project((x, y, 1)) - q| of the fine-grid nodes before refinement, px.
  double max_initial_residual_px = 0.0;
  // max |project((x, y, 1)) - q| of the stored rays over the checked rows, px.
  double max_residual_px = 0.0;
};

// Rays of every supersample and Gauss point of `rect` (use the whole image
// for rendering).
RayTable ComputeRayTable(const CameraModel& camera, const PixelRect& rect,
                         const RayTableOptions& options, RayTableSummary* summary);

}  // namespace omm
