#include "pipeline/calibration/spline_extrapolation.h"

#include <cmath>
#include <cstdio>
#include <optional>
#include <vector>

#include <fmt/format.h>
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
// left of x = 1000 px, solved with a spline and with OPENCV8 (once per process).
class SplineExtrapolationTest : public ::testing::Test {
 protected:
  struct Solves {
    CameraModel truth;
    CalibrationResult spline, opencv8;
    std::optional<CalibrationUncertainty> spline_uncertainty, opencv8_uncertainty;
  };
  static void SetUpTestSuite() {
    solves_ = new Solves;
    const BoardSpec board;
    solves_->truth = testing::TruthCamera();
    const testing::SyntheticPlates plates =
        testing::MakeSyntheticPlates(board, solves_->truth, 24, kDistanceMm, 5);
    std::vector<PlateObservation> observations = plates.Observe(kNoisePx, 11);
    for (PlateObservation& o : observations) {
      for (Eigen::Index k = 0; k < o.q_px.cols(); ++k)
        if (o.q_px(0, k) >= kObservedBelowXPx) o.weight(k) = 0.0;
      o.usable = (o.weight.array() > 0.0).count() >= 12;
    }
    solves_->spline =
        CalibrateCamera(board, observations,
                        testing::SyntheticSolveOptions(
                            "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=10_Ny=8_fov_x_deg=38"));
    solves_->opencv8 =
        CalibrateCamera(board, observations, testing::SyntheticSolveOptions("LENSMODEL_OPENCV8"));
    solves_->spline_uncertainty = CalibrationUncertainty::Compute(solves_->spline.record);
    solves_->opencv8_uncertainty = CalibrationUncertainty::Compute(solves_->opencv8.record);
  }
  static void TearDownTestSuite() { delete solves_; }
  void SetUp() override {
    ASSERT_TRUE(solves_->spline.usable) << solves_->spline.brief;
    ASSERT_TRUE(solves_->opencv8.usable) << solves_->opencv8.brief;
    ASSERT_TRUE(solves_->spline_uncertainty && solves_->opencv8_uncertainty);
  }
  static const Solves& S() { return *solves_; }

 private:
  static Solves* solves_;
};
SplineExtrapolationTest::Solves* SplineExtrapolationTest::solves_ = nullptr;

// Beyond the marks the spline was pulled toward the bare stereographic
// projection (11.9 px RMS off), the OPENCV8 fit extrapolates the truth
// (0.026 px). The extrapolated spline follows the fit there.
TEST_F(SplineExtrapolationTest, FollowsAParametricFitThatIsSurerBeyondTheMarks) {
  const Solves& s = S();
  const SplineExtrapolation extrapolation = ExtrapolateSplineByParametric(
      s.spline.camera, *s.spline_uncertainty, s.opencv8.camera, *s.opencv8_uncertainty,
      s.opencv8.rms_px, kDistanceMm, InlierMarksInCamera(s.spline));
  ASSERT_TRUE(extrapolation.applied) << extrapolation.why_not;
  CameraModel extrapolated = s.spline.camera;
  extrapolated.intrinsics = extrapolation.intrinsics;

  const double spline_beyond = ErrorOverColumns(s.spline.camera, s.truth, 1300.0, 1600.0);
  const double opencv8_beyond = ErrorOverColumns(s.opencv8.camera, s.truth, 1300.0, 1600.0);
  const double extrapolated_beyond = ErrorOverColumns(extrapolated, s.truth, 1300.0, 1600.0);
  const double spline_among = ErrorOverColumns(s.spline.camera, s.truth, 0.0, 900.0);
  const double extrapolated_among = ErrorOverColumns(extrapolated, s.truth, 0.0, 900.0);
  std::printf(
      "beyond the marks: spline %.4f px, OPENCV8 %.4f px, extrapolated %.4f px; "
      "among them: spline %.4f px, extrapolated %.4f px; marks moved <= %.5f px\n",
      spline_beyond, opencv8_beyond, extrapolated_beyond, spline_among, extrapolated_among,
      extrapolation.max_change_at_marks_px);
  EXPECT_LT(extrapolated_beyond, 0.2 * spline_beyond);
  const std::string described =
      DescribeSplineExtrapolation(extrapolation, s.opencv8.rms_px, SplineExtrapolationOptions());
  EXPECT_NE(described.find("the spline follows that fit"), std::string::npos) << described;
  EXPECT_EQ(described.find("except at"), std::string::npos) << described;
  EXPECT_LT(extrapolated_beyond, 2.0 * opencv8_beyond + kNoisePx);
  // Among the marks no farther from the truth (here, where the fit is the
  // truth, closer: 0.146 -> 0.010 px).
  EXPECT_LT(extrapolated_among, spline_among + 0.1 * kNoisePx);
}

// A parametric model that folds inside the imager (a strong k3: mrcal finds
// no ray beyond the fold, in the corners) guides the spline where it has rays
// and is no target where it has none: the step is still taken (it was refused
// as "not finite" when those targets were NaN).
TEST_F(SplineExtrapolationTest, AParametricModelThatFoldsIsNoTargetBeyondItsFold) {
  const Solves& s = S();
  CameraModel folded = s.opencv8.camera;
  folded.intrinsics(8) = -55.0;  // k3: d r_d / d r = 0 near r = 0.37, the corners' radius
  Eigen::Matrix3Xd corner_ray;
  ASSERT_TRUE(UnprojectPixels(folded, Eigen::Vector2d(1599.0, 1199.0), &corner_ray));
  ASSERT_FALSE(corner_ray.allFinite()) << "the model must fold inside the imager";
  // Its misfit: how far it projects the marks from the OPENCV8 fit (~the truth).
  const Eigen::Matrix3Xd marks = InlierMarksInCamera(s.spline);
  Eigen::Matrix2Xd q_folded, q_fit;
  ASSERT_TRUE(ProjectPoints(folded, marks, &q_folded));
  ASSERT_TRUE(ProjectPoints(s.opencv8.camera, marks, &q_fit));
  const double misfit_px = std::sqrt((q_folded - q_fit).colwise().squaredNorm().mean());
  // The grid points it has no ray for, counted directly.
  const SplineExtrapolationOptions options;
  Eigen::Matrix2Xd grid_q;
  ImagerGridPoints(s.spline.camera, kDistanceMm, options.grid_nx, options.grid_ny, &grid_q);
  Eigen::Matrix3Xd grid_rays;
  ASSERT_TRUE(UnprojectPixels(folded, grid_q, &grid_rays));
  int without_ray = 0;
  for (Eigen::Index k = 0; k < grid_rays.cols(); ++k) without_ray += !grid_rays.col(k).allFinite();
  // (Its own projection uncertainty is taken from the unfolded fit's solve.)
  const SplineExtrapolation extrapolation =
      ExtrapolateSplineByParametric(s.spline.camera, *s.spline_uncertainty, folded,
                                    *s.opencv8_uncertainty, misfit_px, kDistanceMm, marks, options);
  std::printf("misfit %.3f px; %d of %d grid points without its ray; marks moved <= %.5f px\n",
              misfit_px, extrapolation.num_without_parametric_ray,
              options.grid_nx * options.grid_ny, extrapolation.max_change_at_marks_px);
  ASSERT_TRUE(extrapolation.applied) << extrapolation.why_not;
  EXPECT_GT(without_ray, 0);
  EXPECT_LT(without_ray, options.grid_nx * options.grid_ny / 2);
  EXPECT_EQ(extrapolation.num_without_parametric_ray, without_ray);
  // The lens choice's why names them.
  const std::string described = DescribeSplineExtrapolation(extrapolation, misfit_px, options);
  const std::string clause =
      fmt::format("except at {} of the {} x {} grid's points, where that fit has no ray",
                  without_ray, options.grid_nx, options.grid_ny);
  EXPECT_NE(described.find(clause), std::string::npos) << described;
  EXPECT_TRUE(extrapolation.intrinsics.allFinite());
  // Among the marks, where the spline is far surer than either fit, it stays.
  EXPECT_LT(extrapolation.max_change_at_marks_px, 3 * kNoisePx);
}

}  // namespace
}  // namespace omm
