// Cross sums of two images at every shift by FFT (the correlation theorem):
// the unnormalised cross-correlation behind the coarse image-motion search
// (EstimateImageMotion). Pure kernels on ImageF, through Eigen's FFT
// (unsupported/Eigen/FFT, kissfft backend).
#pragma once

#include <complex>
#include <vector>

#include "pipeline/core/image.h"

namespace omm {

// The smallest n' >= max(n, 1) whose prime factors are 2, 3 and 5 (a fast FFT length).
int FftSize(int n);

// A 2-D DFT, rows x cols, row-major.
using Spectrum = std::vector<std::complex<double>>;

// The 2-D DFT of `image` zero-padded to rows x cols, in double:
// F(u, v) = sum_{r, c} image(r, c) exp(-2 pi i (u r / rows + v c / cols)) at
// [u cols + v]. Requires rows >= image.rows(), cols >= image.cols().
Spectrum Fft2(const ImageF& image, int rows, int cols);

// Every cyclic cross sum of the images a and b whose Fft2 (at the same rows x
// cols) are fa and fb: at [(dy mod rows) cols + (dx mod cols)],
// sum_{r, c} a(r, c) b((r + dy) mod rows, (c + dx) mod cols), with a and b
// zero-padded to rows x cols. Padding to rows >= a.rows() + b.rows() - 1 (and
// likewise cols) makes every shift's sum the plain one over the overlap.
std::vector<double> CrossSums(const Spectrum& fa, const Spectrum& fb, int rows, int cols);

}  // namespace omm
