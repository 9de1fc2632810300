#include "pipeline/mosaic/overlap_alignment.h"

#include <cmath>
#include <numbers>
#include <random>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "pipeline/core/error.h"

namespace omm {
namespace {

// A part region as the low-texture renders show it: shading of 140-280 px
// wavelength and ~2 gray levels (8-bit) amplitude on 0.5, optionally the
// part's outer edge (a line at `edge_angle` from the columns, dark beyond),
// blurred by a Gaussian PSF. Continuous, so a shifted copy is exact.
struct Region {
  double shading = 6.0 / 255.0;  // three components of 2 gray levels
  bool edge = true;
  double edge_angle_rad = 0.12;
  double edge_col = 300.0;  // where the edge crosses row 0
  double psf_px = 0.7;
  double Value(double x, double y) const {
    static constexpr double kWavelengths[] = {140.0, 190.0, 280.0};
    static constexpr double kAngles[] = {0.3, 1.9, 4.0};
    double v = 0.5;
    for (int k = 0; k < 3; ++k) {
      const double phase = 2 * std::numbers::pi / kWavelengths[k] *
                           (std::cos(kAngles[k]) * x + std::sin(kAngles[k]) * y);
      v += shading / 3.0 * std::sin(phase + k);
    }
    if (!edge) return v;
    // Signed distance beyond the edge line, px.
    const double d = (x - edge_col - std::tan(edge_angle_rad) * y) * std::cos(edge_angle_rad);
    const double inside = 0.5 * std::erfc(d / (std::sqrt(2.0) * psf_px));
    return 0.03 + (v - 0.03) * inside;
  }
};

struct Pair {
  ImageF a, b;
};

// a sees the region at x, b at x - shift (so b's content at x + shift is
// a's at x) with a gain ramp and, relative to the level, a misfit (a
// ripple no quintic gain field holds); both with Gaussian noise of
// `noise` sigma.
Pair Render(const Region& region, const Eigen::Vector2d& shift, double noise, int seed,
            double misfit = 0.0) {
  constexpr int kWidth = 400, kHeight = 300;
  std::mt19937 random(seed);
  std::normal_distribution<double> gauss(0.0, noise);
  Pair pair{ImageF(kHeight, kWidth), ImageF(kHeight, kWidth)};
  for (int r = 0; r < kHeight; ++r) {
    for (int c = 0; c < kWidth; ++c) {
      pair.a(r, c) = static_cast<float>(region.Value(c, r) + gauss(random));
      const double ripple = misfit * std::sin(2 * std::numbers::pi * (c / 50.0 + r / 70.0));
      const double gain = (0.9 + 0.05 * c / kWidth - 0.03 * r / kHeight) * (1.0 + ripple);
      pair.b(r, c) =
          static_cast<float>(gain * region.Value(c - shift.x(), r - shift.y()) + gauss(random));
    }
  }
  return pair;
}

constexpr double kNoise = 1.7 / 255.0;  // the renders' noise

// The noise model alone (these images have no misfit).
OverlapAlignmentOptions NoMisfit() {
  OverlapAlignmentOptions options;
  options.misfit_relative = 0.0;
  return options;
}

TEST(OverlapAlignment, FindsTheShiftWithinItsStatedSigma) {
  // Over seeds, the errors scale by their stated covariance (noise only:
  // the images have no misfit) like a standard normal: it is true.
  const Region region;
  const Eigen::Vector2d truth(0.37, -0.61);
  double sum_z2 = 0.0;
  int count = 0;
  for (int seed = 0; seed < 12; ++seed) {
    const Pair pair = Render(region, truth, kNoise, seed);
    const OverlapAlignment aligned = AlignOverlap(pair.a, pair.b, ImageF(), NoMisfit());
    ASSERT_TRUE(aligned.usable) << aligned.why;
    const Eigen::Vector2d error = aligned.shift_px - truth;
    const double z2 = error.dot(aligned.covariance_px2.ldlt().solve(error));
    EXPECT_LT(z2, 13.8) << seed;  // chi2(2) 99.9 %
    sum_z2 += z2;
    ++count;
    // The edge fixes the shift across it to about the floor; along it only
    // the shading holds it, ten times more loosely.
    const Eigen::Vector2d normal(std::cos(region.edge_angle_rad), -std::sin(region.edge_angle_rad));
    const Eigen::Vector2d along(-normal.y(), normal.x());
    EXPECT_LT(std::sqrt(normal.dot(aligned.covariance_px2 * normal)), 0.015);
    EXPECT_GT(std::sqrt(along.dot(aligned.covariance_px2 * along)), 0.1);
  }
  const double rms_z = std::sqrt(sum_z2 / (2.0 * count));
  EXPECT_GT(rms_z, 0.6);
  EXPECT_LT(rms_z, 1.4);
}

TEST(OverlapAlignment, ShadingAloneFixesBothAxesLooselyButTruly) {
  Region region;
  region.edge = false;
  const Eigen::Vector2d truth(-0.2, 0.45);
  const Pair pair = Render(region, truth, kNoise, 7);
  const OverlapAlignment aligned = AlignOverlap(pair.a, pair.b, ImageF(), NoMisfit());
  ASSERT_TRUE(aligned.usable) << aligned.why;
  const Eigen::Vector2d error = aligned.shift_px - truth;
  EXPECT_LT(error.dot(aligned.covariance_px2.ldlt().solve(error)), 13.8);
  // 120 000 px of 2-gray-level shading: a tenth of a pixel or so, no better.
  EXPECT_GT(std::sqrt(aligned.covariance_px2.trace() / 2), 0.03);
  EXPECT_LT(std::sqrt(aligned.covariance_px2.trace() / 2), 0.3);
}

TEST(OverlapAlignment, SamplingEverySecondPixelKeepsTheShiftAndItsSigma) {
  // The smoothed patches vary over ~6 px: every second row and column hold
  // what every pixel does. The sampled fit's shift is within a tenth of the
  // full fit's sigma of it (0.05 at most here), its sigma per axis within
  // 5 % (1.3 % here).
  const Region region;
  OverlapAlignmentOptions every_pixel = NoMisfit(), sampled = NoMisfit();
  every_pixel.sample_stride_px = 1;
  sampled.sample_stride_px = 2;
  for (int seed = 20; seed < 24; ++seed) {
    const Pair pair = Render(region, Eigen::Vector2d(-0.8, 0.3), kNoise, seed);
    const OverlapAlignment full = AlignOverlap(pair.a, pair.b, ImageF(), every_pixel);
    const OverlapAlignment half = AlignOverlap(pair.a, pair.b, ImageF(), sampled);
    ASSERT_TRUE(full.usable && half.usable) << full.why << half.why;
    const Eigen::Vector2d moved = half.shift_px - full.shift_px;
    EXPECT_LT(std::sqrt(moved.dot(full.covariance_px2.ldlt().solve(moved))), 0.1) << seed;
    for (int axis = 0; axis < 2; ++axis) {
      EXPECT_NEAR(std::sqrt(half.covariance_px2(axis, axis) / full.covariance_px2(axis, axis)), 1.0,
                  0.05)
          << seed << " axis " << axis;
    }
    // The pixel count is the pixels' the samples stand for.
    EXPECT_NEAR(half.num_pixels, full.num_pixels, 0.01 * full.num_pixels);
  }
}

TEST(OverlapAlignment, MaskedPixelsDoNotCount) {
  // A stretch of the edge seen elsewhere in b alone (a bore's wall, seen
  // from the other side) biases the shift unless masked.
  const Region region;
  const Eigen::Vector2d truth(0.3, 0.2);
  Pair pair = Render(region, truth, kNoise, 3);
  ImageF mask = ImageF::Ones(pair.a.rows(), pair.a.cols());
  for (int r = 40; r < 200; ++r) {
    for (int c = 250; c < 380; ++c) {
      // The edge, seen 1.5 px further on in b alone (as a bore's wall moves).
      pair.b(r, c) = static_cast<float>(region.Value(c - truth.x() - 1.5, r - truth.y()));
      mask(r, c) = 0.0f;
    }
  }
  const OverlapAlignment aligned = AlignOverlap(pair.a, pair.b, mask, NoMisfit());
  ASSERT_TRUE(aligned.usable) << aligned.why;
  const Eigen::Vector2d error = aligned.shift_px - truth;
  EXPECT_LT(error.dot(aligned.covariance_px2.ldlt().solve(error)), 13.8);
  // Unmasked, the blob pulls the shift beyond its sigma.
  const OverlapAlignment unmasked = AlignOverlap(pair.a, pair.b, ImageF(), NoMisfit());
  ASSERT_TRUE(unmasked.usable) << unmasked.why;
  const Eigen::Vector2d bias = unmasked.shift_px - truth;
  EXPECT_GT(bias.dot(unmasked.covariance_px2.ldlt().solve(bias)), 13.8);
}

TEST(OverlapAlignment, TheMisfitTermCoversASmoothPhotometricMisfitOfItsSize) {
  // A ripple of 0.6 % of the level (rms 0.42 %, periods of 50-70 px) that
  // the quintic gain field cannot hold: the noise-only covariance is far too
  // tight for the shift's error; with misfit_relative at the ripple's rms it
  // covers it. The term widens the sigma along the edge more than across
  // it, where the edge still fixes the shift to a few hundredths of a pixel
  // (0.011 px from the noise alone, 0.022 with the term).
  constexpr double kRipple = 6e-3;
  const Region region;
  const Eigen::Vector2d truth(0.37, -0.61);
  const Eigen::Vector2d normal(std::cos(region.edge_angle_rad), -std::sin(region.edge_angle_rad));
  OverlapAlignmentOptions options;
  options.misfit_relative = kRipple / std::sqrt(2.0);
  double sum_noise_z2 = 0.0, sum_misfit_z2 = 0.0;
  constexpr int kSeeds = 8;
  for (int seed = 0; seed < kSeeds; ++seed) {
    const Pair pair = Render(region, truth, kNoise, seed, kRipple);
    const OverlapAlignment noise_only = AlignOverlap(pair.a, pair.b, ImageF(), NoMisfit());
    const OverlapAlignment with_misfit = AlignOverlap(pair.a, pair.b, ImageF(), options);
    ASSERT_TRUE(noise_only.usable && with_misfit.usable);
    EXPECT_EQ(noise_only.shift_px, with_misfit.shift_px);  // the covariance alone differs
    const Eigen::Vector2d error = with_misfit.shift_px - truth;
    sum_noise_z2 += error.dot(noise_only.covariance_px2.ldlt().solve(error));
    sum_misfit_z2 += error.dot(with_misfit.covariance_px2.ldlt().solve(error));
    const Eigen::Vector2d along(-normal.y(), normal.x());
    const auto sigma = [](const OverlapAlignment& a, const Eigen::Vector2d& d) {
      return std::sqrt(d.dot(a.covariance_px2 * d));
    };
    EXPECT_GT(sigma(with_misfit, along) / sigma(noise_only, along),
              sigma(with_misfit, normal) / sigma(noise_only, normal));
    EXPECT_LT(sigma(with_misfit, normal), 0.03);
  }
  EXPECT_GT(std::sqrt(sum_noise_z2 / (2.0 * kSeeds)), 2.0);  // rms z per axis
  EXPECT_LT(std::sqrt(sum_misfit_z2 / (2.0 * kSeeds)), 1.3);
}

TEST(OverlapAlignment, AFlatOverlapIsNotUsable) {
  const ImageF flat = ImageF::Constant(200, 300, 0.5f);
  const OverlapAlignment aligned = AlignOverlap(flat, flat, ImageF(), {});
  EXPECT_FALSE(aligned.usable);
  EXPECT_FALSE(aligned.why.empty());
  const ImageF unseen = ImageF::Zero(200, 300);
  EXPECT_FALSE(AlignOverlap(unseen, unseen, ImageF(), {}).usable);
}

TEST(OverlapAlignment, OptionsAreChecked) {
  OverlapAlignmentOptions options;
  EXPECT_EQ(options.Check(), "");
  options.min_pixels = 3;
  EXPECT_NE(options.Check(), "");
  options = {};
  options.sample_stride_px = 0;
  EXPECT_NE(options.Check(), "");
  EXPECT_THROW(AlignOverlap(ImageF(), ImageF(), ImageF(), options), InputError);
  EXPECT_THROW(AlignOverlap(ImageF(10, 10), ImageF(10, 11), ImageF(), {}), InputError);
}

}  // namespace
}  // namespace omm
