#include "pipeline/mosaic/exposure_compensation.h"

#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace omm {
namespace {

constexpr int kNumTiles = 9;

// Truth exposures: gains 0.70 .. 0.98 and tile 4's 1, vignetting
// 0.05 .. 0.21. Tile 5's gain, 0.875, is the median: the gauge.
constexpr int kMedianTile = 5;
std::vector<TileExposure> TruthExposures() {
  std::vector<TileExposure> truth(kNumTiles);
  for (int i = 0; i < kNumTiles; ++i) {
    truth[i].gain = i == 4 ? 1.0 : 0.70 + 0.035 * i;
    truth[i].vignetting = 0.05 + 0.02 * i;
  }
  return truth;
}

// The truth's gain of tile i with the gauge's set to 1.
double TruthGain(const std::vector<TileExposure>& truth, int i) {
  return truth[i].gain / truth[kMedianTile].gain;
}

// `num_samples` points of radiance 0.2 .. 0.9, each seen by 2 .. 4 distinct
// tiles at rho^2 uniform in [0, 1], recorded as
// I = g (1 - v rho^2) L (1 + relative_noise N(0, 1)). In `outlier_fraction`
// of the samples one view (a specular spot, a shadow, a misregistered edge)
// is recorded `outlier_factor` times as bright; the other values are the
// same as without outliers.
std::vector<ExposureObservation> Observations(int num_samples, double relative_noise,
                                              std::uint32_t seed, double outlier_fraction = 0.0,
                                              double outlier_factor = 1.0) {
  const std::vector<TileExposure> truth = TruthExposures();
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> radiance(0.2, 0.9), rho2(0.0, 1.0);
  std::uniform_int_distribution<int> count(2, 4), tile(0, kNumTiles - 1);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::mt19937 outlier_rng(seed + 1000);  // its own, so the other values do not change
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::vector<ExposureObservation> obs;
  for (int s = 0; s < num_samples; ++s) {
    const double l = radiance(rng);
    std::vector<bool> used(kNumTiles, false);
    const int n = count(rng);
    const int outlier = uniform(outlier_rng) < outlier_fraction
                            ? std::uniform_int_distribution<int>(0, n - 1)(outlier_rng)
                            : -1;
    for (int m = 0; m < n;) {
      const int i = tile(rng);
      if (used[i]) continue;
      used[i] = true;
      ++m;
      ExposureObservation o;
      o.sample = s;
      o.tile = i;
      o.rho2 = rho2(rng);
      o.value = truth[i].Factor(o.rho2) * l * (1.0 + relative_noise * noise(rng));
      if (m - 1 == outlier) o.value *= outlier_factor;
      obs.push_back(o);
    }
  }
  return obs;
}

// 1 % noise on 20000 samples (~6700 observations per tile). With the
// radiances known, a tile's (a, b) = (g, g v) is a straight-line fit of
// I / L against rho^2 uniform in [0, 1]: sd(a) = s sqrt(4 / n), sd(b) =
// s sqrt(12 / n), s = 1 % of F ~ 0.0085, so 2.1e-4 and 3.6e-4; eliminating a
// radiance per sample of ~3 views costs sqrt(3 / 2) and the gauge (the
// reference tile's own error) sqrt(2): sd(g) ~ 3.6e-4 at g ~ 0.85, 4.2e-4
// relative, sd(v) ~ 7e-4. The bounds are 5 sd. The residuals' robust sigma is the noise's times
// sqrt(1 - 1/n) (about the consensus of n = 2 .. 4 views): ~0.8 %.
TEST(EstimateExposure, RecoversTheTruthFromNoisyObservations) {
  const std::vector<TileExposure> truth = TruthExposures();
  const ExposureSummary summary =
      EstimateExposure(Observations(20000, 0.01, 2), kNumTiles, ExposureOptions());
  ASSERT_TRUE(summary.usable) << summary.brief;
  EXPECT_TRUE(summary.converged) << summary.brief;
  EXPECT_EQ(summary.reference_tile, kMedianTile);
  for (int i = 0; i < kNumTiles; ++i) {
    EXPECT_NEAR(summary.tiles[i].gain / TruthGain(truth, i), 1.0, 2.1e-3) << i;
    EXPECT_NEAR(summary.tiles[i].vignetting, truth[i].vignetting, 3.5e-3) << i;
  }
  EXPECT_NEAR(summary.relative_sigma_after, 0.008, 0.001);
  EXPECT_GT(summary.max_pair_step_before, 0.1);
  EXPECT_LT(summary.max_pair_step_after, 0.002);
}

// 2 % of the samples with one view 30 % too bright, or too dark, in data
// like the test above's. The Cauchy weights (scale 3 sigma ~ 2.3 %, the
// outliers at ~13 scales) all but ignore them: each one's pull on its sample,
// ~ c^2 / 0.3 ~ 2e-3 relative on ~0.7 % of the observations, is a bias ~1e-5.
// What the fit loses is the information the outlying views held, ~1.2 % (a
// sample of n views informs the exposures as n - 1 do: one of 2 views takes
// it all), so it moves from the outlier-free fit by ~ sqrt(0.012) sd: 4e-5 in
// gain, 8e-5 in vignetting. Bounds: 5 of those, and the truth bounds above.
// Outliers of one sign pull the radiances one way: they made the fit stop
// after 3 steps, 5e-3 off in gain, when its step ignored the re-weighting.
TEST(EstimateExposure, GrossOutliersLeaveTheFitWhereItIsWithoutThem) {
  const std::vector<TileExposure> truth = TruthExposures();
  for (const double outlier_factor : {1.3, 0.7}) {
    for (const std::uint32_t seed : {1u, 2u, 3u}) {
      const ExposureSummary clean =
          EstimateExposure(Observations(20000, 0.01, seed), kNumTiles, ExposureOptions());
      const ExposureSummary summary = EstimateExposure(
          Observations(20000, 0.01, seed, 0.02, outlier_factor), kNumTiles, ExposureOptions());
      ASSERT_TRUE(summary.usable) << summary.brief;
      EXPECT_TRUE(summary.converged) << summary.brief;
      for (int i = 0; i < kNumTiles; ++i) {
        const std::string where = "factor " + std::to_string(outlier_factor) + " seed " +
                                  std::to_string(seed) + " tile " + std::to_string(i);
        EXPECT_NEAR(summary.tiles[i].gain / TruthGain(truth, i), 1.0, 2.1e-3) << where;
        EXPECT_NEAR(summary.tiles[i].vignetting, truth[i].vignetting, 3.5e-3) << where;
        EXPECT_NEAR(summary.tiles[i].gain, clean.tiles[i].gain, 2e-4) << where;
        EXPECT_NEAR(summary.tiles[i].vignetting, clean.tiles[i].vignetting, 4e-4) << where;
      }
    }
  }
}

// Exposures 0.7-1 from a start at 1 take more than two steps: a fit cut off
// there has not converged and says so (its exposures are still usable).
TEST(EstimateExposure, AnIterationLimitIsReportedAsNotConverged) {
  ExposureOptions options;
  options.max_iterations = 2;
  const ExposureSummary summary =
      EstimateExposure(Observations(20000, 0.01, 2), kNumTiles, options);
  EXPECT_TRUE(summary.usable) << summary.brief;
  EXPECT_FALSE(summary.converged);
  EXPECT_EQ(summary.iterations, 2);
  EXPECT_NE(summary.brief.find("stopped before converging"), std::string::npos) << summary.brief;
}

// The passes are split in fixed blocks of samples and the blocks' sums added
// in block order: any number of threads gives the same bits.
TEST(EstimateExposure, ResultDoesNotDependOnTheNumberOfThreads) {
  const std::vector<ExposureObservation> obs = Observations(30000, 0.01, 3);
  ExposureOptions options;
  options.num_threads = 1;
  const ExposureSummary one = EstimateExposure(obs, kNumTiles, options);
  for (const int num_threads : {2, 3, 8}) {
    options.num_threads = num_threads;
    const ExposureSummary many = EstimateExposure(obs, kNumTiles, options);
    EXPECT_EQ(many.iterations, one.iterations) << num_threads;
    EXPECT_EQ(many.relative_sigma_after, one.relative_sigma_after) << num_threads;
    EXPECT_EQ(many.max_pair_step_after, one.max_pair_step_after) << num_threads;
    for (int i = 0; i < kNumTiles; ++i) {
      EXPECT_EQ(many.tiles[i].gain, one.tiles[i].gain) << num_threads << " tile " << i;
      EXPECT_EQ(many.tiles[i].vignetting, one.tiles[i].vignetting) << num_threads << " tile " << i;
    }
  }
}

TEST(ExposureOptions, CheckNamesTheProblem) {
  ExposureOptions options;
  EXPECT_EQ(options.Check(), "");
  options.num_threads = 0;
  EXPECT_NE(options.Check().find("num_threads"), std::string::npos);
}

}  // namespace
}  // namespace omm
