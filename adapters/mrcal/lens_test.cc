#include "adapters/mrcal/lens.h"

#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/mrcal/mrcal_lens_projection.h"
#include "adapters/mrcal/synthetic_plates.h"

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

// r_d = r (1 + k1 r^2) with k1 = -2 reaches at most 0.27 (at r = 1 /
// sqrt 6): 272 px from the centre at f = 1000 px. No ray reaches a pixel
// farther out, and the rays beyond r = 1 / sqrt 6 fold back inwards.
CameraModel FoldingCamera() {
  CameraModel camera;
  camera.lens_model = "LENSMODEL_OPENCV4";
  camera.intrinsics.resize(8);
  camera.intrinsics << 1000.0, 1000.0, 800.0, 600.0, -2.0, 0.0, 0.0, 0.0;
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

// FoldingCamera: no ray reaches a pixel more than 272 px from the centre.
TEST(Lens, PixelsBeyondTheFoldOfARadialPolynomialAreUnmapped) {
  const CameraModel camera = FoldingCamera();
  Eigen::Matrix2Xd inside(2, 3);
  inside << 800.0, 1000.0, 650.0, 600.0, 700.0, 450.0;  // 0, 224 and 212 px from the centre
  EXPECT_FALSE(FirstUnmappedPixel(camera, inside, 1e-3).has_value());
  Eigen::Matrix2Xd border = inside;
  border.conservativeResize(2, 5);
  border.col(3) << 1599.0, 1199.0;
  border.col(4) << 0.0, 0.0;
  const std::optional<Eigen::Vector2d> unmapped = FirstUnmappedPixel(camera, border, 1e-3);
  ASSERT_TRUE(unmapped.has_value());
  EXPECT_EQ(*unmapped, Eigen::Vector2d(1599.0, 1199.0));
  EXPECT_FALSE(FirstUnmappedPixel(TwelveMillimetreCamera(), border, 1e-3).has_value());
}

// FoldingCamera: a point at r = 0.5 (26.6 deg off the axis) projects to
// r_d = 0.25, 250 px from the centre, where the pixel's ray is the inner
// branch's r = 0.3 (16.7 deg). At r = 2 it projects 14 000 px out, on the
// far side; behind the camera nothing is folded.
TEST(Lens, PointsBeyondTheFoldOfARadialPolynomialAreFoldedIntoTheImage) {
  CameraModel camera = FoldingCamera();
  Eigen::Matrix3Xd p(3, 5);
  p.col(0) << 0.2, 0.0, 1.0;   // 200 px * (1 - 0.08): its own pixel
  p.col(1) << 0.0, -0.5, 1.0;  // folded to (800, 350)
  p.col(2) << 0.3, 0.4, 1.0;   // r = 0.5 too, folded
  p.col(3) << 2.0, 0.0, 1.0;   // far outside
  p.col(4) << 0.0, 0.1, -1.0;  // behind
  Eigen::Matrix2Xd q;
  ASSERT_TRUE(ProjectPoints(camera, p, &q));
  EXPECT_NEAR(q(1, 1), 350.0, 1e-9);
  EXPECT_LT(q(0, 3), -10000.0);
  EXPECT_EQ(FoldedIntoTheImage(camera, p, q, 0.0),
            (std::vector<bool>{false, true, true, false, false}));
  // With the centre at y = 150, the folded pixel of r = 0.5 straight up is
  // 100 px above the image: checked only within near_px of it.
  camera.intrinsics(3) = 150.0;
  const Eigen::Matrix3Xd up = p.col(1);
  ASSERT_TRUE(ProjectPoints(camera, up, &q));
  EXPECT_NEAR(q(1, 0), -100.0, 1e-9);
  EXPECT_EQ(FoldedIntoTheImage(camera, up, q, 0.0), std::vector<bool>{false});
  EXPECT_EQ(FoldedIntoTheImage(camera, up, q, 150.0), std::vector<bool>{true});
  // A lens without a fold in its field folds nothing there.
  Eigen::Matrix3Xd field(3, 3);
  field << 0.0, 0.3, -0.29, 0.0, 0.22, -0.21, 1.0, 1.0, 1.0;
  ASSERT_TRUE(ProjectPoints(TwelveMillimetreCamera(), field, &q));
  EXPECT_EQ(FoldedIntoTheImage(TwelveMillimetreCamera(), field, q, 100.0),
            (std::vector<bool>{false, false, false}));
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

// The blocks near a point hold every intrinsic that the projection of any
// point whose pixel is within the radius depends on (a nonzero column of
// dq/dintrinsics), over the image and beyond it (where mrcal clamps to the
// outer knots). Radius 20 px, neighbours up to 19 px away: "to first order"
// ignores the spline's slope, < 2 % here.
TEST(Lens, SplinedBlocksNearHoldEveryKnotANeighbourUses) {
  const CameraModel camera = testing::SplinedCamera();
  const MrcalLensProjection lens(camera);
  const int n = static_cast<int>(camera.intrinsics.size());
  const std::vector<int> starts = lens.IntrinsicsBlockStarts();
  // The core, then each row of 10 knots (20 values) in two blocks of 5 knots.
  ASSERT_EQ(starts.size(), 2u + 8 * 2);
  EXPECT_EQ(starts[0], 0);
  for (int row = 0; row < 8; ++row) {
    EXPECT_EQ(starts[1 + 2 * row], 4 + 20 * row);
    EXPECT_EQ(starts[2 + 2 * row], 14 + 20 * row);
  }
  EXPECT_EQ(starts.back(), n);
  constexpr double kRadiusPx = 20.0;
  const double z = 390.0, f = camera.intrinsics[0];
  int checked = 0;
  for (double x = -0.4; x <= 0.4; x += 0.0131) {
    for (double y = -0.3; y <= 0.3; y += 0.0137) {
      const Eigen::Vector3d p(x * z, y * z, z);
      Eigen::Vector2d q;
      ASSERT_TRUE(lens.Project(p, camera.intrinsics.data(), &q, nullptr, nullptr));
      const std::vector<int> near =
          lens.IntrinsicsBlocksNear(p, camera.intrinsics.data(), kRadiusPx);
      ASSERT_FALSE(near.empty());
      EXPECT_EQ(near[0], 0);  // the core
      std::vector<bool> listed(n, false);
      for (size_t k = 0; k < near.size(); ++k) {
        if (k > 0) {
          ASSERT_GT(near[k], near[k - 1]);
        }
        for (int j = starts[near[k]]; j < starts[near[k] + 1]; ++j) listed[j] = true;
      }
      // Alone, a point's 4 rows of 4 knots are in at most 2 blocks per row.
      EXPECT_LE(lens.IntrinsicsBlocksNear(p, camera.intrinsics.data(), 0.0).size(), 1u + 4 * 2);
      for (double dx = -19.0; dx <= 19.0; dx += 4.75) {
        for (double dy = -19.0; dy <= 19.0; dy += 4.75) {
          const Eigen::Vector3d p2 = p + Eigen::Vector3d(dx * z / f, dy * z / f, 0.0);
          Eigen::Vector2d q2;
          RowMajorMatrix2Xd dq_di;
          ASSERT_TRUE(lens.Project(p2, camera.intrinsics.data(), &q2, nullptr, &dq_di));
          if ((q2 - q).norm() > 0.95 * kRadiusPx) continue;
          ++checked;
          for (int j = 0; j < n; ++j) {
            if (dq_di.col(j).isZero(0.0)) continue;
            ASSERT_TRUE(listed[j]) << "intrinsic " << j << " at " << q2.transpose() << ", "
                                   << (q2 - q).norm() << " px from " << q.transpose();
          }
        }
      }
    }
  }
  EXPECT_GT(checked, 100000);
  // Other models: one block, all of it near every point.
  const MrcalLensProjection opencv(TwelveMillimetreCamera());
  EXPECT_EQ(opencv.IntrinsicsBlockStarts(), (std::vector<int>{0, 12}));
  EXPECT_EQ(opencv.IntrinsicsBlocksNear(Eigen::Vector3d(10, 20, 400),
                                        TwelveMillimetreCamera().intrinsics.data(), 5.0),
            std::vector<int>{0});
}

}  // namespace
}  // namespace omm
