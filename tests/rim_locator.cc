#include "tests/rim_locator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <vector>

#include <Eigen/Dense>

#include "pipeline/core/statistics.h"

namespace omm::testing {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Bilinear sample; NaN outside the image or next to an uncovered (0) pixel.
double Sample(const ImageF& image, double x, double y) {
  const double fx = std::floor(x), fy = std::floor(y);
  const int c = static_cast<int>(fx), r = static_cast<int>(fy);
  if (c < 0 || r < 0 || c + 1 >= image.cols() || r + 1 >= image.rows()) return kNaN;
  const double v00 = image(r, c), v01 = image(r, c + 1), v10 = image(r + 1, c),
               v11 = image(r + 1, c + 1);
  if (v00 == 0.0 || v01 == 0.0 || v10 == 0.0 || v11 == 0.0) return kNaN;
  const double ax = x - fx, ay = y - fy;
  return (1 - ay) * ((1 - ax) * v00 + ax * v01) + ay * ((1 - ax) * v10 + ax * v11);
}

struct Circle {
  Eigen::Vector2d centre;
  double radius = 0.0;
};

// Algebraic (Kasa) fit, then Gauss-Newton on the geometric distances.
Circle FitCircle(const std::vector<Eigen::Vector2d>& points) {
  const int n = static_cast<int>(points.size());
  Eigen::MatrixXd a(n, 3);
  Eigen::VectorXd b(n);
  for (int k = 0; k < n; ++k) {
    a.row(k) << points[k].x(), points[k].y(), 1.0;
    b(k) = -points[k].squaredNorm();
  }
  const Eigen::Vector3d abc = a.colPivHouseholderQr().solve(b);
  Circle circle;
  circle.centre = -0.5 * abc.head<2>();
  circle.radius = std::sqrt(std::max(0.0, circle.centre.squaredNorm() - abc(2)));
  for (int iteration = 0; iteration < 10; ++iteration) {
    Eigen::MatrixXd j(n, 3);
    Eigen::VectorXd r(n);
    for (int k = 0; k < n; ++k) {
      const Eigen::Vector2d d = points[k] - circle.centre;
      const double norm = d.norm();
      r(k) = norm - circle.radius;
      j.row(k) << -d.x() / norm, -d.y() / norm, -1.0;
    }
    const Eigen::Vector3d step = j.colPivHouseholderQr().solve(-r);
    circle.centre += step.head<2>();
    circle.radius += step(2);
    if (step.norm() < 1e-9) break;
  }
  return circle;
}

}  // namespace

RimFit LocateDarkDiscRim(const ImageF& image, const Eigen::Vector2d& rough_centre_px,
                         double rough_radius_px, const RimLocatorOptions& options) {
  RimFit fit;
  fit.num_rays = std::max(90, static_cast<int>(2 * std::numbers::pi * rough_radius_px));
  constexpr double kStep = 0.125;
  const double s_min = std::max(2.0, rough_radius_px - options.window_px);
  const double s_max = rough_radius_px + options.window_px;
  std::vector<Eigen::Vector2d> edges;
  for (int k = 0; k < fit.num_rays; ++k) {
    const double angle = 2 * std::numbers::pi * k / fit.num_rays;
    const Eigen::Vector2d u(std::cos(angle), std::sin(angle));
    // The profile from s_min - 4.5 to s_max + 4.5 px.
    const double s0 = s_min - 4.5;
    const int n = static_cast<int>((s_max + 4.5 - s0) / kStep) + 1;
    std::vector<double> profile(n);
    bool valid = true;
    for (int i = 0; i < n && valid; ++i) {
      const Eigen::Vector2d q = rough_centre_px + (s0 + i * kStep) * u;
      profile[i] = Sample(image, q.x(), q.y());
      valid = !std::isnan(profile[i]);
    }
    if (!valid) continue;
    const int step_1px = static_cast<int>(std::lround(1.0 / kStep));
    auto derivative = [&](int i) { return 0.5 * (profile[i + step_1px] - profile[i - step_1px]); };
    const int i_min = static_cast<int>(std::lround((s_min - s0) / kStep));
    const int i_max = static_cast<int>(std::lround((s_max - s0) / kStep));
    double largest = 0.0;
    for (int i = i_min; i <= i_max; ++i) largest = std::max(largest, derivative(i));
    if (!(largest > 0.0)) continue;
    int peak = -1;
    for (int i = i_max - 1; i > i_min; --i) {
      const double d = derivative(i);
      if (d >= 0.5 * largest && d >= derivative(i - 1) && d >= derivative(i + 1)) {
        peak = i;
        break;
      }
    }
    if (peak < 0) continue;
    const int near = static_cast<int>(std::lround(1.5 / kStep));
    const int far = static_cast<int>(std::lround(3.5 / kStep));
    const double inside = Median(
        std::vector<double>(profile.begin() + peak - far, profile.begin() + peak - near + 1));
    // The surface outside is textured: its level AT the rim is the value
    // there of a line fitted to the profile 2-4.5 px outside (a median of it
    // would move the mid-level, and with it the edge, with the texture's slope).
    const int out_near = static_cast<int>(std::lround(2.0 / kStep));
    const int out_far = static_cast<int>(std::lround(4.5 / kStep));
    double sum_x = 0, sum_y = 0, sum_xx = 0, sum_xy = 0;
    const int count = out_far - out_near + 1;
    for (int i = peak + out_near; i <= peak + out_far; ++i) {
      const double x = (i - peak) * kStep;
      sum_x += x;
      sum_y += profile[i];
      sum_xx += x * x;
      sum_xy += x * profile[i];
    }
    const double slope = (count * sum_xy - sum_x * sum_y) / (count * sum_xx - sum_x * sum_x);
    const double outside = (sum_y - slope * sum_x) / count;
    if (!(outside > inside)) continue;
    const double mid = 0.5 * (inside + outside);
    // The crossing of `mid` nearest to the peak within +-1.5 px.
    double best_s = kNaN, best_distance = std::numeric_limits<double>::infinity();
    for (int i = peak - near; i < peak + near; ++i) {
      const double a = profile[i] - mid, b = profile[i + 1] - mid;
      if (a > 0.0 || b < 0.0 || a == b) continue;
      const double s = s0 + (i + a / (a - b)) * kStep;
      const double distance = std::abs(s - (s0 + peak * kStep));
      if (distance < best_distance) {
        best_distance = distance;
        best_s = s;
      }
    }
    if (std::isnan(best_s)) continue;
    edges.emplace_back(rough_centre_px + best_s * u);
  }
  fit.num_edges = static_cast<int>(edges.size());
  if (fit.num_edges < options.min_ray_fraction * fit.num_rays) {
    fit.why_failed = "edges on " + std::to_string(fit.num_edges) + " of " +
                     std::to_string(fit.num_rays) + " rays";
    return fit;
  }
  std::vector<Eigen::Vector2d> inliers = edges;
  Circle circle = FitCircle(inliers);
  for (int pass = 0; pass < 3; ++pass) {
    std::vector<double> abs_residual;
    abs_residual.reserve(edges.size());
    for (const Eigen::Vector2d& p : edges) {
      abs_residual.push_back(std::abs((p - circle.centre).norm() - circle.radius));
    }
    const double sigma = 1.4826 * Median(abs_residual);
    inliers.clear();
    for (size_t k = 0; k < edges.size(); ++k) {
      if (abs_residual[k] <= options.outlier_sigmas * sigma) inliers.push_back(edges[k]);
    }
    circle = FitCircle(inliers);
  }
  double sum2 = 0.0;
  for (const Eigen::Vector2d& p : inliers) {
    sum2 += std::pow((p - circle.centre).norm() - circle.radius, 2);
  }
  fit.ok = true;
  fit.centre_px = circle.centre;
  fit.radius_px = circle.radius;
  fit.num_inliers = static_cast<int>(inliers.size());
  fit.rms_px = std::sqrt(sum2 / inliers.size());
  return fit;
}

Planar2dFit FitPlanar2d(const Eigen::Matrix2Xd& from, const Eigen::Matrix2Xd& to, bool with_scale) {
  const Eigen::Vector2d from_mean = from.rowwise().mean(), to_mean = to.rowwise().mean();
  const Eigen::Matrix2Xd a = from.colwise() - from_mean, b = to.colwise() - to_mean;
  // Closed form: angle from sum of cross and dot products.
  double dot = 0.0, cross = 0.0;
  for (Eigen::Index k = 0; k < a.cols(); ++k) {
    dot += a.col(k).dot(b.col(k));
    cross += a(0, k) * b(1, k) - a(1, k) * b(0, k);
  }
  Planar2dFit fit;
  fit.angle_rad = std::atan2(cross, dot);
  const Eigen::Matrix2d rotation = Eigen::Rotation2Dd(fit.angle_rad).toRotationMatrix();
  fit.scale = with_scale ? std::hypot(dot, cross) / a.squaredNorm() : 1.0;
  fit.t = to_mean - fit.scale * rotation * from_mean;
  fit.residual.resize(from.cols());
  for (Eigen::Index k = 0; k < from.cols(); ++k) {
    fit.residual(k) = (fit.scale * rotation * from.col(k) + fit.t - to.col(k)).norm();
  }
  fit.rms = std::sqrt(fit.residual.squaredNorm() / std::max<Eigen::Index>(1, from.cols()));
  return fit;
}

}  // namespace omm::testing
