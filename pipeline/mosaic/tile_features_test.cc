// The feature kernels against exact answers: Harris on a rotationally
// symmetric blob (its corner is the blob's centre by symmetry), the cubic
// B-spline's interpolation of the pixels and reproduction of linear ramps, and
// box downsampling.
#include "pipeline/mosaic/tile_features.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <random>

#include <gtest/gtest.h>

#include "pipeline/core/cubic_bspline.h"

namespace omm {
namespace {

// A Gaussian blob (sigma 1.2 px) centred at (cx, cy): rotationally
// symmetric, so Harris' response is too and peaks at the centre (the window
// isotropic there, anisotropic elsewhere).
ImageF Blob(int rows, int cols, double cx, double cy) {
  ImageF image(rows, cols);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c)
      image(r, c) = static_cast<float>(
          std::exp(-0.5 * ((c - cx) * (c - cx) + (r - cy) * (r - cy)) / (1.2 * 1.2)));
  return image;
}

// A constant frame is blank; sensor noise of an 8-bit step is content, and
// so is a tile 95 % of which is a uniform dark table.
TEST(BlankImageLevel, ConstantFramesOnly) {
  ImageF image = ImageF::Constant(120, 160, 0.5f);
  const std::optional<double> level = BlankImageLevel(image);
  ASSERT_TRUE(level.has_value());
  EXPECT_FLOAT_EQ(*level, 0.5f);
  std::mt19937 rng(3);
  std::normal_distribution<float> noise(0.0f, 1.0f / 255.0f);
  ImageF noisy = image;
  for (Eigen::Index i = 0; i < noisy.size(); ++i) noisy.data()[i] += noise(rng);
  EXPECT_FALSE(BlankImageLevel(noisy).has_value());
  ImageF table = ImageF::Constant(120, 160, 0.02f);
  table.rightCols(8) = noisy.rightCols(8);  // 5 % of the columns show the part
  EXPECT_FALSE(BlankImageLevel(table).has_value());
}

TEST(SaturatedFraction, CountsPixelsAtFullScale) {
  ImageF image = ImageF::Constant(100, 200, 0.999f);
  EXPECT_EQ(SaturatedFraction(image), 0.0);
  image.topRows(25).setConstant(1.0f);
  EXPECT_DOUBLE_EQ(SaturatedFraction(image), 0.25);
  EXPECT_EQ(SaturatedFraction(ImageF()), 0.0);
}

TEST(DetectHarrisCorners, BlobAtItsCentre) {
  const Eigen::Vector2d centre(99.3, 100.2);
  const ImageF image = Blob(200, 200, centre.x(), centre.y());
  HarrisOptions options;
  options.min_texture_std = 0;  // a lone blob in a flat image: the geometry only
  const std::vector<Corner> corners = DetectHarrisCorners(image, options);
  ASSERT_FALSE(corners.empty());
  const Corner& best = corners.front();
  EXPECT_EQ(best.pixel, Eigen::Vector2i(99, 100));  // the nearest pixel
  // The 3 x 3 quadratic fit of the sampled response: bias well below 0.1 px.
  EXPECT_LT((best.q_px - centre).norm(), 0.1) << best.q_px.transpose();
  // Nothing else: one peak.
  for (const Corner& c : corners)
    EXPECT_LE((c.q_px - best.q_px).norm(), options.nms_radius_px + 1.0) << c.q_px.transpose();
}

TEST(DetectHarrisCorners, BucketingKeepsAtMostMaxPerCell) {
  // A grid of junctions every 16 px: 4 x 4 per 64 px cell, at most 3 kept.
  ImageF image(256, 256);
  for (int r = 0; r < 256; ++r)
    for (int c = 0; c < 256; ++c) image(r, c) = (((c / 16) + (r / 16)) % 2) ? 1.0f : -1.0f;
  image = GaussianBlur(image, 1.0);  // resolved gradients
  HarrisOptions options;
  const std::vector<Corner> corners = DetectHarrisCorners(image, options);
  std::vector<int> count(16, 0);
  for (const Corner& c : corners) {
    ++count[(c.pixel.y() / 64) * 4 + c.pixel.x() / 64];
    // Every corner is a junction, at the 16 px lattice's pixel boundaries
    // (15.5 + 16 k) to within the half pixel of the peak's refinement.
    const Eigen::Vector2d lattice = ((c.q_px.array() + 0.5) / 16.0).round() * 16.0 - 0.5;
    EXPECT_LE((c.q_px - lattice).cwiseAbs().maxCoeff(), 0.5 + 1e-6) << c.q_px.transpose();
  }
  for (int n : count) EXPECT_LE(n, options.max_per_cell);
  EXPECT_GE(corners.size(), 16u * 2);
}

TEST(DetectHarrisCorners, TextureTestDropsNoiseOnFlatAreas) {
  // Noise of std 0.05 everywhere (the sensor's), on a flat left half and a
  // smooth texture on the right (window std ~0.25, weak gradients): Harris
  // responds to the noise alike on both, so without the texture test the
  // flat half fills its cells with corners, with it (0.15) none are left there.
  std::mt19937 rng(5);
  std::normal_distribution<float> noise(0.0f, 0.05f);
  ImageF image(256, 256);
  for (int r = 0; r < 256; ++r)
    for (int c = 0; c < 256; ++c)
      image(r, c) =
          noise(rng) +
          (c < 128 ? 0.0f : static_cast<float>(0.7 * std::sin(0.1 * c) * std::sin(0.1 * r)));
  HarrisOptions options;
  const auto leftmost = [](const std::vector<Corner>& corners) {
    int x = 1 << 30;
    for (const Corner& c : corners) x = std::min(x, c.pixel.x());
    return x;
  };
  const std::vector<Corner> tested = DetectHarrisCorners(image, options);
  ASSERT_FALSE(tested.empty());
  // A window reaching into the texture (half size 15 px) may hold a corner.
  EXPECT_GE(leftmost(tested), 128 - options.texture_half_size_px);
  options.min_texture_std = 0;
  EXPECT_LT(leftmost(DetectHarrisCorners(image, options)), 64);
}

TEST(DetectHarrisCorners, RegionsSearchTheirCellsOnlyAndFindTheWholeImagesCornersThere) {
  // A tile overlapping its neighbours in a known L: the right strip
  // x >= 170 and the bottom strip y >= 200 (two regions meeting in the
  // corner). Searched are the 64 px cells that meet them: x >= 128 or
  // y >= 192. Texture everywhere (blurred noise), so that every cell has
  // corners; no response threshold (fraction 0), the one thing that depends
  // on the maxima outside.
  std::mt19937 rng(3);
  std::normal_distribution<float> noise(0.0f, 10.0f);  // std ~1.4 after the blur
  ImageF image(256, 320);
  for (Eigen::Index i = 0; i < image.size(); ++i) image.data()[i] = noise(rng);
  image = GaussianBlur(image, 2.0);
  HarrisOptions options;
  options.min_response_fraction = 0;
  const std::vector<Eigen::AlignedBox2i> regions = {
      {Eigen::Vector2i(170, 0), Eigen::Vector2i(319, 255)},
      {Eigen::Vector2i(0, 200), Eigen::Vector2i(400, 300)}};  // clipped to the image
  const auto searched = [](const Corner& c) { return c.pixel.x() >= 128 || c.pixel.y() >= 192; };
  const std::vector<Corner> whole = DetectHarrisCorners(image, options);
  std::vector<Corner> expected;
  for (const Corner& c : whole)
    if (searched(c)) expected.push_back(c);
  ASSERT_LT(expected.size(), whole.size());  // the whole image has corners outside
  const std::vector<Corner> found = DetectHarrisCorners(image, options, regions);
  // Corners in every cell that meets a region (4 x 5 cells, the 3 x 2 top
  // left not searched), none outside.
  std::vector<int> count(4 * 5, 0);
  for (const Corner& c : found) {
    EXPECT_TRUE(searched(c)) << c.pixel.transpose();
    ++count[(c.pixel.y() / 64) * 5 + c.pixel.x() / 64];
  }
  for (int cell = 0; cell < 4 * 5; ++cell) {
    if (cell / 5 >= 3 || cell % 5 >= 2) {
      EXPECT_GE(count[cell], 1) << cell;
    }
  }
  // The same corners, bit for bit and in the same order (R computed over
  // boxes equals R over the whole image).
  ASSERT_EQ(found.size(), expected.size());
  for (size_t k = 0; k < found.size(); ++k) {
    EXPECT_EQ(found[k].pixel, expected[k].pixel) << k;
    EXPECT_EQ(found[k].q_px, expected[k].q_px) << k;
    EXPECT_EQ(found[k].response, expected[k].response) << k;
  }
}

TEST(BSpline, InterpolatesThePixelsExactly) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-2.0f, 2.0f);
  ImageF image(40, 50);
  for (Eigen::Index i = 0; i < image.size(); ++i) image.data()[i] = u(rng);
  const ImageF coefficients = CubicBSplineCoefficients(image);
  double max_error = 0;
  for (int r = 1; r + 2 < image.rows(); ++r) {
    for (int c = 1; c + 2 < image.cols(); ++c) {
      double v;
      ASSERT_TRUE(SampleBSpline(coefficients, c, r, &v));
      max_error = std::max(max_error, std::abs(v - image(r, c)));
    }
  }
  // Float coefficients: a few float epsilons of the values' scale.
  EXPECT_LT(max_error, 2e-6);
  double v;
  EXPECT_FALSE(SampleBSpline(coefficients, 0.5, 5, &v));  // the 4 x 4 support leaves the image
}

TEST(BSpline, ReproducesALinearRampAndItsGradient) {
  // Cubic B-splines reproduce polynomials of degree <= 3; a ramp has no
  // border effect in the interior (mirroring keeps it linear near the
  // middle), so values and gradients are exact at fractional positions.
  ImageF image(60, 60);
  for (int r = 0; r < 60; ++r)
    for (int c = 0; c < 60; ++c) image(r, c) = static_cast<float>(0.3 + 0.02 * c - 0.015 * r);
  const ImageF coefficients = CubicBSplineCoefficients(image);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(20.0, 40.0);
  for (int k = 0; k < 100; ++k) {
    const double x = u(rng), y = u(rng);
    double v;
    Eigen::Vector2d g;
    ASSERT_TRUE(SampleBSpline(coefficients, x, y, &v, &g));
    EXPECT_NEAR(v, 0.3 + 0.02 * x - 0.015 * y, 1e-5);
    EXPECT_NEAR(g.x(), 0.02, 1e-5);
    EXPECT_NEAR(g.y(), -0.015, 1e-5);
  }
}

TEST(BSpline, GradientMatchesFiniteDifferences) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  ImageF image(30, 30);
  for (Eigen::Index i = 0; i < image.size(); ++i) image.data()[i] = u(rng);
  const ImageF coefficients = CubicBSplineCoefficients(image);
  // Within a cell the interpolant is a cubic along each axis, and the
  // five-point difference 8 (f(+e) - f(-e)) - (f(+2e) - f(-2e)) over 12 e is
  // exact for cubics: with all samples in the cell (fractions 0.25..0.75,
  // e = 0.1) only the float sampling's rounding (~3e-7 per value of scale ~2,
  // times 18 / (12 e) = 15) separates it from the gradient.
  std::uniform_int_distribution<int> cell(5, 24);
  std::uniform_real_distribution<double> fraction(0.25, 0.75);
  const double e = 0.1;
  const auto derivative = [&](double x, double y, double dx, double dy) {
    double f[4];
    const double k[4] = {-2, -1, 1, 2};
    for (int i = 0; i < 4; ++i)
      EXPECT_TRUE(SampleBSpline(coefficients, x + k[i] * e * dx, y + k[i] * e * dy, &f[i]));
    return (8 * (f[2] - f[1]) - (f[3] - f[0])) / (12 * e);
  };
  double max_error = 0;
  for (int k = 0; k < 50; ++k) {
    const double x = cell(rng) + fraction(rng), y = cell(rng) + fraction(rng);
    double v = 0;
    Eigen::Vector2d g;
    ASSERT_TRUE(SampleBSpline(coefficients, x, y, &v, &g));
    max_error = std::max({max_error, std::abs(g.x() - derivative(x, y, 1, 0)),
                          std::abs(g.y() - derivative(x, y, 0, 1))});
  }
  EXPECT_LT(max_error, 1e-5);
}

TEST(DownsampleBox, IsTheBlockMean) {
  ImageF image(9, 13);
  for (int r = 0; r < 9; ++r)
    for (int c = 0; c < 13; ++c) image(r, c) = static_cast<float>(r * 13 + c);
  const ImageF out = DownsampleBox(image, 3);
  ASSERT_EQ(out.rows(), 3);
  ASSERT_EQ(out.cols(), 4);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c)
      EXPECT_FLOAT_EQ(out(r, c), image.block(3 * r, 3 * c, 3, 3).mean());
}

}  // namespace
}  // namespace omm
