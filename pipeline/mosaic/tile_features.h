// Point features of the mosaic's tiles: exposure normalisation, Harris
// corners with grid bucketing, and the image sampling the matcher needs.
// Pure kernels on ImageF (pipeline/core/image.h); pixels follow the pipeline's
// convention, (0, 0) at the centre of the top-left pixel.
#pragma once

#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "pipeline/core/image.h"

namespace omm {

// (I - median) / (1.4826 MAD) over the whole tile: removes gain and offset so
// that absolute thresholds (Harris' texture test) mean the same in every tile
// (NCC and the matcher's gain/offset model are invariant anyway). Vignetting
// is left: being smooth, it scales the Harris responses of a bucketing cell
// alike and the corners chosen do not change (on the exposure preset, gains
// 0.6-1.15 and vignetting 0.1-0.45, corners repeat between overlapping tiles
// as often as after an exact flat-field correction: register_tiles_test).
// The statistics come from every 7th pixel.
ImageF NormalizeTileIntensity(const ImageF& image);

// The level of a blank image (every pixel but a `max_fraction` equal to the
// median; every 7th pixel looked at): a constant frame, a failed capture, not
// a picture. Sensor noise moves most pixels of a real one by a quantum or more
// (73-100 % of them on the 33 public images of ../shared/data, dim 16-bit
// phase contrast included), and a tile mostly of dark table still has its
// part's pixels. nullopt if the image has content.
std::optional<double> BlankImageLevel(const ImageF& image, double max_fraction = 0.01);

// The fraction of `image`'s pixels at full scale (1): clipped, saturated.
double SaturatedFraction(const ImageF& image);

// Box-filter downsampling by an integer factor: output pixel (r, c) is the
// mean of input rows [r f, r f + f), columns [c f, c f + f), so an offset of
// d output pixels is exactly f d input pixels.
ImageF DownsampleBox(const ImageF& image, int factor);

// Separable Gaussian blur (kernel radius ceil(3 sigma), borders clamped).
ImageF GaussianBlur(const ImageF& image, double sigma_px);

struct HarrisOptions {
  double window_sigma_px = 1.5;  // Gaussian integration window of the structure tensor, px
  double k = 0.04;               // R = det(M) - k trace(M)^2
  int cell_px = 64;              // bucketing: corners are chosen per cell of this size, px
  int max_per_cell = 3;          // strongest corners kept per cell
  int nms_radius_px = 3;         // a corner is the maximum of R over (2r+1)^2 pixels
  // A corner's R must reach this fraction of the 90th percentile of all
  // local maxima's R (drops flat areas and noise).
  double min_response_fraction = 0.02;
  int border_px = 12;  // corners keep at least this distance from the image border, px
  // Texture test: the intensity standard deviation over the
  // (2 texture_half_size_px + 1)^2 window around a corner must reach
  // min_texture_std (units of the image), else the corner is noise on a
  // flat area (weak texture) and would take a bucket's place from a
  // matchable one. RegisterTiles' defaults equal its template's
  // (PatchMatchOptions half_size_px, min_template_std); 0 keeps all.
  int texture_half_size_px = 15;
  double min_texture_std = 0.15;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct Corner {
  Eigen::Vector2i pixel = Eigen::Vector2i::Zero();  // (x, y) of the response maximum
  Eigen::Vector2d q_px = Eigen::Vector2d::Zero();   // sub-pixel peak (quadratic fit of R)
  double response = 0.0;
};

// Harris corners (Harris & Stephens 1988) of a normalised tile: gradients by
// central differences, structure tensor M integrated with a Gaussian window,
// R = det M - k tr(M)^2, local maxima above the threshold, at most
// max_per_cell per grid cell (well distributed), sub-pixel peak by a 3 x 3
// quadratic fit; corners whose window fails the texture test are dropped
// before the bucketing. Sorted by response, strongest first (ties by pixel,
// row-major).
// regions (pixel boxes, corners inclusive; empty: the whole image): only the
// bucketing cells that meet one of them are searched, R computed there
// alone. Those cells' corners are the whole image's but for the response
// threshold, which comes from their own maxima; cells are kept whole so that
// the bucketing chooses as over the whole image.
// Precondition: options.Check() is empty.
std::vector<Corner> DetectHarrisCorners(const ImageF& image, const HarrisOptions& options,
                                        const std::vector<Eigen::AlignedBox2i>& regions = {});

// The cubic B-spline interpolant of the image whose CubicBSplineCoefficients
// (pipeline/core/cubic_bspline.h) are `coefficients`, at (x, y) px, with its
// gradient (d/dx, d/dy); false (outputs untouched) if the 4 x 4 support
// leaves the image. In float, like the coefficients (a few float epsilons of
// the values' scale). The B-spline rather than Keys' cubic convolution for
// sub-pixel matching: Keys' kernel smooths by an amount that depends on the
// fractional position and biased template matches periodically by up to
// ~0.045 px on the simulator's tiles ("pixel locking"); the B-spline's bias
// is far smaller.
bool SampleBSpline(const ImageF& coefficients, double x, double y, double* value, double* dvalue_dx,
                   double* dvalue_dy);

// SampleBSpline at p0 + offsets[i] for every i into value, dvalue_dx and
// dvalue_dy (resized); false if any support leaves the image. The template
// matcher's inner loop (~2e7 samples per registration), with the point
// sampler inlined.
bool SampleBSplinePatch(const ImageF& coefficients, const Eigen::Vector2d& p0,
                        const std::vector<Eigen::Vector2d>& offsets, Eigen::VectorXd* value,
                        Eigen::VectorXd* dvalue_dx, Eigen::VectorXd* dvalue_dy);

// The same, the gradient optional.
inline bool SampleBSpline(const ImageF& coefficients, double x, double y, double* value,
                          Eigen::Vector2d* gradient = nullptr) {
  double gx, gy;
  if (!SampleBSpline(coefficients, x, y, value, &gx, &gy)) return false;
  if (gradient != nullptr) *gradient << gx, gy;
  return true;
}

}  // namespace omm
