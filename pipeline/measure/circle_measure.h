// Centre and radius of a round hole in a top-view image (the orthorectified
// mosaic), with the covariance of the edge fit.
//
// Scene. A through-hole is a dark disc in a textured, brighter surface. The
// part is thick, so inside the top rim one side of the hole shows the bore
// wall (parallax): an intermediate gray crescent between the rim and the
// darker bottom opening. Only the OUTERMOST dark-to-bright step along a ray
// from the centre is the top rim.
//
// Procedure.
//  1. Coarse centre: every pixel's gradient g in an annulus around the
//     expected circle votes for a centre at p - R g/|g| (R the nominal
//     radius; the gradient of a dark disc points outwards), weighted by |g|;
//     the peak of the smoothed vote map within the search square is the
//     centre. Texture votes spread out; the bore wall's inner edge (the
//     bottom rim) shows on part of the circle only and at lower contrast.
//  2. Edge points in wedges: the annulus r +- (band + half-width) around the
//     current circle is cut into wedges of `wedge_arc_px` of arc; along each
//     wedge's centre ray the outermost strong dark-to-bright step within
//     +- band gives a coarse edge (wedges with a second step just inside it,
//     the tips of the bore-wall crescent, are dropped). Then a blurred
//     two-sided ramp step is fitted to the wedge's own pixels (value against
//     radial distance d, no interpolation):
//         f(d) = a + gi u  blurred on u < 0,   b + go u  blurred on u > 0,
//         u = d - x0,  blur a Gaussian of sigma s (PSF, pixel, resampling),
//     i.e. f = a Phi(-u/s) + gi (u Phi(-u/s) - s phi(u/s))
//            + b Phi(u/s)  + go (u Phi(u/s)  + s phi(u/s)),
//     by Gauss-Newton in (x0, [s], a, gi, b, go). The ramps absorb the
//     surface texture's local slope at the rim, which moves a mid-level or a
//     gradient-maximum edge by ~ slope s^2 / contrast. The first pass fits s
//     per wedge; later passes hold it at the first pass's median. A wedge is
//     dropped when its fit is not a clean step: contrast below
//     `min_contrast`, residual RMS above `max_profile_rms_ratio` times the
//     median of the wedges, or x0 off the coarse edge.
//  3. Robust circle fit to the edge points c + (r + x0) n(theta): Gauss-Newton
//     on the radial distances, Huber then Tukey biweight IRLS with the scale
//     from the median absolute residual. Steps 2-3 repeat about the new
//     circle (the band shrinking to the fit's scatter) until it settles.
//  4. The rim of a blurred disc lies sigma^2 / 2r inside the geometric one
//     (the blur kernel's mass beyond a curved edge), so the radius is
//     corrected by + s^2 / 2r.
//
// Covariance of (cx, cy, r). The fit is linear in the edge points' radial
// moves e: delta = S e, S = (J'WJ)^-1 J'W (3 x n, W the final IRLS weights).
// Edge errors are correlated along the arc: the mosaic resamples raw pixels
// (`source_px`), and the surface texture next to the rim moves neighbouring
// edge points together. They are modelled as a stationary sequence along the
// arc; its autocovariance gamma(l) at arc lag l is estimated from the
// residuals, and Cov = S Gamma S'. Two biases of the plain estimate are
// corrected: the residuals lack the three components the fit removed (their
// sum over all lags is zero), and the lag sum must stop where gamma becomes
// noise. See CircleEdgeCovariance in the .cc for the estimator.
//
// Pixel convention: (0, 0) is the centre of the top-left pixel; image(row,
// col) is the value at (x = col, y = row). Pixels equal to 0 are "no tile
// sees this" and invalidate the wedges that touch them.
#pragma once

#include <string>

#include <Eigen/Core>

#include "pipeline/core/image.h"

namespace omm {

struct CircleMeasureOptions {
  double search_fraction = 0.25;         // expected centre within this fraction of the diameter ...
  double search_margin_px = 5.0;         // ... plus this, px
  double rim_band_px = 4.0;              // first pass: rim searched within radius +- this, px
  double profile_half_width_px = 3.0;    // step model fitted to pixels within edge +- this, px
  double wedge_arc_px = 2.0;             // arc length of one wedge at the rim, px
  int min_wedges = 48;                   // at least this many wedges, whatever the radius
  double min_contrast = 0.05;            // surface minus inside level at the rim, image units
  double max_profile_rms_ratio = 3.0;    // wedge dropped above this x the median wedge fit RMS
  double tukey_sigmas = 4.685;           // biweight cut-off, robust sigmas of the residuals
  double max_uncovered_fraction = 0.02;  // of the wedges touching uncovered (0) or off-image pixels
  double min_found_fraction = 0.3;       // inliers below this fraction of the wedges: not found
  double min_inlier_fraction = 0.6;      // ... below this: poor fit
  double max_radius_deviation = 0.05;    // |r / nominal - 1| above this: not the expected hole
  double max_rms_px = 0.5;               // inlier RMS above this: poor fit, px
  double source_px = 1.0;      // size of a source (raw) pixel in image px: noise correlation floor
  int max_passes = 8;          // edge + fit passes at most
  double converged_px = 1e-3;  // stop when a pass moves centre and radius less, px

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct CircleMeasurement {
  bool ok = false;
  std::string
      error;  // when !ok: "not found near the expected position", "cut by ...", "poor fit: ..."
  Eigen::Vector2d centre_px = Eigen::Vector2d::Zero();
  double radius_px = 0.0;
  // Covariance of (cx, cy, r), px^2, from the edge points' scatter and its
  // correlation along the arc (header comment).
  Eigen::Matrix3d covariance_px2 = Eigen::Matrix3d::Zero();
  int num_wedges = 0;           // wedges cast in the last pass
  int num_uncovered = 0;        // ... touching uncovered or off-image pixels
  int num_edge_points = 0;      // ... giving a clean step
  int num_inliers = 0;          // edge points kept by the robust fit
  double rms_px = 0.0;          // RMS radial residual of the inliers
  double edge_sigma_px = 0.0;   // blur of the rim (median fitted s)
  double contrast = 0.0;        // median step height at the rim, image units
  double correlation_px = 0.0;  // arc length per independent edge error, px
  int passes = 0;               // edge + fit passes run
  Eigen::Vector2d coarse_centre_px = Eigen::Vector2d::Zero();  // step 1's centre

  std::string Brief() const;  // one line for a log or a report
};

// Measures the dark round hole of nominal radius `nominal_radius_px` whose
// centre is expected near `expected_centre_px` (within the options' search
// square). A data failure is a result with ok = false and `error` set.
// Preconditions: options.Check() is empty, nominal_radius_px > 0.
CircleMeasurement MeasureCircle(const ImageF& image, const Eigen::Vector2d& expected_centre_px,
                                double nominal_radius_px, const CircleMeasureOptions& options = {});

}  // namespace omm
