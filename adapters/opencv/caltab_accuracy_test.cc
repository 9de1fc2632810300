// Caltab mark centres on the demo preset against the truth: every usable
// image of two seeds, with the perspective-bias correction computed from the
// true pose and camera (the calibration stage uses its first solve instead).
#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

#include "adapters/opencv/plate_detector.h"
#include "adapters/opencv/simulated_caltab_testing.h"
#include "pipeline/calibration/perspective_bias.h"

namespace omm {
namespace {

using testing::MarkErrors;
using testing::SimulatedCalibration;

// RMS over all marks of all full views <= 0.02 px (the requirement; measured
// ~0.006 px), and no mark farther than 0.05 px from its truth (measured max
// ~0.015 px): the remaining error is the edge estimator's aliasing and the
// image noise, ~0.003 px per mark.
TEST(CaltabAccuracy, DemoMarkCentresWithinTwoHundredthsOfAPixel) {
  double sum_sq = 0.0;
  int count = 0;
  for (const std::uint64_t seed : {1, 2}) {
    SimulatedCalibration sim(seed);
    int usable = 0;
    for (int i = 0; i < sim.num_images(); ++i) {
      if (sim.image_truth(i).kind != CalibImageTruth::Kind::kFull) continue;
      const PlateObservation o = DetectPlate(sim.Render(i), sim.truth().board);
      ASSERT_TRUE(o.usable) << "seed " << seed << " image " << i << ": " << o.why_rejected;
      ++usable;
      const PlateObservation corrected = CorrectPerspectiveBias(o, sim.truth().board, sim.truth().camera.model,
                                                                sim.image_truth(i).cam_from_plate);
      const Eigen::VectorXd error_px = MarkErrors(corrected, sim.TrueMarks(i));
      EXPECT_LT(error_px.maxCoeff(), 0.05) << "seed " << seed << " image " << i;
      sum_sq += error_px.squaredNorm();
      count += static_cast<int>(error_px.size());
    }
    EXPECT_EQ(usable, sim.num_images() - 2) << "seed " << seed;
  }
  const double rms_px = std::sqrt(sum_sq / count);
  std::printf("%d marks: rms %.4f px\n", count, rms_px);
  EXPECT_LE(rms_px, 0.02);
}

}  // namespace
}  // namespace omm
