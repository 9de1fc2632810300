// Cubic B-spline coefficients of an image (Unser, Aldroubi & Eden 1991;
// Unser, "Splines: a perfect fit for signal and image processing", IEEE SPM
// 1999): c with sum_k c[k] beta3(x - k) = the pixels at integer x, by the
// causal and anti-causal recursive filters with pole sqrt(3) - 2 and mirrored
// borders. Sampled with CubicBSplineWeights (cubic_weights.h) they
// interpolate the pixels exactly, with a flatter passband than Keys' cubic
// convolution: the template matcher (tile_features.h) and the mosaic's
// resampling (ortho_sampling.h) use them for that.
#pragma once

#include "pipeline/core/image.h"

namespace omm {

// The coefficients of an image of at least 2 x 2 px, in float (exact to the
// mirrored ideal for sides of >= 16 px, where the recursion's start has
// converged to float precision).
ImageF CubicBSplineCoefficients(const ImageF& image);

}  // namespace omm
