#include "pipeline/calibration/spline_extrapolation.h"

#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/mrcal/calibrate.h"
#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/projection_diff.h"
#include "adapters/mrcal/synthetic_plates.h"
#include "adapters/mrcal/uncertainty.h"
#include "pipeline/core/board.h"
#include "pipeline/core/plane_scene.h"

namespace omm {
namespace {

constexpr double kDistanceMm = 390.0;
constexpr double kNoisePx = 0.02;
constexpr double kObservedBelowXPx = 1000.0;  // marks right of this are not observed

// Projection vs the truth over the imager's columns [x0, x1) at the working
// distance, after the rigid motion fitted over the observed columns (the
// solves' camera frame is the truth's up to such a motion), rms px.
double ErrorOverColumns(const CameraModel& camera, const CameraModel& truth, double x0, double x1) {
  Eigen::Matrix2Xd q;
  const Eigen::Matrix3Xd p = ImagerGridPoints(camera, kDistanceMm, 33, 25, &q);
  std::vector<Eigen::Index> observed, wanted;
  for (Eigen::Index k = 0; k < q.cols(); ++k) {
    if (q(0, k) < kObservedBelowXPx - 100.0) observed.push_back(k);
    if (q(0, k) >= x0 && q(0, k) < x1) wanted.push_back(k);
  }
  const ProjectionDiff fit =
      FitRigidToProjections(p(Eigen::all, observed), q(Eigen::all, observed), truth);
  EXPECT_TRUE(fit.converged);
  const Eigen::Matrix3d r = RotationFromAngleAxis(fit.rt_b_from_a.head<3>());
  Eigen::Matrix3Xd p_truth(3, static_cast<Eigen::Index>(wanted.size()));
  for (size_t k = 0; k < wanted.size(); ++k)
    p_truth.col(static_cast<Eigen::Index>(k)) = r * p.col(wanted[k]) + fit.rt_b_from_a.tail<3>();
  Eigen::Matrix2Xd q_truth;
  EXPECT_TRUE(ProjectPoints(truth, p_truth, &q_truth));
  return std::sqrt((q_truth - q(Eigen::all, wanted)).colwise().squaredNorm().mean());
}

// A lens that OPENCV8 represents exactly (the truth camera), observed only
// left of x = 1000 px: beyond, the spline was pulled toward the bare
// stereographic projection (11.9 px RMS off), the OPENCV8 fit extrapolates
// the truth (0.026 px). The extrapolated spline follows the fit there.
TEST(ExtrapolateSplineByParametric, FollowsAParametricFitThatIsSurerBeyondTheMarks) {
  const BoardSpec board;
  const CameraModel truth = testing::TruthCamera();
  const testing::SyntheticPlates plates =
      testing::MakeSyntheticPlates(board, truth, 24, kDistanceMm, 5);
  std::vector<PlateObservation> observations = plates.Observe(kNoisePx, 11);
  for (PlateObservation& o : observations) {
    for (Eigen::Index k = 0; k < o.q_px.cols(); ++k)
      if (o.q_px(0, k) >= kObservedBelowXPx) o.weight(k) = 0.0;
    o.usable = (o.weight.array() > 0.0).count() >= 12;
  }
  const CalibrationResult spline =
      CalibrateCamera(board, observations,
                      testing::SyntheticSolveOptions(
                          "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=10_Ny=8_fov_x_deg=38"));
  const CalibrationResult opencv8 =
      CalibrateCamera(board, observations, testing::SyntheticSolveOptions("LENSMODEL_OPENCV8"));
  ASSERT_TRUE(spline.usable) << spline.brief;
  ASSERT_TRUE(opencv8.usable) << opencv8.brief;
  const auto spline_uncertainty = CalibrationUncertainty::Compute(spline.record);
  const auto opencv8_uncertainty = CalibrationUncertainty::Compute(opencv8.record);
  ASSERT_TRUE(spline_uncertainty && opencv8_uncertainty);

  const SplineExtrapolation extrapolation = ExtrapolateSplineByParametric(
      spline.camera, *spline_uncertainty, opencv8.camera, *opencv8_uncertainty, opencv8.rms_px,
      kDistanceMm, InlierMarksInCamera(spline));
  ASSERT_TRUE(extrapolation.applied) << extrapolation.why_not;
  CameraModel extrapolated = spline.camera;
  extrapolated.intrinsics = extrapolation.intrinsics;

  const double spline_beyond = ErrorOverColumns(spline.camera, truth, 1300.0, 1600.0);
  const double opencv8_beyond = ErrorOverColumns(opencv8.camera, truth, 1300.0, 1600.0);
  const double extrapolated_beyond = ErrorOverColumns(extrapolated, truth, 1300.0, 1600.0);
  const double spline_among = ErrorOverColumns(spline.camera, truth, 0.0, 900.0);
  const double extrapolated_among = ErrorOverColumns(extrapolated, truth, 0.0, 900.0);
  std::printf(
      "beyond the marks: spline %.4f px, OPENCV8 %.4f px, extrapolated %.4f px; "
      "among them: spline %.4f px, extrapolated %.4f px; marks moved <= %.5f px\n",
      spline_beyond, opencv8_beyond, extrapolated_beyond, spline_among, extrapolated_among,
      extrapolation.max_change_at_marks_px);
  EXPECT_LT(extrapolated_beyond, 0.2 * spline_beyond);
  EXPECT_LT(extrapolated_beyond, 2.0 * opencv8_beyond + kNoisePx);
  // Among the marks no farther from the truth (here, where the fit is the
  // truth, closer: 0.146 -> 0.010 px).
  EXPECT_LT(extrapolated_among, spline_among + 0.1 * kNoisePx);
}

}  // namespace
}  // namespace omm
