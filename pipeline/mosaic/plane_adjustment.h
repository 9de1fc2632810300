// The mosaic stage's registration: seed the planar scene, then adjust it.
//
// AdjustPlaneScene = SeedPlaneScene (plane_seed.h: closed-form initial values
// from the plane-induced homographies) + SolvePlaneBundle (adapters/ceres/
// plane_bundle.h: robust bundle adjustment through the calibrated lens model,
// table and intrinsics priors, covariance). The model, the gauge and what the
// data can and cannot determine: pipeline/core/plane_scene.h.
#pragma once

#include "pipeline/core/camera.h"
#include "pipeline/core/plane_scene.h"
#include "pipeline/mosaic/plane_seed.h"

namespace omm {

struct PlaneAdjustment {
  PlaneScene scene;
  PlaneSeedSummary seed;
  PlaneBundleSummary summary;  // usable == false if the seed failed (brief says why)
};

// Throws InputError for an invalid config, options or input (the caller's);
// data failures (too few overlaps, no convergence) come back in the summary.
PlaneAdjustment AdjustPlaneScene(const CameraModel& camera, const PlaneBundleInput& input,
                                 const PlaneBundleConfig& config,
                                 const PlaneBundleOptions& options);

}  // namespace omm
