#include "pipeline/orchestration/calibration_report.h"

#include <gtest/gtest.h>

namespace omm {
namespace {

// A chosen spline extrapolated by an OPENCV8 fit that has rays everywhere.
LensModelChoice ExtrapolatedSpline() {
  LensModelChoice lens;
  lens.lens_model = "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=10_Ny=8_fov_x_deg=31";
  lens.extrapolation.applied = true;
  lens.extrapolation.parametric_model = "LENSMODEL_OPENCV8";
  lens.extrapolation.max_change_px = 24.4;
  lens.extrapolation.max_change_at_marks_px = 0.01;
  return lens;
}

const ReportObject& Beyond(const ReportValue& choice) {
  const ReportValue* beyond = Member(*AsObject(&choice), "spline_beyond_marks");
  EXPECT_NE(beyond, nullptr);
  return *AsObject(beyond);
}

// The grid points where the followed fit has no ray (beyond its fold) are
// counted in the report, and only when there are some.
TEST(LensChoiceReport, CountsTheGridPointsWithoutTheFollowedModelsRay) {
  LensModelChoice folded = ExtrapolatedSpline();
  folded.extrapolation.num_without_parametric_ray = 38;
  const ReportValue with_fold = LensChoiceReport(folded);
  EXPECT_EQ(AsNumber(Member(Beyond(with_fold), "grid_points_without_its_ray")), 38.0);
  EXPECT_EQ(AsBool(Member(Beyond(with_fold), "applied")), true);

  const ReportValue everywhere = LensChoiceReport(ExtrapolatedSpline());
  EXPECT_EQ(Member(Beyond(everywhere), "grid_points_without_its_ray"), nullptr);
  EXPECT_EQ(AsNumber(Member(Beyond(everywhere), "max_change_px")), 24.4);
}

TEST(LensChoiceReport, AnExtrapolationNotTakenSaysWhy) {
  LensModelChoice lens = ExtrapolatedSpline();
  lens.extrapolation = {};
  lens.extrapolation.why_not = "the parametric model maps no pixel of the grid to a ray";
  const ReportValue choice = LensChoiceReport(lens);
  EXPECT_EQ(AsBool(Member(Beyond(choice), "applied")), false);
  EXPECT_EQ(*Member(Beyond(choice), "why_not"),
            ReportValue("the parametric model maps no pixel of the grid to a ray"));
  EXPECT_EQ(Member(Beyond(choice), "grid_points_without_its_ray"), nullptr);
}

}  // namespace
}  // namespace omm
