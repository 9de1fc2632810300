// The planar bundle adjustment, solved with Ceres. No Ceres type leaves this
// adapter: the problem, configuration, options and result are
// pipeline/core/plane_scene.h's, the lens model comes in as a LensProjection.
//
// Cost (all residuals dimensionless, so the covariance is absolute):
//   sum over observations  rho(|(w / sigma_px) (q(R (P + T_i) + t) - q_obs)|^2)
//   + sum over tiles        |(T_i - T_i,commanded) / sigma_table|^2
//   + |U (k - k_calibrated)|^2                  (if the intrinsics are refined;
//                                                k_calibrated: the input's prior
//                                                mean, else the initial k)
// with rho the robust loss (PlaneBundleOptions), but for the first
// observation of a track of exactly two, whose term is |.|^2: with both
// robust, a pair that disagrees by more than twice the loss scale has no
// unique minimum (plane_bundle.cc). Cost functions:
// plane_costs.h. Points are eliminated by the Schur complement (ordering:
// track points first, then pose, table positions, plates, intrinsics).
// Refined intrinsics are a parameter block per block of the lens
// (LensProjection::IntrinsicsBlockStarts), each observation taking those its
// pixel depends on: a splined model's sparsity, which the reduced system then
// keeps.
//
// Gauge. Without it the normal equations are singular (plane_scene.h, (a)):
// kOriginOnOpticalAxis holds t_x, t_y (t on a SubsetManifold), kFixedTrack
// holds one track's P. Everything else is determined by data and priors, so
// ceres::Covariance (sparse QR of the full Jacobian) applies directly; its
// covariance is that of this gauge, and only of this gauge.
#pragma once

#include "pipeline/core/lens_projection.h"
#include "pipeline/core/plane_scene.h"

namespace omm {

// Adjusts *scene, which holds the initial values (sizes: one table position
// per tile, one column of track_xy_mm per track, one PlatePose per plate,
// lens.NumIntrinsics() intrinsics; PlaneSceneSeed gives them), and fills its
// residuals and covariance. The solve runs on one thread, so that its
// result is the same to the bit in every run; the covariance's Jacobian
// evaluates `lens` concurrently (options.num_threads; each block in its own
// slot). Invalid input, config or options give an unusable summary whose
// brief says what is wrong; the stage checks them first.
PlaneBundleSummary SolvePlaneBundle(const LensProjection& lens, const PlaneBundleInput& input,
                                    const PlaneBundleConfig& config,
                                    const PlaneBundleOptions& options, PlaneScene* scene);

// Plate `plate`'s scale s released around a solved scene that held it at 1
// (config.refine_plate_scale false, the covariance computed): s - 1 and its
// sigma as the solve with s free gives them to first order. The marks are
// the only residuals s enters and they involve no track point, so the Schur
// complement of s needs their Jacobian and the scene's covariance C alone:
// S = H_ss - h^T C h, s - 1 = -g_s / S, sigma = S^-1/2, with H_ss, h, g_s
// = J_s^T (J_s, J_scene, r) over the marks (loss applied; the scene's
// gradient is zero at the solution). One evaluation of the marks instead of
// that solve (0.3 s CPU on the demo). Not ok without a covariance or for S <= 0.
struct PlateScaleRelease {
  bool ok = false;
  double scale_minus_1 = 0.0;
  double sigma = 0.0;
};
PlateScaleRelease ReleasePlateScale(const LensProjection& lens, const PlaneBundleInput& input,
                                    const PlaneBundleOptions& options, const PlaneScene& scene,
                                    int plate);

}  // namespace omm
