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

// Summed-area tables of an image's values and squares: any rectangle's
// moments in O(1), so that the exhaustive shift search sums only products.
class Moments {
 public:
  explicit Moments(const ImageF& image)
      : stride_(static_cast<int>(image.cols()) + 1),
        sum_(static_cast<size_t>(stride_) * (image.rows() + 1), 0.0),
        sum_sq_(sum_.size(), 0.0) {
    for (int r = 0; r < image.rows(); ++r) {
      double acc = 0, acc_sq = 0;
      for (int c = 0; c < image.cols(); ++c) {
        const double v = image(r, c);
        acc += v, acc_sq += v * v;
        sum_[(r + 1) * stride_ + c + 1] = sum_[r * stride_ + c + 1] + acc;
        sum_sq_[(r + 1) * stride_ + c + 1] = sum_sq_[r * stride_ + c + 1] + acc_sq;
      }
    }
  }
  // Sums over rows [r0, r1), columns [c0, c1).
  double Sum(int r0, int r1, int c0, int c1) const { return Box(sum_, r0, r1, c0, c1); }
  double SumSq(int r0, int r1, int c0, int c1) const { return Box(sum_sq_, r0, r1, c0, c1); }

 private:
  double Box(const std::vector<double>& t, int r0, int r1, int c0, int c1) const {
    return t[r1 * stride_ + c1] - t[r0 * stride_ + c1] - t[r1 * stride_ + c0] + t[r0 * stride_ + c0];
  }
  int stride_;
  std::vector<double> sum_, sum_sq_;
};

// NCC of a and b over their overlap when b is shifted by (dx, dy): a(r, c)
// against b(r + dy, c + dx). -2 if the overlap is smaller than min_pixels.
double OverlapNcc(const ImageF& a, const ImageF& b, const Moments& ma, const Moments& mb, int dx,
                  int dy, Eigen::Index min_pixels, double* overlap_fraction = nullptr) {
  const int c0 = std::max(0, -dx), c1 = std::min<int>(a.cols(), b.cols() - dx);
  const int r0 = std::max(0, -dy), r1 = std::min<int>(a.rows(), b.rows() - dy);
  if (c1 <= c0 || r1 <= r0) return -2.0;
  const Eigen::Index n = static_cast<Eigen::Index>(c1 - c0) * (r1 - r0);
  if (n < min_pixels) return -2.0;
  double sab = 0;
  for (int r = r0; r < r1; ++r) {
    const float* pa = a.data() + static_cast<size_t>(r) * a.cols();
    const float* pb = b.data() + static_cast<size_t>(r + dy) * b.cols() + dx;
    float fab = 0;
    for (int c = c0; c < c1; ++c) fab += pa[c] * pb[c];
    sab += fab;
  }
  const double sa = ma.Sum(r0, r1, c0, c1), saa = ma.SumSq(r0, r1, c0, c1);
  const double sb = mb.Sum(r0 + dy, r1 + dy, c0 + dx, c1 + dx);
  const double sbb = mb.SumSq(r0 + dy, r1 + dy, c0 + dx, c1 + dx);
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
  Moments ma(la), mb(lb);
  const auto min_pixels = static_cast<Eigen::Index>(options.min_overlap_fraction * la.size());
  double best = -2.0;
  int best_dx = 0, best_dy = 0;
  for (int dy = -static_cast<int>(la.rows()) + 1; dy < la.rows(); ++dy) {
    for (int dx = -static_cast<int>(la.cols()) + 1; dx < la.cols(); ++dx) {
      const double ncc = OverlapNcc(la, lb, ma, mb, dx, dy, min_pixels);
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
    ma = Moments(la);
    mb = Moments(lb);
    const auto min_level = static_cast<Eigen::Index>(options.min_overlap_fraction * la.size());
    best = -2.0;
    for (int dy = cy - radius; dy <= cy + radius; ++dy) {
      for (int dx = cx - radius; dx <= cx + radius; ++dx) {
        const double ncc = OverlapNcc(la, lb, ma, mb, dx, dy, min_level);
        if (ncc > best) best = ncc, best_dx = dx, best_dy = dy;
      }
    }
    factor = next;
    if (best <= -1.0) return estimate;
  }
  estimate.ok = true;
  estimate.shift_px = Eigen::Vector2d(best_dx, best_dy) * factor;
  estimate.ncc = OverlapNcc(la, lb, ma, mb, best_dx, best_dy, 1, &estimate.overlap_fraction);
  return estimate;
}

NccPeak SearchNcc(const ImageF& reference, const Eigen::Vector2i& anchor_px, int half_size_px,
                  const ImageF& target, const Eigen::Vector2i& center_px, int radius_px) {
  NccPeak peak;
  const int h = half_size_px, side = 2 * h + 1, n = side * side;
  const int ax = anchor_px.x(), ay = anchor_px.y();
  const int cx = center_px.x(), cy = center_px.y(), rad = radius_px;
  if (ax - h < 0 || ay - h < 0 || ax + h >= reference.cols() || ay + h >= reference.rows() ||
      cx - rad - h < 0 || cy - rad - h < 0 || cx + rad + h >= target.cols() ||
      cy + rad + h >= target.rows())
    return peak;
  // The zero-mean template, so that the cross term needs no target mean.
  std::vector<float> t0(static_cast<size_t>(n));
  double t_sum = 0;
  for (int r = 0; r < side; ++r)
    for (int c = 0; c < side; ++c) t_sum += reference(ay - h + r, ax - h + c);
  const double t_mean = t_sum / n;
  double t_ss = 0;
  for (int r = 0; r < side; ++r) {
    for (int c = 0; c < side; ++c) {
      const double v = reference(ay - h + r, ax - h + c) - t_mean;
      t0[r * side + c] = static_cast<float>(v);
      t_ss += v * v;
    }
  }
  if (!(t_ss > 0)) return peak;
  const double t_norm = std::sqrt(t_ss);
  const int grid = 2 * rad + 1;
  // Summed-area tables of the searched region (value and square, double), so
  // that each position's window moments cost O(1) and only the cross term
  // is summed per pixel.
  const int region = grid + 2 * h, x0 = cx - rad - h, y0 = cy - rad - h;
  const int stride = region + 1;
  std::vector<double> sum(static_cast<size_t>(stride) * stride, 0.0), sum_sq(sum.size(), 0.0);
  for (int r = 0; r < region; ++r) {
    const float* row = target.data() + static_cast<size_t>(y0 + r) * target.cols() + x0;
    double acc = 0, acc_sq = 0;
    for (int c = 0; c < region; ++c) {
      acc += row[c], acc_sq += static_cast<double>(row[c]) * row[c];
      sum[(r + 1) * stride + c + 1] = sum[r * stride + c + 1] + acc;
      sum_sq[(r + 1) * stride + c + 1] = sum_sq[r * stride + c + 1] + acc_sq;
    }
  }
  const auto box = [&](const std::vector<double>& table, int r, int c) {
    return table[(r + side) * stride + c + side] - table[r * stride + c + side] -
           table[(r + side) * stride + c] + table[r * stride + c];
  };
  std::vector<double> scores(static_cast<size_t>(grid) * grid, -2.0);
  double best = -2.0, best_s = 0, best_ss = 0;
  int best_index = -1;
  for (int dy = -rad; dy <= rad; ++dy) {
    for (int dx = -rad; dx <= rad; ++dx) {
      // The cross term against the zero-mean template: float sums per row
      // (<= a few hundred terms of normalised intensities), double across rows.
      double st = 0;
      for (int r = 0; r < side; ++r) {
        const float* row = target.data() + static_cast<size_t>(cy + dy - h + r) * target.cols() +
                           (cx + dx - h);
        const float* tr = t0.data() + r * side;
        float fst = 0;
        for (int c = 0; c < side; ++c) fst += row[c] * tr[c];
        st += fst;
      }
      const double s = box(sum, dy + rad, dx + rad), ss = box(sum_sq, dy + rad, dx + rad);
      const double var = ss - s * s / n;
      const int index = (dy + rad) * grid + (dx + rad);
      scores[index] = var > 0 ? st / (t_norm * std::sqrt(var)) : -2.0;
      if (scores[index] > best) best = scores[index], best_index = index, best_s = s, best_ss = ss;
    }
  }
  if (best_index < 0) return peak;
  const int bx = best_index % grid, by = best_index / grid;
  peak.ok = true;
  peak.ncc = best;
  peak.pixel << cx + bx - rad, cy + by - rad;
  peak.q_px = peak.pixel.cast<double>();
  peak.target_mean = best_s / n;
  peak.target_std = std::sqrt(std::max(best_ss / n - peak.target_mean * peak.target_mean, 0.0));
  if (bx > 0 && bx + 1 < grid) {
    const double l = scores[by * grid + bx - 1], r = scores[by * grid + bx + 1];
    const double d = l - 2 * best + r;
    if (d < 0) peak.q_px.x() += std::clamp(0.5 * (l - r) / d, -0.5, 0.5);
  }
  if (by > 0 && by + 1 < grid) {
    const double u = scores[(by - 1) * grid + bx], d2 = scores[(by + 1) * grid + bx];
    const double d = u - 2 * best + d2;
    if (d < 0) peak.q_px.y() += std::clamp(0.5 * (u - d2) / d, -0.5, 0.5);
  }
  return peak;
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
  const double t_std = t_norm / std::sqrt(static_cast<double>(n));
  if (t_std < options.min_template_std) return match;

  // 1. Integer NCC search around the prediction (translation of the template).
  const int px = static_cast<int>(std::lround(predicted_q_px.x()));
  const int py = static_cast<int>(std::lround(predicted_q_px.y()));
  const int rad = search_radius_px;
  // The search window plus the B-spline's support around any refined position.
  if (px - rad - h - 2 < 0 || py - rad - h - 2 < 0 || px + rad + h + 3 >= target.cols() ||
      py + rad + h + 3 >= target.rows())
    return match;
  const NccPeak peak = SearchNcc(reference, anchor_px, h, target, {px, py}, rad);
  if (!peak.ok || peak.ncc < options.min_ncc - 0.1) return match;
  // Radius 0: the prediction is already sub-pixel (a relocation); start there.
  const Eigen::Vector2d start = rad == 0 ? predicted_q_px : peak.q_px;

  // 2. Least-squares template matching: position, gain and offset, starting
  // from the moments of the best integer window.
  std::vector<Eigen::Vector2d> offsets(static_cast<size_t>(n));
  for (int r = -h, i = 0; r <= h; ++r)
    for (int c = -h; c <= h; ++c, ++i) offsets[i] = dtarget_dreference * Eigen::Vector2d(c, r);
  Eigen::Vector2d q = start;
  double gain = t_std / std::max(peak.target_std, 1e-6);
  double offset = t_mean - gain * peak.target_mean;
  bool converged = false;
  Eigen::VectorXd sampled(n);  // the target at the last iteration's position
  Eigen::Matrix4d normal;
  for (int it = 0; it < options.max_iterations && !converged; ++it) {
    // Upper triangle of the 4 x 4 normal matrix of (dq_x, dq_y, dgain, doffset).
    double n00 = 0, n01 = 0, n02 = 0, n03 = 0, n11 = 0, n12 = 0, n13 = 0, n22 = 0, n23 = 0;
    double b0 = 0, b1 = 0, b2 = 0, b3 = 0;
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector2d p = q + offsets[i];
      double v;
      Eigen::Vector2d g;
      if (!SampleBSpline(target_spline, p.x(), p.y(), &v, &g)) return match;
      sampled(i) = v;
      const double e = gain * v + offset - templ(i);
      const double j0 = gain * g.x(), j1 = gain * g.y();
      n00 += j0 * j0, n01 += j0 * j1, n02 += j0 * v, n03 += j0;
      n11 += j1 * j1, n12 += j1 * v, n13 += j1;
      n22 += v * v, n23 += v;
      b0 -= j0 * e, b1 -= j1 * e, b2 -= v * e, b3 -= e;
    }
    normal << n00, n01, n02, n03, n01, n11, n12, n13, n02, n12, n22, n23, n03, n13, n23, n;
    const Eigen::Vector4d step = normal.ldlt().solve(Eigen::Vector4d(b0, b1, b2, b3));
    if (!step.allFinite()) return match;
    match.iterations = it + 1;
    converged = step.head<2>().norm() < options.convergence_px;
    if (converged) break;  // the samples stay those of q (within convergence_px of q + step)
    q += step.head<2>();
    gain += step(2);
    offset += step(3);
    if ((q - start).norm() > options.max_refinement_px) return match;
  }
  // Quality at the final position (the last iteration's samples).
  const Eigen::VectorXd s0 = sampled.array() - sampled.mean();
  match.ncc = s0.dot(t0) / (s0.norm() * t_norm);
  match.residual_rms = (gain * sampled.array() + offset - templ.array()).matrix().norm() /
                       std::sqrt(static_cast<double>(n));
  const double variance = match.residual_rms * match.residual_rms * n / (n - 4);
  match.sigma_px = std::sqrt(0.5 * variance * normal.inverse().topLeftCorner<2, 2>().trace());
  match.q_px = q;
  match.ok = converged && match.ncc >= options.min_ncc;
  return match;
}

}  // namespace omm
