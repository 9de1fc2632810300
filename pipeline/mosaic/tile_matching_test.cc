// The matching kernels on images with a known motion: EstimateTranslation on
// two crops of one texture, and SearchNcc / MatchPatch on a band-limited
// texture sampled at a known sub-pixel shift (so the truth is exact).
#include "pipeline/mosaic/tile_matching.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "pipeline/mosaic/tile_features.h"

namespace omm {
namespace {

ImageF RandomTexture(int rows, int cols, double blur_px, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> n(0.0f, 1.0f);
  ImageF image(rows, cols);
  for (Eigen::Index i = 0; i < image.size(); ++i) image.data()[i] = n(rng);
  return NormalizeTileIntensity(GaussianBlur(image, blur_px));
}

TEST(EstimateTranslation, FindsAKnownShiftOfTwoCrops) {
  const ImageF big = RandomTexture(520, 700, 3.0, 5);
  // a = big at (x0, y0), b = big at (x1, y1): content at q in a is at
  // q + (x0 - x1, y0 - y1) in b. Even shifts: exact at finest_factor 2.
  for (const Eigen::Vector2i& p : {Eigen::Vector2i(240, 10), Eigen::Vector2i(20, 200),
                                   Eigen::Vector2i(150, 150)}) {
    const int x0 = 100, y0 = 100;
    const ImageF a = big.block(y0, x0, 300, 400);
    const ImageF b = big.block(p.y(), p.x(), 300, 400);
    const TranslationEstimate e = EstimateTranslation(a, b, TranslationSearchOptions());
    ASSERT_TRUE(e.ok);
    EXPECT_EQ(e.shift_px, Eigen::Vector2d(x0 - p.x(), y0 - p.y()));
    EXPECT_GT(e.ncc, 0.99);  // the same pixels at the final level
  }
}

// A sum of sinusoids below 0.2 cycles/px, sampled at (x - dx, y - dy).
ImageF Sinusoids(int rows, int cols, double dx, double dy) {
  ImageF image(rows, cols);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const double x = c - dx, y = r - dy;
      image(r, c) = static_cast<float>(std::sin(0.61 * x + 0.2 * y) + 0.7 * std::cos(0.37 * y - 0.5 * x + 1.0) +
                                       0.5 * std::sin(0.9 * y + 0.3));
    }
  }
  return image;
}

TEST(MatchPatch, RecoversAKnownSubPixelShift) {
  const ImageF reference = Sinusoids(120, 120, 0, 0);
  const Eigen::Vector2d shift(2.37, -1.62);
  const ImageF target = Sinusoids(120, 120, shift.x(), shift.y());
  const ImageF spline = BSplineCoefficients(target);
  PatchMatchOptions options;
  const Eigen::Vector2i anchor(60, 55);
  // Predicted 2 px off: the NCC search finds the integer peak, LSQ the rest.
  const PatchMatch m = MatchPatch(reference, anchor, target, spline,
                                  anchor.cast<double>() + shift + Eigen::Vector2d(1.4, -0.9),
                                  Eigen::Matrix2d::Identity(), 3, options);
  ASSERT_TRUE(m.ok);
  // Truth: the anchor's content sits at anchor + shift. The bound is the
  // B-spline's interpolation error at these frequencies (<= 0.15 cycles/px).
  EXPECT_LT((m.q_px - (anchor.cast<double>() + shift)).norm(), 2e-3);
  EXPECT_GT(m.ncc, 0.9999);

  // Radius 0 (a relocation) starts at the prediction and converges to the same point.
  const PatchMatch warm = MatchPatch(reference, anchor, target, spline, m.q_px + Eigen::Vector2d(0.2, 0.1),
                                     Eigen::Matrix2d::Identity(), 0, options);
  ASSERT_TRUE(warm.ok);
  EXPECT_LT((warm.q_px - m.q_px).norm(), 10 * options.convergence_px);
}

TEST(SearchNcc, FindsTheIntegerShiftWithNccOne) {
  const ImageF reference = RandomTexture(100, 100, 1.5, 9);
  ImageF target = ImageF::Constant(100, 100, 0.0f);
  target.block(13, 8, 80, 85) = reference.block(10, 10, 80, 85);  // content moves by (-2, +3)
  const NccPeak peak = SearchNcc(reference, {50, 50}, 7, target, {47, 54}, 4);
  ASSERT_TRUE(peak.ok);
  EXPECT_EQ(peak.pixel, Eigen::Vector2i(48, 53));
  EXPECT_NEAR(peak.ncc, 1.0, 1e-5);
  EXPECT_FALSE(SearchNcc(reference, {50, 50}, 7, target, {5, 50}, 4).ok);  // window leaves target
}

}  // namespace
}  // namespace omm
