// The working-distance check on poses of known geometry.
#include "pipeline/mosaic/working_distance.h"

#include <cmath>
#include <numbers>
#include <vector>

#include <gtest/gtest.h>

namespace omm {
namespace {

using Vector6d = Eigen::Matrix<double, 6, 1>;

Vector6d Pose(double tilt_about_x_rad, const Eigen::Vector3d& t_mm) {
  Vector6d rt;
  rt << tilt_about_x_rad, 0.0, 0.0, t_mm;
  return rt;
}

// A plane through t tilted by a about x has the normal (0, -sin a, cos a):
// the axis meets it at z = t_z - t_y tan a.
TEST(WorkingDistance, TheAxisMeetsATiltedPlaneWhereGeometrySays) {
  const double a = std::numbers::pi / 6.0;
  const std::optional<double> z =
      AxisDistanceMm(Eigen::Vector3d(a, 0.0, 0.0), Eigen::Vector3d(10.0, 20.0, 400.0));
  ASSERT_TRUE(z.has_value());
  EXPECT_NEAR(*z, 400.0 - 20.0 * std::tan(a), 1e-9);
  // Face-on: the plane's own z.
  EXPECT_NEAR(*AxisDistanceMm(Eigen::Vector3d::Zero(), Eigen::Vector3d(-50.0, 30.0, 250.0)), 250.0,
              1e-12);
  // Edge-on, and behind the camera: no distance.
  EXPECT_FALSE(AxisDistanceMm(Eigen::Vector3d(std::numbers::pi / 2.0, 0.0, 0.0),
                              Eigen::Vector3d(0.0, 0.0, 400.0))
                   .has_value());
  EXPECT_FALSE(
      AxisDistanceMm(Eigen::Vector3d::Zero(), Eigen::Vector3d(0.0, 0.0, -400.0)).has_value());
}

// Plates calibrated at 340-440 mm: a part at 394 mm is where they were;
// table positions in cm or inches put it 10x or 25x off.
TEST(WorkingDistance, APartFarFromTheCalibrationsDistancesIsFlagged) {
  const std::vector<Vector6d> plates = {
      Pose(0.3, {0.0, 0.0, 340.0}), Pose(-0.2, {20.0, 10.0, 440.0}), Pose(0.0, {0.0, 0.0, 400.0})};
  const WorkingDistanceOptions options;
  const Eigen::Vector3d face_on = Eigen::Vector3d::Zero();
  const WorkingDistanceCheck right =
      CheckWorkingDistance(face_on, {0.0, 0.0, 394.0}, plates, options);
  ASSERT_TRUE(right.ok);
  EXPECT_TRUE(right.consistent);
  EXPECT_NEAR(right.calibration_min_mm, 340.0, 1e-9);
  EXPECT_NEAR(right.calibration_max_mm, 440.0 - 10.0 * std::tan(-0.2), 1e-9);
  for (const double factor : {10.0, 25.4, 1.0 / 10.0, 1.0 / 25.4}) {
    const WorkingDistanceCheck wrong =
        CheckWorkingDistance(face_on, {0.0, 0.0, 394.0 * factor}, plates, options);
    ASSERT_TRUE(wrong.ok);
    EXPECT_FALSE(wrong.consistent) << factor;
    EXPECT_NEAR(wrong.part_mm, 394.0 * factor, 1e-9);
  }
  // Up to max_ratio beyond the plates' range is still the calibration's.
  EXPECT_TRUE(CheckWorkingDistance(face_on, {0.0, 0.0, 175.0}, plates, options).consistent);
  EXPECT_TRUE(CheckWorkingDistance(face_on, {0.0, 0.0, 880.0}, plates, options).consistent);
  // No plate pose: no check.
  EXPECT_FALSE(CheckWorkingDistance(face_on, {0.0, 0.0, 394.0}, {}, options).ok);
}

TEST(WorkingDistance, OptionsAreChecked) {
  EXPECT_TRUE(WorkingDistanceOptions{}.Check().empty());
  WorkingDistanceOptions options;
  options.max_ratio = 1.0;
  EXPECT_FALSE(options.Check().empty());
}

}  // namespace
}  // namespace omm
