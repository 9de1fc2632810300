// Direct (area) alignment of two tiles' pictures of one part region.
//
// Why. On a low-texture part a tile can share no corner with its
// neighbours that the template matcher trusts (low-texture seed 201: a tile
// whose overlaps hold only 20-40 mm shading, the part's outer edge and no
// whole hole; 0 good matches in 3 pairs) and is then held by its table
// prior alone, 0.14 raw px per axis at sigma 0.02 mm. Its overlaps still
// carry its position: a long straight edge fixes it across the edge to a few
// hundredths of a pixel, and the shading, integrated over 10^5 pixels, in
// every direction. Using every pixel's gradient, not corners, gets it.
//
// Model. a and b are two patches on one grid (the part plane, resampled
// through the current scene), each with its own exposure. With x the grid
// position, u = (x - centre) / half_size in [-1, 1]^2,
//     a(x) = g(u) b(x + s) + o,   g a quintic polynomial in u = (u, v),
// s the shift (grid px) that the scene misplaces b's content by, g a smooth
// gain field (the two tiles' gain and vignetting ratio: a quadratic leaves
// 7e-4 of a 0.13 fall-off's ratio over a 34 % overlap, a cubic 3e-5, but up
// to 5e-3 of the ratio of a 0.1 and a 0.45 fall-off, which a quintic
// follows) and o an offset.
//
// Both patches are first smoothed by a Gaussian (smoothing_sigma_px): on
// weak shading the raw gradient is mostly noise (the shading's ~1e-4 per px
// against the noise's ~7e-3), which would both bias the shift (noise in
// the regressor) and understate its sigma. The smoothed b(x + s) and its
// gradient are interpolated with Catmull-Rom. The fit is Gauss-Newton with
// Huber weights (iteratively reweighted: a burr or a bore wall seen from two
// sides is an outlier, not a shift). The smoothed residuals are correlated
// (kernel G * G), so Cov(theta) = H^-1 (J' W K W J) H^-1 sigma^2 (H = J' W J;
// K the correlation G * G, applied by a Gaussian blur of sqrt(2) times the
// smoothing; sigma^2 the raw residuals' robust variance).
//
// Misfit. On weak shading a photometric misfit of 1e-4 (what the gain
// field leaves of the tiles' vignetting, their different blur) moves s by
// tenths of a pixel: on low-texture seed 201 rendered through the true scene
// (true lens and table positions), shading-only overlaps came out 0.2-0.35
// px off against a noise sigma of 0.08, while the part's edge held its
// normal to 0.005 px. The misfit is modelled as a smooth random field of
// sigma misfit_relative times the mean level and correlation
// exp(-d^2 / 4 L^2) (L = misfit_scale_px); it adds
// sigma_m^2 H^-1 J' W C W J H^-1 to Cov(s). A sharp edge's few pixels of
// large gradient are hardly moved by it; shading's many of small gradient
// are. misfit_relative was set with a cubic gain field from 14 low-texture
// projects rendered through their true scene (seeds 201-207, with and
// without exposure differences; every pair of overlapping tiles, whose
// shift's truth is 0): the shifts' rms z per axis was 0.65 (low-texture)
// and 1.10 (with exposure differences) with it, 1.36 and 1.70 without. On
// 20 more (seeds 243-252) the cubic left 0.59 and 1.74 (17 of 159 shading
// shifts beyond chi2's 99.9 %), growing with the tiles' vignetting
// difference (rms z 1.51 under 0.05, 2.01 over 0.15): the ratio of unequal
// fall-offs, which a cubic cannot follow. With the quintic, the same term
// and no other change: 0.81 and 0.94 there (none beyond 99.9 %), 0.89 and
// 1.04 on seeds 201-207, 0.76 and 0.94 on 10 projects of other grids (4 x
// 1 to 5 x 2), flat in the vignetting difference. A floor (min_sigma_px)
// stays for what neither term holds (resampling).
//
// Samples. The smoothed patches vary over ~6 px, so the fit samples every
// second row and column (sample_stride_px): the covariance below is that of
// the estimator on these samples, and on 300 overlaps of 15 low-texture, 6
// low-texture-exposure and 3 exposure projects, aligned on their true scene,
// the shifts moved by 0.018 of their sigma rms (0.21 at most) against
// every pixel's fit, the sigmas by 3 % at most, in 0.4 of the time.
//
// Covariance of s. Only its 2 x 2 block is needed: (e_i, K e_j) with e_i the
// image of W J H^-1's column i, two blurred images for K, whatever the
// number of gain terms.
//
// Only pixels where both patches are valid (> 0, below saturation) and
// `mask` is set, over the smoothing's support, count: the caller masks
// what is not on the plane (holes: their walls move with the view), and a
// masked pixel is unseen in both patches.
#pragma once

#include <string>

#include <Eigen/Core>

#include "pipeline/core/image.h"

namespace omm {

struct OverlapAlignmentOptions {
  // Both patches are smoothed by a Gaussian of this sigma, grid px.
  double smoothing_sigma_px = 6.0;
  // The fit samples every this-th row and column of the smoothed patches.
  int sample_stride_px = 2;
  int max_iterations = 30;
  // Converged when the shift changes by less than this, grid px.
  double shift_tolerance_px = 1e-4;
  // Huber's threshold in units of the residuals' robust sigma (1.4826 MAD).
  double huber_sigmas = 2.0;
  // A valid pixel is within (kDarkestCovered, max_value) in both patches
  // (0: not seen; kDarkestCovered: black, clipped; max_value: clipped).
  double max_value = 0.98;
  // Fewer valid pixels than this: not usable.
  int min_pixels = 2000;
  // The shift may not leave b's support: |s| per axis at most this, grid px.
  double max_shift_px = 3.0;
  // The photometric misfit (header): its sigma relative to the mean level
  // and its correlation length, grid px.
  double misfit_relative = 5e-4;
  double misfit_scale_px = 50.0;
  // Floor of the shift's sigma, added in quadrature (grid px).
  double min_sigma_px = 0.01;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct OverlapAlignment {
  bool usable = false;
  std::string why;                                           // if not usable
  Eigen::Vector2d shift_px = Eigen::Vector2d::Zero();        // s: b's content at x + s is a's at x
  Eigen::Matrix2d covariance_px2 = Eigen::Matrix2d::Zero();  // of s, floored
  int num_pixels = 0;           // valid pixels used: the samples, stride^2 pixels each
  double residual_sigma = 0.0;  // robust sigma of the raw residuals, intensity units
  double misfit_sigma = 0.0;    // of the smooth misfit (header), intensity units
  int num_iterations = 0;
};

// Aligns b to a (same size; mask: nonzero where a pixel may count, may be
// empty for all). Pure; throws InputError for invalid options.
OverlapAlignment AlignOverlap(const ImageF& a, const ImageF& b, const ImageF& mask,
                              const OverlapAlignmentOptions& options);

}  // namespace omm
