// Parts of the report's calibration section built from the stage's results.
#pragma once

#include "pipeline/calibration/calibrate_stage.h"
#include "pipeline/core/report.h"

namespace omm {

// calibration.lens_model_choice: the model, why, the candidates and, for a
// chosen spline, what its extrapolation beyond the marks did
// (spline_beyond_marks: `grid_points_without_its_ray` only where the
// parametric model it follows has no ray at some grid points).
ReportValue LensChoiceReport(const LensModelChoice& lens);

}  // namespace omm
