#include "adapters/mrcal/cross_validation.h"

#include <gtest/gtest.h>

#include <iostream>

#include "adapters/mrcal/synthetic_plates.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

// Truth OPENCV8 whose higher terms are small: a pinhole cannot follow its
// k1 = -0.12 and its halves disagree; OPENCV4 and OPENCV8 both fit to the
// noise (measured 0.024 vs 0.023 px), a tie the simpler OPENCV4 wins.
TEST(CrossValidation, PicksTheModelThatFitsTheLens) {
  const BoardSpec board;
  const testing::SyntheticPlates plates =
      testing::MakeSyntheticPlates(board, testing::TruthCamera(), 18, 390.0, 1);
  CrossValidationOptions options;
  options.calibration.width_px = 1600;
  options.calibration.height_px = 1200;
  const CrossValidationSummary summary = CrossValidateLensModels(
      board, plates.Observe(0.03, 21), {"LENSMODEL_PINHOLE", "LENSMODEL_OPENCV4", "LENSMODEL_OPENCV8"}, options);
  std::cout << summary.brief << "\n";
  for (const LensModelScore& score : summary.scores) {
    std::cout << score.lens_model << " " << score.mean_diff_rms_px << "\n";
  }
  ASSERT_EQ(summary.scores.size(), 3u);
  for (const LensModelScore& score : summary.scores) {
    EXPECT_TRUE(score.usable);
    EXPECT_EQ(score.diff_rms_px.size(), 3u);  // alternating + 2 random splits
  }
  EXPECT_GT(summary.scores[0].mean_diff_rms_px, 5.0 * summary.scores[2].mean_diff_rms_px);
  EXPECT_LT(summary.scores[1].mean_diff_rms_px, 1.1 * summary.scores[2].mean_diff_rms_px);
  EXPECT_EQ(summary.chosen_lens_model, "LENSMODEL_OPENCV4");
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
