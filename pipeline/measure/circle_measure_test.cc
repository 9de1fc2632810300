#include "pipeline/measure/circle_measure.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <optional>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "pipeline/measure/synthetic_hole.h"

namespace omm {
namespace {

using testing::SyntheticHole;

// The demo's geometry (pipeline/simulate presets): 0.15 mm mosaic pixels, a
// 12 mm part seen from ~410 mm, so the bottom rim shows 2.9 % smaller than
// the top one and shifted by 2.9 % of the hole's distance from the camera's
// axis; the simulator's rich texture, its PSF, and the noise measured in a
// demo mosaic.
constexpr double kDepthRatio = 0.029;
constexpr double kPsfPx = 0.75;
constexpr double kNoise = 0.003;

// A textured hole of radius `radius_px` whose centre lies `axis_px` from the
// camera's axis in direction `angle_rad`.
SyntheticHole DemoHole(double radius_px, double axis_px, double angle_rad, std::uint64_t seed) {
  SyntheticHole hole;
  hole.width_px = hole.height_px = static_cast<int>(2 * radius_px + 40);
  hole.centre_px = Eigen::Vector2d::Constant(0.5 * hole.width_px);
  hole.radius_px = radius_px;
  hole.bottom_radius_px = radius_px * (1.0 - kDepthRatio);
  hole.bottom_shift_px =
      kDepthRatio * axis_px * Eigen::Vector2d(std::cos(angle_rad), std::sin(angle_rad));
  hole.texture_seed = seed;
  hole.psf_sigma_px = kPsfPx;
  hole.noise_sigma = kNoise;
  hole.noise_seed = seed;
  return hole;
}

double Sigma(const CircleMeasurement& m, int i) { return std::sqrt(m.covariance_px2(i, i)); }

TEST(CircleMeasureOptions, CheckNamesTheBadField) {
  EXPECT_EQ(CircleMeasureOptions{}.Check(), "");
  CircleMeasureOptions options;
  options.wedge_arc_px = 0.0;
  EXPECT_NE(options.Check().find("wedge_arc_px"), std::string::npos);
  options = {};
  options.min_found_fraction = 0.9;
  EXPECT_NE(options.Check().find("min_found_fraction"), std::string::npos);
}

// A flat dark disc on a flat surface, blurred, no noise. What is left is the
// model's own error: the pixels' area integration and the discrete PSF
// (as the simulator renders) make the profile depend slightly on the pixel
// phase along the rim, which averages out over the perimeter.
TEST(CircleMeasure, CleanDiscWithinAHundredthOfAPixel) {
  for (const double radius : {15.0, 40.0, 120.0}) {
    SyntheticHole hole;
    hole.width_px = hole.height_px = static_cast<int>(2 * radius + 40);
    hole.centre_px = Eigen::Vector2d(0.5 * hole.width_px + 0.3, 0.5 * hole.height_px - 0.4);
    hole.radius_px = hole.bottom_radius_px = radius;
    hole.psf_sigma_px = kPsfPx;
    const ImageF image = RenderSyntheticHole(hole);
    const CircleMeasurement m =
        MeasureCircle(image, hole.centre_px + Eigen::Vector2d(3.0, -2.0), radius);
    ASSERT_TRUE(m.ok) << m.error;
    std::printf("r %.0f: error (%.4f, %.4f) px, radius %+.4f px; %s\n", radius,
                m.centre_px.x() - hole.centre_px.x(), m.centre_px.y() - hole.centre_px.y(),
                m.radius_px - radius, m.Brief().c_str());
    EXPECT_LT((m.centre_px - hole.centre_px).norm(), 0.01) << radius;
    EXPECT_NEAR(m.radius_px, radius, 0.01) << radius;
  }
}

// The expected centre may be off by a quarter of the diameter plus a few px.
TEST(CircleMeasure, FoundFromAQuarterDiameterAway) {
  for (const double angle : {0.3, 2.0, 4.1}) {
    const SyntheticHole hole = DemoHole(30.0, 400.0, angle + 1.0, 11);
    const ImageF image = RenderSyntheticHole(hole);
    const Eigen::Vector2d off =
        (0.25 * 60.0 + 4.0) * Eigen::Vector2d(std::cos(angle), std::sin(angle));
    const CircleMeasurement m = MeasureCircle(image, hole.centre_px + off, 30.0);
    ASSERT_TRUE(m.ok) << m.error;
    EXPECT_LT((m.centre_px - hole.centre_px).norm(), 0.05) << angle;
  }
}

// Many seeded draws of texture and noise, holes of three sizes at random
// places under the camera: the errors against the truth scatter as the
// reported covariance says (standard deviation of error / sigma within
// [0.8, 1.25], 200 draws: the sample standard deviation itself is good to
// ~5 %), and are small. With `given_nadir`, MeasureCircle is told the
// camera's nadir (as the measure stage does) and models the bottom rim
// about it. With `max_cut_fraction`, each picture is a partial view: its
// pixels beyond a chord in a random direction are uncovered (0), the chord
// cutting off a uniform fraction up to that of the rim, and the fit may
// leave that much uncovered (hole_views.h: kPartialViewMaxUncovered).
void ExpectScatterMatchesCovariance(bool given_nadir, double max_cut_fraction = 0.0) {
  std::mt19937_64 rng(2024);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::vector<double> z[3];
  double sum2_centre = 0.0, sum_radius = 0.0, sum2_radius = 0.0;
  int draws = 0;
  for (int k = 0; k < 210; ++k) {
    const double radius = std::vector<double>{20.0, 40.0, 80.0}[k % 3] * (1.0 + 0.1 * uniform(rng));
    // Hole centres uniform over a disc of 700 px (105 mm) about the axis.
    SyntheticHole hole = DemoHole(radius, 700.0 * std::sqrt(uniform(rng)),
                                  2 * std::numbers::pi * uniform(rng), 100 + k);
    hole.centre_px += Eigen::Vector2d(uniform(rng), uniform(rng));
    hole.texture_offset_mm = Eigen::Vector2d(200.0 * uniform(rng), 200.0 * uniform(rng));
    CircleMeasureOptions options;
    if (max_cut_fraction > 0.0) {
      // A chord at distance r cos(pi f) from the centre cuts off f of the rim.
      const double direction = 2 * std::numbers::pi * uniform(rng);
      hole.uncovered_normal = Eigen::Vector2d(std::cos(direction), std::sin(direction));
      hole.uncovered_offset_px =
          hole.uncovered_normal.dot(hole.centre_px) +
          hole.radius_px * std::cos(std::numbers::pi * max_cut_fraction * uniform(rng));
      options.max_uncovered_fraction = max_cut_fraction + 0.1;  // the rays reach past the rim
    }
    const ImageF image = RenderSyntheticHole(hole);
    const Eigen::Vector2d guess =
        hole.centre_px + 0.2 * radius * Eigen::Vector2d(uniform(rng) - 0.5, uniform(rng) - 0.5);
    // DemoHole's bottom rim: shifted by kDepthRatio of the way to the nadir.
    std::optional<Eigen::Vector2d> nadir;
    if (given_nadir) nadir = hole.centre_px + hole.bottom_shift_px / kDepthRatio;
    const CircleMeasurement m = MeasureCircle(image, guess, std::round(radius), options, nadir);
    ASSERT_TRUE(m.ok) << k << ": " << m.error;
    const Eigen::Vector3d error(m.centre_px.x() - hole.centre_px.x(),
                                m.centre_px.y() - hole.centre_px.y(), m.radius_px - hole.radius_px);
    for (int i = 0; i < 3; ++i) z[i].push_back(error(i) / Sigma(m, i));
    sum2_centre += error.head<2>().squaredNorm();
    sum_radius += error(2);
    sum2_radius += error(2) * error(2);
    ++draws;
  }
  const char* names[3] = {"cx", "cy", "r"};
  for (int i = 0; i < 3; ++i) {
    double mean = 0.0, sum2 = 0.0;
    for (double v : z[i]) mean += v / draws;
    for (double v : z[i]) sum2 += (v - mean) * (v - mean);
    const double sd = std::sqrt(sum2 / (draws - 1));
    std::printf("%s: error / sigma mean %+.3f, sd %.3f\n", names[i], mean, sd);
    EXPECT_GE(sd, 0.8) << names[i];
    EXPECT_LE(sd, 1.25) << names[i];
  }
  const double centre_rms = std::sqrt(sum2_centre / (2 * draws));
  const double radius_mean = sum_radius / draws, radius_rms = std::sqrt(sum2_radius / draws);
  std::printf("centre rms %.4f px per axis, radius mean %+.4f rms %.4f px\n", centre_rms,
              radius_mean, radius_rms);
  if (max_cut_fraction > 0.0) return;  // an arc places the circle less well, as its covariance says
  EXPECT_LT(centre_rms, 0.02);
  EXPECT_LT(radius_rms, 0.02);
}

TEST(CircleMeasure, CovarianceMatchesTheScatter) { ExpectScatterMatchesCovariance(false); }

TEST(CircleMeasure, CovarianceMatchesTheScatterGivenTheNadir) {
  ExpectScatterMatchesCovariance(true);
}

// Partial views (hole_views.h), up to 40 % of the rim uncovered: the
// covariance still says how their errors scatter (measured: sd 1.04, 0.99,
// 1.08; centre 0.021 px rms per axis, radius 0.018, against 0.016 and 0.013
// for whole views).
TEST(CircleMeasure, CovarianceOfAPartialViewMatchesTheScatter) {
  ExpectScatterMatchesCovariance(true, 0.4);
}

// The bore wall inside the rim, as a ring (the camera's axis through the
// hole) or a crescent (the axis farther away), does not bias the radius or
// the centre: only the outermost step is the rim, and where the wall is
// narrow its inner edge is modelled. Flat surface and noise, so what is
// left is the wall's effect. Walls more than 2 blur sigmas wide are
// resolved (the ring of this radius is 2.3 px = 2.9 sigma); narrower rings
// are not (header).
TEST(CircleMeasure, BoreWallDoesNotBiasTheFit) {
  double worst_centre = 0.0, worst_radius = 0.0;
  for (const double axis : {0.0, 80.0, 200.0, 800.0}) {
    for (int k = 0; k < 3; ++k) {
      SyntheticHole hole = DemoHole(80.0, axis, 2.1 * k + 0.4, 5 + k);
      hole.texture_seed.reset();
      hole.centre_px += Eigen::Vector2d(0.37 * k, -0.21 * k);
      const ImageF image = RenderSyntheticHole(hole);
      const CircleMeasurement m =
          MeasureCircle(image, hole.centre_px + Eigen::Vector2d(4.0, 2.0), 80.0);
      ASSERT_TRUE(m.ok) << m.error;
      // The noise alone scatters each coordinate by sigma ~0.0035 px: 0.015
      // px is the 1e-4 quantile of the centre's 2-D error, 0.01 px 4 sigma of
      // the radius (sigma ~0.0025 px).
      EXPECT_LT((m.centre_px - hole.centre_px).norm(), 0.015) << axis << " " << k;
      EXPECT_NEAR(m.radius_px, hole.radius_px, 0.01) << axis << " " << k;
      worst_centre = std::max(worst_centre, (m.centre_px - hole.centre_px).norm());
      worst_radius = std::max(worst_radius, std::abs(m.radius_px - hole.radius_px));
    }
  }
  std::printf("worst: centre %.4f px, radius %.4f px\n", worst_centre, worst_radius);
}

// A hole of radius r at a random sub-pixel place in a frame 40 px wider,
// seen from a nadir `nadir_distance` px away in a random direction
// (returned in *nadir): its bottom rim is the top rim scaled by k about it.
SyntheticHole HoleWithBore(double radius_px, double k, double nadir_distance_px,
                           std::mt19937_64* rng, Eigen::Vector2d* nadir) {
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  SyntheticHole hole;
  hole.width_px = hole.height_px = static_cast<int>(2 * radius_px + 40);
  const double dx = uniform(*rng), dy = uniform(*rng);
  hole.centre_px = Eigen::Vector2d::Constant(0.5 * hole.width_px) + Eigen::Vector2d(dx, dy);
  hole.radius_px = radius_px;
  hole.bottom_radius_px = k * radius_px;
  const double angle = 2 * std::numbers::pi * uniform(*rng);
  *nadir = hole.centre_px + nadir_distance_px * Eigen::Vector2d(std::cos(angle), std::sin(angle));
  hole.bottom_shift_px = (1.0 - k) * (*nadir - hole.centre_px);
  return hole;
}

// `hole` rendered with the simulator's blur (0.8 px) and sensor noise at the
// surface's level (shot noise of 0.5 x 12000 electrons: 0.0065), its texture
// and noise drawn from `seed`, the texture at a random place.
ImageF RenderWithSensorNoise(SyntheticHole hole, std::uint64_t seed, std::mt19937_64* rng) {
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  hole.texture_seed = seed;
  hole.texture_offset_mm = Eigen::Vector2d(200.0 * uniform(*rng), 200.0 * uniform(*rng));
  hole.psf_sigma_px = 0.8;
  hole.noise_sigma = 0.0065;
  hole.noise_seed = seed;
  return RenderSyntheticHole(hole);
}

// demo-101's hole_13 (60 mm at 0.15 mm per px: r = 200 px) with the nadir
// of the tile that renders it 0.97 r from its centre, the 10 mm part seen
// from 385 mm (k = 0.9746): the wall shows (1 - k)(r - D cos a) wide, under
// 2.5 blurs (2 px) over 100 degrees of the rim on the nadir's side, where it
// merges with the rim. Given the nadir, those wedges are left out.
// Bound, from issue 5 (every diameter and distance within 0.05 raw px; raw
// px = source_px = 0.96 px here): with sigma 0.011 raw px (hole_13's
// diameter) a measurement stays within 0.05 raw px at 3.3 sigma (1 in 1000)
// only if its bias is under 0.014 raw px = 0.0134 px. The mean errors over
// 30 seeded textures (standard error ~0.002 px) must be under that: the
// diameter and the centre along the nadir's direction, which enters a
// distance. Without the nadir: -0.023 px and -0.020 px; with it -0.009
// and -0.007 px.
TEST(CircleMeasure, NarrowWallNearTheNadirDoesNotBiasTheFit) {
  constexpr double kRadius = 200.0, kScale = 0.9746, kNadirDistance = 0.97 * kRadius;
  constexpr double kBiasBoundPx = 0.0134;
  constexpr int kDraws = 30;
  std::mt19937_64 rng(2026);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  double sum_along = 0.0, sum_diameter = 0.0, sum_z2_along = 0.0, sum_z2_radius = 0.0;
  int narrow = 0;
  for (int k = 0; k < kDraws; ++k) {
    Eigen::Vector2d nadir;
    SyntheticHole hole = HoleWithBore(kRadius, kScale, kNadirDistance, &rng, &nadir);
    const Eigen::Vector2d to_nadir = (nadir - hole.centre_px).normalized();
    hole.texture_seed = 300 + k;
    hole.texture_offset_mm = Eigen::Vector2d(200.0 * uniform(rng), 200.0 * uniform(rng));
    hole.psf_sigma_px = kPsfPx;
    hole.noise_sigma = kNoise;
    hole.noise_seed = 300 + k;
    const CircleMeasurement m =
        MeasureCircle(RenderSyntheticHole(hole), hole.centre_px, kRadius, {}, nadir);
    ASSERT_TRUE(m.ok) << k << ": " << m.error;
    EXPECT_NEAR(m.bottom_rim_scale, kScale, 1e-3) << k;
    EXPECT_TRUE(m.narrow_wall_skipped) << k;
    narrow += m.num_narrow_wall;
    const double along = (m.centre_px - hole.centre_px).dot(to_nadir);
    const double sigma_along =
        std::sqrt(to_nadir.dot(m.covariance_px2.topLeftCorner<2, 2>() * to_nadir));
    sum_along += along;
    sum_diameter += 2.0 * (m.radius_px - kRadius);
    sum_z2_along += std::pow(along / sigma_along, 2);
    sum_z2_radius += std::pow((m.radius_px - kRadius) / Sigma(m, 2), 2);
  }
  const double mean_along = sum_along / kDraws, mean_diameter = sum_diameter / kDraws;
  std::printf(
      "mean errors: centre along the nadir %+.4f px, diameter %+.4f px; rms z %.2f, %.2f; "
      "%.0f narrow-wall wedges per hole\n",
      mean_along, mean_diameter, std::sqrt(sum_z2_along / kDraws),
      std::sqrt(sum_z2_radius / kDraws), static_cast<double>(narrow) / kDraws);
  EXPECT_LT(std::abs(mean_along), kBiasBoundPx);
  EXPECT_LT(std::abs(mean_diameter), kBiasBoundPx);
}

// lmp-206's hole_14 (issue 5's worst small hole: diameter -0.098 raw px,
// z -3.1): an 8 mm hole (r = 26.75 px) 570 px from the nadir of the only
// tile that sees it, the 16 mm part seen from 387 mm (k = 0.9603). The bore
// wall is a crescent up to 24 px wide over 270 degrees of the rim, beyond
// the fit's reach, so its bottom rim is not resolved and k is not fitted;
// it narrows below 2.5 blurs only near its two cusps. The noise is the
// simulator's sensor at the surface's level (shot noise of 0.5 x 12000
// electrons: 0.0065), twice DemoHole's. Over 30 textures the radius must be
// unbiased (mean within 0.01 px: 3 standard errors of the mean, the draws'
// rms being ~0.02 px) and scatter as its sigma says (rms error / sigma
// under 1.4: the rms of 30 draws is good to ~13 %). The real hole's error
// is a tail of that scatter, not the wall: refitted with the true k its
// radius moved by 0.0005 px, and its edges sat inside the true rim by the
// same ~0.04 px on the crescent's and on the hidden side.
TEST(CircleMeasure, WideCrescentFarFromTheNadirDoesNotBiasTheFit) {
  constexpr double kRadius = 26.75, kScale = 0.9603, kNadirDistance = 570.0;
  constexpr int kDraws = 30;
  std::mt19937_64 rng(2027);
  double sum = 0.0, sum2 = 0.0, sum_z2 = 0.0;
  for (int k = 0; k < kDraws; ++k) {
    Eigen::Vector2d nadir;
    const SyntheticHole hole = HoleWithBore(kRadius, kScale, kNadirDistance, &rng, &nadir);
    const CircleMeasurement m =
        MeasureCircle(RenderWithSensorNoise(hole, 700 + k, &rng),
                      hole.centre_px + Eigen::Vector2d(1.0, -1.0), std::round(kRadius), {}, nadir);
    ASSERT_TRUE(m.ok) << k << ": " << m.error;
    const double error = m.radius_px - kRadius;
    sum += error;
    sum2 += error * error;
    sum_z2 += std::pow(error / Sigma(m, 2), 2);
  }
  const double mean = sum / kDraws, rms = std::sqrt(sum2 / kDraws);
  const double rms_z = std::sqrt(sum_z2 / kDraws);
  std::printf("radius error mean %+.4f px, rms %.4f px, rms z %.2f\n", mean, rms, rms_z);
  EXPECT_LT(std::abs(mean), 0.01);
  EXPECT_LT(rms_z, 1.4);
}

// An 8 mm hole (r = 26.75 px) seen by a camera whose axis passes near it
// (k = 0.97, blur 0.8 px, the simulator's sensor noise as in
// WideCrescentFarFromTheNadirDoesNotBiasTheFit): its wall shows narrower
// than 2.5 blurs on most of the rim, where it merges with the rim's step,
// and the view resolves no bottom rim. Alone (without a prior), over 30
// textures, the radius comes out 0.18 px small with the axis through the
// centre and 0.08 px small with it 1.36 radii away (seed 217's hole_09),
// the centre 0.04 px off towards the nadir, rms error / sigma 8.8 and 2.8.
// Given the bore a resolved view measured (a 60 mm hole of the same part:
// k and the wall's level), the narrow wedges' wall is tied to the rim.
// Bounds on the means of 60 draws: the draws scatter by ~0.014 px (radius)
// and ~0.02 px (centre along the nadir's direction), standard errors of
// the means ~0.002 and ~0.0026 px; 3 of them plus the step model's known
// bias from the blur's shape (header: up to 0.01 px with synthetic_hole's
// kernel) gives 0.016 and 0.018 px. Without the prior these means are
// ~10 (radius) and ~2 (centre) times the bounds. rms error / sigma under
// 1.4 as in the crescent test.
TEST(CircleMeasure, NarrowRingNearTheAxisIsUnbiasedGivenTheBorePrior) {
  constexpr double kRadius = 26.75, kScale = 0.97;
  constexpr int kDraws = 60;
  std::mt19937_64 rng(2030);
  const auto render = [&](const SyntheticHole& hole, std::uint64_t seed) {
    return RenderWithSensorNoise(hole, seed, &rng);
  };
  // The resolved view: the wall 0 to 15 px wide, 2 blurs to 6 px on two arcs.
  Eigen::Vector2d nadir;
  const SyntheticHole large = HoleWithBore(200.0, kScale, 300.0, &rng, &nadir);
  const CircleMeasurement resolved =
      MeasureCircle(render(large, 55), large.centre_px, 200.0, {}, nadir);
  ASSERT_TRUE(resolved.ok) << resolved.error;
  EXPECT_NEAR(resolved.bottom_rim_scale, kScale, 1e-3);
  // The wall's level, wall minus table (0.12): its error e moves the tied
  // rim by ~2 e px (a 0.01 error: 0.02 px), so it must hold to ~0.005.
  EXPECT_NEAR(resolved.wall_contrast, large.wall - large.table, 0.005);
  const BorePrior prior{resolved.bottom_rim_scale, resolved.wall_contrast};
  for (const double axis_radii : {0.0, 1.36}) {
    double sum_radius = 0.0, sum_along = 0.0, sum_z2_radius = 0.0, sum_z2_along = 0.0;
    for (int k = 0; k < kDraws; ++k) {
      const SyntheticHole hole = HoleWithBore(kRadius, kScale, axis_radii * kRadius, &rng, &nadir);
      const CircleMeasurement m =
          MeasureCircle(render(hole, 900 + k), hole.centre_px + Eigen::Vector2d(1.0, -1.0),
                        std::round(kRadius), {}, nadir, prior);
      ASSERT_TRUE(m.ok) << axis_radii << " " << k << ": " << m.error;
      EXPECT_TRUE(m.bore_prior_used) << axis_radii << " " << k;
      const Eigen::Vector2d to_nadir =
          axis_radii > 0.0 ? (nadir - hole.centre_px).normalized() : Eigen::Vector2d(1.0, 0.0);
      const double along = (m.centre_px - hole.centre_px).dot(to_nadir);
      const double sigma_along =
          std::sqrt(to_nadir.dot(m.covariance_px2.topLeftCorner<2, 2>() * to_nadir));
      sum_radius += m.radius_px - kRadius;
      sum_along += along;
      sum_z2_radius += std::pow((m.radius_px - kRadius) / Sigma(m, 2), 2);
      sum_z2_along += std::pow(along / sigma_along, 2);
    }
    const double mean_radius = sum_radius / kDraws, mean_along = sum_along / kDraws;
    const double rms_z_radius = std::sqrt(sum_z2_radius / kDraws);
    const double rms_z_along = std::sqrt(sum_z2_along / kDraws);
    std::printf(
        "axis %.2f radii: mean errors radius %+.4f px, centre along %+.4f px; rms z %.2f, "
        "%.2f\n",
        axis_radii, mean_radius, mean_along, rms_z_radius, rms_z_along);
    EXPECT_LT(std::abs(mean_radius), 0.016) << axis_radii;
    EXPECT_LT(std::abs(mean_along), 0.018) << axis_radii;
    EXPECT_LT(rms_z_radius, 1.4) << axis_radii;
    EXPECT_LT(rms_z_along, 1.4) << axis_radii;
  }
}

// Some views of a hole near the axis fit a bottom rim of their own: on
// synthetic 40 px holes (demo-281's 12 mm hole_03, k 0.98, its ring 0.8 px
// wide) 13 of 180 views did, from 12-16 wedges, with k 0.74-0.81 (texture
// taken for a wall) where the truth is 0.98, and read the radius 0.13-0.21
// px small (mean -0.16 px; the hole in demo-281 -0.08 px, 4.6 of its
// diameter's sigma). Given the BorePrior, the prior's narrow wall decides:
// every view is tied to it, and those views' mean radius error is within
// the bound of NarrowRingNearTheAxisIsUnbiasedGivenTheBorePrior.
TEST(CircleMeasure, NarrowRingNearTheAxisTrustsThePriorOverItsOwnBottomRim) {
  constexpr double kRadius = 40.0, kScale = 0.98;
  constexpr int kDraws = 60;
  std::mt19937_64 rng(2031);
  Eigen::Vector2d nadir;
  const SyntheticHole large = HoleWithBore(200.0, kScale, 300.0, &rng, &nadir);
  const CircleMeasurement resolved =
      MeasureCircle(RenderWithSensorNoise(large, 55, &rng), large.centre_px, 200.0, {}, nadir);
  ASSERT_TRUE(resolved.ok) << resolved.error;
  const BorePrior prior{resolved.bottom_rim_scale, resolved.wall_contrast};
  double sum_own = 0.0, sum_z2_own = 0.0;
  int num_own = 0;
  for (const double axis_radii : {0.0, 0.3, 0.6}) {
    for (int k = 0; k < kDraws; ++k) {
      const SyntheticHole hole = HoleWithBore(kRadius, kScale, axis_radii * kRadius, &rng, &nadir);
      const CircleMeasurement m =
          MeasureCircle(RenderWithSensorNoise(hole, 900 + k, &rng),
                        hole.centre_px + Eigen::Vector2d(1.0, -1.0), kRadius, {}, nadir, prior);
      ASSERT_TRUE(m.ok) << axis_radii << " " << k << ": " << m.error;
      EXPECT_TRUE(m.bore_prior_used) << axis_radii << " " << k;
      if (!m.bottom_rim_modelled) continue;  // no bottom rim of its own
      ++num_own;
      sum_own += m.radius_px - kRadius;
      sum_z2_own += std::pow((m.radius_px - kRadius) / Sigma(m, 2), 2);
    }
  }
  ASSERT_GE(num_own, 5) << "too few views fitted a bottom rim of their own to tell";
  std::printf("%d views with their own bottom rim: mean radius error %+.4f px, rms z %.2f\n",
              num_own, sum_own / num_own, std::sqrt(sum_z2_own / num_own));
  EXPECT_LT(std::abs(sum_own / num_own), 0.016);
  EXPECT_LT(std::sqrt(sum_z2_own / num_own), 1.4);
}

// A borrowed wall level that is off (here by 0.02, a sixth of the level)
// moves the tied rim by ~2 px per unit of level: radius +0.04 px, several
// of its edge sigmas. Given the level's sigma, the covariance carries that
// term and covers the error; without it the errors are far outside.
TEST(CircleMeasure, TheBorrowedWallLevelsSigmaCoversItsError) {
  constexpr double kRadius = 26.75, kScale = 0.97, kWallError = 0.02;
  constexpr int kDraws = 30;
  std::mt19937_64 rng(2032);
  double z2_plain = 0.0, z2_radius = 0.0, z2_centre = 0.0;
  for (int k = 0; k < kDraws; ++k) {
    Eigen::Vector2d nadir;
    const SyntheticHole hole = HoleWithBore(kRadius, kScale, 1.36 * kRadius, &rng, &nadir);
    const ImageF image = RenderWithSensorNoise(hole, 1200 + k, &rng);
    const double level = hole.wall - hole.table + kWallError;
    const Eigen::Vector2d start = hole.centre_px + Eigen::Vector2d(1.0, -1.0);
    const CircleMeasurement plain =
        MeasureCircle(image, start, std::round(kRadius), {}, nadir, BorePrior{kScale, level, 0.0});
    const CircleMeasurement m = MeasureCircle(image, start, std::round(kRadius), {}, nadir,
                                              BorePrior{kScale, level, kWallError});
    ASSERT_TRUE(plain.ok && m.ok) << k;
    ASSERT_TRUE(m.bore_prior_used) << k;
    // Same fit, wider covariance.
    EXPECT_EQ(m.centre_px, plain.centre_px);
    EXPECT_EQ(m.radius_px, plain.radius_px);
    const Eigen::Vector2d to_nadir = (nadir - hole.centre_px).normalized();
    const double along = (m.centre_px - hole.centre_px).dot(to_nadir);
    z2_plain += std::pow((plain.radius_px - kRadius) / Sigma(plain, 2), 2);
    z2_radius += std::pow((m.radius_px - kRadius) / Sigma(m, 2), 2);
    z2_centre += std::pow(
        along / std::sqrt(to_nadir.dot(m.covariance_px2.topLeftCorner<2, 2>() * to_nadir)), 2);
  }
  const double plain_z = std::sqrt(z2_plain / kDraws), radius_z = std::sqrt(z2_radius / kDraws),
               centre_z = std::sqrt(z2_centre / kDraws);
  std::printf("rms z of the radius: %.2f without the level's sigma, %.2f with; centre %.2f\n",
              plain_z, radius_z, centre_z);
  EXPECT_GT(plain_z, 2.0);
  EXPECT_LT(radius_z, 1.4);
  EXPECT_LT(centre_z, 1.4);
}

// The prior changes nothing where a view resolves its own bottom rim or its
// narrow wall covers less than half the rim (far from the axis): the
// results are the same to the bit.
TEST(CircleMeasure, BorePriorLeavesOtherViewsAlone) {
  std::mt19937_64 rng(2031);
  const BorePrior prior{0.95, 0.2};  // deliberately unlike the truth
  for (const auto& [radius, axis] : {std::pair{200.0, 300.0}, std::pair{26.75, 570.0}}) {
    Eigen::Vector2d nadir;
    SyntheticHole hole = HoleWithBore(radius, 0.97, axis, &rng, &nadir);
    hole.texture_seed = 77;
    hole.psf_sigma_px = 0.8;
    hole.noise_sigma = 0.0065;
    const ImageF image = RenderSyntheticHole(hole);
    const CircleMeasurement alone = MeasureCircle(image, hole.centre_px, radius, {}, nadir);
    const CircleMeasurement given = MeasureCircle(image, hole.centre_px, radius, {}, nadir, prior);
    ASSERT_TRUE(alone.ok) << alone.error;
    EXPECT_FALSE(given.bore_prior_used) << radius;
    EXPECT_EQ(given.centre_px, alone.centre_px) << radius;
    EXPECT_EQ(given.radius_px, alone.radius_px) << radius;
    EXPECT_EQ(given.covariance_px2, alone.covariance_px2) << radius;
  }
}

// Dark specks and bright burrs touching the rim, and a brightness step
// across the hole (a seam between tiles of different exposure): their
// wedges are outliers of the circle fit.
TEST(CircleMeasure, BurrsSpecksAndSeamsAreOutliers) {
  SyntheticHole hole = DemoHole(50.0, 900.0, 0.7, 31);
  const Eigen::Vector2d c = hole.centre_px;
  auto at = [&](double angle, double out) -> Eigen::Vector2d {
    return c + (50.0 + out) * Eigen::Vector2d(std::cos(angle), std::sin(angle));
  };
  hole.blobs = {{at(0.3, 2.0), 3.0, 0.08f},
                {at(1.9, 1.5), 2.0, 0.9f},
                {at(3.4, 2.5), 4.0, 0.1f},
                {at(5.0, 1.0), 1.5, 0.95f}};
  hole.seam_normal = Eigen::Vector2d(1.0, 0.3).normalized();
  hole.seam_offset_px = hole.seam_normal.dot(c) + 10.0;
  hole.seam_gain = 0.85;
  const ImageF image = RenderSyntheticHole(hole);
  const CircleMeasurement m = MeasureCircle(image, c + Eigen::Vector2d(-5.0, 6.0), 50.0);
  ASSERT_TRUE(m.ok) << m.error;
  std::printf("%s\n", m.Brief().c_str());
  // The same hole without them: within 3 sigma of it.
  hole.blobs.clear();
  hole.seam_gain = 1.0;
  const CircleMeasurement plain = MeasureCircle(RenderSyntheticHole(hole), c, 50.0);
  ASSERT_TRUE(plain.ok) << plain.error;
  for (int i = 0; i < 2; ++i) {
    EXPECT_NEAR(m.centre_px(i), hole.centre_px(i), 3.0 * Sigma(m, i)) << i;
  }
  EXPECT_NEAR(m.radius_px, hole.radius_px, 3.0 * Sigma(m, 2));
  EXPECT_LT(m.num_inliers, plain.num_inliers);
}

// A camera clips at full scale (1): where the surface beside the rim
// clips, the rim step's bright side is flat and its mid-level crossing
// moves outwards. Given which pixels are clipped, those wedges are left out
// and the rest place the hole; where most of the rim is clipped, it is
// refused. Here a gain of 2.4 beyond a line 20 px from the centre clips the
// flat surface (0.5) on 37 % of the rim.
// A camera clips at full scale: where the textured surface beside the rim
// clips, the rim step's bright side is flat and its mid-level crossing moves
// inwards. At a gain of 1.8 over 12 textures, 28-55 % of the rim's wedges
// read clipped pixels, and the radius read 0.033 px small on average against
// the same hole unclipped. Given which pixels are clipped, those wedges are
// left out: 0.010 px small, each within 1.5 of its sigma of the unclipped
// fit; a rim more than half clipped is refused.
TEST(CircleMeasure, RimNextToSaturatedPixelsIsLeftOut) {
  double given_sum = 0.0, unaware_sum = 0.0;
  int num_given = 0, num_refused = 0;
  constexpr int kTextures = 12;
  for (int k = 0; k < kTextures; ++k) {
    const SyntheticHole hole = DemoHole(50.0, 300.0, 0.7 + k, 41 + k);
    const ImageF linear = RenderSyntheticHole(hole);
    const Eigen::Vector2d start = hole.centre_px + Eigen::Vector2d(3.0, -2.0);
    const CircleMeasurement unclipped = MeasureCircle(linear, start, 50.0);
    ASSERT_TRUE(unclipped.ok) << unclipped.error;
    ImageF image = linear * 1.8f;
    const ImageMask saturated = (image.array() >= 1.0f).cast<std::uint8_t>();
    image = image.cwiseMin(1.0f);
    const CircleMeasurement given =
        MeasureCircle(image, start, 50.0, {}, std::nullopt, std::nullopt, &saturated);
    const CircleMeasurement unaware = MeasureCircle(image, start, 50.0);
    ASSERT_TRUE(unaware.ok) << unaware.error;
    EXPECT_EQ(unaware.num_saturated, 0);
    unaware_sum += unaware.radius_px - unclipped.radius_px;
    std::printf(
        "texture %d: %d of %d wedges next to clipped pixels; radius %+.4f px given them, "
        "%+.4f unaware\n",
        k, given.num_saturated, given.num_wedges, given.radius_px - unclipped.radius_px,
        unaware.radius_px - unclipped.radius_px);
    if (!given.ok) {
      EXPECT_GT(given.num_saturated, 0.5 * given.num_wedges) << given.error;
      EXPECT_EQ(given.error.rfind("rim saturated", 0), 0u) << given.error;
      ++num_refused;
      continue;
    }
    EXPECT_GT(given.num_saturated, 0);
    EXPECT_LT(std::abs(given.radius_px - unclipped.radius_px), 1.5 * Sigma(given, 2)) << k;
    given_sum += given.radius_px - unclipped.radius_px;
    ++num_given;
  }
  ASSERT_GE(num_given, kTextures / 2);
  EXPECT_GE(num_refused, 1);
  const double given_bias = given_sum / num_given, unaware_bias = unaware_sum / kTextures;
  std::printf(
      "radius against the unclipped: %+.4f px given the clipped pixels (%d fits), %+.4f "
      "unaware\n",
      given_bias, num_given, unaware_bias);
  EXPECT_LT(std::abs(given_bias), 0.4 * std::abs(unaware_bias));
}

// A hole reaching into the mosaic's uncovered area (pixels exactly 0) is
// reported as cut, not fitted to the rest of its rim; uncovered pixels
// farther out do not matter.
TEST(CircleMeasure, CutByTheBorderIsAnError) {
  SyntheticHole hole = DemoHole(40.0, 300.0, 1.0, 41);
  hole.uncovered_normal = Eigen::Vector2d(0.6, 0.8);
  hole.uncovered_offset_px = hole.uncovered_normal.dot(hole.centre_px) + 30.0;
  CircleMeasurement m = MeasureCircle(RenderSyntheticHole(hole), hole.centre_px, 40.0);
  EXPECT_FALSE(m.ok);
  EXPECT_NE(m.error.find("cut by the mosaic border"), std::string::npos) << m.error;

  hole.uncovered_offset_px = hole.uncovered_normal.dot(hole.centre_px) + 52.0;
  m = MeasureCircle(RenderSyntheticHole(hole), hole.centre_px, 40.0);
  EXPECT_TRUE(m.ok) << m.error;
}

// ReachPx bounds the pixels a fit reads beyond its circle (what a tile must
// cover for its view of a hole: TilesSeeingDisc, hole_views.cc): with every
// pixel beyond it uncovered, about a known centre (a hole's views after the
// first), the fit is the same to the last bit; at the 8 px that
// hole_views.cc took before, the rays' ends read uncovered pixels, and two
// tiles of the reference projects that counted as seeing a hole whole failed
// as "cut by the mosaic border (2 % / 7 % of the rim not covered)".
TEST(CircleMeasure, ReachPxBoundsThePixelsAFitReads) {
  CircleMeasureOptions options;
  options.search_fraction = 0.0;
  const double radius = 40.0;
  // Off the axes (where a sample's 2 x 2 block reaches farthest out).
  for (const Eigen::Vector2d& normal :
       {Eigen::Vector2d(0.6, -0.8), Eigen::Vector2d(std::sqrt(0.5), std::sqrt(0.5))}) {
    SyntheticHole hole = DemoHole(radius, 300.0, 1.0, 43);
    const CircleMeasurement covered =
        MeasureCircle(RenderSyntheticHole(hole), hole.centre_px, radius, options);
    ASSERT_TRUE(covered.ok) << covered.error;
    hole.uncovered_normal = normal;
    hole.uncovered_offset_px = normal.dot(hole.centre_px) + radius + options.ReachPx();
    const CircleMeasurement beyond =
        MeasureCircle(RenderSyntheticHole(hole), hole.centre_px, radius, options);
    ASSERT_TRUE(beyond.ok) << beyond.error;
    EXPECT_EQ(beyond.num_uncovered, 0);
    EXPECT_EQ(beyond.centre_px, covered.centre_px);
    EXPECT_EQ(beyond.radius_px, covered.radius_px);

    hole.uncovered_offset_px = normal.dot(hole.centre_px) + radius + options.ReachPx() - 2.0;
    const CircleMeasurement nearer =
        MeasureCircle(RenderSyntheticHole(hole), hole.centre_px, radius, options);
    EXPECT_GT(nearer.num_uncovered, 0);
  }
}

// Uncovered pixels deep inside a hole (a gap in the tiles' cover that only
// its interior falls in) cut the inner end of the rays that cross them; the
// rest of each ray, out to the rim and beyond, is fitted as before.
TEST(CircleMeasure, UncoveredPixelsDeepInsideTheHoleDoNotMatter) {
  for (const double radius : {40.0, 120.0}) {
    const SyntheticHole hole = DemoHole(radius, 300.0, 1.0, 61);
    ImageF image = RenderSyntheticHole(hole);
    const CircleMeasurement covered = MeasureCircle(image, hole.centre_px, radius);
    ASSERT_TRUE(covered.ok) << covered.error;
    // The rays reach in to half the radius inside the rim (at most 30 px):
    // the gap covers their inner 40-60 %.
    const double gap_radius = radius - 0.7 * std::min(0.5 * radius, 30.0);
    int num_gap = 0;
    for (int y = 0; y < image.rows(); ++y) {
      for (int x = 0; x < image.cols(); ++x) {
        if ((Eigen::Vector2d(x, y) - hole.centre_px).norm() < gap_radius) {
          image(y, x) = 0.0f;
          ++num_gap;
        }
      }
    }
    const CircleMeasurement m = MeasureCircle(image, hole.centre_px, radius);
    ASSERT_TRUE(m.ok) << m.error;
    std::printf("r %.0f, gap r %.1f (%d px): centre moved (%.5f, %.5f) px, radius %+.5f px; %s\n",
                radius, gap_radius, num_gap, m.centre_px.x() - covered.centre_px.x(),
                m.centre_px.y() - covered.centre_px.y(), m.radius_px - covered.radius_px,
                m.Brief().c_str());
    EXPECT_EQ(m.num_uncovered, 0);
    EXPECT_LT((m.centre_px - covered.centre_px).norm(), 0.1 * Sigma(covered, 0));
    EXPECT_LT(std::abs(m.radius_px - covered.radius_px), 0.1 * Sigma(covered, 2));
  }
}

// No hole where one is expected: textured surface only, or a hole of
// another size.
TEST(CircleMeasure, MissingHoleIsNotFound) {
  SyntheticHole hole = DemoHole(40.0, 300.0, 1.0, 51);
  hole.width_px = hole.height_px = 200;
  hole.centre_px = {100.0, 100.0};
  hole.radius_px = hole.bottom_radius_px = 0.0;
  CircleMeasurement m = MeasureCircle(RenderSyntheticHole(hole), hole.centre_px, 40.0);
  EXPECT_FALSE(m.ok);
  EXPECT_NE(m.error.find("not found"), std::string::npos) << m.error;

  hole = DemoHole(30.0, 300.0, 1.0, 52);
  hole.width_px = hole.height_px = 200;
  hole.centre_px = {100.0, 100.0};
  m = MeasureCircle(RenderSyntheticHole(hole), hole.centre_px, 40.0);
  EXPECT_FALSE(m.ok);
  EXPECT_NE(m.error.find("not found"), std::string::npos) << m.error;
}

}  // namespace
}  // namespace omm
