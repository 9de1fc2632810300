// Weights of the separable cubic interpolation kernels on a 4-sample support
// (the samples at -1, 0, 1, 2 for a position t in [0, 1) past sample 0), as
// packed polynomials in t (Horner). T: double, or float where the samplers
// pack four weights per SSE register.
#pragma once

#include <Eigen/Core>

namespace omm {

// Catmull-Rom, i.e. Keys' cubic convolution with a = -1/2: interpolates the
// samples themselves.
template <typename T>
inline void CatmullRomWeights(T t, T w[4]) {
  using Array = Eigen::Array<T, 4, 1>;
  const Array a0(0, 1, 0, 0), a1(-0.5, 0, 0.5, 0), a2(1, -2.5, 2, -0.5), a3(-0.5, 1.5, -1.5, 0.5);
  Eigen::Map<Array> weights(w);
  weights = ((a3 * t + a2) * t + a1) * t + a0;
}

// The cubic B-spline: interpolates when the samples are the B-spline
// coefficients of the signal.
template <typename T>
inline void CubicBSplineWeights(T t, T w[4]) {
  using Array = Eigen::Array<T, 4, 1>;
  constexpr T k6 = T{1} / 6;
  const Array a0(k6, 4 * k6, k6, 0), a1(-0.5, 0, 0.5, 0), a2(0.5, -1, 0.5, 0),
      a3(-k6, 0.5, -0.5, k6);
  Eigen::Map<Array> weights(w);
  weights = ((a3 * t + a2) * t + a1) * t + a0;
}

}  // namespace omm
