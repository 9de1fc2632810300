#include "pipeline/mosaic/pair_scatter.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

namespace omm {
namespace {

// Three pairs of 40 matches each, residuals drawn at 1x, 1x and 3x their
// declared sigma (weight 1, isotropic), plus a tie track without an anchor.
// The noisy pair is scaled by the median pair's scatter over its own; the
// others, anchors and the tie keep their weights.
TEST(PairScatter, ANoisyPairIsWeightedByItsOwnScatter) {
  PlaneBundleInput input;
  input.observation_sigma_px = 0.05;
  std::vector<int> anchor_of_track;
  std::vector<Eigen::Vector2d> residuals;
  std::mt19937 rng(3);
  std::normal_distribution<double> normal(0.0, 1.0);
  const int pair_tiles[3][2] = {{0, 1}, {1, 2}, {0, 2}};
  const double true_scatter[3] = {1.0, 1.0, 3.0};
  for (int p = 0; p < 3; ++p) {
    for (int m = 0; m < 40; ++m) {
      const int track = static_cast<int>(anchor_of_track.size());
      anchor_of_track.push_back(static_cast<int>(input.observations.size()));
      input.observations.push_back({pair_tiles[p][0], track, Eigen::Vector2d(10.0 * m, 5.0)});
      residuals.emplace_back(0.0, 0.0);  // an anchor's residual is not the pair's scatter
      input.observations.push_back({pair_tiles[p][1], track, Eigen::Vector2d(10.0 * m, 7.0)});
      residuals.push_back(true_scatter[p] * input.observation_sigma_px *
                          Eigen::Vector2d(normal(rng), normal(rng)));
    }
  }
  const int tie_track = static_cast<int>(anchor_of_track.size());
  input.observations.push_back({0, tie_track, Eigen::Vector2d(1.0, 1.0), 4.0});
  input.observations.push_back({2, tie_track, Eigen::Vector2d(1.0, 1.0), 4.0});
  residuals.emplace_back(1.0, 1.0);
  residuals.emplace_back(-1.0, 1.0);
  input.num_tracks = tie_track + 1;
  Eigen::Matrix2Xd residual_px(2, residuals.size());
  for (size_t i = 0; i < residuals.size(); ++i)
    residual_px.col(static_cast<Eigen::Index>(i)) = residuals[i];

  const PlaneBundleInput before = input;
  const std::vector<PairScatter> pairs = WeightPairsByScatter(anchor_of_track, residual_px, &input);
  ASSERT_EQ(pairs.size(), 3u);
  // By (tile_a, tile_b): (0, 1), (0, 2), (1, 2).
  EXPECT_EQ(pairs[0].tile_a, 0);
  EXPECT_EQ(pairs[0].tile_b, 1);
  EXPECT_EQ(pairs[1].tile_b, 2);
  EXPECT_EQ(pairs[2].tile_a, 1);
  for (const PairScatter& pair : pairs) EXPECT_EQ(pair.num_observations, 40);
  // 80 residual components each: the scatter within ~3 of its standard errors (8 %).
  EXPECT_NEAR(pairs[0].scatter, 1.0, 0.25);
  EXPECT_NEAR(pairs[1].scatter, 3.0, 0.75);
  EXPECT_NEAR(pairs[2].scatter, 1.0, 0.25);
  const double median = std::max(pairs[0].scatter, pairs[2].scatter);  // the middle of three
  EXPECT_DOUBLE_EQ(pairs[1].weight_scale, median / pairs[1].scatter);
  // The other two are at or below the median (the middle of three): kept.
  EXPECT_EQ(pairs[0].weight_scale, 1.0);
  EXPECT_EQ(pairs[2].weight_scale, 1.0);
  // Observations 160-239 are pair (0, 2)'s: its matches (odd) scaled, its
  // anchors (even) and every other pair's observations kept.
  for (size_t o = 0; o < 240; ++o) {
    const bool noisy_match = o >= 160 && o % 2 == 1;
    EXPECT_EQ(input.observations[o].weight,
              before.observations[o].weight * (noisy_match ? pairs[1].weight_scale : 1.0))
        << o;
  }
  // The tie (no anchor) is left alone.
  EXPECT_EQ(input.observations[240].weight, 4.0);
  EXPECT_EQ(input.observations[241].weight, 4.0);
}

}  // namespace
}  // namespace omm
