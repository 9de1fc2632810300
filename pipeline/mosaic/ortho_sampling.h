// Sampling a tile at a fractional pixel for the mosaic: separable cubic
// kernels on a 4 x 4 support (samples at floor(q) - 1 .. floor(q) + 2 on each
// axis; q must lie in [1, W - 2] x [1, H - 2]).
//
// Catmull-Rom (Keys, a = -1/2) interpolates the pixels directly. Its
// frequency response dips between samples: a blurred edge sampled half-way
// between pixels is interpolated slightly softer than one sampled on them, so
// the mid-level crossing of a resampled edge moves with the sampling phase.
// Resampling a tile at 1.02-1.06 tile px per mosaic px walks the phase
// slowly along the mosaic (a beat of ~18-50 mosaic px), which turns that into
// edge errors correlated over long arcs of a hole's rim.
//
// The cubic B-spline interpolator (Unser, Aldroubi & Eden 1991; Unser, "Splines:
// a perfect fit for signal and image processing", IEEE SPM 1999) samples the
// same 4 x 4 support, but of coefficients c with sum_k c[k] beta3(x - k) = the
// pixels at integer x: a recursive prefilter (pole sqrt(3) - 2, mirrored
// borders) computes them once per tile (~6 ms for 1600 x 1200). Its passband
// is flatter: on a blurred disc (PSF sigma 0.6 px) the edge position error
// varies by 0.015 tile px peak to peak over the sampling phase against
// Catmull-Rom's 0.046, and the radius at 1.02-1.056 tile px per mosaic px by
// 0.006-0.009 against 0.015-0.024 (ortho_sampling_test.cc).
#pragma once

#include <cstddef>

#include <Eigen/Core>

#include "pipeline/core/image.h"

namespace omm {

enum class OrthoInterpolator {
  kCatmullRom,    // the pixels themselves, Catmull-Rom weights
  kCubicBSpline,  // B-spline coefficients (CubicBSplineCoefficients), B-spline weights
};

// Weights of the samples at -1, 0, 1, 2 for a position t in [0, 1) past sample 0.
inline void CatmullRomWeights(double t, double w[4]) {
  const double t2 = t * t, t3 = t2 * t;
  w[0] = 0.5 * (-t3 + 2.0 * t2 - t);
  w[1] = 0.5 * (3.0 * t3 - 5.0 * t2 + 2.0);
  w[2] = 0.5 * (-3.0 * t3 + 4.0 * t2 + t);
  w[3] = 0.5 * (t3 - t2);
}
inline void CubicBSplineWeights(double t, double w[4]) {
  const double s = 1.0 - t, t2 = t * t, t3 = t2 * t;
  w[0] = s * s * s / 6.0;
  w[1] = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0;
  w[2] = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0;
  w[3] = t3 / 6.0;
}
inline void CubicWeights(OrthoInterpolator kind, double t, double w[4]) {
  if (kind == OrthoInterpolator::kCatmullRom)
    CatmullRomWeights(t, w);
  else
    CubicBSplineWeights(t, w);
}

// The B-spline coefficients of an image (at least 2 x 2): the cubic spline
// through its pixels, mirrored at the borders (exactly for sides of >= 16 px,
// where the recursion's start has converged to float precision).
ImageF CubicBSplineCoefficients(const ImageF& image);

// sum_ij wy[j] wx[i] image(iy - 1 + j, ix - 1 + i) with (ix, iy) = floor(q)
// and the weights of `kind` at q's fraction: the interpolated value when
// `image` holds what `kind` samples (the pixels or their B-spline
// coefficients). Precondition: q in [1, W - 2] x [1, H - 2].
inline float SampleCubic(OrthoInterpolator kind, const ImageF& image, const Eigen::Vector2d& q) {
  const int ix = static_cast<int>(q.x()), iy = static_cast<int>(q.y());
  double wx[4], wy[4];
  CubicWeights(kind, q.x() - ix, wx);
  CubicWeights(kind, q.y() - iy, wy);
  double sum = 0.0;
  for (int j = 0; j < 4; ++j) {
    const float* row =
        image.data() + static_cast<std::ptrdiff_t>(iy - 1 + j) * image.cols() + ix - 1;
    sum += wy[j] * (wx[0] * row[0] + wx[1] * row[1] + wx[2] * row[2] + wx[3] * row[3]);
  }
  return static_cast<float>(sum);
}

}  // namespace omm
