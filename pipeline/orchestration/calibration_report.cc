#include "pipeline/orchestration/calibration_report.h"

namespace omm {

ReportValue LensChoiceReport(const LensModelChoice& lens) {
  ReportObject choice{{"lens_model", lens.lens_model}, {"forced", lens.forced}, {"why", lens.why}};
  if (!lens.candidates.empty()) {
    ReportValue::Array candidates;
    for (const LensCandidate& c : lens.candidates) {
      candidates.emplace_back(ReportObject{{"lens_model", c.lens_model},
                                           {"num_params", c.num_params},
                                           {"usable", c.usable},
                                           {"rms_px", c.rms_px},
                                           {"num_measurements", c.num_measurements},
                                           {"num_states", c.num_states},
                                           {"sigma_px", c.sigma_px}});
    }
    choice.emplace_back(
        "criterion",
        "residual structure: OPENCV8 and a splined model solved on all images; the splined "
        "model is chosen only if its residual drop passes an F-test (extra sum of squares) and "
        "the misfit it removes is a set fraction of the noise or more (both levels in 'why'); "
        "sigma_px = rms sqrt(M / (M - P))");
    choice.emplace_back("candidates", candidates);
  }
  const SplineExtrapolation& e = lens.extrapolation;
  if (e.applied || !e.why_not.empty()) {
    ReportObject beyond{{"applied", e.applied}};
    if (e.applied) {
      beyond.emplace_back("follows", e.parametric_model);
      beyond.emplace_back("max_change_px", e.max_change_px);
      beyond.emplace_back("max_change_at_marks_px", e.max_change_at_marks_px);
      if (e.num_without_parametric_ray > 0)
        beyond.emplace_back("grid_points_without_its_ray", e.num_without_parametric_ray);
    } else {
      beyond.emplace_back("why_not", e.why_not);
    }
    choice.emplace_back("spline_beyond_marks", beyond);
  }
  return choice;
}

}  // namespace omm
