#include "pipeline/measure/circle_measure.h"

#include <gtest/gtest.h>

#include "pipeline/measure/synthetic_hole.h"

namespace omm {
namespace {

// A flat dark disc on a flat surface, blurred, no noise: the fit recovers
// the truth to the model's accuracy.
TEST(CircleMeasure, CleanDiscToAHundredthOfAPixel) {
  testing::SyntheticHole hole;
  hole.centre_px = {80.3, 79.6};
  hole.radius_px = 40.0;
  hole.bottom_radius_px = 40.0;
  const ImageF image = testing::RenderSyntheticHole(hole);
  const CircleMeasurement m = MeasureCircle(image, {86.0, 75.0}, 40.0);
  ASSERT_TRUE(m.ok) << m.error;
  EXPECT_LT((m.centre_px - hole.centre_px).norm(), 0.01);
  EXPECT_NEAR(m.radius_px, hole.radius_px, 0.01);
}

}  // namespace
}  // namespace omm
