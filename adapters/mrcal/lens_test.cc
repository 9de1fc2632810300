#include "adapters/mrcal/lens.h"

#include <gtest/gtest.h>

#include "adapters/mrcal/mrcal_lens_projection.h"

namespace omm {
namespace {

CameraModel TwelveMillimetreCamera() {
  CameraModel camera;
  camera.lens_model = "LENSMODEL_OPENCV8";
  camera.intrinsics.resize(12);
  camera.intrinsics << 2670.0, 2668.0, 812.0, 590.0, -0.12, 0.09, 0.0004, -0.0003, 0.01,
      0.002, -0.001, 0.003;
  camera.width_px = 1600;
  camera.height_px = 1200;
  return camera;
}

TEST(Lens, ParameterCounts) {
  EXPECT_EQ(LensModelNumParams("LENSMODEL_OPENCV4"), 8);
  EXPECT_EQ(LensModelNumParams("LENSMODEL_OPENCV8"), 12);
  EXPECT_EQ(LensModelNumParams("LENSMODEL_NOPE"), -1);
  EXPECT_FALSE(IsValidLensModel("LENSMODEL_SPLINED_STEREOGRAPHIC"));  // unconfigured
}

TEST(Lens, ProjectUnprojectRoundTrip) {
  const CameraModel camera = TwelveMillimetreCamera();
  Eigen::Matrix2Xd q(2, 4);
  q << 0.0, 1599.0, 800.0, 13.5, 0.0, 1199.0, 600.0, 1100.25;
  Eigen::Matrix3Xd v;
  ASSERT_TRUE(UnprojectPixels(camera, q, &v));
  Eigen::Matrix2Xd q_back;
  ASSERT_TRUE(ProjectPoints(camera, v * 390.0, &q_back));
  EXPECT_LT((q_back - q).cwiseAbs().maxCoeff(), 1e-6);
}

TEST(Lens, AnalyticGradientsMatchFiniteDifferences) {
  const CameraModel camera = TwelveMillimetreCamera();
  Eigen::Matrix3Xd p(3, 2);
  p << 40.0, -85.0, -30.0, 60.0, 390.0, 410.0;
  Eigen::Matrix2Xd q;
  Eigen::MatrixXd dq_dp, dq_di;
  ASSERT_TRUE(ProjectPoints(camera, p, &q, &dq_dp, &dq_di));
  const double h = 1e-6;
  for (int k = 0; k < 3; ++k) {
    Eigen::Matrix3Xd p_h = p;
    p_h.row(k).array() += h;
    Eigen::Matrix2Xd q_h;
    ASSERT_TRUE(ProjectPoints(camera, p_h, &q_h));
    for (int i = 0; i < 2; ++i) {
      EXPECT_NEAR((q_h(0, i) - q(0, i)) / h, dq_dp(2 * i, k), 1e-3);
      EXPECT_NEAR((q_h(1, i) - q(1, i)) / h, dq_dp(2 * i + 1, k), 1e-3);
    }
  }
  for (int k = 0; k < camera.intrinsics.size(); ++k) {
    CameraModel c_h = camera;
    const double step = 1e-7 * std::max(1.0, std::abs(camera.intrinsics[k]));
    c_h.intrinsics[k] += step;
    Eigen::Matrix2Xd q_h;
    ASSERT_TRUE(ProjectPoints(c_h, p, &q_h));
    for (int i = 0; i < 2; ++i) {
      const double scale = std::max(1.0, std::abs(dq_di(2 * i, k)));
      EXPECT_NEAR((q_h(0, i) - q(0, i)) / step, dq_di(2 * i, k), 1e-3 * scale);
    }
  }
}

TEST(Lens, PointGradientsAloneMatchGradientsWithIntrinsics) {
  // mrcal 2.2 mis-fills dq_dp for N > 1 when dq_dintrinsics is not requested;
  // ProjectPoints must hide that.
  const CameraModel camera = TwelveMillimetreCamera();
  Eigen::Matrix3Xd p(3, 3);
  p << 40.0, -85.0, 10.0, -30.0, 60.0, 75.0, 390.0, 410.0, 380.0;
  Eigen::Matrix2Xd q;
  Eigen::MatrixXd dq_dp_alone, dq_dp_both, dq_di;
  ASSERT_TRUE(ProjectPoints(camera, p, &q, &dq_dp_alone));
  ASSERT_TRUE(ProjectPoints(camera, p, &q, &dq_dp_both, &dq_di));
  EXPECT_EQ(dq_dp_alone, dq_dp_both);
  EXPECT_GT(dq_dp_alone.row(5).norm(), 1.0);  // the last point's gradient is not zero
}

// The Ceres costs' one-point projection calls mrcal directly: the same
// numbers as ProjectPoints with the given intrinsics, with or without the
// intrinsics' gradient (mrcal's dq_dp caveat is about the points after the
// first), and a failure for a model that does not fit its intrinsics.
TEST(Lens, MrcalLensProjectionIsProjectPoints) {
  const CameraModel camera = TwelveMillimetreCamera();
  CameraModel other = camera;
  other.intrinsics(0) += 3.0;
  other.intrinsics(5) += 0.01;
  const MrcalLensProjection lens(camera);
  const Eigen::Vector3d p(-85.0, 60.0, 410.0);
  for (const CameraModel& c : {camera, other}) {
    Eigen::Matrix2Xd q;
    Eigen::MatrixXd dq_dp, dq_di;
    ASSERT_TRUE(ProjectPoints(c, p, &q, &dq_dp, &dq_di));
    Eigen::Vector2d q_alone, q_both;
    Matrix23d dp_alone, dp_both;
    RowMajorMatrix2Xd di;
    ASSERT_TRUE(lens.Project(p, c.intrinsics.data(), &q_alone, &dp_alone, nullptr));
    ASSERT_TRUE(lens.Project(p, c.intrinsics.data(), &q_both, &dp_both, &di));
    EXPECT_EQ(q_alone, q.col(0));
    EXPECT_EQ(q_both, q.col(0));
    EXPECT_EQ(Eigen::MatrixXd(dp_alone), dq_dp);
    EXPECT_EQ(Eigen::MatrixXd(dp_both), dq_dp);
    EXPECT_EQ(Eigen::MatrixXd(di), dq_di);
  }
  CameraModel wrong = camera;
  wrong.intrinsics.conservativeResize(8);
  Eigen::Vector2d q;
  EXPECT_FALSE(
      MrcalLensProjection(wrong).Project(p, wrong.intrinsics.data(), &q, nullptr, nullptr));
}

}  // namespace
}  // namespace omm
