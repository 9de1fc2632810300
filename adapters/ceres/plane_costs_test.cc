#include "adapters/ceres/plane_costs.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <numbers>
#include <vector>

#include <ceres/gradient_checker.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/mrcal_lens_projection.h"
#include "adapters/mrcal/synthetic_plates.h"
#include "pipeline/core/plane_scene.h"

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

// A splined lens's intrinsics in blocks (IntrinsicsBlocks): the cost is the
// one-block cost to the bit (the values in no block are NaN here: not read
// where the projection does not depend on them); a point that needs a knot
// outside its blocks fails the evaluation and counts.
TEST(PlaneCosts, ReprojectionInIntrinsicsBlocksIsTheOneBlockCost) {
  const CameraModel camera = testing::SplinedCamera();
  const MrcalLensProjection lens(camera);
  Eigen::Vector3d r = LookingDownR();
  Eigen::Vector3d t(1.5, -2.0, 391.0);
  Eigen::Vector2d table_pos(140.2, -104.9);
  Eigen::Vector2d point(-180.0, 60.0);
  Eigen::VectorXd k = camera.intrinsics;
  const Eigen::Vector3d p_cam =
      RotationFromAngleAxis(r) * MovedTrackPoint(table_pos.data(), point.data()) + t;
  const std::vector<int> starts = lens.IntrinsicsBlockStarts();
  // 50 px: room for the numeric differentiation's steps.
  const std::vector<int> near = lens.IntrinsicsBlocksNear(p_cam, k.data(), 50.0);
  ASSERT_LT(near.size(), starts.size() - 1);
  std::atomic<int> num_outside{0};
  Eigen::VectorXd others = k;
  IntrinsicsBlocks blocks{{}, others.data(), &num_outside};
  std::vector<double*> params = {r.data(), t.data(), table_pos.data(), point.data()};
  for (int b : near) {
    const int size = starts[b + 1] - starts[b];
    blocks.ranges.emplace_back(starts[b], size);
    params.push_back(k.data() + starts[b]);
    others.segment(starts[b], size).setConstant(std::numeric_limits<double>::quiet_NaN());
  }
  Eigen::Matrix2d scale;
  scale << 0.9, 0.3, 0.3, 0.2;
  scale /= 0.07;
  const Eigen::Vector2d q_px(300.0, 900.0);
  const TrackReprojectionCost split(lens, q_px, scale, blocks);
  const TrackReprojectionCost whole(lens, q_px, scale);
  ASSERT_EQ(split.parameter_block_sizes().size(), 4 + near.size());
  ExpectJacobiansMatch(split, params);

  using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  std::vector<RowMajor> j_split, j_whole;
  for (int size : split.parameter_block_sizes()) j_split.push_back(RowMajor::Zero(2, size));
  for (int size : whole.parameter_block_sizes()) j_whole.push_back(RowMajor::Zero(2, size));
  std::vector<double*> j_split_ptr, j_whole_ptr;
  for (RowMajor& j : j_split) j_split_ptr.push_back(j.data());
  for (RowMajor& j : j_whole) j_whole_ptr.push_back(j.data());
  const double* whole_params[] = {r.data(), t.data(), table_pos.data(), point.data(), k.data()};
  Eigen::Vector2d res_split, res_whole;
  ASSERT_TRUE(split.Evaluate(params.data(), res_split.data(), j_split_ptr.data()));
  ASSERT_TRUE(whole.Evaluate(whole_params, res_whole.data(), j_whole_ptr.data()));
  EXPECT_EQ(res_split, res_whole);
  for (int b = 0; b < 4; ++b) EXPECT_EQ(j_split[b], j_whole[b]) << "block " << b;
  RowMajor j_intrinsics = RowMajor::Zero(2, k.size());
  for (size_t b = 0; b < near.size(); ++b)
    j_intrinsics.middleCols(starts[near[b]], j_split[4 + b].cols()) = j_split[4 + b];
  EXPECT_EQ(j_intrinsics, j_whole[4]);
  EXPECT_EQ(num_outside, 0);

  // The core and a block the point does not use: it fails, and counts.
  int unused = 1;
  while (std::find(near.begin(), near.end(), unused) != near.end()) ++unused;
  const IntrinsicsBlocks wrong{
      {{0, 4}, {starts[unused], starts[unused + 1] - starts[unused]}}, k.data(), &num_outside};
  const TrackReprojectionCost outside(lens, q_px, scale, wrong);
  const double* outside_params[] = {r.data(),     t.data(), table_pos.data(),
                                    point.data(), k.data(), k.data() + starts[unused]};
  EXPECT_FALSE(outside.Evaluate(outside_params, res_split.data(), nullptr));
  EXPECT_EQ(num_outside, 1);
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

  // In blocks {0}, {1, 2}, {3}: the same residual, to the bit.
  const IntrinsicsPriorCost blocks_prior(calibrated, held_information, {1, 3}, {0, 1, 3, 4});
  ASSERT_EQ(blocks_prior.parameter_block_sizes(), (std::vector<int>{1, 2, 1}));
  ExpectJacobiansMatch(blocks_prior, {k.data(), k.data() + 1, k.data() + 3});
  Eigen::Vector2d blocks_residual;
  const double* blocks_params[] = {k.data(), k.data() + 1, k.data() + 3};
  ASSERT_TRUE(blocks_prior.Evaluate(blocks_params, blocks_residual.data(), nullptr));
  EXPECT_EQ(blocks_residual, free_residual);
}

}  // namespace
}  // namespace omm
