#include "adapters/mrcal/calibrate.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/mrcal_problem.h"
#include "adapters/mrcal/projection_diff.h"
#include "adapters/mrcal/synthetic_plates.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

constexpr double kDistanceMm = 390.0;

TEST(Calibrate, HomographySeedRecoversAPinholePose) {
  const BoardSpec board;
  CameraModel pinhole{"LENSMODEL_PINHOLE", Eigen::Vector4d(2600, 2600, 799.5, 599.5), 1600, 1200};
  const testing::SyntheticPlates plates = testing::MakeSyntheticPlates(board, pinhole, 6, 390, 3);
  for (size_t i = 0; i < plates.q_truth_px.size(); ++i) {
    Vector6d rt;
    ASSERT_TRUE(PlatePoseFromHomography(BoardPoints(board), plates.q_truth_px[i],
                                        Eigen::VectorXd::Ones(49), 2600,
                                        Eigen::Vector2d(799.5, 599.5), &rt));
    // Exact data through an exact pinhole: only rounding is left.
    EXPECT_LT((rt - plates.rt_cam_from_plate[i]).cwiseAbs().maxCoeff(), 1e-8) << i;
  }
}

// With the right model and tiny noise, the unregularised solve is the truth.
TEST(Calibrate, TinyNoiseRecoversTheTruth) {
  const BoardSpec board;
  const CameraModel truth = testing::TruthCamera();
  const testing::SyntheticPlates plates =
      testing::MakeSyntheticPlates(board, truth, 18, kDistanceMm, 1);
  CalibrationOptions options = testing::SyntheticSolveOptions("LENSMODEL_OPENCV8");
  options.apply_regularization = false;
  const CalibrationResult result = CalibrateCamera(board, plates.Observe(1e-6, 7), options);
  ASSERT_TRUE(result.usable) << result.brief;
  EXPECT_EQ(result.record.images.size(), 18u);
  EXPECT_EQ(result.num_observations_used, 18 * 49);
  EXPECT_EQ(result.num_outliers, 0);
  EXPECT_LT(result.rms_px, 2e-6);
  EXPECT_LT((result.camera.intrinsics.head<4>() - truth.intrinsics.head<4>()).cwiseAbs().maxCoeff(),
            1e-3);
  // The rational coefficients are nearly degenerate with each other (a
  // numerator and denominator sharing a factor), so compare projections.
  EXPECT_LT(ProjectionDiffRms(result.camera, truth, kDistanceMm), 1e-4);
  for (size_t i = 0; i < plates.rt_cam_from_plate.size(); ++i) {
    EXPECT_LT((result.record.images[i].rt_cam_from_plate - plates.rt_cam_from_plate[i])
                  .cwiseAbs()
                  .maxCoeff(),
              1e-5);
  }
}

// mrcal 2.2's regularisation (on by default) pulls the distortions and the
// centre a little; with this lens and plate coverage its bias on the
// projection at the working distance is negligible (measured 3e-4 px).
TEST(Calibrate, RegularizationBiasIsNegligible) {
  const BoardSpec board;
  const CameraModel truth = testing::TruthCamera();
  const testing::SyntheticPlates plates =
      testing::MakeSyntheticPlates(board, truth, 18, kDistanceMm, 1);
  const CalibrationResult result = CalibrateCamera(
      board, plates.Observe(1e-6, 7), testing::SyntheticSolveOptions("LENSMODEL_OPENCV8"));
  ASSERT_TRUE(result.usable) << result.brief;
  EXPECT_LT(ProjectionDiffRms(result.camera, truth, kDistanceMm), 1e-3);
}

TEST(Calibrate, FlagsAGrossOutlier) {
  const BoardSpec board;
  const CameraModel truth = testing::TruthCamera();
  const testing::SyntheticPlates plates = testing::MakeSyntheticPlates(board, truth, 18, kDistanceMm, 1);
  std::vector<PlateObservation> observations = plates.Observe(0.03, 7);
  observations[4].q_px(0, 10) += 3.0;      // 100 sigma off
  observations[5].weight[20] = 0.0;        // not observed
  observations[6].usable = false;          // rejected by detection
  const CalibrationResult result =
      CalibrateCamera(board, observations, testing::SyntheticSolveOptions("LENSMODEL_OPENCV8"));
  ASSERT_TRUE(result.usable) << result.brief;
  ASSERT_EQ(result.record.images.size(), 17u);
  EXPECT_EQ(result.images_not_used, std::vector<std::string>{"calib_6.png"});
  EXPECT_TRUE(result.record.images[4].outlier[10]);
  EXPECT_TRUE(result.record.images[5].outlier[20]);
  EXPECT_EQ(result.per_image[4].num_outliers, 1);
  EXPECT_EQ(result.per_image[5].num_outliers, 0);  // unobserved, not an outlier
  EXPECT_EQ(result.per_image[5].num_inliers, 48);
  EXPECT_NEAR(result.rms_px, 0.03, 0.005);
}

TEST(Calibrate, TooFewImagesIsAResultNotACrash) {
  const BoardSpec board;
  const testing::SyntheticPlates plates =
      testing::MakeSyntheticPlates(board, testing::TruthCamera(), 3, kDistanceMm, 1);
  const CalibrationResult result = CalibrateCamera(
      board, plates.Observe(0.03, 7), testing::SyntheticSolveOptions("LENSMODEL_OPENCV8"));
  EXPECT_FALSE(result.usable);
  EXPECT_NE(result.brief.find("too few"), std::string::npos);
}

TEST(Calibrate, BadOptionsThrow) {
  CalibrationOptions options = testing::SyntheticSolveOptions("LENSMODEL_SPLINED_STEREOGRAPHIC");
  EXPECT_FALSE(options.Check().empty());
  EXPECT_THROW(CalibrateCamera(BoardSpec(), {}, options), InputError);
}

TEST(Calibrate, SplinedModelSeededFromOpencv4FitsTheLens) {
  const BoardSpec board;
  const CameraModel truth = testing::TruthCamera();
  const testing::SyntheticPlates plates = testing::MakeSyntheticPlates(board, truth, 18, kDistanceMm, 1);
  const CalibrationResult result =
      CalibrateCamera(board, plates.Observe(0.02, 7),
                      testing::SyntheticSolveOptions(
                          "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_fov_x_deg=40"));
  ASSERT_TRUE(result.usable) << result.brief;
  EXPECT_NEAR(result.rms_px, 0.02, 0.004);
  EXPECT_EQ(result.num_outliers, 0);
}

// The re-solve from a solution on observations that moved (another noise
// draw: 0.03 px) reaches the minimum a solve from the seed reaches, and finds
// the outliers of the new observations, not the old ones.
TEST(Calibrate, RefineFromAnEarlierSolutionReachesTheFreshSolve) {
  const BoardSpec board;
  const CameraModel truth = testing::TruthCamera();
  const testing::SyntheticPlates plates =
      testing::MakeSyntheticPlates(board, truth, 18, kDistanceMm, 1);
  const CalibrationOptions options = testing::SyntheticSolveOptions("LENSMODEL_OPENCV8");
  std::vector<PlateObservation> before = plates.Observe(0.03, 7);
  before[4].q_px(0, 10) += 3.0;
  std::vector<PlateObservation> after = plates.Observe(0.03, 8);
  after[5].q_px(1, 30) += 3.0;
  const CalibrationResult earlier = CalibrateCamera(board, before, options);
  ASSERT_TRUE(earlier.usable) << earlier.brief;
  ASSERT_TRUE(earlier.record.images[4].outlier[10]);

  const CalibrationResult refined = RefineCalibration(earlier, after, options);
  const CalibrationResult fresh = CalibrateCamera(board, after, options);
  ASSERT_TRUE(refined.usable) << refined.brief;
  ASSERT_TRUE(fresh.usable) << fresh.brief;
  EXPECT_FALSE(refined.record.images[4].outlier[10]);
  EXPECT_TRUE(refined.record.images[5].outlier[30]);
  EXPECT_EQ(refined.num_outliers, fresh.num_outliers);
  EXPECT_NEAR(refined.rms_px, fresh.rms_px, 1e-6);
  EXPECT_LT(ProjectionDiffRms(refined.camera, fresh.camera, kDistanceMm), 1e-5);

  // An image of the earlier solve without a usable observation: refused,
  // rather than solved on its old marks.
  after[3].usable = false;
  EXPECT_THROW(RefineCalibration(earlier, after, options), InputError);
  after.erase(after.begin() + 3);
  EXPECT_THROW(RefineCalibration(earlier, after, options), InputError);
}

// Rms projection difference between two cameras over the pixels of the
// marks (where the data hold a splined model; beyond them its knots follow
// the regularisation), after the rigid motion that explains it best.
double DiffAtMarksPx(const CameraModel& a, const CameraModel& b,
                     const std::vector<PlateObservation>& observations) {
  Eigen::Matrix2Xd q_px(2, 0);
  for (const PlateObservation& observation : observations) {
    q_px.conservativeResize(2, q_px.cols() + observation.q_px.cols());
    q_px.rightCols(observation.q_px.cols()) = observation.q_px;
  }
  Eigen::Matrix3Xd v;
  if (!UnprojectPixels(a, q_px, &v)) return std::numeric_limits<double>::infinity();
  const Eigen::Matrix3Xd p = kDistanceMm * v.colwise().normalized();
  const ProjectionDiff diff = FitRigidToProjections(p, q_px, b);
  return diff.converged ? diff.rms_px : std::numeric_limits<double>::infinity();
}

// A splined model's re-solve keeps the earlier core (held, as in the solve
// from the seed, where it comes from OPENCV4); the knots take up the rest,
// so that where the marks are the projection is the fresh solve's to well
// within the noise's own effect (another draw of it moves the projection
// there by 0.019 px).
TEST(Calibrate, RefineOfASplinedModelHoldsItsCore) {
  const BoardSpec board;
  const CameraModel truth = testing::TruthCamera();
  const testing::SyntheticPlates plates =
      testing::MakeSyntheticPlates(board, truth, 18, kDistanceMm, 1);
  const CalibrationOptions options = testing::SyntheticSolveOptions(
      "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_fov_x_deg=40");
  const CalibrationResult earlier = CalibrateCamera(board, plates.Observe(0.02, 7), options);
  ASSERT_TRUE(earlier.usable) << earlier.brief;
  const std::vector<PlateObservation> after = plates.Observe(0.02, 8);
  const CalibrationResult refined = RefineCalibration(earlier, after, options);
  const CalibrationResult fresh = CalibrateCamera(board, after, options);
  ASSERT_TRUE(refined.usable) << refined.brief;
  EXPECT_EQ(refined.camera.intrinsics.head<4>(), earlier.camera.intrinsics.head<4>());
  EXPECT_NEAR(refined.rms_px, fresh.rms_px, 1e-4);
  // Measured 1.4e-4 px; each is 0.014 px from the truth there.
  EXPECT_LT(DiffAtMarksPx(refined.camera, fresh.camera, after), 1e-3);
}

// The packed states' difference in units of the parameters' own scatter:
// sqrt(d' J'J d / s^2), with s^2 the residuals' variance at a.
double MahalanobisDistance(const mrcal_internal::Problem& a, const mrcal_internal::Problem& b) {
  Eigen::VectorXd x;
  Eigen::SparseMatrix<double, Eigen::RowMajor> J;
  if (!mrcal_internal::EvaluateCallback(a, &x, &J)) return INFINITY;
  const Eigen::VectorXd d = mrcal_internal::PackedState(a) - mrcal_internal::PackedState(b);
  const double variance = x.squaredNorm() / static_cast<double>(x.size() - d.size());
  return std::sqrt((J * d).squaredNorm() / variance);
}

TEST(MrcalProblem, PackedStateRoundTrips) {
  const BoardSpec board;
  const testing::SyntheticPlates plates =
      testing::MakeSyntheticPlates(board, testing::TruthCamera(), 6, kDistanceMm, 1);
  CalibrationResult result = CalibrateCamera(board, plates.Observe(0.02, 7),
                                             testing::SyntheticSolveOptions("LENSMODEL_OPENCV8"));
  ASSERT_TRUE(result.usable) << result.brief;
  result.record.problem.optimize_calobject_warp = true;
  const mrcal_internal::Problem problem = mrcal_internal::ToProblem(result.record);
  mrcal_internal::Problem copy = problem;
  copy.intrinsics.assign(copy.intrinsics.size(), 0.0);
  for (mrcal_pose_t& pose : copy.frames_toref) pose = {};
  copy.calobject_warp = {};
  mrcal_internal::SetPackedState(mrcal_internal::PackedState(problem), &copy);
  for (size_t k = 0; k < problem.intrinsics.size(); ++k) {
    EXPECT_NEAR(copy.intrinsics[k], problem.intrinsics[k], 1e-12 * std::abs(problem.intrinsics[k]));
  }
  for (size_t f = 0; f < problem.frames_toref.size(); ++f) {
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(copy.frames_toref[f].r.xyz[k], problem.frames_toref[f].r.xyz[k], 1e-15);
      EXPECT_NEAR(copy.frames_toref[f].t.xyz[k], problem.frames_toref[f].t.xyz[k], 1e-12);
    }
  }
  EXPECT_EQ(copy.calobject_warp.x2, problem.calobject_warp.x2);
}

// The marks weighed as the plate detector weighs marks of 0.005 px
// (nominal_sigma_px 0.02 / 0.005 = 4, its largest weight).
std::vector<PlateObservation> Weighed(std::vector<PlateObservation> observations) {
  for (PlateObservation& observation : observations) observation.weight *= 4.0;
  return observations;
}

// A splined lens's re-solve on observations that moved (another noise
// draw), as the calibration stage's bias rounds run it, on a lens its knots
// cannot represent exactly (a finer spline over another field), so that the
// residuals do not vanish at the optimum: the line search scales steps, the
// state reaches mrcal_optimize's own optimum, and mrcal_optimize, run after,
// stays there.
TEST(MrcalProblem, GaussNewtonWithLineSearchReachesMrcalsOptimumOfASplinedLens) {
  const BoardSpec board;
  const testing::SyntheticPlates plates =
      testing::MakeSyntheticPlates(board, testing::SplinedCamera(), 18, kDistanceMm, 1);
  const CalibrationResult earlier =
      CalibrateCamera(board, Weighed(plates.Observe(0.005, 7)),
                      testing::SyntheticSolveOptions(
                          "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=10_Ny=8_fov_x_deg=30"));
  ASSERT_TRUE(earlier.usable) << earlier.brief;
  SolveRecord moved = earlier.record;
  const std::vector<PlateObservation> after = plates.Observe(0.005, 8);
  for (size_t i = 0; i < moved.images.size(); ++i) moved.images[i].q_px = after[i].q_px;

  mrcal_internal::Problem by_mrcal = mrcal_internal::ToProblem(moved);
  mrcal_internal::Optimize(&by_mrcal);
  mrcal_internal::Problem searched = mrcal_internal::ToProblem(moved);
  const GaussNewtonSummary summary = mrcal_internal::ConvergeByGaussNewton(&searched);
  EXPECT_GT(summary.scaled, 0);
  EXPECT_LT(summary.final_cost, summary.initial_cost);
  // Measured 1.8e-5 and 9e-6.
  EXPECT_LT(MahalanobisDistance(by_mrcal, searched), 1e-4);
  const mrcal_internal::Problem before_mrcal = searched;
  mrcal_internal::Optimize(&searched);
  EXPECT_LT(MahalanobisDistance(searched, before_mrcal), 1e-4);
}

}  // namespace
}  // namespace omm
