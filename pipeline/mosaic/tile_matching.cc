#include "pipeline/mosaic/tile_matching.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <Eigen/Dense>

#include "pipeline/mosaic/tile_features.h"

namespace omm {

std::string TranslationSearchOptions::Check() const {
  if (coarse_max_size_px < 16) return "translation.coarse_max_size_px must be >= 16";
  if (!(min_overlap_fraction > 0 && min_overlap_fraction < 1))
    return "translation.min_overlap_fraction must be in (0, 1)";
  if (finest_factor < 1) return "translation.finest_factor must be >= 1";
  return {};
}

std::string PatchMatchOptions::Check() const {
  if (half_size_px < 3) return "patch.half_size_px must be >= 3";
  if (!(min_ncc > 0 && min_ncc < 1)) return "patch.min_ncc must be in (0, 1)";
  if (!(min_template_std >= 0)) return "patch.min_template_std must be >= 0";
  if (max_iterations < 1) return "patch.max_iterations must be >= 1";
  if (!(convergence_px > 0)) return "patch.convergence_px must be > 0";
  if (!(max_refinement_px > 0)) return "patch.max_refinement_px must be > 0";
  return {};
}

namespace {

// NCC of a and b over their overlap when b is shifted by (dx, dy): a(r, c)
// against b(r + dy, c + dx). -2 if the overlap is smaller than min_pixels.
double OverlapNcc(const ImageF& a, const ImageF& b, int dx, int dy, Eigen::Index min_pixels,
                  double* overlap_fraction = nullptr) {
  const int c0 = std::max(0, -dx), c1 = std::min<int>(a.cols(), b.cols() - dx);
  const int r0 = std::max(0, -dy), r1 = std::min<int>(a.rows(), b.rows() - dy);
  if (c1 <= c0 || r1 <= r0) return -2.0;
  const Eigen::Index n = static_cast<Eigen::Index>(c1 - c0) * (r1 - r0);
  if (n < min_pixels) return -2.0;
  double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
  for (int r = r0; r < r1; ++r) {
    const float* pa = a.data() + static_cast<size_t>(r) * a.cols();
    const float* pb = b.data() + static_cast<size_t>(r + dy) * b.cols() + dx;
    float fa = 0, fb = 0, faa = 0, fbb = 0, fab = 0;
    for (int c = c0; c < c1; ++c) {
      const float va = pa[c], vb = pb[c];
      fa += va;
      fb += vb;
      faa += va * va;
      fbb += vb * vb;
      fab += va * vb;
    }
    sa += fa, sb += fb, saa += faa, sbb += fbb, sab += fab;
  }
  const double inv_n = 1.0 / static_cast<double>(n);
  const double var_a = saa - sa * sa * inv_n, var_b = sbb - sb * sb * inv_n;
  if (overlap_fraction != nullptr) *overlap_fraction = static_cast<double>(n) / a.size();
  if (var_a <= 0 || var_b <= 0) return -2.0;
  return (sab - sa * sb * inv_n) / std::sqrt(var_a * var_b);
}

}  // namespace

TranslationEstimate EstimateTranslation(const ImageF& a, const ImageF& b,
                                        const TranslationSearchOptions& options) {
  TranslationEstimate estimate;
  const int largest = static_cast<int>(std::max(a.rows(), a.cols()));
  int factor = std::max(1, (largest + options.coarse_max_size_px - 1) / options.coarse_max_size_px);
  ImageF la = DownsampleBox(a, factor), lb = DownsampleBox(b, factor);
  const auto min_pixels = static_cast<Eigen::Index>(options.min_overlap_fraction * la.size());
  double best = -2.0;
  int best_dx = 0, best_dy = 0;
  for (int dy = -static_cast<int>(la.rows()) + 1; dy < la.rows(); ++dy) {
    for (int dx = -static_cast<int>(la.cols()) + 1; dx < la.cols(); ++dx) {
      const double ncc = OverlapNcc(la, lb, dx, dy, min_pixels);
      if (ncc > best) best = ncc, best_dx = dx, best_dy = dy;
    }
  }
  if (best <= -1.0) return estimate;
  while (factor > options.finest_factor) {
    const int next = std::max(options.finest_factor, factor / 2);
    const int cx = best_dx * factor / next, cy = best_dy * factor / next;
    const int radius = factor / next + 1;
    la = DownsampleBox(a, next);
    lb = DownsampleBox(b, next);
    const auto min_level = static_cast<Eigen::Index>(options.min_overlap_fraction * la.size());
    best = -2.0;
    for (int dy = cy - radius; dy <= cy + radius; ++dy) {
      for (int dx = cx - radius; dx <= cx + radius; ++dx) {
        const double ncc = OverlapNcc(la, lb, dx, dy, min_level);
        if (ncc > best) best = ncc, best_dx = dx, best_dy = dy;
      }
    }
    factor = next;
    if (best <= -1.0) return estimate;
  }
  estimate.ok = true;
  estimate.shift_px = Eigen::Vector2d(best_dx, best_dy) * factor;
  estimate.ncc = OverlapNcc(la, lb, best_dx, best_dy, 1, &estimate.overlap_fraction);
  return estimate;
}

PatchMatch MatchPatch(const ImageF& reference, const Eigen::Vector2i& anchor_px,
                      const ImageF& target, const ImageF& target_spline,
                      const Eigen::Vector2d& predicted_q_px,
                      const Eigen::Matrix2d& dtarget_dreference, int search_radius_px,
                      const PatchMatchOptions& options) {
  PatchMatch match;
  const int h = options.half_size_px, side = 2 * h + 1, n = side * side;
  const int ax = anchor_px.x(), ay = anchor_px.y();
  if (ax - h < 0 || ay - h < 0 || ax + h >= reference.cols() || ay + h >= reference.rows())
    return match;
  Eigen::VectorXd templ(n);
  for (int r = 0; r < side; ++r)
    for (int c = 0; c < side; ++c) templ(r * side + c) = reference(ay - h + r, ax - h + c);
  const double t_mean = templ.mean();
  const Eigen::VectorXd t0 = templ.array() - t_mean;
  const double t_norm = t0.norm();
  if (t_norm / std::sqrt(static_cast<double>(n)) < options.min_template_std) return match;

  // 1. Integer NCC search around the prediction (translation of the template).
  const int px = static_cast<int>(std::lround(predicted_q_px.x()));
  const int py = static_cast<int>(std::lround(predicted_q_px.y()));
  const int rad = search_radius_px;
  if (px - rad - h - 2 < 0 || py - rad - h - 2 < 0 || px + rad + h + 3 >= target.cols() ||
      py + rad + h + 3 >= target.rows())
    return match;
  const int grid = 2 * rad + 1;
  std::vector<double> scores(static_cast<size_t>(grid) * grid, -2.0);
  for (int dy = -rad; dy <= rad; ++dy) {
    for (int dx = -rad; dx <= rad; ++dx) {
      double s = 0, ss = 0, st = 0;
      for (int r = 0; r < side; ++r) {
        const float* row = target.data() + static_cast<size_t>(py + dy - h + r) * target.cols() +
                           (px + dx - h);
        const double* tr = t0.data() + r * side;
        for (int c = 0; c < side; ++c) {
          const double v = row[c];
          s += v;
          ss += v * v;
          st += v * tr[c];
        }
      }
      const double var = ss - s * s / n;
      scores[(dy + rad) * grid + (dx + rad)] = var > 0 ? st / (t_norm * std::sqrt(var)) : -2.0;
    }
  }
  const auto best_it = std::max_element(scores.begin(), scores.end());
  const int best_index = static_cast<int>(best_it - scores.begin());
  const int bx = best_index % grid, by = best_index / grid;
  if (*best_it < options.min_ncc - 0.1) return match;
  Eigen::Vector2d start(px + bx - rad, py + by - rad);
  // Quadratic peak of the NCC surface where the neighbours exist.
  if (bx > 0 && bx + 1 < grid) {
    const double l = scores[by * grid + bx - 1], m = *best_it, r = scores[by * grid + bx + 1];
    const double d = l - 2 * m + r;
    if (d < 0) start.x() += std::clamp(0.5 * (l - r) / d, -0.5, 0.5);
  }
  if (by > 0 && by + 1 < grid) {
    const double u = scores[(by - 1) * grid + bx], m = *best_it, d2 = scores[(by + 1) * grid + bx];
    const double d = u - 2 * m + d2;
    if (d < 0) start.y() += std::clamp(0.5 * (u - d2) / d, -0.5, 0.5);
  }

  // 2. Least-squares template matching: position, gain and offset.
  Eigen::Vector2d q = start;
  double gain = 1.0, offset = 0.0;
  {
    // Initial gain and offset from the moments at the start.
    double s = 0, ss = 0;
    int count = 0;
    for (int r = -h; r <= h; ++r) {
      for (int c = -h; c <= h; ++c) {
        const Eigen::Vector2d p = q + dtarget_dreference * Eigen::Vector2d(c, r);
        double v;
        if (!SampleBSpline(target_spline, p.x(), p.y(), &v)) return match;
        s += v, ss += v * v, ++count;
      }
    }
    const double mean = s / count, sd = std::sqrt(std::max(ss / count - mean * mean, 1e-12));
    gain = (t_norm / std::sqrt(static_cast<double>(n))) / sd;
    offset = t_mean - gain * mean;
  }
  Eigen::VectorXd sampled(n);
  bool converged = false;
  for (int it = 0; it < options.max_iterations && !converged; ++it) {
    Eigen::Matrix4d normal = Eigen::Matrix4d::Zero();
    Eigen::Vector4d rhs = Eigen::Vector4d::Zero();
    for (int r = -h, i = 0; r <= h; ++r) {
      for (int c = -h; c <= h; ++c, ++i) {
        const Eigen::Vector2d p = q + dtarget_dreference * Eigen::Vector2d(c, r);
        double v;
        Eigen::Vector2d g;
        if (!SampleBSpline(target_spline, p.x(), p.y(), &v, &g)) return match;
        sampled(i) = v;
        const double residual = gain * v + offset - templ(i);
        const Eigen::Vector4d jac(gain * g.x(), gain * g.y(), v, 1.0);
        normal.selfadjointView<Eigen::Lower>().rankUpdate(jac);
        rhs -= jac * residual;
      }
    }
    const Eigen::Vector4d step = normal.selfadjointView<Eigen::Lower>().ldlt().solve(rhs);
    if (!step.allFinite()) return match;
    q += step.head<2>();
    gain += step(2);
    offset += step(3);
    match.iterations = it + 1;
    converged = step.head<2>().norm() < options.convergence_px;
    if ((q - start).norm() > options.max_refinement_px) return match;
  }
  // Quality at the final position.
  for (int r = -h, i = 0; r <= h; ++r) {
    for (int c = -h; c <= h; ++c, ++i) {
      const Eigen::Vector2d p = q + dtarget_dreference * Eigen::Vector2d(c, r);
      if (!SampleBSpline(target_spline, p.x(), p.y(), &sampled(i))) return match;
    }
  }
  const Eigen::VectorXd s0 = sampled.array() - sampled.mean();
  match.ncc = s0.dot(t0) / (s0.norm() * t_norm);
  match.residual_rms = (gain * sampled.array() + offset - templ.array()).matrix().norm() /
                       std::sqrt(static_cast<double>(n));
  match.q_px = q;
  match.ok = converged && match.ncc >= options.min_ncc;
  return match;
}

}  // namespace omm
