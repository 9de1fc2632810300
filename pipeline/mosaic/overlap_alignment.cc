#include "pipeline/mosaic/overlap_alignment.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <vector>

#include <Eigen/Dense>

#include "pipeline/core/cubic_weights.h"
#include "pipeline/core/error.h"
#include "pipeline/core/statistics.h"
#include "pipeline/mosaic/tile_features.h"

namespace omm {
namespace {

constexpr int kGainDegree = 5;  // the gain field's polynomial degree (header)
constexpr int kNumGainTerms = (kGainDegree + 1) * (kGainDegree + 2) / 2;
constexpr double kPi = std::numbers::pi;
constexpr int kNumParameters = 2 + kNumGainTerms + 1;  // s, g, o
// A smoothed pixel whose kernel saw only valid pixels (float rounding).
constexpr float kFullSupport = 1.0f - 1e-4f;
using Parameters = Eigen::Matrix<double, kNumParameters, 1>;
using Row = Eigen::Matrix<double, 1, kNumParameters>;
using Square = Eigen::Matrix<double, kNumParameters, kNumParameters>;

// 1 where a pixel is seen and not clipped, else 0.
ImageF ValidPixels(const ImageF& image, double max_value) {
  return image.unaryExpr(
      [max_value](float v) { return v > kDarkestCovered && v < max_value ? 1.0f : 0.0f; });
}

double HuberWeight(double r, double threshold) {
  return std::abs(r) <= threshold ? 1.0 : threshold / std::abs(r);
}

double RobustSigma(const std::vector<double>& residuals) {
  std::vector<double> absolute(residuals.size());
  std::transform(residuals.begin(), residuals.end(), absolute.begin(),
                 [](double r) { return std::abs(r); });
  return 1.4826 * Median(std::move(absolute));
}

// d/dt of CatmullRomWeights.
void CatmullRomDerivativeWeights(double t, double w[4]) {
  const double t2 = t * t;
  w[0] = -0.5 + 2.0 * t - 1.5 * t2;
  w[1] = -5.0 * t + 4.5 * t2;
  w[2] = 0.5 + 4.0 * t - 4.5 * t2;
  w[3] = -t + 1.5 * t2;
}

// b and its gradient at (x, y), Catmull-Rom; false if the 4 x 4 support
// leaves the image or touches a sample whose `support` is below 1 (an
// invalid pixel within the smoothing's reach).
bool SampleWithGradient(const ImageF& b, const ImageF& support, double x, double y, double* value,
                        Eigen::Vector2d* grad) {
  const double fx = std::floor(x), fy = std::floor(y);
  const int ix = static_cast<int>(fx) - 1, iy = static_cast<int>(fy) - 1;
  if (ix < 0 || iy < 0 || ix + 3 >= b.cols() || iy + 3 >= b.rows()) return false;
  double wx[4], wy[4], dwx[4], dwy[4];
  CatmullRomWeights(x - fx, wx);
  CatmullRomWeights(y - fy, wy);
  CatmullRomDerivativeWeights(x - fx, dwx);
  CatmullRomDerivativeWeights(y - fy, dwy);
  double v = 0.0, gx = 0.0, gy = 0.0;
  for (int r = 0; r < 4; ++r) {
    double row_v = 0.0, row_d = 0.0;
    for (int c = 0; c < 4; ++c) {
      if (!(support(iy + r, ix + c) >= kFullSupport)) return false;
      const double sample = b(iy + r, ix + c);
      row_v += wx[c] * sample;
      row_d += dwx[c] * sample;
    }
    v += wy[r] * row_v;
    gx += wy[r] * row_d;
    gy += dwy[r] * row_v;
  }
  *value = v;
  *grad = Eigen::Vector2d(gx, gy);
  return true;
}

// sum_p sum_q e(p) G(p - q) e(q)' over the images e = (e_0, e_1), G the
// normalised Gaussian of blur_sigma_px; computed on blocks of factor x
// factor pixels (their sums) when the kernel is wide.
Eigen::Matrix2d CorrelatedProducts(const std::array<ImageF, 2>& e, double blur_sigma_px,
                                   int factor) {
  const double factor2 = static_cast<double>(factor) * factor;
  std::array<ImageF, 2> sums = e;
  if (factor > 1) {
    for (int i = 0; i < 2; ++i) sums[i] = DownsampleBox(e[i], factor) * static_cast<float>(factor2);
  }
  // G is symmetric: (e_0, G e_1) = (e_1, G e_0).
  Eigen::Matrix2d products;
  for (int j = 0; j < 2; ++j) {
    const ImageF blurred = GaussianBlur(sums[j], blur_sigma_px / factor);
    for (int k = j; k < 2; ++k) {
      // A block's kernel weight is factor^2 pixels' (G in block units / factor^2).
      products(j, k) = products(k, j) =
          sums[k].cast<double>().cwiseProduct(blurred.cast<double>()).sum() / factor2;
    }
  }
  return products;
}

// The gain field's terms at a pixel: x^(d - j) y^j for degree d = 0..kGainDegree
// (x, y) the pixel's place scaled to [-1, 1] over the patch.
class GainBasis {
 public:
  GainBasis(int rows, int cols)
      : centre_(0.5 * (cols - 1), 0.5 * (rows - 1)), half_size_(centre_.cwiseMax(1.0)) {}

  std::array<double, kNumGainTerms> Terms(const Eigen::Vector2i& p) const {
    const Eigen::Vector2d u = (p.cast<double>() - centre_).cwiseQuotient(half_size_);
    const double x = u.x(), y = u.y();
    // Each degree's terms from the last's.
    std::array<double, kNumGainTerms> t;
    t[0] = 1.0;
    int first = 0, k = 1;
    for (int d = 1; d <= kGainDegree; ++d) {
      for (int j = 0; j < d; ++j) t[k++] = t[first + j] * x;
      t[k++] = t[first + d - 1] * y;
      first += d;
    }
    return t;
  }

 private:
  Eigen::Vector2d centre_, half_size_;
};

double GainAt(const Parameters& theta, const std::array<double, kNumGainTerms>& terms) {
  double gain = 0.0;
  for (int k = 0; k < kNumGainTerms; ++k) gain += theta(2 + k) * terms[k];
  return gain;
}

// b(x + s), its gradient and g(u) at a pixel the fit uses: J's row is
// rebuilt from them (storing 24 doubles a pixel would take ~100 MB an
// overlap).
struct Sample {
  float value, gx, gy, gain;
};

// r = a - (g b(x + s) + o); J = dr/dtheta.
Row JacobianRow(const std::array<double, kNumGainTerms>& terms, const Sample& sample) {
  Row row;
  row(0) = -sample.gain * sample.gx;
  row(1) = -sample.gain * sample.gy;
  for (int k = 0; k < kNumGainTerms; ++k) row(2 + k) = -terms[k] * sample.value;
  row(kNumParameters - 1) = -1.0;
  return row;
}

// The patches smoothed, where they may be sampled, and a's pixels the fit
// may use.
struct SmoothedOverlap {
  ImageF smooth_a, smooth_b;
  ImageF support_b;  // b's smoothing kernel's share of valid pixels
  ImageF valid_b;    // 1 where raw b is valid (sampled for the noise estimate)
  std::vector<Eigen::Vector2i> pixels;
};

SmoothedOverlap SmoothOverlap(const ImageF& a, const ImageF& b, const ImageF& mask,
                              const OverlapAlignmentOptions& options) {
  const double sigma = options.smoothing_sigma_px;
  SmoothedOverlap overlap;
  // Masked pixels count as unseen in both patches: nothing within the
  // smoothing's reach of them counts.
  ImageF valid_a = ValidPixels(a, options.max_value);
  overlap.valid_b = ValidPixels(b, options.max_value);
  if (mask.size() != 0) {
    const ImageF keep = mask.unaryExpr([](float m) { return m > 0.0f ? 1.0f : 0.0f; });
    valid_a = valid_a.cwiseProduct(keep);
    overlap.valid_b = overlap.valid_b.cwiseProduct(keep);
  }
  const ImageF support_a = GaussianBlur(valid_a, sigma);
  overlap.support_b = GaussianBlur(overlap.valid_b, sigma);
  overlap.smooth_a = GaussianBlur(a, sigma);
  overlap.smooth_b = GaussianBlur(b, sigma);
  // The blur clamps at the window's border: pixels within its reach are left out.
  const int margin = static_cast<int>(std::ceil(3.0 * sigma)) + 2;
  const int stride = options.sample_stride_px;
  for (int r = margin; r < a.rows() - margin; r += stride) {
    for (int c = margin; c < a.cols() - margin; c += stride) {
      if (!(support_a(r, c) >= kFullSupport)) continue;
      overlap.pixels.emplace_back(c, r);
    }
  }
  return overlap;
}

// The fit linearised at theta: the pixels where smoothed b(x + s) can be
// sampled, their residuals and samples.
struct Linearisation {
  std::vector<Eigen::Vector2i> used;
  std::vector<double> residuals;
  std::vector<Sample> samples;
};

void Linearise(const SmoothedOverlap& overlap, const GainBasis& basis, const Parameters& theta,
               Linearisation* lin_out) {
  Linearisation& lin = *lin_out;  // its buffers kept between iterations
  lin.used.clear();
  lin.residuals.clear();
  lin.samples.clear();
  const Eigen::Vector2d shift = theta.head<2>();
  for (const Eigen::Vector2i& p : overlap.pixels) {
    double value;
    Eigen::Vector2d grad;
    if (!SampleWithGradient(overlap.smooth_b, overlap.support_b, p.x() + shift.x(),
                            p.y() + shift.y(), &value, &grad)) {
      continue;
    }
    const double gain = GainAt(theta, basis.Terms(p));
    lin.used.push_back(p);
    lin.residuals.push_back(overlap.smooth_a(p.y(), p.x()) -
                            (gain * value + theta(kNumParameters - 1)));
    lin.samples.push_back({static_cast<float>(value), static_cast<float>(grad.x()),
                           static_cast<float>(grad.y()), static_cast<float>(gain)});
  }
}

// J' W J and J' W r, W the Huber weights at `threshold`, by blocks of rows
// (a matrix product each: the 24 x 24 outer products one row at a time took
// most of the fit's time).
void NormalEquations(const Linearisation& lin, const GainBasis& basis, double threshold,
                     Square* normal, Parameters* gradient) {
  normal->setZero();
  gradient->setZero();
  constexpr int kBlock = 512;
  Eigen::Matrix<double, kNumParameters, kBlock> block;
  Eigen::Matrix<double, kBlock, 1> block_residuals;
  const std::vector<double>& residuals = lin.residuals;
  for (size_t first = 0; first < residuals.size(); first += kBlock) {
    const int n = static_cast<int>(std::min<size_t>(kBlock, residuals.size() - first));
    for (int k = 0; k < n; ++k) {
      const size_t i = first + k;
      const double root_w = std::sqrt(HuberWeight(residuals[i], threshold));
      block.col(k) = root_w * JacobianRow(basis.Terms(lin.used[i]), lin.samples[i]).transpose();
      block_residuals(k) = root_w * residuals[i];
    }
    normal->selfadjointView<Eigen::Lower>().rankUpdate(block.leftCols(n));
    gradient->noalias() += block.leftCols(n) * block_residuals.head(n);
  }
  *normal = normal->selfadjointView<Eigen::Lower>();
}

// The noise of a - (g b + o), unsmoothed: the residuals at the used pixels
// where raw b's samples are all valid.
std::vector<double> RawResiduals(const ImageF& a, const ImageF& b, const SmoothedOverlap& overlap,
                                 const Linearisation& lin, const GainBasis& basis,
                                 const Parameters& theta) {
  std::vector<double> raw;
  for (const Eigen::Vector2i& p : lin.used) {
    double value;
    Eigen::Vector2d grad;
    if (!SampleWithGradient(b, overlap.valid_b, p.x() + theta(0), p.y() + theta(1), &value, &grad))
      continue;
    raw.push_back(a(p.y(), p.x()) -
                  (GainAt(theta, basis.Terms(p)) * value + theta(kNumParameters - 1)));
  }
  return raw;
}

// e_i = W J H^-1's column i as an image, for the shift's two parameters:
// Cov(shift) = (e_i, K e_j), K the residuals' correlation (header).
std::array<ImageF, 2> ShiftInfluence(const Linearisation& lin, const GainBasis& basis,
                                     double threshold, const Square& normal, int rows, int cols) {
  const Square inverse = normal.ldlt().solve(Square::Identity());
  std::array<ImageF, 2> e = {ImageF::Zero(rows, cols), ImageF::Zero(rows, cols)};
  for (size_t i = 0; i < lin.used.size(); ++i) {
    const double w = HuberWeight(lin.residuals[i], threshold);
    const Row row = JacobianRow(basis.Terms(lin.used[i]), lin.samples[i]);
    for (int k = 0; k < 2; ++k)
      e[k](lin.used[i].y(), lin.used[i].x()) = static_cast<float>(w * row.dot(inverse.row(k)));
  }
  return e;
}

}  // namespace

std::string OverlapAlignmentOptions::Check() const {
  if (!(smoothing_sigma_px > 0.0)) return "smoothing_sigma_px must be > 0";
  if (sample_stride_px < 1) return "sample_stride_px must be at least 1";
  if (max_iterations < 1) return "max_iterations must be at least 1";
  if (!(shift_tolerance_px > 0.0)) return "shift_tolerance_px must be > 0";
  if (!(huber_sigmas > 0.0)) return "huber_sigmas must be > 0";
  if (!(max_value > 0.0 && max_value <= 1.0)) return "max_value must be in (0, 1]";
  if (min_pixels < kNumParameters) {
    return "min_pixels must be at least the " + std::to_string(kNumParameters) + " parameters";
  }
  if (!(max_shift_px > 0.0)) return "max_shift_px must be > 0";
  if (!(min_sigma_px >= 0.0)) return "min_sigma_px must be >= 0";
  if (!(misfit_scale_px > smoothing_sigma_px))
    return "misfit_scale_px must exceed smoothing_sigma_px";
  if (!(misfit_relative >= 0.0)) return "misfit_relative must be >= 0";
  return "";
}

OverlapAlignment AlignOverlap(const ImageF& a, const ImageF& b, const ImageF& mask,
                              const OverlapAlignmentOptions& options) {
  if (const std::string why = options.Check(); !why.empty())
    throw InputError("OverlapAlignmentOptions", why);
  if (a.rows() != b.rows() || a.cols() != b.cols() ||
      (mask.size() != 0 && (mask.rows() != a.rows() || mask.cols() != a.cols()))) {
    throw InputError("AlignOverlap", "the patches and the mask must have one size");
  }
  OverlapAlignment result;
  const int rows = static_cast<int>(a.rows()), cols = static_cast<int>(a.cols());
  const double sigma = options.smoothing_sigma_px;
  const SmoothedOverlap overlap = SmoothOverlap(a, b, mask, options);
  const GainBasis basis(rows, cols);
  // The samples stand for stride^2 pixels each.
  const int stride2 = options.sample_stride_px * options.sample_stride_px;

  // Gauss-Newton with Huber weights on the smoothed patches.
  Parameters theta = Parameters::Zero();
  theta(2) = 1.0;  // g0
  Square normal;
  Linearisation lin;
  double huber_threshold = 0.0;
  const auto no_gradient = [&result] {
    result.why = "the overlap holds no gradient to align on";
    return result;
  };
  for (int iteration = 0; iteration < options.max_iterations; ++iteration) {
    result.num_iterations = iteration + 1;
    Linearise(overlap, basis, theta, &lin);
    result.num_pixels = static_cast<int>(lin.residuals.size()) * stride2;
    if (result.num_pixels < options.min_pixels) {
      result.why = "too few pixels seen by both";
      return result;
    }
    huber_threshold = options.huber_sigmas * std::max(RobustSigma(lin.residuals), 1e-9);
    Parameters gradient;
    NormalEquations(lin, basis, huber_threshold, &normal, &gradient);
    const Eigen::LDLT<Square> ldlt(normal);
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return no_gradient();
    const Parameters step = -ldlt.solve(gradient);
    if (!step.allFinite()) return no_gradient();
    theta += step;
    if (theta.head<2>().cwiseAbs().maxCoeff() > options.max_shift_px) {
      result.why = "the shift left the allowed range";
      return result;
    }
    if (step.head<2>().norm() < options.shift_tolerance_px) break;
  }

  const std::vector<double> raw_residuals = RawResiduals(a, b, overlap, lin, basis, theta);
  if (static_cast<int>(raw_residuals.size()) * stride2 < options.min_pixels) {
    result.why = "too few pixels seen by both";
    return result;
  }
  result.residual_sigma = RobustSigma(raw_residuals);
  // Cov(theta) = H^-1 J' W K W J H^-1 (header): its shift block is (e_i, K
  // e_j), two images whatever the number of gain terms.
  const std::array<ImageF, 2> e = ShiftInfluence(lin, basis, huber_threshold, normal, rows, cols);
  // The noise: its smoothed residuals correlate as K = G * G. e is nonzero
  // on the samples' lattice only, one pixel of each stride x stride block.
  Eigen::Matrix2d covariance =
      result.residual_sigma * result.residual_sigma *
      CorrelatedProducts(e, std::sqrt(2.0) * sigma, options.sample_stride_px);
  // The misfit: a smooth field of misfit_relative of the level.
  double level = 0.0;
  for (const Eigen::Vector2i& p : lin.used) level += overlap.smooth_a(p.y(), p.x());
  level /= static_cast<double>(lin.used.size());
  const double scale = options.misfit_scale_px;
  const int factor = std::max(1, static_cast<int>(scale / 8.0));
  result.misfit_sigma = options.misfit_relative * level;
  covariance += result.misfit_sigma * result.misfit_sigma * 4.0 * kPi * scale * scale *
                CorrelatedProducts(e, std::sqrt(2.0) * scale, factor);
  result.covariance_px2 = covariance +
                          options.min_sigma_px * options.min_sigma_px * Eigen::Matrix2d::Identity();
  result.shift_px = theta.head<2>();
  result.usable = result.covariance_px2.allFinite();
  if (!result.usable) result.why = "the shift's covariance is not finite";
  return result;
}

}  // namespace omm
