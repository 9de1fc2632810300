#include "pipeline/core/subpixel_edges.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include <Eigen/Cholesky>

namespace omm {
namespace {

// Keys' cubic convolution (a = -1/2) weights of the four samples around a
// point at fraction t past the second one.
inline void KeysWeights(double t, double w[4]) {
  const double t2 = t * t, t3 = t2 * t;
  w[0] = -0.5 * t3 + t2 - 0.5 * t;
  w[1] = 1.5 * t3 - 2.5 * t2 + 1.0;
  w[2] = -1.5 * t3 + 2.0 * t2 + 0.5 * t;
  w[3] = 0.5 * t3 - 0.5 * t2;
}

// Interpolated value at (x, y); false if the 4x4 neighbourhood leaves the
// image. Cubic rather than bilinear: at a blurred edge linear interpolation
// errs by t(1-t)(1-2t)/6 f''' (t the pixel phase), ~0.03 px of edge position
// for a 0.75 px blur, and these phase errors do not average out fully over
// one mark's perimeter; cubic convolution is exact for quadratics.
bool Interpolate(const ImageF& image, double x, double y, double* value) {
  const double fx = std::floor(x), fy = std::floor(y);
  const Eigen::Index c = static_cast<Eigen::Index>(fx), r = static_cast<Eigen::Index>(fy);
  if (c < 1 || r < 1 || c + 2 >= image.cols() || r + 2 >= image.rows()) return false;
  double wx[4], wy[4];
  KeysWeights(x - fx, wx);
  KeysWeights(y - fy, wy);
  double sum = 0.0;
  for (int i = 0; i < 4; ++i) {
    const float* row = &image(r - 1 + i, c - 1);
    sum += wy[i] * (wx[0] * row[0] + wx[1] * row[1] + wx[2] * row[2] + wx[3] * row[3]);
  }
  *value = sum;
  return true;
}

double Median(std::vector<double> values) {
  const auto mid = values.begin() + values.size() / 2;
  std::nth_element(values.begin(), mid, values.end());
  return *mid;
}

// level(p) = a + b . (p - origin), least squares with one round of rejecting
// samples beyond 3 robust sigmas (clutter such as a printed label).
struct LevelPlane {
  Eigen::Vector3d coeffs = Eigen::Vector3d::Zero();
  Eigen::Vector2d origin = Eigen::Vector2d::Zero();
  double At(const Eigen::Vector2d& p) const { return coeffs(0) + coeffs.tail<2>().dot(p - origin); }
};

LevelPlane FitLevelPlane(const std::vector<Eigen::Vector2d>& at, const std::vector<double>& value,
                         const Eigen::Vector2d& origin) {
  LevelPlane plane;
  plane.origin = origin;
  std::vector<bool> use(at.size(), true);
  for (int round = 0; round < 2; ++round) {
    Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
    Eigen::Vector3d atb = Eigen::Vector3d::Zero();
    for (size_t i = 0; i < at.size(); ++i) {
      if (!use[i]) continue;
      const Eigen::Vector3d row(1.0, at[i].x() - origin.x(), at[i].y() - origin.y());
      ata += row * row.transpose();
      atb += row * value[i];
    }
    plane.coeffs = ata.ldlt().solve(atb);
    if (round == 1) break;
    std::vector<double> abs_res(at.size());
    for (size_t i = 0; i < at.size(); ++i) abs_res[i] = std::abs(value[i] - plane.At(at[i]));
    const double threshold = std::max(3.0 * 1.4826 * Median(abs_res), 1e-6);
    for (size_t i = 0; i < at.size(); ++i) use[i] = abs_res[i] <= threshold;
  }
  return plane;
}

}  // namespace

std::string EllipseEdgeOptions::Check() const {
  if (!(ray_half_length_px > 0.0)) return "ray_half_length_px must be > 0";
  if (!(plateau_px > 0.0 && plateau_px < ray_half_length_px)) {
    return "plateau_px must be in (0, ray_half_length_px)";
  }
  if (!(ray_spacing_px > 0.0)) return "ray_spacing_px must be > 0";
  if (!(sample_step_px > 0.0 && sample_step_px <= 1.0)) return "sample_step_px must be in (0, 1]";
  if (min_rays < 8) return "min_rays must be >= 8";
  return {};
}

EllipseEdges FindEllipseEdges(const ImageF& image, const Ellipse& rough, const EllipseEdgeOptions& options) {
  EllipseEdges edges;
  const double a = rough.SemiMajorPx(), b = rough.SemiMinorPx();
  const double perimeter = 2.0 * std::numbers::pi * std::sqrt(0.5 * (a * a + b * b));
  edges.num_rays = std::max(options.min_rays, static_cast<int>(std::ceil(perimeter / options.ray_spacing_px)));
  const double inner = std::min(options.ray_half_length_px, 0.5 * b);
  const double outer = options.ray_half_length_px;
  const double plateau_in = std::min(options.plateau_px, 0.5 * inner);

  // Rays: boundary point, normal, and whether the whole ray is on the image.
  struct Ray {
    Eigen::Vector2d base, normal;
  };
  std::vector<Ray> rays;
  rays.reserve(static_cast<size_t>(edges.num_rays));
  std::vector<Eigen::Vector2d> in_at, out_at;
  std::vector<double> in_value, out_value;
  for (int k = 0; k < edges.num_rays; ++k) {
    const double t = 2.0 * std::numbers::pi * k / edges.num_rays;
    const Ray ray{rough.PointAt(t), rough.NormalAt(t)};
    double v0, v1;
    if (!Interpolate(image, ray.base.x() - inner * ray.normal.x(), ray.base.y() - inner * ray.normal.y(), &v0) ||
        !Interpolate(image, ray.base.x() + outer * ray.normal.x(), ray.base.y() + outer * ray.normal.y(), &v1)) {
      ++edges.num_rays_off_image;
      continue;
    }
    rays.push_back(ray);
    for (double s = -inner; s <= -inner + plateau_in + 1e-9; s += options.sample_step_px) {
      const Eigen::Vector2d p = ray.base + s * ray.normal;
      double v;
      Interpolate(image, p.x(), p.y(), &v);
      in_at.push_back(p);
      in_value.push_back(v);
    }
    for (double s = outer - options.plateau_px; s <= outer + 1e-9; s += options.sample_step_px) {
      const Eigen::Vector2d p = ray.base + s * ray.normal;
      double v;
      Interpolate(image, p.x(), p.y(), &v);
      out_at.push_back(p);
      out_value.push_back(v);
    }
  }
  if (rays.size() < 8) {
    edges.points_px.resize(2, 0);
    return edges;
  }
  const LevelPlane inside = FitLevelPlane(in_at, in_value, rough.centre_px);
  const LevelPlane outside = FitLevelPlane(out_at, out_value, rough.centre_px);
  edges.contrast = outside.coeffs(0) - inside.coeffs(0);
  const double polarity = edges.contrast >= 0.0 ? 1.0 : -1.0;

  // f(s) rises through 0 at the edge whatever the polarity.
  auto profile = [&](const Ray& ray, double s, double* f) {
    const Eigen::Vector2d p = ray.base + s * ray.normal;
    double v;
    if (!Interpolate(image, p.x(), p.y(), &v)) return false;
    *f = polarity * (v - 0.5 * (inside.At(p) + outside.At(p)));
    return true;
  };

  std::vector<Eigen::Vector2d> points;
  std::vector<double> sigmas;
  points.reserve(rays.size());
  const double search_lo = -inner + plateau_in, search_hi = outer - options.plateau_px;
  for (const Ray& ray : rays) {
    // Every upward crossing on the grid; keep the ray only if there is one.
    int crossings = 0;
    double lo = 0, hi = 0, f_lo = 0, f_hi = 0;
    double s_prev = search_lo, f_prev = 0.0;
    if (!profile(ray, s_prev, &f_prev)) continue;  // the ray leaves the image
    for (double s = search_lo + options.sample_step_px; s <= search_hi + 1e-9; s += options.sample_step_px) {
      double f = 0.0;
      if (!profile(ray, s, &f)) {
        crossings = -1;
        break;
      }
      if (f_prev < 0.0 && f >= 0.0) {
        ++crossings;
        lo = s_prev, hi = s, f_lo = f_prev, f_hi = f;
      } else if (f_prev >= 0.0 && f < 0.0) {
        ++crossings;  // a downward crossing means clutter or noise: ambiguous
      }
      s_prev = s;
      f_prev = f;
    }
    if (crossings != 1) continue;
    // Illinois false position on the (continuous) interpolated profile.
    int side = 0;
    double s_root = lo;
    for (int it = 0; it < 40 && hi - lo > 1e-5; ++it) {
      s_root = (lo * f_hi - hi * f_lo) / (f_hi - f_lo);
      double f = 0.0;
      if (!profile(ray, s_root, &f)) break;  // unreachable: [lo, hi] was sampled
      if (f < 0.0) {
        lo = s_root, f_lo = f;
        if (side == -1) f_hi *= 0.5;
        side = -1;
      } else {
        hi = s_root, f_hi = f;
        if (side == 1) f_lo *= 0.5;
        side = 1;
      }
    }
    const Eigen::Vector2d point = ray.base + s_root * ray.normal;
    points.push_back(point);
    double f_minus, f_plus;
    if (profile(ray, s_root - 0.5, &f_minus) && profile(ray, s_root + 0.5, &f_plus) && f_plus > f_minus) {
      const double local_contrast = std::abs(outside.At(point) - inside.At(point));
      sigmas.push_back(local_contrast / (std::sqrt(2.0 * std::numbers::pi) * (f_plus - f_minus)));
    }
  }
  edges.points_px.resize(2, static_cast<Eigen::Index>(points.size()));
  for (size_t i = 0; i < points.size(); ++i) edges.points_px.col(static_cast<Eigen::Index>(i)) = points[i];
  if (!sigmas.empty()) edges.edge_sigma_px = Median(sigmas);
  return edges;
}

std::string MarkRefinementOptions::Check() const {
  if (std::string why = edges.Check(); !why.empty()) return "edges: " + why;
  if (std::string why = fit.Check(); !why.empty()) return "fit: " + why;
  if (!(min_contrast > 0.0)) return "min_contrast must be > 0";
  if (!(min_inlier_fraction > 0.0 && min_inlier_fraction <= 1.0)) return "min_inlier_fraction must be in (0, 1]";
  if (max_passes < 1) return "max_passes must be >= 1";
  if (!(converged_px > 0.0)) return "converged_px must be > 0";
  return {};
}

MarkFit RefineEllipticalMark(const ImageF& image, const Ellipse& rough, const MarkRefinementOptions& options) {
  MarkFit mark;
  Ellipse guide = rough;
  // Pass 1 along the rough normals, then along the fitted ones. Rays off the
  // edge put one side's plateau into the blur and pull the levels; the error
  // shrinks ~10x per pass (more for sharp edges), so a few passes converge.
  for (int pass = 0; pass < options.max_passes; ++pass) {
    const EllipseEdges edges = FindEllipseEdges(image, guide, options.edges);
    if (edges.num_rays_off_image > 0) {
      mark.why_failed = "mark touches the image border";
      return mark;
    }
    mark.contrast = edges.contrast;
    mark.edge_sigma_px = edges.edge_sigma_px;
    mark.num_edge_points = static_cast<int>(edges.points_px.cols());
    if (std::abs(edges.contrast) < options.min_contrast) {
      mark.why_failed = "mark contrast too low";
      return mark;
    }
    const EllipseFit fit = FitEllipse(edges.points_px, options.fit);
    if (!fit.ok) {
      mark.why_failed = fit.why_failed;
      return mark;
    }
    if (fit.num_inliers < options.min_inlier_fraction * edges.num_rays) {
      mark.why_failed = "too few clean edge points";
      return mark;
    }
    const double moved_px = (fit.ellipse.centre_px - guide.centre_px).norm();
    guide = fit.ellipse;
    mark.ellipse = fit.ellipse;
    mark.centre_cov_px2 = fit.centre_cov_px2;
    mark.rms_px = fit.rms_px;
    mark.num_inliers = fit.num_inliers;
    if (pass > 0 && moved_px < options.converged_px) break;
  }
  mark.sigma_px = std::sqrt(0.5 * mark.centre_cov_px2.trace());
  mark.ok = true;
  return mark;
}

}  // namespace omm
