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

#include "pipeline/core/cubic_bspline.h"
#include "pipeline/core/cubic_weights.h"
#include "pipeline/core/image.h"

namespace omm {

enum class OrthoInterpolator {
  kCatmullRom,    // the pixels themselves, Catmull-Rom weights
  kCubicBSpline,  // B-spline coefficients (CubicBSplineCoefficients), B-spline weights
};

// The weights of `kind` (pipeline/core/cubic_weights.h).
template <typename T>
inline void CubicWeights(OrthoInterpolator kind, T t, T w[4]) {
  if (kind == OrthoInterpolator::kCatmullRom)
    CatmullRomWeights(t, w);
  else
    CubicBSplineWeights(t, w);
}

// sum_ij wy[j] wx[i] image(iy - 1 + j, ix - 1 + i) with (ix, iy) = floor(q)
// and the weights of `kind` at q's fraction: the interpolated value when
// `image` holds what `kind` samples (the pixels or their B-spline
// coefficients). Precondition: q in [1, W - 2] x [1, H - 2].
// In float, like the image: four weights or pixels per SSE register.
inline float SampleCubic(OrthoInterpolator kind, const ImageF& image, const Eigen::Vector2d& q) {
  const int ix = static_cast<int>(q.x()), iy = static_cast<int>(q.y());
  Eigen::Array4f wx, wy;
  CubicWeights(kind, static_cast<float>(q.x() - ix), wx.data());
  CubicWeights(kind, static_cast<float>(q.y() - iy), wy.data());
  const float* row = image.data() + static_cast<std::ptrdiff_t>(iy - 1) * image.cols() + ix - 1;
  const Eigen::Index stride = image.cols();
  const Eigen::Map<const Eigen::Array4f> r0(row), r1(row + stride), r2(row + 2 * stride),
      r3(row + 3 * stride);
  return (wx * (wy(0) * r0 + wy(1) * r1 + wy(2) * r2 + wy(3) * r3)).sum();
}

// Per pixel (row, col) of `image`: whether the 4 x 4 samples SampleCubic
// reads at a q with floor(q) = (col, row) hold one at full scale (>= 1, a
// clipped sample: the value interpolated there is not the scene's). Empty
// when no sample is at full scale. Pure.
ImageMask ClippedSupport(const ImageF& image);

}  // namespace omm
