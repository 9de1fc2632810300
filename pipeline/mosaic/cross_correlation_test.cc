// The FFT cross sums against the direct sums they stand for, on small random
// images (exact integers would hide nothing: the FFT's round-off is the point).
#include "pipeline/mosaic/cross_correlation.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

namespace omm {
namespace {

ImageF RandomImage(int rows, int cols, std::mt19937* rng) {
  std::normal_distribution<float> n(0.0f, 1.0f);
  ImageF image(rows, cols);
  for (Eigen::Index i = 0; i < image.size(); ++i) image.data()[i] = n(*rng);
  return image;
}

// sum_{r, c} a(r, c) b((r + dy) mod rows, (c + dx) mod cols), a and b
// zero-padded to rows x cols, in long double.
double DirectCyclicSum(const ImageF& a, const ImageF& b, int rows, int cols, int dx, int dy) {
  long double sum = 0;
  for (int r = 0; r < a.rows(); ++r) {
    for (int c = 0; c < a.cols(); ++c) {
      const int rb = (r + dy) % rows, cb = (c + dx) % cols;
      if (rb < b.rows() && cb < b.cols()) sum += static_cast<long double>(a(r, c)) * b(rb, cb);
    }
  }
  return static_cast<double>(sum);
}

TEST(CrossCorrelation, FftSizeIsTheNextProductOf2And3And5) {
  EXPECT_EQ(FftSize(0), 1);
  EXPECT_EQ(FftSize(1), 1);
  EXPECT_EQ(FftSize(7), 8);
  EXPECT_EQ(FftSize(91), 96);
  EXPECT_EQ(FftSize(97), 100);
  EXPECT_EQ(FftSize(121), 125);
  EXPECT_EQ(FftSize(191), 192);  // 2 * 96 - 1: EstimateImageMotion's coarsest level
}

// Every entry against the direct sum, for odd, even, prime (kissfft's generic
// radix) and non-square sizes, padded and not. Every cross sum is bounded by
// |a| |b| (Cauchy-Schwarz); the FFT's error is of order eps log2(n) of that
// (measured <= 1.6e-16 here); 1e-14 |a| |b| is 60 times the measured.
TEST(CrossCorrelation, CrossSumsEqualTheDirectCyclicSums) {
  struct Case {
    int a_rows, a_cols, b_rows, b_cols, rows, cols;
  };
  const std::vector<Case> cases = {
      {6, 8, 6, 8, 6, 8},      // even, unpadded: cyclic wrap-around
      {5, 7, 5, 7, 5, 7},      // odd, prime columns
      {5, 7, 5, 7, 9, 13},     // zero-padded to 2 n - 1: every shift's plain overlap
      {4, 9, 6, 3, 11, 12},    // different sizes, non-square, prime rows
      {12, 5, 12, 5, 24, 10},  // the padding FftSize would choose
  };
  std::mt19937 rng(7);
  double worst = 0;
  for (const Case& k : cases) {
    SCOPED_TRACE(::testing::Message() << k.a_rows << "x" << k.a_cols << " and " << k.b_rows << "x"
                                      << k.b_cols << " in " << k.rows << "x" << k.cols);
    const ImageF a = RandomImage(k.a_rows, k.a_cols, &rng);
    const ImageF b = RandomImage(k.b_rows, k.b_cols, &rng);
    const std::vector<double> sums =
        CrossSums(Fft2(a, k.rows, k.cols), Fft2(b, k.rows, k.cols), k.rows, k.cols);
    ASSERT_EQ(sums.size(), static_cast<size_t>(k.rows) * k.cols);
    const double bound = a.cast<double>().norm() * b.cast<double>().norm();
    for (int dy = 0; dy < k.rows; ++dy) {
      for (int dx = 0; dx < k.cols; ++dx) {
        const double error =
            std::abs(sums[dy * k.cols + dx] - DirectCyclicSum(a, b, k.rows, k.cols, dx, dy));
        worst = std::max(worst, error / bound);
        ASSERT_LE(error, 1e-14 * bound) << "dx " << dx << " dy " << dy;
      }
    }
  }
  RecordProperty("worst_relative_error", ::testing::PrintToString(worst));
}

// b a cyclic shift of a by (dx, dy): the cross sum at that shift is sum a^2,
// the largest of all (Cauchy-Schwarz, strict for a random image), so the
// peak is at the shift, in every quadrant (negative shifts wrap).
TEST(CrossCorrelation, AShiftedCopyPeaksAtItsShift) {
  const int rows = 15, cols = 20;
  std::mt19937 rng(11);
  const ImageF a = RandomImage(rows, cols, &rng);
  for (const auto& [dx, dy] :
       std::vector<std::pair<int, int>>{{3, 2}, {-4, 5}, {7, -6}, {-1, -1}}) {
    ImageF b(rows, cols);
    for (int r = 0; r < rows; ++r) {
      for (int c = 0; c < cols; ++c) b((r + dy + rows) % rows, (c + dx + cols) % cols) = a(r, c);
    }
    const std::vector<double> sums =
        CrossSums(Fft2(a, rows, cols), Fft2(b, rows, cols), rows, cols);
    const auto peak = std::max_element(sums.begin(), sums.end()) - sums.begin();
    EXPECT_EQ(peak, ((dy + rows) % rows) * cols + (dx + cols) % cols) << dx << ", " << dy;
    const double energy = a.cast<double>().squaredNorm();
    EXPECT_NEAR(sums[peak], energy, 1e-13 * energy);
  }
}

}  // namespace
}  // namespace omm
