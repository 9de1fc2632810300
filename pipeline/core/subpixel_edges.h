// Sub-pixel edge points of an elliptical mark and the mark's refined centre.
//
// Edge model. The image of a dark dot on a bright ground (or the reverse) is
// the ideal two-level image blurred by the optics' PSF and integrated over the
// pixel. For a symmetric blur, the point where the intensity crosses the level
// halfway between the local dark and bright levels lies on the geometric edge
// of a straight boundary; on a curved one it moves inwards by ~sigma^2 / 2R
// (R the radius of curvature), the same amount on opposite sides of an
// ellipse, so the fitted centre is unaffected. This "mid-level" edge is used
// rather than the gradient maximum because it needs no derivative and because
// it sits at the edge profile's inflection, where bilinear interpolation is
// exact to second order (its error term is the second derivative along x and
// y, zero there); a plane fit of each level around the mark removes the effect
// of smooth illumination gradients, which would otherwise pull the centre
// towards the darker side.
//
// Procedure: rays along the normals of a rough ellipse, one per
// `ray_spacing_px` of its perimeter, evenly spaced in the ellipse's parametric
// angle, sampled by cubic interpolation; the outer `plateau_px` of each ray
// (samples every `plateau_step_px`) gives the inside and outside levels (a
// robust plane fit of each over all rays); the mid-level crossing is
// bracketed on a `bracket_step_px` grid and solved to 1e-5 px by false
// position on the interpolated profile.
// RefineEllipticalMark repeats this along the normals of the previous fit
// until the centre settles and fits an ellipse (ellipse_fit.h) to the edge
// points of the last pass.
//
// Pixel convention: (0, 0) is the centre of the top-left pixel; image(row, col)
// is the value at (x = col, y = row).
#pragma once

#include <string>

#include <Eigen/Core>

#include "pipeline/core/ellipse_fit.h"
#include "pipeline/core/image.h"

namespace omm {

struct EllipseEdgeOptions {
  double ray_half_length_px = 4.0;  // rays span the rough boundary +- this, px
  double plateau_px = 1.5;          // outer part of each ray used for the levels, px
  double ray_spacing_px = 1.0;      // rays per px of the rough perimeter (1/spacing)
  double plateau_step_px = 0.25;    // level samples along each plateau, px
  // Grid on which the mid-level crossing is bracketed, px. The root is then
  // solved on the continuous profile, so the step only decides which rays
  // cross more than once (none of the demo's 371,000 at 0.25 or 0.5 px);
  // 0.25 moved its centres by 3e-6 px RMS and cost a quarter more samples.
  double bracket_step_px = 0.5;
  int min_rays = 24;                // at least this many rays, whatever the size

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// One pass's edge points of a mark (RefineEllipticalMark), on rays along the
// normals of its rough boundary, clipped to half the minor axis inside so
// that they never cross the centre.
struct EllipseEdges {
  Eigen::Matrix2Xd points_px;     // one edge point per ray that crossed cleanly
  int num_rays = 0;               // rays cast
  int num_rays_off_image = 0;     // rays (partly) outside the image: not used
  double contrast = 0.0;          // median (outside - inside) level, image units
  double edge_sigma_px = 0.0;     // median blur: contrast / (sqrt(2 pi) slope at the crossing)
  // 1-sigma pixel noise at the inside and outside levels (image units): robust
  // scatter of the plateaus' raw pixels about their level planes.
  double pixel_noise_inside = 0.0;
  double pixel_noise_outside = 0.0;
};

struct MarkRefinementOptions {
  EllipseEdgeOptions edges;
  EllipseFitOptions fit;
  double min_contrast = 0.04;        // |outside - inside| below this: fail (image units)
  double min_inlier_fraction = 0.6;  // fraction of cast rays that must end as inliers
  int max_passes = 5;                // edge passes, each along the previous fit's normals
  // Stop when a pass, or the passes still to come (predicted from the last
  // two moves, which shrink geometrically), move the centre less, px.
  double converged_px = 2e-4;

  std::string Check() const;
};

struct MarkFit {
  bool ok = false;
  std::string why_failed;  // set when !ok: "mark touches the image border", ...
  Ellipse ellipse;         // fitted boundary; its centre is the mark centre
  // Covariance of the centre from the image noise (see RefineEllipticalMark).
  Eigen::Matrix2d centre_cov_px2 = Eigen::Matrix2d::Zero();
  double sigma_px = 0.0;   // sqrt(trace(centre_cov) / 2): isotropic 1-sigma of the centre
  double rms_px = 0.0;     // RMS edge-point distance to the fit
  double contrast = 0.0;
  double edge_sigma_px = 0.0;
  int num_edge_points = 0;
  int num_passes = 0;  // edge passes made
  int num_inliers = 0;
};

// Sub-pixel centre of one elliptical mark from its rough boundary (within
// ~ray_half_length_px / 2 of the true one).
//
// Centre covariance: first-order propagation of the pixel noise through the
// last pass. The fitted centre is linear in the edge points' moves across the
// curve (EllipseFit::centre_sensitivity); a point moves by -(profile noise at
// its crossing) / (profile slope there); the profile noise is the cubic
// interpolation of the pixel noise minus the mid-level's noise (the level
// planes are linear in their samples). Summed per pixel, with each pixel's
// noise variance interpolated linearly in its level between the plateaus'
// measured variances (shot plus read noise is linear in the level). This
// counts the correlation of neighbouring edge points, which share pixels,
// and leaves out the fit's systematic misfit (not noise); the scatter of
// centres over simulated noise draws matches it (caltab_simulated_test.cc).
MarkFit RefineEllipticalMark(const ImageF& image, const Ellipse& rough,
                             const MarkRefinementOptions& options = {});

}  // namespace omm
