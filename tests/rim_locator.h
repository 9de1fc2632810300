// An independent locator of circular edges in a top-view image (the mosaic,
// or another program's panorama), for checking the mosaic's geometry against
// the truth. Deliberately shares no code with the pipeline's own edge fitting
// (pipeline/core/subpixel_edges.h).
//
// Model. A round hole (or a dark dot) of the part's top surface is darker than
// the surface around it. A through-hole of a thick part also shows, on one
// side, its bore wall inside the rim (parallax), so the inside of the image
// of a hole is not one level: only the OUTERMOST strong dark-to-bright edge
// along a ray from the centre is the top rim. Along each of N rays from the
// rough centre, the radial derivative (central difference over +-1 px) is
// scanned in [r - window, r + window]; the outermost local maximum above half
// the ray's largest is the rim's coarse position. It is refined to the
// crossing of the level halfway between the inside (the median of the
// profile 1.5-3.5 px inside) and the surface's level at the rim (a line
// fitted to the profile 2-4.5 px outside, extrapolated: the surface is
// textured), by linear interpolation between 0.125 px samples (the mid-level
// of a symmetric blur of a step lies on the step). A circle is
// fitted to the edge points (algebraic, then geometric Gauss-Newton), points
// beyond 3 robust sigmas are dropped and the fit repeated.
//
// Accuracy: on the demo's flat printed caltab dots the centres agree with
// the truth to ~0.006 raw px RMS; on textured hole rims the texture's blobs
// next to the rim move the centres by up to ~0.025 mm (measured in a mosaic
// built from the true scene; mosaic_stage_test.cc).
//
// Pixel convention: (0, 0) is the centre of the top-left pixel; image(row,
// col) is the value at (x = col, y = row). Pixels equal to 0 (not covered by
// any tile) invalidate the rays that touch them.
#pragma once

#include <string>

#include <Eigen/Core>

#include "pipeline/core/image.h"

namespace omm::testing {

struct RimLocatorOptions {
  double window_px = 4.0;         // rim searched within rough radius +- this, px
  double min_ray_fraction = 0.7;  // of the rays cast, at least this many must give an edge
  double outlier_sigmas = 3.0;    // edge points beyond this many robust sigmas are dropped
};

struct RimFit {
  bool ok = false;
  std::string why_failed;
  Eigen::Vector2d centre_px = Eigen::Vector2d::Zero();
  double radius_px = 0.0;
  int num_rays = 0;
  int num_edges = 0;    // rays that gave an edge point
  int num_inliers = 0;  // edge points kept by the final fit
  double rms_px = 0.0;  // RMS radial residual of the inliers
};

// Fits the rim of the dark disc whose boundary is roughly the circle
// (rough_centre_px, rough_radius_px).
RimFit LocateDarkDiscRim(const ImageF& image, const Eigen::Vector2d& rough_centre_px,
                         double rough_radius_px, const RimLocatorOptions& options = {});

// Least-squares rigid (or, with `with_scale`, similarity) transform taking
// `from` onto `to` (2 x N each): to ~ s R(angle) from + t.
struct Planar2dFit {
  double angle_rad = 0.0;
  double scale = 1.0;
  Eigen::Vector2d t = Eigen::Vector2d::Zero();
  Eigen::VectorXd residual;  // |s R from_k + t - to_k| per point
  double rms = 0.0;
};
Planar2dFit FitPlanar2d(const Eigen::Matrix2Xd& from, const Eigen::Matrix2Xd& to, bool with_scale);

}  // namespace omm::testing
