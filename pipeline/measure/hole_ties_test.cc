#include "pipeline/measure/hole_ties.h"

#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>

#include "pipeline/measure/measurement_uncertainty.h"

namespace omm {
namespace {

HoleTie Tie(int hole, std::vector<int> tiles, const Eigen::Matrix2d& covariance) {
  HoleTie tie;
  tie.hole = hole;
  tie.centre_mm = Eigen::Vector2d(10.0 * hole, -5.0);
  tie.tiles = std::move(tiles);
  for (size_t v = 0; v < tie.tiles.size(); ++v) {
    tie.q_px.emplace_back(100.0 + v, 200.0 - v);
    tie.covariance_px2.push_back(covariance);
  }
  return tie;
}

// Each view's weighted residual is its covariance's whitening:
// |w S r / sigma|^2 = r' C^-1 r, for an anisotropic, rotated C; the tracks
// and P's initial values are appended after the existing ones.
TEST(HoleTies, TracksWhitenEachViewByItsCovariance) {
  Eigen::Matrix2d covariance;
  covariance << 4e-4, 1.5e-4, 1.5e-4, 2.5e-4;
  const std::vector<HoleTie> ties = {Tie(0, {0, 1}, covariance), Tie(3, {1, 2, 4}, covariance)};
  PlaneBundleInput input;
  input.observation_sigma_px = 0.05;
  input.num_tracks = 7;
  input.observations.resize(11);
  PlaneScene scene;
  scene.track_xy_mm = Eigen::Matrix2Xd::Ones(2, 7);
  const int first = AddHoleTieTracks(ties, &input, &scene);
  EXPECT_EQ(first, 11);
  ASSERT_EQ(input.observations.size(), 16u);
  EXPECT_EQ(input.num_tracks, 9);
  ASSERT_EQ(scene.track_xy_mm.cols(), 9);
  EXPECT_EQ(scene.track_xy_mm.col(6), Eigen::Vector2d::Ones());
  EXPECT_EQ(scene.track_xy_mm.col(8), ties[1].centre_mm);
  const int expected_tracks[] = {7, 7, 8, 8, 8};
  const int expected_tiles[] = {0, 1, 1, 2, 4};
  const Eigen::Vector2d r(0.013, -0.021);
  for (int k = 0; k < 5; ++k) {
    const TrackObservation& obs = input.observations[first + k];
    EXPECT_EQ(obs.track, expected_tracks[k]);
    EXPECT_EQ(obs.tile, expected_tiles[k]);
    const Eigen::Vector2d whitened = obs.weight * obs.shape * r / input.observation_sigma_px;
    EXPECT_NEAR(whitened.squaredNorm(), r.dot(covariance.inverse() * r), 1e-9);
    // The shape is 1 along the stiffest direction (TrackObservation).
    EXPECT_NEAR(obs.shape.eigenvalues().real().maxCoeff(), 1.0, 1e-12);
  }
}

// chi2 of the views' residuals against the quantile for 2 (views - 1) dof:
// a tie at 3 sigma per view over 2 views (chi2 18 > 13.8) is inconsistent,
// one at 2 sigma (chi2 8) is not; a third view adds 2 dof.
TEST(HoleTies, InconsistentBeyondTheChiSquareQuantile) {
  const double sigma = 0.01;
  const Eigen::Matrix2d covariance = sigma * sigma * Eigen::Matrix2d::Identity();
  const std::vector<HoleTie> ties = {Tie(0, {0, 1}, covariance), Tie(1, {1, 2}, covariance),
                                     Tie(2, {2, 3, 4}, covariance)};
  const int first = 5;
  Eigen::Matrix2Xd residual_px = Eigen::Matrix2Xd::Constant(2, first + 7, 1.0);
  const double three = 3.0 * sigma / std::sqrt(2.0), two = 2.0 * sigma / std::sqrt(2.0);
  residual_px.middleCols(first, 2).setConstant(three);      // chi2 18
  residual_px.middleCols(first + 2, 2).setConstant(two);    // chi2 8
  residual_px.middleCols(first + 4, 3).setConstant(three);  // chi2 27 > 18.5 (4 dof)
  HoleTieOptions options;
  EXPECT_EQ(InconsistentHoleTies(ties, first, residual_px, options), (std::vector<int>{0, 2}));
  EXPECT_NEAR(ChiSquareQuantile(options.consistency_probability, 2), 13.8, 0.05);
  options.consistency_probability = 0.99999999;
  EXPECT_TRUE(InconsistentHoleTies(ties, first, residual_px, options).empty());
}

TEST(HoleTies, OptionsAreChecked) {
  EXPECT_EQ(HoleTieOptions{}.Check(), "");
  HoleTieOptions options;
  options.min_views = 1;
  EXPECT_NE(options.Check(), "");
  options = HoleTieOptions{};
  options.min_sigma_px = 0.0;
  EXPECT_NE(options.Check(), "");
  options = HoleTieOptions{};
  options.consistency_probability = 1.0;
  EXPECT_NE(options.Check(), "");
}

}  // namespace
}  // namespace omm
