// The homography fits against known homographies: exact correspondences give
// the homography back to round-off, degenerate samples are flagged, and the
// point transfer's Jacobian matches finite differences.
#include "pipeline/mosaic/homography.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <Eigen/Dense>

namespace omm {
namespace {

struct Case {
  std::string name;
  Eigen::Matrix3d h;       // b ~ h a
  Eigen::Vector2d size;    // the points lie in [0, size] (px), or around 0 (rays)
  Eigen::Vector2d origin;  // the region's corner
};

// A 1600 x 1200 px image's homographies and the registration's ray
// coordinates (x / z, z = 1: RegisterTiles fits its homographies on rays).
std::vector<Case> Cases() {
  Eigen::Matrix3d tile_px, perspective_px, tile_rays;
  // Neighbouring tiles: most of an image width of translation, a small
  // rotation and scale, a slight tilt of the plane.
  tile_px << 1.0003, 0.002, -1380.5, -0.0015, 0.9998, 14.25, 2e-7, -3e-7, 1;
  // A general view of a plane: shear, anisotropic scale, strong perspective
  // (w from 0.76 to 1.48 over the image).
  perspective_px << 0.8, 0.3, 200, -0.2, 1.1, 50, 3e-4, -2e-4, 1;
  tile_rays << 0.9997, 0.0021, -0.4312, -0.0014, 1.0002, 0.0041, 6e-4, -9e-4, 1;
  return {{"tile_px", tile_px, {1599, 1199}, {0, 0}},
          {"perspective_px", perspective_px, {1599, 1199}, {0, 0}},
          {"tile_rays", tile_rays, {1.0, 0.75}, {-0.5, -0.375}}};
}

Eigen::Matrix2Xd RandomPoints(const Case& c, int n, std::mt19937* rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Eigen::Matrix2Xd p(2, n);
  for (int i = 0; i < n; ++i)
    p.col(i) = c.origin + Eigen::Vector2d(u(*rng), u(*rng)).cwiseProduct(c.size);
  return p;
}

Eigen::Matrix2Xd TransferAll(const Eigen::Matrix3d& h, const Eigen::Matrix2Xd& a) {
  Eigen::Matrix2Xd b(2, a.cols());
  for (Eigen::Index i = 0; i < a.cols(); ++i) b.col(i) = Transfer(h, a.col(i));
  return b;
}

// The largest distance between the transfers of two homographies over a
// 9 x 9 grid covering the case's region, in units of the region's size.
double TransferDistance(const Eigen::Matrix3d& h, const Eigen::Matrix3d& truth, const Case& c) {
  double worst = 0;
  for (int i = 0; i <= 8; ++i) {
    for (int j = 0; j <= 8; ++j) {
      const Eigen::Vector2d a = c.origin + Eigen::Vector2d(i / 8.0, j / 8.0).cwiseProduct(c.size);
      worst = std::max(worst, (Transfer(h, a) - Transfer(truth, a)).norm() / c.size.maxCoeff());
    }
  }
  return worst;
}

TEST(Homography, HartleyNormaliserCentresAndScalesThePoints) {
  std::mt19937 rng(1);
  for (const Case& c : Cases()) {
    const Eigen::Matrix2Xd p = RandomPoints(c, 7, &rng);
    const Eigen::Matrix3d t = HartleyNormaliser(p);
    Eigen::Matrix2Xd q(2, p.cols());
    for (Eigen::Index i = 0; i < p.cols(); ++i) q.col(i) = (t * p.col(i).homogeneous()).head<2>();
    // Round-off of coordinates up to 1600 scaled by ~1e-3: ~1e-16.
    EXPECT_LT(q.rowwise().mean().norm(), 1e-14) << c.name;
    EXPECT_NEAR(q.colwise().norm().mean(), std::sqrt(2.0), 1e-14) << c.name;
  }
}

// Four points, one in each quadrant of the region: a well-spread sample
// (as a tile pair's matches are), so that no three are nearly collinear.
Eigen::Matrix<double, 2, 4> SpreadPoints(const Case& c, std::mt19937* rng) {
  std::uniform_real_distribution<double> u(0.05, 0.45);
  Eigen::Matrix<double, 2, 4> p;
  for (int i = 0; i < 4; ++i) {
    const Eigen::Vector2d quadrant(0.5 * (i % 2), 0.5 * (i / 2));
    p.col(i) = c.origin + (quadrant + Eigen::Vector2d(u(*rng), u(*rng))).cwiseProduct(c.size);
  }
  return p;
}

// Exact correspondences: both fits give the truth back, to round-off
// amplified by the normalised DLT system's conditioning. Measured worst over
// the 3 x 20 trials, of the region's size: FitHomography4 5.8e-15,
// FitHomography on the 4 points 3.2e-13 (M^T M squares the condition
// number), on 30 random points 1.8e-15. The bounds, 1e-13 and 1e-11 (a
// 1600 px image: 1.6e-10 and 1.6e-8 px), are 17 to 57 times the measured:
// room for other platforms' round-off, and any real error fails them.
TEST(Homography, ExactCorrespondencesGiveTheHomographyBack) {
  std::mt19937 rng(2);
  double worst4 = 0, worst_fit4 = 0, worst_fit30 = 0;
  for (const Case& c : Cases()) {
    for (int trial = 0; trial < 20; ++trial) {
      const Eigen::Matrix<double, 2, 4> a4 = SpreadPoints(c, &rng);
      const Eigen::Matrix<double, 2, 4> b4 = TransferAll(c.h, a4);
      const Eigen::Matrix3d h4 = FitHomography4(a4, b4);
      ASSERT_TRUE(h4.allFinite()) << c.name;
      worst4 = std::max(worst4, TransferDistance(h4, c.h, c));
      worst_fit4 = std::max(worst_fit4, TransferDistance(FitHomography(a4, b4), c.h, c));
      const Eigen::Matrix2Xd a = RandomPoints(c, 30, &rng);
      worst_fit30 =
          std::max(worst_fit30, TransferDistance(FitHomography(a, TransferAll(c.h, a)), c.h, c));
    }
  }
  EXPECT_LT(worst4, 1e-13);
  EXPECT_LT(worst_fit4, 1e-11);
  EXPECT_LT(worst_fit30, 1e-13);
  RecordProperty("worst_FitHomography4", ::testing::PrintToString(worst4));
  RecordProperty("worst_FitHomography_4", ::testing::PrintToString(worst_fit4));
  RecordProperty("worst_FitHomography_30", ::testing::PrintToString(worst_fit30));
}

// Four spread points and arbitrary targets (no common truth): exactly one
// homography maps them, so the two fits agree (RANSAC's inlier sets with
// FitHomography4 are FitHomography's). Measured worst 0 of the region's
// size; bound as above.
TEST(Homography, FitHomography4AgreesWithFitHomography) {
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 1.0);
  double worst_fit = 0, worst_agree = 0;
  for (const Case& c : Cases()) {
    for (int trial = 0; trial < 20; ++trial) {
      const Eigen::Matrix<double, 2, 4> a = SpreadPoints(c, &rng);
      Eigen::Matrix<double, 2, 4> b = TransferAll(c.h, a);
      for (int i = 0; i < 4; ++i)
        b.col(i) += 0.01 * c.size.maxCoeff() * Eigen::Vector2d(noise(rng), noise(rng));
      const Eigen::Matrix3d h4 = FitHomography4(a, b);
      ASSERT_TRUE(h4.allFinite()) << c.name;
      const Eigen::Matrix3d h = FitHomography(a, b);
      for (int i = 0; i < 4; ++i) {
        const Eigen::Vector2d q = Transfer(h4, a.col(i));
        worst_fit = std::max(worst_fit, (q - b.col(i)).norm() / c.size.maxCoeff());
        worst_agree = std::max(worst_agree, (q - Transfer(h, a.col(i))).norm() / c.size.maxCoeff());
      }
    }
  }
  EXPECT_LT(worst_fit, 1e-13);
  EXPECT_LT(worst_agree, 1e-11);
  RecordProperty("worst_through_points", ::testing::PrintToString(worst_fit));
  RecordProperty("worst_agreement", ::testing::PrintToString(worst_agree));
}

// Degenerate samples: three collinear points (in a and b, or in b only: no
// homography of full rank maps them) or a repeated point leave the 4-point
// system without a unique solution; FitHomography4 says so by a non-finite
// H. (Before the check, the collinear ones gave a finite H through the
// sample.)
TEST(Homography, FitHomography4OfADegenerateSampleIsNotFinite) {
  std::mt19937 rng(5);
  for (const Case& c : Cases()) {
    Eigen::Matrix<double, 2, 4> unit, a, b;
    // (0.1, 0.2), (0.4, 0.35), (0.7, 0.5) of the region: collinear.
    unit << 0.1, 0.4, 0.7, 0.3, 0.2, 0.35, 0.5, 0.9;
    for (int i = 0; i < 4; ++i) a.col(i) = c.origin + unit.col(i).cwiseProduct(c.size);
    b = TransferAll(c.h, a);
    EXPECT_FALSE(FitHomography4(a, b).allFinite()) << c.name << ": collinear in a and b";
    const Eigen::Matrix<double, 2, 4> spread = SpreadPoints(c, &rng);
    EXPECT_FALSE(FitHomography4(spread, b).allFinite()) << c.name << ": collinear in b";
    EXPECT_FALSE(FitHomography4(b, spread).allFinite()) << c.name << ": collinear in a";
    a = spread;
    b = TransferAll(c.h, a);
    a.col(3) = a.col(1), b.col(3) = b.col(1);
    EXPECT_FALSE(FitHomography4(a, b).allFinite()) << c.name << ": a repeated point";
  }
}

// FitHomography on the collinear sample: the DLT's null space has more than
// one dimension; the result is finite and one of its members.
TEST(Homography, FitHomographyOnADegenerateSampleFitsThePoints) {
  double worst = 0;
  for (const Case& c : Cases()) {
    Eigen::Matrix<double, 2, 4> unit, a;
    unit << 0.1, 0.4, 0.7, 0.3, 0.2, 0.35, 0.5, 0.9;
    for (int i = 0; i < 4; ++i) a.col(i) = c.origin + unit.col(i).cwiseProduct(c.size);
    const Eigen::Matrix2Xd b = TransferAll(c.h, a);
    const Eigen::Matrix3d h = FitHomography(a, b);
    ASSERT_TRUE(h.allFinite()) << c.name;
    for (int i = 0; i < 4; ++i)
      worst = std::max(worst, (Transfer(h, a.col(i)) - b.col(i)).norm() / c.size.maxCoeff());
  }
  EXPECT_LT(worst, 1e-13);  // measured 2.4e-15 of the region's size
  RecordProperty("worst", ::testing::PrintToString(worst));
}

// Central differences with a step of 1e-4 of the region: truncation error
// ~ step^2 |Transfer'''| ~ 1e-8 relative, round-off ~ eps / step ~ 2e-12
// relative; measured 1.7e-9 of the Jacobian's norm, bound 1e-7.
TEST(Homography, TransferJacobianMatchesFiniteDifferences) {
  double worst = 0;
  std::mt19937 rng(4);
  for (const Case& c : Cases()) {
    const Eigen::Matrix2Xd points = RandomPoints(c, 10, &rng);
    const double step = 1e-4 * c.size.maxCoeff();
    for (Eigen::Index i = 0; i < points.cols(); ++i) {
      const Eigen::Vector2d a = points.col(i);
      Eigen::Matrix2d numeric;
      for (int k = 0; k < 2; ++k) {
        const Eigen::Vector2d d = step * Eigen::Vector2d::Unit(k);
        numeric.col(k) = (Transfer(c.h, a + d) - Transfer(c.h, a - d)) / (2 * step);
      }
      const Eigen::Matrix2d analytic = TransferJacobian(c.h, a);
      worst = std::max(worst, (analytic - numeric).norm() / analytic.norm());
    }
  }
  EXPECT_LT(worst, 1e-7);
  RecordProperty("worst", ::testing::PrintToString(worst));
}

}  // namespace
}  // namespace omm
