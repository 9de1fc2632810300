#include "pipeline/core/cubic_bspline.h"

#include <algorithm>
#include <cassert>
#include <cmath>

#include <Eigen/Core>

namespace omm {
namespace {

// The cubic B-spline prefilter's pole and gain, (1 - z)(1 - 1/z).
const double kPole = std::sqrt(3.0) - 2.0;
constexpr double kGain = 6.0;
// Terms of the causal initial sum: |pole|^k < 1e-9 (float images).
const int kInitTerms = static_cast<int>(std::ceil(std::log(1e-9) / std::log(-kPole)));

// The prefilter along one line of n >= 2 samples, x(k) the k-th (a pixel, or
// a whole row of pixels, so that the recursion down the columns runs
// vectorised across them), in place.
template <typename Line>
void PrefilterLine(int n, Line x) {
  const float z = static_cast<float>(kPole), gain = static_cast<float>(kGain);
  // Causal: c+(0) = sum_k z^k s(k) (mirrored signal, truncated).
  float zk = z;
  for (int k = 1; k < std::min(n, kInitTerms); ++k, zk *= z) x(0) += zk * x(k);
  x(0) *= gain;
  for (int k = 1; k < n; ++k) x(k) = gain * x(k) + z * x(k - 1);
  // Anti-causal.
  x(n - 1) = (z / (z * z - 1.0f)) * (x(n - 1) + z * x(n - 2));
  for (int k = n - 2; k >= 0; --k) x(k) = z * (x(k + 1) - x(k));
}

}  // namespace

ImageF CubicBSplineCoefficients(const ImageF& image) {
  assert(image.rows() >= 2 && image.cols() >= 2);
  ImageF c = image;
  // Along y, whole rows at a time; along x, kRows rows at a time (a
  // column-major block: each column's kRows pixels form one vector).
  PrefilterLine(static_cast<int>(c.rows()), [&](int y) { return c.row(y).array(); });
  constexpr int kRows = 8;
  Eigen::Array<float, kRows, Eigen::Dynamic> block =
      Eigen::Array<float, kRows, Eigen::Dynamic>::Zero(kRows, c.cols());
  for (Eigen::Index y = 0; y < c.rows(); y += kRows) {
    const Eigen::Index rows = std::min<Eigen::Index>(kRows, c.rows() - y);
    block.topRows(rows) = c.middleRows(y, rows).array();
    PrefilterLine(static_cast<int>(c.cols()), [&](int x) { return block.col(x); });
    c.middleRows(y, rows) = block.topRows(rows).matrix();
  }
  return c;
}

}  // namespace omm
