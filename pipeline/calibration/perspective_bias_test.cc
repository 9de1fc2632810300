#include "pipeline/calibration/perspective_bias.h"

#include <cmath>
#include <numbers>

#include <Eigen/LU>
#include <gtest/gtest.h>

namespace omm {
namespace {

CameraModel Pinhole() {
  CameraModel camera;
  camera.lens_model = "LENSMODEL_PINHOLE";
  camera.intrinsics.resize(4);
  camera.intrinsics << 2670.0, 2670.0, 800.0, 600.0;
  camera.width_px = 1600;
  camera.height_px = 1200;
  return camera;
}

Eigen::Isometry3d Tilted(double tilt_deg, double distance_mm) {
  Eigen::Isometry3d cam_from_plate = Eigen::Isometry3d::Identity();
  cam_from_plate.linear() =
      (Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(tilt_deg * std::numbers::pi / 180.0, Eigen::Vector3d::UnitX()))
          .toRotationMatrix();
  cam_from_plate.translation() << 20.0, -10.0, distance_mm;
  return cam_from_plate;
}

// Exact reference for a pinhole: the circle (conic diag(1, 1, -rho^2) about
// the mark) maps through the homography H = K [r1 r2 t] to the conic
// H^-T C H^-1, whose centre is closed-form.
TEST(PerspectiveBias, MatchesTheExactConicCentreForAPinhole) {
  BoardSpec board;
  const CameraModel camera = Pinhole();
  const Eigen::Isometry3d cam_from_plate = Tilted(35.0, 390.0);
  Eigen::Matrix2Xd delta;
  ASSERT_TRUE(PerspectiveBiasCorrections(board, camera, cam_from_plate, &delta));
  Eigen::Matrix3d k;
  k << 2670.0, 0.0, 800.0, 0.0, 2670.0, 600.0, 0.0, 0.0, 1.0;
  Eigen::Matrix3d rt;
  rt << cam_from_plate.linear().col(0), cam_from_plate.linear().col(1), cam_from_plate.translation();
  const Eigen::Matrix3d h = k * rt;
  const Eigen::Matrix3Xd marks = BoardPoints(board);
  const double rho = 0.5 * board.dot_diameter_mm;
  double max_delta = 0.0;
  for (int i = 0; i < marks.cols(); ++i) {
    Eigen::Matrix3d circle;
    circle << 1, 0, -marks(0, i), 0, 1, -marks(1, i), -marks(0, i), -marks(1, i),
        marks(0, i) * marks(0, i) + marks(1, i) * marks(1, i) - rho * rho;
    const Eigen::Matrix3d h_inv = h.inverse();
    const Eigen::Matrix3d conic = h_inv.transpose() * circle * h_inv;
    const Eigen::Vector2d centre = -conic.topLeftCorner<2, 2>().inverse() * conic.topRightCorner<2, 1>();
    const Eigen::Vector3d m = h * Eigen::Vector3d(marks(0, i), marks(1, i), 1.0);
    const Eigen::Vector2d expected = m.head<2>() / m.z() - centre;
    EXPECT_LT((delta.col(i) - expected).norm(), 1e-7) << i;
    max_delta = std::max(max_delta, delta.col(i).norm());
  }
  // The bias is worth correcting at this tilt: well above the 0.02 px budget.
  EXPECT_GT(max_delta, 0.03);
}

TEST(PerspectiveBias, VanishesFacingTheCamera) {
  BoardSpec board;
  Eigen::Isometry3d facing = Eigen::Isometry3d::Identity();
  facing.translation() << 0.0, 0.0, 390.0;
  Eigen::Matrix2Xd delta;
  ASSERT_TRUE(PerspectiveBiasCorrections(board, Pinhole(), facing, &delta));
  // Parallel planes map circles to circles centred on the centre's image.
  EXPECT_LT(delta.cwiseAbs().maxCoeff(), 1e-9);
}

TEST(PerspectiveBias, LeavesChessboardsAndRejectedImagesAlone) {
  BoardSpec chess;
  chess.type = BoardType::kChessboard;
  Eigen::Matrix2Xd delta;
  ASSERT_TRUE(PerspectiveBiasCorrections(chess, Pinhole(), Tilted(30.0, 400.0), &delta));
  EXPECT_EQ(delta.cwiseAbs().maxCoeff(), 0.0);

  BoardSpec board;
  PlateObservation rejected;
  rejected.q_px.setConstant(2, 49, 5.0);
  rejected.weight.setOnes(49);
  const PlateObservation out = CorrectPerspectiveBias(rejected, board, Pinhole(), Tilted(30.0, 400.0));
  EXPECT_EQ(out.q_px, rejected.q_px);
}

TEST(PerspectiveBias, FailsBehindTheCamera) {
  BoardSpec board;
  Eigen::Isometry3d behind = Eigen::Isometry3d::Identity();
  behind.translation() << 0.0, 0.0, -390.0;
  Eigen::Matrix2Xd delta;
  EXPECT_FALSE(PerspectiveBiasCorrections(board, Pinhole(), behind, &delta));
}

}  // namespace
}  // namespace omm
