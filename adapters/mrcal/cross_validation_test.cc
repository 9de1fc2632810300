#include "adapters/mrcal/cross_validation.h"

#include <gtest/gtest.h>

#include <iostream>

#include "adapters/mrcal/synthetic_plates.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

// Truth OPENCV8 (its k3 and rational terms matter at the edges): OPENCV4
// cannot follow it and the halves disagree more; OPENCV8 wins.
TEST(CrossValidation, PicksTheModelThatFitsTheLens) {
  const BoardSpec board;
  const testing::SyntheticPlates plates =
      testing::MakeSyntheticPlates(board, testing::TruthCamera(), 18, 390.0, 1);
  CrossValidationOptions options;
  options.calibration.width_px = 1600;
  options.calibration.height_px = 1200;
  const CrossValidationSummary summary = CrossValidateLensModels(
      board, plates.Observe(0.03, 21), {"LENSMODEL_OPENCV4", "LENSMODEL_OPENCV8"}, options);
  std::cout << summary.brief << "\n";
  ASSERT_EQ(summary.scores.size(), 2u);
  for (const LensModelScore& score : summary.scores) {
    EXPECT_TRUE(score.usable);
    EXPECT_EQ(score.diff_rms_px.size(), 3u);  // alternating + 2 random splits
  }
  EXPECT_EQ(summary.chosen_lens_model, "LENSMODEL_OPENCV8");
}

TEST(CrossValidation, BadCandidatesThrow) {
  CrossValidationOptions options;
  options.calibration.width_px = 1600;
  options.calibration.height_px = 1200;
  EXPECT_THROW(CrossValidateLensModels(BoardSpec(), {}, {}, options), InputError);
  EXPECT_THROW(CrossValidateLensModels(BoardSpec(), {}, {"LENSMODEL_NOPE"}, options), InputError);
}

}  // namespace
}  // namespace omm
