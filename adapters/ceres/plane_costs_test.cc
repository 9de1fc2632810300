#include "adapters/ceres/plane_costs.h"

#include <cmath>
#include <numbers>
#include <vector>

#include <ceres/gradient_checker.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "adapters/mrcal/lens.h"

namespace omm {
namespace {

// mrcal's projection behind the LensProjection interface (the stage's
// MrcalLensProjection lives in pipeline/mosaic, above this adapter).
class MrcalProjection : public LensProjection {
 public:
  explicit MrcalProjection(CameraModel camera) : camera_(std::move(camera)) {}
  int NumIntrinsics() const override { return static_cast<int>(camera_.intrinsics.size()); }
  bool Project(const Eigen::Vector3d& p_cam, const double* intrinsics, Eigen::Vector2d* q_px,
               Matrix23d* dq_dp, RowMajorMatrix2Xd* dq_dintrinsics) const override {
    CameraModel camera = camera_;
    camera.intrinsics = Eigen::Map<const Eigen::VectorXd>(intrinsics, NumIntrinsics());
    Eigen::Matrix2Xd q;
    Eigen::MatrixXd dp, di;
    if (!ProjectPoints(camera, p_cam, &q, dq_dp ? &dp : nullptr,
                       dq_dintrinsics ? &di : nullptr)) {
      return false;
    }
    *q_px = q.col(0);
    if (dq_dp) *dq_dp = dp;
    if (dq_dintrinsics) *dq_dintrinsics = di;
    return true;
  }

 private:
  CameraModel camera_;
};

CameraModel TwelveMillimetreCamera() {
  CameraModel camera;
  camera.lens_model = "LENSMODEL_OPENCV8";
  camera.intrinsics.resize(12);
  camera.intrinsics << 2667.0, 2665.0, 805.0, 596.0, -0.11, 0.08, 0.0004, -0.0003, 0.01,
      0.002, -0.001, 0.003;
  camera.width_px = 1600;
  camera.height_px = 1200;
  return camera;
}

// A camera looking down at the part (part -Z along the camera's z), rotated
// 130 deg about its axis and tilted 4 deg: |r| is close to pi, where the
// angle-axis chain rule is most easily wrong.
Eigen::Vector3d LookingDownR() {
  const Eigen::Matrix3d r =
      (Eigen::AngleAxisd(130.0 * std::numbers::pi / 180.0, Eigen::Vector3d::UnitZ()) *
       Eigen::AngleAxisd(4.0 * std::numbers::pi / 180.0, Eigen::Vector3d(0.6, 0.8, 0.0)) *
       Eigen::AngleAxisd(std::numbers::pi, Eigen::Vector3d::UnitX()))
          .toRotationMatrix();
  const Eigen::AngleAxisd aa(r);
  return aa.angle() * aa.axis();
}

ceres::NumericDiffOptions RiddersOptions() {
  ceres::NumericDiffOptions options;
  options.ridders_relative_initial_step_size = 1e-3;
  return options;
}

// Runs the gradient checker at `blocks`; the relative error bound 1e-6 is far
// above Ridders' extrapolation error (~1e-9 here) and far below any chain-rule
// slip (a wrong sign or a missing factor is O(1)).
void ExpectJacobiansMatch(const ceres::CostFunction& cost, const std::vector<double*>& blocks) {
  const std::vector<const ceres::Manifold*> euclidean(blocks.size(), nullptr);
  ceres::GradientChecker checker(&cost, &euclidean, RiddersOptions());
  ceres::GradientChecker::ProbeResults results;
  const bool ok = checker.Probe(blocks.data(), 1e-6, &results);
  EXPECT_TRUE(ok) << results.error_log;
  EXPECT_TRUE(results.return_value);
}

TEST(PlaneCosts, RightJacobianLinearisesTheExponential) {
  for (const Eigen::Vector3d& r :
       {LookingDownR(), Eigen::Vector3d(0.1, -0.2, 0.05), Eigen::Vector3d(1e-6, 0.0, 2e-6)}) {
    const Eigen::Vector3d dr(2e-6, -1e-6, 1.5e-6);
    auto rot = [](const Eigen::Vector3d& v) {
      return v.norm() > 0 ? Eigen::AngleAxisd(v.norm(), v.normalized()).toRotationMatrix()
                          : Eigen::Matrix3d::Identity();
    };
    const Eigen::Matrix3d expected = rot(r + dr);
    const Eigen::Matrix3d linearised = rot(r) * rot(RightJacobianSO3(r) * dr);
    // Second-order remainder: |dr|^2 ~ 1e-11.
    EXPECT_LT((expected - linearised).norm(), 1e-10);
  }
}

TEST(PlaneCosts, TrackReprojectionJacobiansMatchNumeric) {
  const MrcalProjection lens(TwelveMillimetreCamera());
  const TrackReprojectionCost cost(lens, Eigen::Vector2d(300.0, 900.0), 1.0 / 0.07);
  Eigen::Vector3d r = LookingDownR();
  Eigen::Vector3d t(1.5, -2.0, 391.0);
  Eigen::Vector2d table_pos(140.2, -104.9);
  Eigen::Vector2d point(-180.0, 60.0);
  Eigen::VectorXd intrinsics = TwelveMillimetreCamera().intrinsics;
  ExpectJacobiansMatch(cost, {r.data(), t.data(), table_pos.data(), point.data(),
                              intrinsics.data()});
  // Scaled by a matrix (an edge's shaped weight): the residual is that
  // matrix times the pixel error, exactly (the same float operations).
  Eigen::Matrix2d scale;
  scale << 0.9, 0.3, 0.3, 0.2;
  scale /= 0.07;
  const TrackReprojectionCost shaped(lens, Eigen::Vector2d(300.0, 900.0), scale);
  ExpectJacobiansMatch(shaped,
                       {r.data(), t.data(), table_pos.data(), point.data(), intrinsics.data()});
  const TrackReprojectionCost px(lens, Eigen::Vector2d(300.0, 900.0), 1.0);
  const double* params[] = {r.data(), t.data(), table_pos.data(), point.data(), intrinsics.data()};
  Eigen::Vector2d error_px, residual;
  ASSERT_TRUE(px.Evaluate(params, error_px.data(), nullptr));
  ASSERT_TRUE(shaped.Evaluate(params, residual.data(), nullptr));
  EXPECT_EQ(residual, Eigen::Vector2d(scale * error_px));
}

TEST(PlaneCosts, PlateMarkReprojectionJacobiansMatchNumeric) {
  const MrcalProjection lens(TwelveMillimetreCamera());
  const PlateMarkReprojectionCost cost(lens, Eigen::Vector2d(-37.5, 25.0),
                                       Eigen::Vector2d(700.0, 500.0), 1.0 / 0.05);
  Eigen::Vector3d r = LookingDownR();
  Eigen::Vector3d t(0.0, 0.0, 389.0);
  Eigen::Vector2d table_pos(0.1, 105.0);
  Eigen::Vector3d pose(20.0, -90.0, 0.7);
  double height = 3.0;
  double scale = 1.0002;
  Eigen::VectorXd intrinsics = TwelveMillimetreCamera().intrinsics;
  ExpectJacobiansMatch(cost, {r.data(), t.data(), table_pos.data(), pose.data(), &height,
                              &scale, intrinsics.data()});
}

TEST(PlaneCosts, PriorJacobiansMatchNumericAndCostIsTheGaussian) {
  const TablePriorCost table_prior(Eigen::Vector2d(140.0, -105.0), 0.02);
  Eigen::Vector2d table_pos(140.013, -105.021);
  ExpectJacobiansMatch(table_prior, {table_pos.data()});

  Eigen::MatrixXd a = Eigen::MatrixXd::Random(4, 4);
  const Eigen::MatrixXd information = a * a.transpose() + Eigen::MatrixXd::Identity(4, 4);
  const Eigen::Vector4d calibrated(2667.0, 2665.0, 805.0, 596.0);
  const IntrinsicsPriorCost intrinsics_prior(calibrated, information, {});
  Eigen::Vector4d k(2667.3, 2664.8, 805.2, 595.9);
  ExpectJacobiansMatch(intrinsics_prior, {k.data()});
  // |residual|^2 is the Mahalanobis norm the prior stands for.
  Eigen::Vector4d residual;
  const double* params[] = {k.data()};
  ASSERT_TRUE(intrinsics_prior.Evaluate(params, residual.data(), nullptr));
  EXPECT_NEAR(residual.squaredNorm(), (k - calibrated).dot(information * (k - calibrated)),
              1e-9);

  // Held intrinsics (1 and 3): no residual, a zero Jacobian column; the norm
  // is the free ones'.
  const std::vector<int> free = {0, 2};
  Eigen::MatrixXd held_information = Eigen::MatrixXd::Zero(4, 4);
  held_information(free, free) = information(free, free);
  const IntrinsicsPriorCost held_prior(calibrated, held_information, {1, 3});
  ASSERT_EQ(held_prior.num_residuals(), 2);
  ExpectJacobiansMatch(held_prior, {k.data()});
  Eigen::Vector2d free_residual;
  ASSERT_TRUE(held_prior.Evaluate(params, free_residual.data(), nullptr));
  EXPECT_NEAR(free_residual.squaredNorm(),
              (k - calibrated).dot(held_information * (k - calibrated)), 1e-9);
}

}  // namespace
}  // namespace omm
