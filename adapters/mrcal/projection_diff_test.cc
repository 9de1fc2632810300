#include "adapters/mrcal/projection_diff.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/synthetic_plates.h"
#include "adapters/mrcal/uncertainty.h"

namespace omm {
namespace {

constexpr double kDistanceMm = 390.0;

TEST(ProjectionDiff, IdenticalModelsDifferByZero) {
  const CameraModel camera = testing::TruthCamera();
  const ProjectionDiff diff = FitProjectionDiff(camera, camera, kDistanceMm);
  EXPECT_TRUE(diff.converged);
  EXPECT_LT(diff.rms_px, 1e-6);  // mrcal_unproject's tolerance
  EXPECT_LT(diff.rt_b_from_a.norm(), 1e-9);
}

// The camera turned and shifted slightly: its pixels of A's grid points are
// project(T p). Unfitted they differ by ~1 px; the fit recovers T and leaves
// nothing.
TEST(ProjectionDiff, ATinyRigidMotionVanishesAfterTheFit) {
  const CameraModel camera = testing::TruthCamera();
  const Eigen::Matrix3Xd p = ImagerGridPoints(camera, kDistanceMm, 40, 30);
  Vector6d rt_true;
  rt_true << Eigen::Vector3d(0.3, -0.5, 0.8).normalized() * 3e-4, 0.05, -0.03, 0.1;
  const Eigen::AngleAxisd rotation(rt_true.head<3>().norm(), rt_true.head<3>().normalized());
  const Eigen::Matrix3Xd p_moved = (rotation.toRotationMatrix() * p).colwise() + rt_true.tail<3>();
  Eigen::Matrix2Xd q_moved, q;
  ASSERT_TRUE(ProjectPoints(camera, p_moved, &q_moved));
  ASSERT_TRUE(ProjectPoints(camera, p, &q));
  ASSERT_GT((q_moved - q).colwise().norm().mean(), 0.4);
  const ProjectionDiff diff = FitRigidToProjections(p, q_moved, camera);
  EXPECT_TRUE(diff.converged);
  EXPECT_LT(diff.rms_px, 1e-7);
  EXPECT_LT((diff.rt_b_from_a - rt_true).head<3>().norm(), 1e-9);
}

TEST(ProjectionDiff, APerturbedDistortionRemains) {
  const CameraModel camera = testing::TruthCamera();
  CameraModel perturbed = camera;
  perturbed.intrinsics[4] += 2e-3;  // k1: ~0.3 px at the corners
  const ProjectionDiff diff = FitProjectionDiff(camera, perturbed, kDistanceMm);
  EXPECT_TRUE(diff.converged);
  // The rigid fit absorbs what it can (mostly a scale through z); the radial
  // shape stays.
  EXPECT_GT(diff.rms_px, 0.02);
  EXPECT_GT(diff.max_px, 0.05);
}

}  // namespace
}  // namespace omm
