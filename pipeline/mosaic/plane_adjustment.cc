#include "pipeline/mosaic/plane_adjustment.h"

#include "adapters/ceres/plane_bundle.h"
#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/mrcal_lens_projection.h"
#include "pipeline/core/error.h"

namespace omm {

PlaneAdjustment AdjustPlaneScene(const CameraModel& camera, const PlaneBundleInput& input,
                                 const PlaneBundleConfig& config,
                                 const PlaneBundleOptions& options) {
  if (LensModelNumParams(camera.lens_model) != camera.intrinsics.size()) {
    throw InputError("", "camera: lens model '" + camera.lens_model + "' with " +
                             std::to_string(camera.intrinsics.size()) + " intrinsics");
  }
  for (const std::string& error :
       {config.Check(), options.Check(),
        CheckPlaneBundleInput(input, config, static_cast<int>(camera.intrinsics.size()))}) {
    if (!error.empty()) throw InputError("", "plane bundle adjustment: " + error);
  }
  PlaneAdjustment result;
  result.seed = SeedPlaneScene(camera, input, &result.scene);
  if (!result.seed.ok) {
    result.summary.brief = "plane BA UNUSABLE: seeding failed: " + result.seed.why_failed;
    return result;
  }
  const MrcalLensProjection lens(camera);
  result.summary = SolvePlaneBundle(lens, input, config, options, &result.scene);
  return result;
}

}  // namespace omm
