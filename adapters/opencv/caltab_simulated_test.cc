// Caltab detection on the simulator's images (pipeline/simulate), scored
// against the truth: orientation at every rotation and tilt, the rejections,
// the perspective-bias correction and the honesty of each mark's sigma.
#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/opencv/plate_detector.h"
#include "adapters/opencv/simulated_caltab_testing.h"
#include "pipeline/calibration/perspective_bias.h"

namespace omm {
namespace {

using testing::MarkErrors;
using testing::SimulatedCalibration;

constexpr double kDeg = std::numbers::pi / 180.0;

// Every rotation about the plate normal (30-degree steps and the diagonals),
// each with a tilt from 0 to 45 deg about a varying axis, the plate 480-510 mm
// away and off-centre (the whole plate in view): the triangle fixes the orientation, so every mark must
// land on its own truth (a swap would be a pitch, ~80 px, away), and the
// bias-corrected centres must keep their accuracy out to 45 deg.
TEST(CaltabSimulated, EveryRotationAndTiltUpTo45Deg) {
  SimulatedCalibration sim(1);
  const std::vector<double> rotations_deg = {0, 30, 45, 60, 90, 120, 135, 150, 180, 210, 225, 240, 270, 300, 315, 330};
  const std::vector<double> tilts_deg = {0, 20, 35, 45};
  double sum_sq = 0.0;
  int count = 0;
  for (size_t k = 0; k < rotations_deg.size(); ++k) {
    const double rotation = rotations_deg[k] * kDeg, tilt = tilts_deg[k % tilts_deg.size()] * kDeg;
    const double tilt_axis = (37.0 + 71.0 * static_cast<double>(k)) * kDeg;
    const Eigen::Isometry3d cam_from_plate =
        Eigen::Translation3d(10.0 * std::cos(1.3 * k), 8.0 * std::sin(1.7 * k), 480.0 + 2.0 * k) *
        Eigen::AngleAxisd(tilt, Eigen::Vector3d(std::cos(tilt_axis), std::sin(tilt_axis), 0.0)) *
        Eigen::AngleAxisd(rotation, Eigen::Vector3d::UnitZ());
    // Render it as image 0 (a full view in every seed's plan).
    CalibImageTruth& view = sim.plan.truth.calib_images[0];
    ASSERT_EQ(view.kind, CalibImageTruth::Kind::kFull);
    view.cam_from_plate = cam_from_plate;
    const double half_plate = 0.5 * sim.truth().plate_size_mm;
    Eigen::Matrix3Xd plate_corners(3, 4);
    plate_corners << -half_plate, half_plate, half_plate, -half_plate, -half_plate, -half_plate, half_plate,
        half_plate, 0, 0, 0, 0;
    Eigen::Matrix2Xd corners_px;
    ASSERT_TRUE(ProjectPoints(sim.truth().camera.model, cam_from_plate * plate_corners, &corners_px));
    ASSERT_GT(corners_px.minCoeff(), 10.0) << "test pose: the plate must be in view " << k << "\n" << corners_px;
    ASSERT_LT(corners_px.row(0).maxCoeff(), sim.truth().camera.model.width_px - 10.0);
    ASSERT_LT(corners_px.row(1).maxCoeff(), sim.truth().camera.model.height_px - 10.0) << k << "\n" << corners_px;
    const PlateObservation o = DetectPlate(sim.Render(0), sim.truth().board);
    const std::string what = "rotation " + std::to_string(rotations_deg[k]) + " deg, tilt " +
                             std::to_string(tilts_deg[k % tilts_deg.size()]) + " deg";
    ASSERT_TRUE(o.usable) << what << ": " << o.why_rejected;
    const PlateObservation corrected =
        CorrectPerspectiveBias(o, sim.truth().board, sim.truth().camera.model, cam_from_plate);
    const Eigen::VectorXd error_px = MarkErrors(corrected, sim.TrueMarks(0));
    EXPECT_LT(error_px.maxCoeff(), 0.5) << what << ": a mark is not where its truth is (swapped?)";
    // The demo's bound (caltab_accuracy_test.cc) holds per view, at 45 deg too.
    const double rms_px = std::sqrt(error_px.squaredNorm() / static_cast<double>(error_px.size()));
    EXPECT_LT(rms_px, 0.02) << what;
    sum_sq += error_px.squaredNorm();
    count += static_cast<int>(error_px.size());
  }
  std::printf("rms over %zu views: %.4f px\n", rotations_deg.size(), std::sqrt(sum_sq / count));
}

// The partly visible view and the one without a plate of three seeds are
// rejected, each with its reason.
TEST(CaltabSimulated, PartialAndAbsentPlatesAreRejectedWithTheirReason) {
  for (const std::uint64_t seed : {1, 2, 3}) {
    SimulatedCalibration sim(seed);
    int partial = 0, absent = 0;
    for (int i = 0; i < sim.num_images(); ++i) {
      const CalibImageTruth::Kind kind = sim.image_truth(i).kind;
      if (kind == CalibImageTruth::Kind::kFull) continue;
      const PlateObservation o = DetectPlate(sim.Render(i), sim.truth().board);
      EXPECT_FALSE(o.usable) << "seed " << seed << " image " << i;
      if (kind == CalibImageTruth::Kind::kPartial) {
        ++partial;
        EXPECT_EQ(o.why_rejected, "plate partly outside the image") << "seed " << seed;
      } else {
        ++absent;
        EXPECT_EQ(o.why_rejected, "plate not found") << "seed " << seed;
      }
    }
    EXPECT_EQ(partial, 1);
    EXPECT_EQ(absent, 1);
  }
}

// The centre of the imaged ellipse is off the image of the dot's centre by
// ~rho^2 tilt / distance^2 (perspective_bias.h): on the tilted views (> 15 deg)
// of seed 2, several hundredths of a pixel. The correction computed with the
// true pose and camera must remove it down to the detector's own error.
TEST(CaltabSimulated, BiasCorrectionReducesTheErrorOnTiltedViews) {
  SimulatedCalibration sim(2);
  double raw_sq = 0.0, corrected_sq = 0.0;
  int count = 0, views = 0;
  for (int i = 0; i < sim.num_images(); ++i) {
    if (sim.image_truth(i).kind != CalibImageTruth::Kind::kFull || sim.TiltDeg(i) < 15.0) continue;
    const PlateObservation o = DetectPlate(sim.Render(i), sim.truth().board);
    ASSERT_TRUE(o.usable) << i << ": " << o.why_rejected;
    const PlateObservation corrected = CorrectPerspectiveBias(o, sim.truth().board, sim.truth().camera.model,
                                                              sim.image_truth(i).cam_from_plate);
    const Eigen::Matrix2Xd truth_px = sim.TrueMarks(i);
    raw_sq += MarkErrors(o, truth_px).squaredNorm();
    corrected_sq += MarkErrors(corrected, truth_px).squaredNorm();
    count += static_cast<int>(truth_px.cols());
    ++views;
  }
  const double raw_rms = std::sqrt(raw_sq / count), corrected_rms = std::sqrt(corrected_sq / count);
  std::printf("%d tilted views: raw rms %.4f px, corrected rms %.4f px\n", views, raw_rms, corrected_rms);
  ASSERT_GE(views, 8);
  // The bias is real (well above the detector's noise) ...
  EXPECT_GT(raw_rms, 0.04);
  // ... and the correction removes nearly all of it.
  EXPECT_LT(corrected_rms, 0.2 * raw_rms);
  EXPECT_LT(corrected_rms, 0.01);
}

// sigma_px is the predicted 1-sigma of a mark centre from image noise. Over
// independent noise draws of one view (the same reflectance exposed again),
// each mark's centre scatters about its mean; that scatter must match sigma_px.
TEST(CaltabSimulated, MarkSigmaMatchesTheScatterOverNoiseDraws) {
  SimulatedCalibration sim(1);
  constexpr int kDraws = 24;
  int flat = -1, tilted = -1;
  for (int i = 0; i < sim.num_images(); ++i) {
    if (sim.image_truth(i).kind != CalibImageTruth::Kind::kFull) continue;
    if (flat < 0 || sim.TiltDeg(i) < sim.TiltDeg(flat)) flat = i;
    if (tilted < 0 || sim.TiltDeg(i) > sim.TiltDeg(tilted)) tilted = i;
  }
  for (const int index : {flat, tilted}) {
    const ImageF reflectance = sim.renderer->CalibReflectance(index, sim.rays);
    const int n = sim.truth().board.rows * sim.truth().board.cols;
    Eigen::MatrixXd x(kDraws, n), y(kDraws, n);
    Eigen::VectorXd predicted_var = Eigen::VectorXd::Zero(n);
    for (int d = 0; d < kDraws; ++d) {
      const PlateObservation o = DetectPlate(sim.Expose(reflectance, index, 1000 + d, 7), sim.truth().board);
      ASSERT_TRUE(o.usable) << o.why_rejected;
      x.row(d) = o.q_px.row(0);
      y.row(d) = o.q_px.row(1);
      predicted_var += o.sigma_px.cwiseAbs2();
    }
    predicted_var /= kDraws;
    // Per coordinate variance pooled over the marks (each mark has its own mean).
    const double observed_var =
        0.5 *
        ((x.rowwise() - x.colwise().mean()).squaredNorm() + (y.rowwise() - y.colwise().mean()).squaredNorm()) /
        (static_cast<double>(kDraws - 1) * n);
    const double ratio = std::sqrt(observed_var / predicted_var.mean());
    std::printf("view %d (tilt %.1f deg): observed %.4f px, predicted %.4f px, ratio %.3f\n", index, sim.TiltDeg(index),
                std::sqrt(observed_var), std::sqrt(predicted_var.mean()), ratio);
    // 2 x 49 x 23 degrees of freedom: the pooled ratio is known to ~1.5 %
    // (1 sigma). Measured: 1.010 (flat view) and 1.004 (30 deg); the
    // residual-based estimate it replaced was 25 % pessimistic here.
    EXPECT_NEAR(ratio, 1.0, 0.06) << "view " << index;
  }
}

}  // namespace
}  // namespace omm
