#include "pipeline/measure/circle_measure.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <optional>
#include <sstream>
#include <vector>

#include <Eigen/Dense>

#include "pipeline/core/statistics.h"

namespace omm {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

bool Covered(const ImageF& image, Eigen::Index row, Eigen::Index col) {
  return row >= 0 && col >= 0 && row < image.rows() && col < image.cols() &&
         image(row, col) != 0.0f;
}

// Bilinear value at (x, y); NaN off the image or next to an uncovered pixel.
double Bilinear(const ImageF& image, double x, double y) {
  const double fx = std::floor(x), fy = std::floor(y);
  const auto c = static_cast<Eigen::Index>(fx), r = static_cast<Eigen::Index>(fy);
  // Covered() for the 2 x 2 block, its bounds tested once (a hot path).
  if (c < 0 || r < 0 || c + 1 >= image.cols() || r + 1 >= image.rows() || image(r, c) == 0.0f ||
      image(r, c + 1) == 0.0f || image(r + 1, c) == 0.0f || image(r + 1, c + 1) == 0.0f) {
    return kNaN;
  }
  const double ax = x - fx, ay = y - fy;
  return (1 - ay) * ((1 - ax) * image(r, c) + ax * image(r, c + 1)) +
         ay * ((1 - ax) * image(r + 1, c) + ax * image(r + 1, c + 1));
}

struct Circle {
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();
  double radius = 0.0;
};

// Step 1 (header): gradient votes for the centre of a dark disc of radius
// `radius` within `search` px (square) of `expected`.
Eigen::Vector2d VoteCentre(const ImageF& image, const Eigen::Vector2d& expected, double radius,
                           double search) {
  const int half = static_cast<int>(std::ceil(search));
  const int size = 2 * half + 1;
  Eigen::MatrixXd votes = Eigen::MatrixXd::Zero(size, size);
  const Eigen::Vector2d origin = expected.array().round() - half;  // votes(0, 0) is here
  const double reach = radius + search + 2.0;
  const auto col_lo = static_cast<Eigen::Index>(std::max(1.0, std::floor(expected.x() - reach)));
  const auto col_hi = static_cast<Eigen::Index>(
      std::min(static_cast<double>(image.cols() - 2), std::ceil(expected.x() + reach)));
  const auto row_lo = static_cast<Eigen::Index>(std::max(1.0, std::floor(expected.y() - reach)));
  const auto row_hi = static_cast<Eigen::Index>(
      std::min(static_cast<double>(image.rows() - 2), std::ceil(expected.y() + reach)));
  const double inner2 = std::pow(std::max(0.0, radius - search - 2.0), 2), outer2 = reach * reach;
  for (Eigen::Index row = row_lo; row <= row_hi; ++row) {
    for (Eigen::Index col = col_lo; col <= col_hi; ++col) {
      const double dx0 = col - expected.x(), dy0 = row - expected.y();
      const double rho2 = dx0 * dx0 + dy0 * dy0;
      if (rho2 < inner2 || rho2 > outer2) continue;
      const float l = image(row, col - 1), r = image(row, col + 1);
      const float u = image(row - 1, col), d = image(row + 1, col);
      if (l == 0.0f || r == 0.0f || u == 0.0f || d == 0.0f) continue;  // next to uncovered
      const double gx = 0.5 * (r - l), gy = 0.5 * (d - u);
      const double g = std::sqrt(gx * gx + gy * gy);
      if (g <= 0.0) continue;
      const double vx = col - radius * gx / g - origin.x(), vy = row - radius * gy / g - origin.y();
      const double fx = std::floor(vx), fy = std::floor(vy);
      const int c = static_cast<int>(fx), rr = static_cast<int>(fy);
      if (c < 0 || rr < 0 || c + 1 >= size || rr + 1 >= size) continue;
      const double ax = vx - fx, ay = vy - fy;
      votes(rr, c) += g * (1 - ax) * (1 - ay);
      votes(rr, c + 1) += g * ax * (1 - ay);
      votes(rr + 1, c) += g * (1 - ax) * ay;
      votes(rr + 1, c + 1) += g * ax * ay;
    }
  }
  // Smooth by a separable [1 2 3 2 1] kernel: a radius off by a px or two
  // spreads the rim's votes over a small ring.
  const double k[5] = {1, 2, 3, 2, 1};
  Eigen::MatrixXd tmp = Eigen::MatrixXd::Zero(size, size),
                  smooth = Eigen::MatrixXd::Zero(size, size);
  for (int r = 0; r < size; ++r) {
    for (int c = 0; c < size; ++c) {
      for (int i = -2; i <= 2; ++i) {
        if (c + i >= 0 && c + i < size) tmp(r, c) += k[i + 2] * votes(r, c + i);
      }
    }
  }
  for (int r = 0; r < size; ++r) {
    for (int c = 0; c < size; ++c) {
      for (int i = -2; i <= 2; ++i) {
        if (r + i >= 0 && r + i < size) smooth(r, c) += k[i + 2] * tmp(r + i, c);
      }
    }
  }
  Eigen::Index best_r = half, best_c = half;
  smooth.maxCoeff(&best_r, &best_c);
  return origin + Eigen::Vector2d(static_cast<double>(best_c), static_cast<double>(best_r));
}

// Standard normal density and distribution.
// Standard normal density and distribution at z from one exponential: the
// distribution by Abramowitz & Stegun 7.1.26 (|error| < 1e-7, far below the
// pixel noise), which shares exp(-z^2 / 2) with the density.
struct Normal01 {
  double pdf, cdf;
};
Normal01 NormalAt(double z) {
  const double e = std::exp(-0.5 * z * z);
  const double t = 1.0 / (1.0 + 0.3275911 * std::abs(z) / std::numbers::sqrt2);
  const double tail =
      0.5 * t *
      (0.254829592 +
       t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429)))) *
      e;
  return {e / std::sqrt(2.0 * kPi), z >= 0.0 ? 1.0 - tail : tail};
}

// x solving a x = b for a symmetric positive definite `a` (its lower
// triangle read) by Cholesky; false if a pivot is not positive. The damped
// step's system: Eigen's pivoting LDLT ran dynamic-size kernels on it, a
// tenth of the fit's time.
template <int N>
bool SolveSpd(Eigen::Matrix<double, N, N> a, const Eigen::Matrix<double, N, 1>& b,
              Eigen::Matrix<double, N, 1>* x) {
  // Unrolled (N is 6 or 7): the loops' own bookkeeping was most of the time.
#pragma GCC unroll 8
  for (int j = 0; j < N; ++j) {
#pragma GCC unroll 8
    for (int k = 0; k < j; ++k) {
#pragma GCC unroll 8
      for (int i = j; i < N; ++i) a(i, j) -= a(i, k) * a(j, k);
    }
    if (!(a(j, j) > 0.0)) return false;
    const double d = std::sqrt(a(j, j));
    for (int i = j; i < N; ++i) a(i, j) /= d;
  }
  for (int i = 0; i < N; ++i) {  // L y = b
    double v = b(i);
    for (int k = 0; k < i; ++k) v -= a(i, k) * (*x)(k);
    (*x)(i) = v / a(i, i);
  }
  for (int i = N - 1; i >= 0; --i) {  // L' x = y
    double v = (*x)(i);
    for (int k = i + 1; k < N; ++k) v -= a(k, i) * (*x)(k);
    (*x)(i) = v / a(i, i);
  }
  return true;
}

struct StepFit {
  bool ok = false;
  double x0 = 0.0;             // rim position, px of d
  double x1 = 0.0;             // bottom-rim position (the wall's inner edge), px of d
  double sigma = 0.0;          // blur, px
  double contrast = 0.0;       // surface minus the level just inside the rim, image units
  double wall_contrast = 0.0;  // wall minus hole level (c1), image units
  double rms = 0.0;            // residual RMS, image units
};

// Which parameters a step fit has.
enum class Inner {
  kRamp,   // no wall term; a ramp gi inside the rim
  kFree,   // wall term with x1 free
  kFixed,  // wall term with x1 held (from the bottom-rim circle)
  kTied,   // wall term with x1 = x0 - w and the wall's level c1 held (BorePrior)
};

// The rim profile of the header fitted to (d, value) samples by
// Levenberg-damped Gauss-Newton, the blur s fitted too:
//   f = a + c0 Phi(z0) + go Rout(u0) + [gi Rin(u0)] + [c1 (Phi(z1) - Phi(z0)) if x1 < x0],
//   u_j = d - x_j, z_j = u_j / s, Rout(u) = u Phi(u/s) + s phi(u/s),
//   Rin(u) = u Phi(-u/s) - s phi(u/s) (ramps blurred by the same Gaussian);
// the last term is the bore wall, the band [x1, x0] between the bottom rim
// and the top rim (absent where the wall is hidden, x1 >= x0). kTied: the
// band's width w = `x1` and its level c1 = `wall_level` are given, so the
// wall term moves with x0 and has no free parameter.
template <Inner kInner>
StepFit FitStepOf(const std::vector<double>& d, const std::vector<double>& v, double x0, double x1,
                  double sigma, double wall_level) {
  constexpr bool kWall = kInner != Inner::kRamp;
  constexpr bool kTiedWall = kInner == Inner::kTied;
  constexpr int kLinear = kTiedWall ? 3 : 4;                  // a, c0, go, and gi or c1 (not tied)
  constexpr int kNonlinear = kInner == Inner::kFree ? 3 : 2;  // x0, [x1,] s
  constexpr int kParams = kNonlinear + kLinear;
  using Normal = Eigen::Matrix<double, kParams, kParams>;
  using Vector = Eigen::Matrix<double, kParams, 1>;
  using Linear = Eigen::Matrix<double, kLinear, 1>;
  const int n = static_cast<int>(d.size());
  StepFit fit;
  if (n < kParams + 3) return fit;
  const double tied_width = x1;
  if constexpr (kTiedWall) x1 = x0 - tied_width;
  struct Params {
    double x0, x1, s;
    Linear lin;
  };
  // The Jacobian's rows (nonlinear parameters first, then the linear ones)
  // and the residuals at the last point evaluated.
  Eigen::Matrix<double, kParams, Eigen::Dynamic> rows(kParams, n);
  Eigen::VectorXd residual(n);
  // Sum of squared residuals; rows and residuals kept for normal_equations.
  auto evaluate = [&](const Params& p) {
    const double x1_here = kTiedWall ? p.x0 - tied_width : p.x1;
    const bool band = kWall && x1_here < p.x0;
    const double c0 = p.lin(1), go = p.lin(2), l3 = kTiedWall ? wall_level : p.lin(kLinear - 1);
    double cost = 0.0;
    for (int i = 0; i < n; ++i) {
      const double di = d[static_cast<size_t>(i)];
      const double u0 = di - p.x0, z0 = u0 / p.s;
      const Normal01 n0 = NormalAt(z0);
      const double cdf0 = n0.cdf, pdf0 = n0.pdf;
      const double z1 = (di - x1_here) / p.s;
      const Normal01 n1 = band ? NormalAt(z1) : Normal01{0.0, 0.0};
      const double cdf1 = n1.cdf, pdf1 = n1.pdf;
      Linear basis;
      double r;
      if constexpr (kTiedWall) {
        basis << 1.0, cdf0, u0 * cdf0 + p.s * pdf0;
        r = basis.dot(p.lin) + wall_level * (cdf1 - cdf0) - v[static_cast<size_t>(i)];
      } else {
        basis << 1.0, cdf0, u0 * cdf0 + p.s * pdf0,
            kWall ? (band ? cdf1 - cdf0 : 0.0) : u0 * (1.0 - cdf0) - p.s * pdf0;
        r = basis.dot(p.lin) - v[static_cast<size_t>(i)];
      }
      cost += r * r;
      residual(i) = r;
      auto row = rows.col(i);
      if constexpr (kTiedWall) {
        row(0) = -(c0 * pdf0 / p.s + go * cdf0) + l3 * (pdf0 - pdf1) / p.s;
        row(1) = -c0 * z0 * pdf0 / p.s + go * pdf0 + l3 * (z0 * pdf0 - z1 * pdf1) / p.s;
      } else if constexpr (kWall) {
        row(0) = -(c0 * pdf0 / p.s + go * cdf0) + (band ? l3 * pdf0 / p.s : 0.0);
        if constexpr (kInner == Inner::kFree) row(1) = band ? -l3 * pdf1 / p.s : 0.0;
        row(kNonlinear - 1) =
            -c0 * z0 * pdf0 / p.s + go * pdf0 + (band ? l3 * (z0 * pdf0 - z1 * pdf1) / p.s : 0.0);
      } else {
        row(0) = -(c0 * pdf0 / p.s + go * cdf0 + l3 * (1.0 - cdf0));
        row(1) = -c0 * z0 * pdf0 / p.s + (go - l3) * pdf0;
      }
      row.template segment<kLinear>(kNonlinear) = basis;
    }
    return cost;
  };
  // The normal equations of the last point evaluated, J'J's lower triangle
  // (all SolveSpd reads): built only where a step is taken from that point.
  auto normal_equations = [&](Normal* jtj, Vector* jtr) {
    jtj->setZero();
    jtr->setZero();
    for (int i = 0; i < n; ++i) {
#pragma GCC unroll 8  // as in SolveSpd
      for (int c = 0; c < kParams; ++c) {
#pragma GCC unroll 8
        for (int r = c; r < kParams; ++r) (*jtj)(r, c) += rows(r, i) * rows(c, i);
      }
      *jtr += rows.col(i) * residual(i);
    }
  };
  Params p{x0, x1, sigma, Linear::Zero()};
  // The linear parameters at the start: least squares (tiny ridge: the wall
  // column is zero where the wall is hidden). The residuals at zero are
  // -v, less the tied wall term.
  evaluate(p);
  using LinearNormal = Eigen::Matrix<double, kLinear, kLinear>;
  LinearNormal btb = LinearNormal::Zero();
  Linear btv = Linear::Zero();
  for (int i = 0; i < n; ++i) {
    const Linear basis = rows.col(i).template segment<kLinear>(kNonlinear);
    btb.noalias() += basis * basis.transpose();
    btv += basis * (kTiedWall ? residual(i) : -v[static_cast<size_t>(i)]);
  }
  p.lin = (btb + 1e-12 * LinearNormal::Identity()).ldlt().solve(-btv);
  double current = evaluate(p);
  Normal jtj;
  Vector jtr;
  normal_equations(&jtj, &jtr);
  double lambda = 1e-3;
  for (int iteration = 0; iteration < 30; ++iteration) {
    bool improved = false, converged = false;
    for (int attempt = 0; attempt < 10 && !improved; ++attempt) {
      Normal damped = jtj;
      damped.diagonal() += lambda * damped.diagonal() + Vector::Constant(1e-12);
      Vector step;
      if (!SolveSpd<kParams>(damped, -jtr, &step)) {
        lambda *= 10;
        continue;
      }
      Params next = p;
      next.x0 += step(0);
      if constexpr (kInner == Inner::kFree) next.x1 += step(1);
      next.s += step(kNonlinear - 1);
      next.lin += step.template segment<kLinear>(kNonlinear);
      if (!(next.s > 0.2)) {
        lambda *= 10;
        continue;
      }
      const double cost = evaluate(next);
      if (cost < current) {
        converged = step.template head<kNonlinear>().cwiseAbs().maxCoeff() < 1e-4;
        // The two-step fit also stops where the cost stalls: a wall narrower
        // than ~2 blurs trades x1 against c1 along a curved valley, which
        // the steps crawl along (a quarter of these fits ran to the cap).
        if constexpr (kInner == Inner::kFree) converged |= current - cost < 1e-3 * current;
        p = next;
        current = cost;
        if (!converged) normal_equations(&jtj, &jtr);
        lambda = std::max(1e-7, lambda * 0.3);
        improved = true;
      } else {
        lambda *= 10;
      }
    }
    if (!improved || converged) break;
  }
  fit.ok = std::isfinite(p.x0) && std::isfinite(current);
  fit.x0 = p.x0;
  fit.x1 = kTiedWall ? p.x0 - tied_width : p.x1;
  fit.sigma = p.s;
  const bool band = kWall && fit.x1 < p.x0;
  fit.wall_contrast = band ? (kTiedWall ? wall_level : p.lin(kLinear - 1)) : 0.0;
  fit.contrast = p.lin(1) - fit.wall_contrast;
  fit.rms = std::sqrt(current / n);
  return fit;
}

// kTied: x1 is the wall's width and `wall_level` its level (FitStepOf).
StepFit FitStep(const std::vector<double>& d, const std::vector<double>& v, double x0, double x1,
                double sigma, Inner inner, double wall_level = 0.0) {
  switch (inner) {
    case Inner::kRamp: return FitStepOf<Inner::kRamp>(d, v, x0, x1, sigma, wall_level);
    case Inner::kFree: return FitStepOf<Inner::kFree>(d, v, x0, x1, sigma, wall_level);
    case Inner::kFixed: return FitStepOf<Inner::kFixed>(d, v, x0, x1, sigma, wall_level);
    case Inner::kTied: return FitStepOf<Inner::kTied>(d, v, x0, x1, sigma, wall_level);
  }
  return {};
}

// One wedge's edges (step 2).
struct WedgeEdge {
  double angle = 0.0;      // of the wedge's centre ray, rad
  bool uncovered = false;  // touches uncovered or off-image pixels
  bool saturated = false;  // its rim step reads saturated pixels: left out
  bool ok = false;         // a clean rim step
  bool inner_ok = false;   // ... and a resolved bottom-rim step inside it
  bool narrow = false;     // the predicted wall is visible but too narrow to resolve
  bool wall_fitted = false;  // pass (b): the wall's level fitted with the rim (two-step fit)
  StepFit step;
};

struct EdgePass {
  std::vector<WedgeEdge> wedges;
  double sigma = kNaN;  // median fitted blur
};

// Where the ray from `centre` at direction n leaves `bottom`, as d (distance
// from centre minus radius); NaN if it misses.
double BottomRimOffset(const Circle& circle, const Circle& bottom, const Eigen::Vector2d& n) {
  const Eigen::Vector2d q = bottom.centre - circle.centre;
  const double b = n.dot(q), disc = b * b - q.squaredNorm() + bottom.radius * bottom.radius;
  if (disc < 0.0) return kNaN;
  return b + std::sqrt(disc) - circle.radius;
}

// A wedge's pixels in the annulus: radial distance d from the circle, px,
// and value; the saturated ones' d apart.
struct WedgePixels {
  std::vector<double> d, v;
  std::vector<double> saturated_d;
  bool SaturatedWithin(double lo, double hi) const {
    return std::any_of(saturated_d.begin(), saturated_d.end(),
                       [lo, hi](double x) { return x >= lo && x <= hi; });
  }
};

// A step fit's samples: a wedge's pixels with d in [lo, hi].
struct StepSamples {
  std::vector<double> d, v;
  void Take(const WedgePixels& pixels, double lo, double hi) {
    d.clear();
    v.clear();
    for (size_t i = 0; i < pixels.d.size(); ++i) {
      if (pixels.d[i] >= lo && pixels.d[i] <= hi) {
        d.push_back(pixels.d[i]);
        v.push_back(pixels.v[i]);
      }
    }
  }
};

// The annulus d_lo <= d <= d_hi about `circle`, pixel by pixel into its
// wedges; the `saturated` ones (if given) apart. A wedge with an uncovered
// pixel outside radius `rcover` is marked uncovered.
std::vector<WedgePixels> GatherWedgePixels(const ImageF& image, const ImageMask* saturated,
                                           const Circle& circle, double d_lo, double d_hi,
                                           double rcover, std::vector<WedgeEdge>* wedges) {
  const int num = static_cast<int>(wedges->size());
  std::vector<WedgePixels> pixels(static_cast<size_t>(num));
  const double rmax = circle.radius + d_hi, rmin = std::max(0.0, circle.radius + d_lo);
  // A wedge's share of the annulus, and some: one allocation each.
  const auto per_wedge = static_cast<size_t>(kPi * (rmax * rmax - rmin * rmin) / num) + 8;
  for (WedgePixels& p : pixels) p.d.reserve(per_wedge), p.v.reserve(per_wedge);
  const auto col_lo = static_cast<Eigen::Index>(std::floor(circle.centre.x() - rmax));
  const auto col_hi = static_cast<Eigen::Index>(std::ceil(circle.centre.x() + rmax));
  const auto row_lo = static_cast<Eigen::Index>(std::floor(circle.centre.y() - rmax));
  const auto row_hi = static_cast<Eigen::Index>(std::ceil(circle.centre.y() + rmax));
  for (Eigen::Index row = row_lo; row <= row_hi; ++row) {
    for (Eigen::Index col = col_lo; col <= col_hi; ++col) {
      const double dx = col - circle.centre.x(), dy = row - circle.centre.y();
      const double rho = std::sqrt(dx * dx + dy * dy);
      if (rho < rmin || rho > rmax) continue;
      double t = std::atan2(dy, dx);
      if (t < 0) t += 2 * kPi;
      const auto k = static_cast<size_t>(std::min(num - 1, static_cast<int>(t / (2 * kPi) * num)));
      if (!Covered(image, row, col)) {
        if (rho >= rcover) (*wedges)[k].uncovered = true;
        continue;
      }
      if (saturated != nullptr && (*saturated)(row, col)) {
        pixels[k].saturated_d.push_back(rho - circle.radius);
        continue;
      }
      pixels[k].d.push_back(rho - circle.radius);
      pixels[k].v.push_back(image(row, col));
    }
  }
  return pixels;
}

// A wedge's centre ray from the circle's d_lo to d_hi, sampled every kStep
// px (bilinear), and its rises over 1 px, deriv(i) = value(i + h) -
// value(i - h), h = kHalfRise (zero where they reach beyond the covered
// samples).
class RayProfile {
 public:
  static constexpr double kStep = 0.25;
  static constexpr int kHalfRise = 2;  // samples: 0.5 px

  RayProfile(double d_lo, double d_hi)
      : d_lo_(d_lo),
        value_(static_cast<int>(std::lround((d_hi - d_lo) / kStep)) + 1),
        deriv_(Eigen::VectorXd::Zero(value_.size())) {}

  // The ray along n; false where it is covered too little inside `d_fit`
  // for a step fit there.
  bool Sample(const ImageF& image, const Circle& circle, const Eigen::Vector2d& n, double d_fit) {
    const int samples = static_cast<int>(value_.size());
    first_ = samples;
    for (int i = samples - 1; i >= 0; --i) {
      const Eigen::Vector2d p = circle.centre + (circle.radius + Offset(i)) * n;
      value_(i) = Bilinear(image, p.x(), p.y());
      if (std::isnan(value_(i))) break;
      first_ = i;
    }
    if (first_ > Index(d_fit) - kHalfRise) return false;
    deriv_.head(first_ + kHalfRise).setZero();
    for (int i = first_ + kHalfRise; i + kHalfRise < samples; ++i)
      deriv_(i) = value_(i + kHalfRise) - value_(i - kHalfRise);
    return true;
  }

  int Index(double d) const { return static_cast<int>(std::lround((d - d_lo_) / kStep)); }
  double Offset(int i) const { return d_lo_ + i * kStep; }
  int FirstRise() const { return first_ + kHalfRise; }  // the innermost rise of covered samples
  double Rise(int i) const { return deriv_(i); }
  bool IsPeak(int i) const { return deriv_(i) >= deriv_(i - 1) && deriv_(i) >= deriv_(i + 1); }

 private:
  double d_lo_;
  Eigen::VectorXd value_, deriv_;
  int first_ = 0;  // samples [first_, size) are covered
};

// The rim on a profile: the outermost strong dark-to-bright step within
// [d_lo, d_hi], a local maximum of at least half the largest rise there; its
// index, -1 if none.
int RimPeak(const RayProfile& profile, double d_lo, double d_hi) {
  const int i_lo = profile.Index(d_lo), i_hi = profile.Index(d_hi);
  double largest = 0.0;
  for (int i = i_lo; i <= i_hi; ++i) largest = std::max(largest, profile.Rise(i));
  if (!(largest > 0.0)) return -1;
  for (int i = i_hi; i >= i_lo; --i)
    if (profile.Rise(i) >= 0.5 * largest && profile.IsPeak(i)) return i;
  return -1;
}

// A clean rim step: its rim within 1 px of the profile's, contrast and blur
// in range.
bool IsRimStep(const StepFit& step, double x_rim, const CircleMeasureOptions& options) {
  return step.ok && std::abs(step.x0 - x_rim) <= 1.0 && step.contrast >= options.min_contrast &&
         step.sigma < options.profile_half_width_px;
}

// Pass (b)'s fit of a wedge (Inner::kFree): its rim at x_rim, and the bottom
// rim looked for down to `reach` inside it, as a step of its own when far
// inside, else as a two-step fit.
void FitRimAndBottomRim(const WedgePixels& pixels, const RayProfile& profile, int peak, double band,
                        double reach, double sigma, const CircleMeasureOptions& options,
                        StepSamples* samples, WedgeEdge* wedge) {
  const double hw = options.profile_half_width_px;
  const double x_rim = profile.Offset(peak);
  samples->Take(pixels, x_rim - hw, x_rim + hw);
  wedge->step = FitStep(samples->d, samples->v, x_rim, x_rim - hw, sigma, Inner::kRamp);
  wedge->ok = IsRimStep(wedge->step, x_rim, options);
  // The bottom rim: the strongest rise inside the rim's flank ...
  const int stop = std::max(profile.FirstRise(), profile.Index(x_rim - reach + band));
  double best = 0.2 * options.min_contrast;
  int inner_peak = -1;
  for (int i = peak - static_cast<int>(std::lround(2.0 * sigma / RayProfile::kStep)); i >= stop;
       --i) {
    if (profile.Rise(i) > best && profile.IsPeak(i)) {
      best = profile.Rise(i);
      inner_peak = i;
    }
  }
  const double x_peak = profile.Offset(inner_peak);
  if (wedge->ok && inner_peak >= 0 && x_peak < x_rim - 2.0 * hw) {
    // ... far inside: a step of its own.
    samples->Take(pixels, x_peak - hw, x_peak + hw);
    const StepFit step = FitStep(samples->d, samples->v, x_peak, x_peak - hw, sigma, Inner::kRamp);
    if (step.ok && std::abs(step.x0 - x_peak) <= 1.0 &&
        step.contrast >= 0.5 * options.min_contrast) {
      wedge->step.x1 = step.x0;
      wedge->step.wall_contrast = step.contrast;
      wedge->inner_ok = true;
    }
    return;
  }
  // ... or near: both steps in one fit, started there or on two shoulders
  // of the rim's flank (a narrow wall shows as a shoulder, not a peak); it
  // must explain the same samples clearly better than the rim alone.
  std::vector<double> starts = {x_rim - 2.0 * sigma, x_rim - 3.5 * sigma};
  if (inner_peak >= 0) starts.push_back(x_peak);
  const double lo = std::min(x_rim - hw, *std::min_element(starts.begin(), starts.end()) - hw);
  samples->Take(pixels, lo, x_rim + hw);
  std::optional<StepFit> alone;  // fitted when a two-step fit needs the comparison
  for (const double x1 : starts) {
    const StepFit step = FitStep(samples->d, samples->v, x_rim, x1, sigma, Inner::kFree);
    if (!(IsRimStep(step, x_rim, options) && step.x1 < step.x0 - 2.0 * step.sigma &&
          step.x1 > lo + step.sigma && step.wall_contrast >= 0.5 * options.min_contrast)) {
      continue;
    }
    if (!alone) alone = FitStep(samples->d, samples->v, x_rim, x_rim, sigma, Inner::kRamp);
    if (step.rms < 0.7 * alone->rms && (!wedge->inner_ok || step.rms < wedge->step.rms)) {
      wedge->step = step;
      wedge->ok = wedge->inner_ok = wedge->wall_fitted = true;
    }
  }
}

// One pass of step 2 about `circle` (the header's passes a-c): `inner` is
// kRamp for the rims alone, kFree to look for the bottom rim on each ray as
// well, kFixed to take it from `bottom`. The blur is fitted per wedge,
// `sigma` (the previous pass's median) only places the shoulder starts.
// With kFixed, wedges whose wall is visible but narrower than `narrow_px`
// are marked narrow (none if 0); given `narrow_wall_level` (BorePrior), they
// are fitted with the wall tied to the rim at that level (kTied).
EdgePass FindEdges(const ImageF& image, const ImageMask* saturated, const Circle& circle,
                   double band, double sigma, Inner inner, const std::optional<Circle>& bottom,
                   double narrow_px, std::optional<double> narrow_wall_level,
                   const CircleMeasureOptions& options) {
  const double hw = options.profile_half_width_px;
  const int num =
      std::max(options.min_wedges,
               static_cast<int>(std::lround(2 * kPi * circle.radius / options.wedge_arc_px)));
  EdgePass pass;
  pass.wedges.resize(static_cast<size_t>(num));
  // The bore wall can be wide (a thick part far from the camera's axis):
  // the bottom rim is looked for down to `reach` inside the rim.
  const double reach =
      std::clamp(0.5 * circle.radius, band + 2.0 * hw, std::max(band + 2.0 * hw, 30.0));
  const double d_lo = -band - (inner == Inner::kFree ? reach : hw + 1.0), d_hi = band + hw + 1.0;
  const double rcover = circle.radius - band - hw - 1.0;  // uncovered pixels matter outside this
  const std::vector<WedgePixels> pixels =
      GatherWedgePixels(image, saturated, circle, d_lo, d_hi, rcover, &pass.wedges);
  RayProfile profile(d_lo, d_hi);
  StepSamples samples;
  for (int k = 0; k < num; ++k) {
    WedgeEdge& wedge = pass.wedges[static_cast<size_t>(k)];
    wedge.angle = 2 * kPi * (k + 0.5) / num;
    if (wedge.uncovered) continue;
    const Eigen::Vector2d n(std::cos(wedge.angle), std::sin(wedge.angle));
    if (!profile.Sample(image, circle, n, -band - hw)) {
      wedge.uncovered = true;
      continue;
    }
    const int peak = RimPeak(profile, -band, band);
    if (peak < 0) continue;
    const WedgePixels& wedge_pixels = pixels[static_cast<size_t>(k)];
    if (wedge_pixels.SaturatedWithin(profile.Offset(peak) - hw, profile.Offset(peak) + hw)) {
      wedge.saturated = true;
      continue;
    }
    if (inner == Inner::kFree) {
      FitRimAndBottomRim(wedge_pixels, profile, peak, band, reach, sigma, options, &samples,
                         &wedge);
      continue;
    }
    const double x_rim = profile.Offset(peak);
    double x1 = kNaN;
    Inner mode = inner;
    if (inner == Inner::kFixed) {
      x1 = bottom ? BottomRimOffset(circle, *bottom, n) : kNaN;
      wedge.narrow = x1 < 0.0 && x1 > -narrow_px;
      // Beyond the window's reach (a wide wall) or no bottom rim: the ramp.
      if (!(x1 > x_rim - hw - 3.0 * sigma)) mode = Inner::kRamp;
      if (wedge.narrow && narrow_wall_level) {
        mode = Inner::kTied;
        x1 = -x1;  // the band's width
      }
    }
    samples.Take(wedge_pixels, x_rim - hw, x_rim + hw);
    wedge.step =
        FitStep(samples.d, samples.v, x_rim, x1, sigma, mode, narrow_wall_level.value_or(0.0));
    wedge.ok = IsRimStep(wedge.step, x_rim, options);
  }
  // A wedge whose step fits its pixels far worse than the median wedge's is
  // no clean edge (a burr, a scratch).
  std::vector<double> rms, sigmas;
  for (const WedgeEdge& w : pass.wedges) {
    if (!w.ok) continue;
    rms.push_back(w.step.rms);
    sigmas.push_back(w.step.sigma);
  }
  const double rms_limit = options.max_profile_rms_ratio * Median(rms);
  for (WedgeEdge& w : pass.wedges) {
    if (w.ok && w.step.rms > rms_limit) w.ok = w.inner_ok = false;
  }
  pass.sigma = Median(sigmas);
  return pass;
}

struct CircleFit {
  Circle circle;
  std::vector<int> index;        // wedge of each point
  Eigen::Matrix2Xd points;       // edge points
  Eigen::VectorXd residual;      // radial, px
  Eigen::VectorXd weight;        // final IRLS weight
  double scale = 0.0;            // robust sigma of the residuals
  Eigen::Matrix3Xd sensitivity;  // d (cx, cy, r) / d (radial move of point i)
};

// IRLS weights of a residual: Huber's (k = 1.345 robust sigmas) and Tukey's
// biweight (cut-off `tukey` robust sigmas), `scale` the robust sigma.
double HuberWeight(double residual, double scale) {
  const double a = std::abs(residual) / (1.345 * scale);
  return a <= 1.0 ? 1.0 : 1.0 / a;
}
double TukeyWeight(double residual, double tukey, double scale) {
  const double a = residual / (tukey * scale);
  return std::abs(a) < 1.0 ? std::pow(1.0 - a * a, 2) : 0.0;
}

// 1.4826 median |residual|, at least 1e-6 (an exact fit).
double RobustScale(const Eigen::VectorXd& residual) {
  std::vector<double> abs_res(static_cast<size_t>(residual.size()));
  for (Eigen::Index i = 0; i < residual.size(); ++i)
    abs_res[static_cast<size_t>(i)] = std::abs(residual(i));
  return std::max(1.4826 * Median(std::move(abs_res)), 1e-6);
}

// Step 3: IRLS circle fit, Huber then Tukey, starting from `start`.
CircleFit FitCircleRobust(const Eigen::Matrix2Xd& points, const Circle& start, double tukey) {
  const Eigen::Index n = points.cols();
  CircleFit fit;
  fit.circle = start;
  fit.points = points;
  fit.weight = Eigen::VectorXd::Ones(n);
  fit.residual.resize(n);
  Eigen::MatrixXd jac(n, 3);
  auto linearise = [&]() {
    for (Eigen::Index i = 0; i < n; ++i) {
      const Eigen::Vector2d u = points.col(i) - fit.circle.centre;
      const double norm = u.norm();
      fit.residual(i) = norm - fit.circle.radius;
      jac.row(i) << -u.x() / norm, -u.y() / norm, -1.0;
    }
  };
  auto solve = [&]() {
    const Eigen::MatrixXd jw = fit.weight.asDiagonal() * jac;
    const Eigen::Vector3d step =
        (jac.transpose() * jw).ldlt().solve(-jw.transpose() * fit.residual);
    fit.circle.centre += step.head<2>();
    fit.circle.radius += step(2);
    return step.norm();
  };
  linearise();
  // Huber (k = 1.345 sigma) with the scale re-estimated, then Tukey with it held.
  for (int iteration = 0; iteration < 10; ++iteration) {
    fit.scale = RobustScale(fit.residual);
    for (Eigen::Index i = 0; i < n; ++i) fit.weight(i) = HuberWeight(fit.residual(i), fit.scale);
    const double moved = solve();
    linearise();
    if (moved < 1e-7) break;
  }
  fit.scale = RobustScale(fit.residual);
  for (int iteration = 0; iteration < 30; ++iteration) {
    for (Eigen::Index i = 0; i < n; ++i)
      fit.weight(i) = TukeyWeight(fit.residual(i), tukey, fit.scale);
    const double moved = solve();
    linearise();
    if (moved < 1e-9) break;
  }
  for (Eigen::Index i = 0; i < n; ++i)
    fit.weight(i) = TukeyWeight(fit.residual(i), tukey, fit.scale);
  // delta = -(J'WJ)^-1 J'W delta_residual; a point moving out by e raises its residual by e.
  const Eigen::MatrixXd jw = fit.weight.asDiagonal() * jac;
  fit.sensitivity = -(jac.transpose() * jw).ldlt().solve(jw.transpose());
  return fit;
}

// The bottom rim as the top rim `top` scaled by k about the nadir (header):
// the k whose circle nadir + k (c - nadir), k r fits the bottom-rim points
// best, by Gauss-Newton on their distances to it with Huber, then Tukey
// weights as in FitCircleRobust. nullopt unless it settles in (0, 1).
std::optional<double> FitBottomScale(const Eigen::Matrix2Xd& points, const Circle& top,
                                     const Eigen::Vector2d& nadir, double start, double tukey) {
  const Eigen::Index n = points.cols();
  const Eigen::Vector2d b = top.centre - nadir;
  double k = start, scale = 0.0;
  Eigen::VectorXd residual(n), slope(n);
  constexpr int kHuberIterations = 10, kIterations = 20;
  for (int iteration = 0; iteration < kIterations; ++iteration) {
    for (Eigen::Index i = 0; i < n; ++i) {
      const Eigen::Vector2d u = points.col(i) - nadir - k * b;
      const double norm = u.norm();
      residual(i) = norm - k * top.radius;
      slope(i) = -u.dot(b) / norm - top.radius;
    }
    if (iteration < kHuberIterations) scale = RobustScale(residual);
    double jwj = 0.0, jwr = 0.0;
    for (Eigen::Index i = 0; i < n; ++i) {
      const double w = iteration < kHuberIterations ? HuberWeight(residual(i), scale)
                                                    : TukeyWeight(residual(i), tukey, scale);
      jwj += w * slope(i) * slope(i);
      jwr += w * slope(i) * residual(i);
    }
    if (!(jwj > 0.0)) return std::nullopt;
    k -= jwr / jwj;
  }
  if (!(k > 0.0 && k < 1.0)) return std::nullopt;
  return k;
}

// The edge errors' spectral density at the circle's frequencies (0 and 1
// per turn), per wedge: f = sum over all lags l of gamma(l), gamma the
// autocovariance of the errors along the arc, lag in wedges. Then the fit's
// covariance is f S S' (S the sensitivity): S's rows lie in the span of
// 1, cos, sin, where a stationary sequence's covariance acts as f when the
// spectrum is flat over the lowest frequencies.
// Estimate: the pooled autocovariance of the inlier residuals, gamma_res(l),
// summed over |l| < L, L the first lag where it is <= 0 (the correlation
// has died out). The fit removed three components from the n residuals, so
// E gamma_res(l) = gamma(l) - 3 f / n for l << n: the sum is divided by
// 1 - 3 (2L - 1) / n. Floors: the white estimate (f = gamma(0)) and the
// correlation the image's resampling implies (`min_samples` wedges per
// independent error).
struct EdgeErrorSpectrum {
  double density = 0.0;                  // f, px^2
  double samples_per_independent = 1.0;  // f / gamma(0)
};

EdgeErrorSpectrum EstimateEdgeErrorSpectrum(const CircleFit& fit, int num_wedges,
                                            double min_samples) {
  std::vector<double> by_wedge(static_cast<size_t>(num_wedges), kNaN);
  int n = 0;
  for (Eigen::Index i = 0; i < fit.weight.size(); ++i) {
    if (fit.weight(i) <= 0.0) continue;
    by_wedge[static_cast<size_t>(fit.index[static_cast<size_t>(i)])] = fit.residual(i);
    ++n;
  }
  auto autocovariance = [&](int lag) {
    double sum = 0.0;
    int count = 0;
    for (int k = 0; k < num_wedges; ++k) {
      const double a = by_wedge[static_cast<size_t>(k)];
      const double b = by_wedge[static_cast<size_t>((k + lag) % num_wedges)];
      if (std::isnan(a) || std::isnan(b)) continue;
      sum += a * b;
      ++count;
    }
    return count > 0 ? sum / count : 0.0;
  };
  const double gamma0 = autocovariance(0);
  EdgeErrorSpectrum spectrum;
  spectrum.density = gamma0 * n / std::max(1, n - 3);
  if (!(gamma0 > 0.0)) return spectrum;
  // Lags while the bias correction stays moderate: 3 (2L - 1) / n <= 1/2.
  const int max_lag = std::max(1, static_cast<int>((n / 6.0 + 1.0) / 2.0));
  double sum = gamma0;
  int lag = 1;
  for (; lag <= max_lag; ++lag) {
    const double g = autocovariance(lag);
    if (g <= 0.0) break;
    sum += 2.0 * g;
  }
  const double corrected = sum / (1.0 - 3.0 * (2.0 * lag - 1.0) / n);
  spectrum.density = std::max({spectrum.density, corrected, gamma0 * min_samples});
  spectrum.samples_per_independent = spectrum.density / gamma0;
  return spectrum;
}

// The bore's bottom rim as the passes learn it (header): with a nadir, the
// top rim scaled by k about it, k fitted to `points`; without one, a free
// circle.
struct BottomRim {
  std::optional<Circle> free;
  std::optional<double> scale;
  Eigen::Matrix2Xd points;

  bool Known() const { return free.has_value() || scale.has_value(); }
  std::optional<Circle> Below(const Circle& top,
                              const std::optional<Eigen::Vector2d>& nadir) const {
    if (!scale) return free;
    return Circle{*nadir + *scale * (top.centre - *nadir), *scale * top.radius};
  }
};

// Wedges that could give a rim edge: all but the narrow-wall ones left out,
// those next to saturated pixels and the uncovered ones (a partial view's).
int UsableWedges(const CircleMeasurement& result) {
  return result.num_wedges - (result.narrow_wall_skipped ? result.num_narrow_wall : 0) -
         result.num_saturated - result.num_uncovered;
}

// A pass's wedges: those whose rim edge the circle fit takes, and those that
// resolved the bottom rim.
struct WedgeSelection {
  std::vector<int> rim;
  std::vector<int> bottom_rim;
};

// Sorts a pass's wedges, counting them into `result`.
WedgeSelection SelectWedges(const EdgePass& pass, CircleMeasurement* result) {
  const int num = static_cast<int>(pass.wedges.size());
  result->num_wedges = num;
  result->num_uncovered = 0;
  result->num_saturated = 0;
  result->num_narrow_wall = 0;
  for (const WedgeEdge& w : pass.wedges) result->num_narrow_wall += w.narrow ? 1 : 0;
  // Left out while the rest spans half the rim or more; else the fit
  // keeps them (the header's limit).
  result->narrow_wall_skipped =
      result->num_narrow_wall > 0 && 2 * result->num_narrow_wall <= num && !result->bore_prior_used;
  WedgeSelection selection;
  for (int k = 0; k < num; ++k) {
    const WedgeEdge& w = pass.wedges[static_cast<size_t>(k)];
    if (w.uncovered) ++result->num_uncovered;
    if (w.saturated) ++result->num_saturated;
    if (w.ok && !(w.narrow && result->narrow_wall_skipped)) selection.rim.push_back(k);
    if (w.inner_ok) selection.bottom_rim.push_back(k);
  }
  result->num_edge_points = static_cast<int>(selection.rim.size());
  return selection;
}

// Why a pass's edges cannot place the hole ("" when they can).
std::string PassError(const CircleMeasurement& result, const CircleMeasureOptions& options) {
  if (result.num_uncovered > options.max_uncovered_fraction * result.num_wedges) {
    char text[128];
    std::snprintf(text, sizeof(text), "cut by the mosaic border (%.0f%% of the rim not covered)",
                  100.0 * result.num_uncovered / result.num_wedges);
    return text;
  }
  if (result.num_saturated > options.max_saturated_fraction * result.num_wedges) {
    char text[128];
    std::snprintf(text, sizeof(text),
                  "rim saturated (%.0f%% of it next to pixels at full scale: lower the exposure)",
                  100.0 * result.num_saturated / result.num_wedges);
    return text;
  }
  const int usable = UsableWedges(result);
  if (result.num_edge_points < options.min_found_fraction * usable) {
    return "not found near the expected position (clean edges on " +
           std::to_string(result.num_edge_points) + " of " + std::to_string(usable) + " wedges)";
  }
  return {};
}

// The edge points of the wedges `which` about `circle`: on the top rim (the
// steps' x0) or on the bottom rim (x1).
Eigen::Matrix2Xd RimPoints(const EdgePass& pass, const Circle& circle,
                           const std::vector<int>& which, bool bottom_rim) {
  Eigen::Matrix2Xd points(2, static_cast<Eigen::Index>(which.size()));
  for (size_t i = 0; i < which.size(); ++i) {
    const WedgeEdge& w = pass.wedges[static_cast<size_t>(which[i])];
    const double offset = bottom_rim ? w.step.x1 : w.step.x0;
    points.col(static_cast<Eigen::Index>(i)) =
        circle.centre +
        (circle.radius + offset) * Eigen::Vector2d(std::cos(w.angle), std::sin(w.angle));
  }
  return points;
}

// What pass (b), which looked for the bottom rim on each ray, tells: the
// bottom rim where enough wedges resolved it, the wall's level, and whether
// the BorePrior is to be used instead.
void LearnBottomRim(const EdgePass& pass, const WedgeSelection& wedges, const Circle& circle,
                    double sigma, const std::optional<Eigen::Vector2d>& nadir_px,
                    const std::optional<BorePrior>& prior, const CircleMeasureOptions& options,
                    BottomRim* bottom, CircleMeasurement* result) {
  const int num = static_cast<int>(pass.wedges.size());
  if (static_cast<int>(wedges.bottom_rim.size()) >= std::max(12, num / 10)) {
    const Eigen::Matrix2Xd points = RimPoints(pass, circle, wedges.bottom_rim, true);
    std::vector<double> offsets;
    offsets.reserve(wedges.bottom_rim.size());
    for (int k : wedges.bottom_rim) offsets.push_back(pass.wedges[static_cast<size_t>(k)].step.x1);
    if (nadir_px) {
      bottom->points = points;
      bottom->scale = FitBottomScale(points, circle, *nadir_px,
                                     1.0 + Median(offsets) / circle.radius, options.tukey_sigmas);
    }
    if (!bottom->scale) {
      const CircleFit fit = FitCircleRobust(
          points, Circle{circle.centre, circle.radius + Median(offsets)}, options.tukey_sigmas);
      // The bottom rim looks smaller than the top one and lies inside it.
      if (fit.circle.radius > 0.0 && fit.circle.radius < circle.radius &&
          (fit.circle.centre - circle.centre).norm() < circle.radius) {
        bottom->free = fit.circle;
      }
    }
  }
  // The wall's level where a wall 2 blurs to 2 profile half widths wide was
  // fitted with the rim (a BorePrior for other views): the model the tied
  // wall uses. (Wider walls, fitted apart or with the rim's window short of
  // the hole's level, read it 10 % off on synthetic holes.)
  std::vector<double> walls;
  for (int k : wedges.bottom_rim) {
    const WedgeEdge& w = pass.wedges[static_cast<size_t>(k)];
    if (w.wall_fitted) walls.push_back(w.step.wall_contrast);
  }
  if (walls.size() >= 12) result->wall_contrast = Median(walls);
  result->num_bottom_rim_points = static_cast<int>(wedges.bottom_rim.size());
  result->bottom_rim_modelled = bottom->Known();
  if (nadir_px && prior) {
    // The prior's wall, narrower than min_wall_blurs blurs on more than half
    // the rim: those wedges cannot be left out (the Limits), and the view's
    // own bottom rim, if it fitted one, is no better: a ring under a blur
    // wide, or texture taken for one, with the wall's contrast free to trade
    // against x0 (on synthetic 40 px holes near the axis, k 0.98, the 7 % of
    // views that fitted their own k read the radius 0.15-0.17 px small).
    const Circle prior_bottom{*nadir_px + prior->bottom_rim_scale * (circle.centre - *nadir_px),
                              prior->bottom_rim_scale * circle.radius};
    int narrow = 0;
    for (const WedgeEdge& w : pass.wedges) {
      const double x1 = BottomRimOffset(circle, prior_bottom,
                                        Eigen::Vector2d(std::cos(w.angle), std::sin(w.angle)));
      narrow += x1 < 0.0 && x1 > -options.min_wall_blurs * sigma ? 1 : 0;
    }
    if (2 * narrow > num) {
      bottom->scale = prior->bottom_rim_scale;
      result->bore_prior_used = true;
    }
  }
}

// The final fit's inliers: their count, RMS residual and median contrast.
void SummariseInliers(const CircleFit& fit, const EdgePass& pass, CircleMeasurement* result) {
  result->num_inliers = 0;
  double sum2 = 0.0;
  std::vector<double> contrasts;
  for (Eigen::Index i = 0; i < fit.weight.size(); ++i) {
    if (fit.weight(i) <= 0.0) continue;
    ++result->num_inliers;
    sum2 += fit.residual(i) * fit.residual(i);
    contrasts.push_back(
        pass.wedges[static_cast<size_t>(fit.index[static_cast<size_t>(i)])].step.contrast);
  }
  result->rms_px = std::sqrt(sum2 / std::max(1, result->num_inliers));
  result->contrast = Median(contrasts);
}

// Why the final fit is not the hole ("" when it is): too few of the wedges
// that could give an edge on one circle, another radius, or texture.
std::string FitError(const CircleMeasurement& result, double nominal_radius_px,
                     const CircleMeasureOptions& options) {
  const int usable = UsableWedges(result);
  const auto num = static_cast<double>(usable);
  char text[160];
  if (result.num_inliers < options.min_found_fraction * num) {
    return "not found near the expected position (" + std::to_string(result.num_inliers) + " of " +
           std::to_string(usable) + " wedges fit one circle)";
  }
  if (std::abs(result.radius_px / nominal_radius_px - 1.0) > options.max_radius_deviation) {
    std::snprintf(text, sizeof(text),
                  "not found near the expected position (the circle found has radius %.1f px, "
                  "nominal %.1f px)",
                  result.radius_px, nominal_radius_px);
    return text;
  }
  if (result.rms_px > options.max_rms_px) {
    // Edges scattered by px about the best circle: texture, not a rim.
    std::snprintf(text, sizeof(text),
                  "not found near the expected position (no rim of the nominal radius: edges "
                  "%.2f px RMS off the best circle)",
                  result.rms_px);
    return text;
  }
  if (result.num_inliers < options.min_inlier_fraction * num) {
    std::snprintf(text, sizeof(text), "poor fit: %d of %d wedges fit the circle, rms %.3f px",
                  result.num_inliers, usable, result.rms_px);
    return text;
  }
  return {};
}

// What the borrowed wall level's own error moves the tied rim (~2 px per
// unit of level): the covariance term of (cx, cy, r) by central
// differences, refitting at the level +- its sigma; zero where a refit
// fails or uses no prior.
Eigen::Matrix3d WallLevelCovariance(const ImageF& image, const ImageMask* saturated,
                                    const Eigen::Vector2d& expected_centre_px,
                                    double nominal_radius_px, const CircleMeasureOptions& options,
                                    const Eigen::Vector2d& nadir_px, const BorePrior& prior) {
  const auto refit = [&](double sign) {
    BorePrior shifted = prior;
    shifted.wall_contrast += sign * prior.wall_contrast_sigma;
    shifted.wall_contrast_sigma = 0.0;
    return MeasureCircle(image, expected_centre_px, nominal_radius_px, options, nadir_px, shifted,
                         saturated);
  };
  const CircleMeasurement plus = refit(1.0), minus = refit(-1.0);
  if (!(plus.ok && minus.ok && plus.bore_prior_used && minus.bore_prior_used)) {
    return Eigen::Matrix3d::Zero();
  }
  const Eigen::Vector3d g(0.5 * (plus.centre_px.x() - minus.centre_px.x()),
                          0.5 * (plus.centre_px.y() - minus.centre_px.y()),
                          0.5 * (plus.radius_px - minus.radius_px));
  return g * g.transpose();
}

}  // namespace

std::string CircleMeasureOptions::Check() const {
  std::ostringstream why;
  if (!(search_fraction >= 0.0 && search_fraction <= 1.0))
    why << "search_fraction must be in [0, 1]; ";
  if (!(search_margin_px >= 0.0)) why << "search_margin_px must be >= 0; ";
  if (!(rim_band_px >= 1.0)) why << "rim_band_px must be >= 1; ";
  if (!(profile_half_width_px >= 1.5)) why << "profile_half_width_px must be >= 1.5; ";
  if (!(wedge_arc_px > 0.0)) why << "wedge_arc_px must be > 0; ";
  if (min_wedges < 16) why << "min_wedges must be >= 16; ";
  if (!(min_contrast > 0.0)) why << "min_contrast must be > 0; ";
  if (!(max_profile_rms_ratio > 1.0)) why << "max_profile_rms_ratio must be > 1; ";
  if (!(tukey_sigmas > 1.0)) why << "tukey_sigmas must be > 1; ";
  if (!(max_uncovered_fraction >= 0.0 && max_uncovered_fraction < 1.0)) {
    why << "max_uncovered_fraction must be in [0, 1); ";
  }
  if (!(max_saturated_fraction >= 0.0 && max_saturated_fraction < 1.0)) {
    why << "max_saturated_fraction must be in [0, 1); ";
  }
  if (!(min_found_fraction > 0.0 && min_found_fraction <= min_inlier_fraction &&
        min_inlier_fraction <= 1.0)) {
    why << "need 0 < min_found_fraction <= min_inlier_fraction <= 1; ";
  }
  if (!(max_radius_deviation > 0.0)) why << "max_radius_deviation must be > 0; ";
  if (!(max_rms_px > 0.0)) why << "max_rms_px must be > 0; ";
  if (!(source_px > 0.0)) why << "source_px must be > 0; ";
  if (!(min_wall_blurs >= 0.0)) why << "min_wall_blurs must be >= 0; ";
  if (max_passes < 1) why << "max_passes must be >= 1; ";
  if (!(converged_px > 0.0)) why << "converged_px must be > 0; ";
  std::string text = why.str();
  if (!text.empty()) text.resize(text.size() - 2);
  return text;
}

std::string CircleMeasurement::Brief() const {
  char line[256];
  if (!ok) return error;
  std::snprintf(line, sizeof(line),
                "centre (%.3f, %.3f) px, r %.3f px, sigma (%.4f, %.4f, %.4f) px; %d/%d edges, %d "
                "inliers, rms %.3f px, blur %.2f px, correlation %.1f px",
                centre_px.x(), centre_px.y(), radius_px, std::sqrt(covariance_px2(0, 0)),
                std::sqrt(covariance_px2(1, 1)), std::sqrt(covariance_px2(2, 2)), num_edge_points,
                num_wedges, num_inliers, rms_px, edge_sigma_px, correlation_px);
  if (num_saturated == 0) return line;
  return std::string(line) + "; " + std::to_string(num_saturated) +
         " wedges next to saturated pixels left out";
}

CircleMeasurement MeasureCircle(const ImageF& image, const Eigen::Vector2d& expected_centre_px,
                                double nominal_radius_px, const CircleMeasureOptions& options,
                                const std::optional<Eigen::Vector2d>& nadir_px,
                                const std::optional<BorePrior>& prior, const ImageMask* saturated) {
  assert(options.Check().empty() && nominal_radius_px > 0.0);
  CircleMeasurement result;
  const double search = options.SearchPx(nominal_radius_px);
  result.coarse_centre_px = VoteCentre(image, expected_centre_px, nominal_radius_px, search);
  Circle circle{result.coarse_centre_px, nominal_radius_px};
  double band = options.rim_band_px;
  double sigma = 1.0;
  BottomRim bottom;
  CircleFit fit;
  EdgePass pass;
  for (int p = 0; p < options.max_passes; ++p) {
    result.passes = p + 1;
    // Passes: rims alone (the blur), then with the bottom rim looked for on
    // each ray (its circle), then with the bottom rim from that circle.
    const Inner inner = p == 0           ? Inner::kRamp
                        : p == 1         ? Inner::kFree
                        : bottom.Known() ? Inner::kFixed
                                         : Inner::kRamp;
    pass = FindEdges(image, saturated, circle, band, sigma, inner, bottom.Below(circle, nadir_px),
                     bottom.scale ? options.min_wall_blurs * sigma : 0.0,
                     result.bore_prior_used ? std::optional(prior->wall_contrast) : std::nullopt,
                     options);
    if (std::isfinite(pass.sigma)) sigma = pass.sigma;
    const WedgeSelection wedges = SelectWedges(pass, &result);
    result.error = PassError(result, options);
    if (!result.error.empty()) return result;
    if (inner == Inner::kFree) {
      LearnBottomRim(pass, wedges, circle, sigma, nadir_px, prior, options, &bottom, &result);
    }
    fit = FitCircleRobust(RimPoints(pass, circle, wedges.rim, false), circle, options.tukey_sigmas);
    fit.index = wedges.rim;
    const double moved = std::max((fit.circle.centre - circle.centre).norm(),
                                  std::abs(fit.circle.radius - circle.radius));
    circle = fit.circle;
    // k relates the bottom rim to the top rim as now placed (an early pass's
    // rim can be off by a tenth of a px where a narrow wall merges with it).
    if (bottom.scale && !result.bore_prior_used) {
      bottom.scale =
          FitBottomScale(bottom.points, circle, *nadir_px, *bottom.scale, options.tukey_sigmas)
              .value_or(*bottom.scale);
    }
    result.bottom_rim_scale = bottom.scale.value_or(0.0);
    band = std::clamp(4.0 * fit.scale, 1.0, options.rim_band_px);
    if (p >= 2 && moved < options.converged_px) break;
  }
  SummariseInliers(fit, pass, &result);
  result.edge_sigma_px = sigma;
  result.centre_px = circle.centre;
  result.radius_px = circle.radius + sigma * sigma / (2.0 * circle.radius);
  result.error = FitError(result, nominal_radius_px, options);
  if (!result.error.empty()) return result;

  // Covariance (header; EdgeErrorSpectrum).
  const EdgeErrorSpectrum spectrum = EstimateEdgeErrorSpectrum(
      fit, result.num_wedges, options.source_px / (2 * kPi * circle.radius / result.num_wedges));
  result.covariance_px2 = spectrum.density * fit.sensitivity * fit.sensitivity.transpose();
  result.correlation_px =
      spectrum.samples_per_independent * 2 * kPi * circle.radius / result.num_wedges;
  result.ok = true;
  if (result.bore_prior_used && prior->wall_contrast_sigma > 0.0) {
    result.covariance_px2 += WallLevelCovariance(image, saturated, expected_centre_px,
                                                 nominal_radius_px, options, *nadir_px, *prior);
  }
  return result;
}

}  // namespace omm
