#include "pipeline/measure/hole_ties.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>

#include "pipeline/core/statistics.h"
#include "pipeline/measure/measurement_uncertainty.h"
#include "pipeline/mosaic/plane_adjustment.h"
#include "pipeline/mosaic/synthetic_plane.h"

namespace omm {
namespace {

HoleTie Tie(int hole, std::vector<int> tiles, const Eigen::Matrix2d& covariance) {
  HoleTie tie;
  tie.hole = hole;
  tie.centre_mm = Eigen::Vector2d(10.0 * hole, -5.0);
  tie.tiles = std::move(tiles);
  tie.num_whole = static_cast<int>(tie.tiles.size());
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

// A synthetic plane whose tile kEmptyTile has no match.
constexpr int kEmptyTile = 4;
SyntheticPlaneOptions EmptyTileOptions() {
  SyntheticPlaneOptions options;
  options.num_tracks = 600;
  options.empty_tile = kEmptyTile;
  return options;
}

// Its registration: the matches alone, no covariance.
PlaneAdjustment Registered(const SyntheticPlane& s) {
  PlaneBundleConfig config;
  config.compute_covariance = false;
  return AdjustPlaneScene(s.camera, s.input, config, PlaneBundleOptions{});
}

// Four ties of true points that the synthetic plane's tile `empty_tile`
// sees, each seen by min_views tiles or more, their views 0.01 px noisy
// (seeded); P's initial values 0.06 mm off.
std::vector<HoleTie> TiesOfTheEmptyTile(const SyntheticPlane& s, int empty_tile, size_t min_views) {
  constexpr double kSigmaPx = 0.01;
  std::mt19937 rng(5);
  std::normal_distribution<double> normal(0.0, kSigmaPx);
  std::vector<HoleTie> ties;
  for (int k = 0; k < s.truth.track_xy_mm.cols() && ties.size() < 4; ++k) {
    const Eigen::Vector3d p(s.truth.track_xy_mm(0, k), s.truth.track_xy_mm(1, k), 0.0);
    HoleTie tie;
    tie.hole = static_cast<int>(ties.size());
    tie.centre_mm = p.head<2>() + Eigen::Vector2d(0.05, -0.03);
    for (int i = 0; i < static_cast<int>(s.truth.table_pos_mm.size()); ++i) {
      const Eigen::Vector2d q = ProjectPartPoint(s.camera, s.truth, p, s.truth.table_pos_mm[i]);
      if ((q.array() < 50.0).any() || q.x() > s.camera.width_px - 50.0 ||
          q.y() > s.camera.height_px - 50.0)
        continue;
      tie.tiles.push_back(i);
      tie.q_px.push_back(q + Eigen::Vector2d(normal(rng), normal(rng)));
      tie.covariance_px2.push_back(kSigmaPx * kSigmaPx * Eigen::Matrix2d::Identity());
    }
    tie.num_whole = static_cast<int>(tie.tiles.size());
    const bool sees_the_empty_tile =
        std::find(tie.tiles.begin(), tie.tiles.end(), empty_tile) != tie.tiles.end();
    if (sees_the_empty_tile && tie.tiles.size() >= min_views) ties.push_back(std::move(tie));
  }
  return ties;
}

// AdjustWithHoleTies on a synthetic plane whose centre tile has no match
// (held by its table prior, 0.02 mm per axis): four ties of 0.01 px views
// between it and its neighbours, one with a view 0.5 px off (a misfitted
// hole). The wrong tie is dropped; the other three place the tile relative
// to its neighbours to ~1 um (0.01 px / sqrt(3) at ~0.15 mm/px): within 5 um
// of the truth, its stated sigma below 3 um.
TEST(HoleTies, TiesPlaceATileWithoutMatchesAndAWrongViewIsDropped) {
  const SyntheticPlane s = MakeSyntheticPlane(EmptyTileOptions());
  const PlaneAdjustment registered = Registered(s);
  ASSERT_TRUE(registered.summary.usable) << registered.summary.brief;

  std::vector<HoleTie> ties = TiesOfTheEmptyTile(s, kEmptyTile, 2);
  ASSERT_EQ(ties.size(), 4u);
  ties[3].q_px[0] += Eigen::Vector2d(0.5, 0.0);

  const TiedAdjustment tied =
      AdjustWithHoleTies(s.camera, s.input, registered.scene, PlateOnPart{}, IntrinsicsPrior{},
                         FinalAdjustmentOptions{}, ties, HoleTieOptions{});
  ASSERT_TRUE(tied.adjusted.summary.usable) << tied.adjusted.summary.brief;
  EXPECT_FALSE(tied.ties_failed);
  EXPECT_EQ(tied.dropped, std::vector<int>{3});
  ASSERT_EQ(tied.kept.size(), 3u);
  EXPECT_EQ(tied.adjusted.input.num_tracks, s.input.num_tracks + 3);
  EXPECT_EQ(tied.first_tie_observation, static_cast<int>(s.input.observations.size()));
  // Held by its prior before, observed (through the ties) now.
  EXPECT_EQ(registered.summary.tiles_without_observations, std::vector<int>{kEmptyTile});
  EXPECT_TRUE(tied.adjusted.summary.tiles_without_observations.empty());

  // The empty tile against its neighbours' mean (the gauge and the table's
  // scale, shared by all tiles, cancel to first order), mm.
  const auto relative_error = [&](const PlaneScene& scene) {
    Eigen::Vector2d mean = Eigen::Vector2d::Zero(), truth_mean = Eigen::Vector2d::Zero();
    for (int i = 0; i < 9; ++i) {
      if (i == kEmptyTile) continue;
      mean += scene.table_pos_mm[i] / 8.0;
      truth_mean += s.truth.table_pos_mm[i] / 8.0;
    }
    return ((scene.table_pos_mm[kEmptyTile] - mean) -
            (s.truth.table_pos_mm[kEmptyTile] - truth_mean))
        .norm();
  };
  // Its sigma, of the same difference, from the joint covariance (T_i at
  // 6 + 2 i).
  const Eigen::MatrixXd& covariance = tied.adjusted.scene.covariance;
  ASSERT_GE(covariance.rows(), 6 + 2 * 9);
  double sigma_mm = 0.0;
  for (int axis = 0; axis < 2; ++axis) {
    Eigen::VectorXd g = Eigen::VectorXd::Zero(covariance.rows());
    for (int i = 0; i < 9; ++i) g(6 + 2 * i + axis) = i == kEmptyTile ? 1.0 : -1.0 / 8.0;
    sigma_mm = std::max(sigma_mm, std::sqrt(g.dot(covariance * g)));
  }
  std::printf("empty tile: by its prior %.4f mm from the truth, tied %.4f mm (sigma %.4f mm)\n",
              relative_error(registered.scene), relative_error(tied.adjusted.scene), sigma_mm);
  EXPECT_LT(relative_error(tied.adjusted.scene), 0.005);
  EXPECT_LT(sigma_mm, 0.003);
}

// A tie whose last view is a cut one (hole_views.h, FitCutViews) 0.5 px off:
// the tie loses that view and keeps its whole ones, which still tie.
TEST(HoleTies, ACutViewThatDisagreesIsLeftOutAndItsTieKept) {
  const SyntheticPlane s = MakeSyntheticPlane(EmptyTileOptions());
  const PlaneAdjustment registered = Registered(s);
  ASSERT_TRUE(registered.summary.usable) << registered.summary.brief;
  std::vector<HoleTie> ties = TiesOfTheEmptyTile(s, kEmptyTile, 3);
  ASSERT_EQ(ties.size(), 4u);
  HoleTie& cut = ties[2];
  cut.num_whole = static_cast<int>(cut.tiles.size()) - 1;
  cut.q_px.back() += Eigen::Vector2d(0.5, 0.0);

  const TiedAdjustment tied =
      AdjustWithHoleTies(s.camera, s.input, registered.scene, PlateOnPart{}, IntrinsicsPrior{},
                         FinalAdjustmentOptions{}, ties, HoleTieOptions{});
  ASSERT_TRUE(tied.adjusted.summary.usable) << tied.adjusted.summary.brief;
  EXPECT_TRUE(tied.dropped.empty());
  EXPECT_EQ(tied.num_cut_views_dropped, 1);
  ASSERT_EQ(tied.kept.size(), 4u);
  EXPECT_EQ(tied.kept[2].tiles.size(), static_cast<size_t>(cut.num_whole));
  EXPECT_EQ(tied.kept[2].q_px.size(), tied.kept[2].tiles.size());
  EXPECT_EQ(tied.kept[3].tiles.size(), ties[3].tiles.size());
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
  options = HoleTieOptions{};
  options.max_cut_uncovered = 1.0;
  EXPECT_NE(options.Check(), "");
}

}  // namespace
}  // namespace omm
