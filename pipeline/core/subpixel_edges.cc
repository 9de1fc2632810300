#include "pipeline/core/subpixel_edges.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include <Eigen/Cholesky>

#include "pipeline/core/cubic_weights.h"
#include "pipeline/core/statistics.h"

namespace omm {
namespace {

// Whether the 4x4 neighbourhood that InterpolateOnImage reads at (x, y) is
// on the image: floor(x) in [1, cols - 3] (false for NaN). A convex set, so a
// segment whose ends are in it lies in it.
bool InterpolationDomain(const ImageF& image, double x, double y) {
  return x >= 1.0 && y >= 1.0 && x < image.cols() - 2.0 && y < image.rows() - 2.0;
}

// Interpolated value at (x, y), a point of InterpolationDomain. Cubic rather
// than bilinear: at a blurred edge linear interpolation errs by
// t(1-t)(1-2t)/6 f''' (t the pixel phase), ~0.03 px of edge position for a
// 0.75 px blur, and these phase errors do not average out fully over one
// mark's perimeter; Keys' cubic convolution (CatmullRomWeights) is exact for
// quadratics. In float, like the image (a few float epsilons of its scale):
// four weights or pixels per SSE register, where the rays sample it ~10^7
// times per project.
double InterpolateOnImage(const ImageF& image, double x, double y) {
  // Truncation is floor on the domain (SSE2 has no rounding instruction:
  // std::floor took a dozen).
  const Eigen::Index c = static_cast<Eigen::Index>(x), r = static_cast<Eigen::Index>(y);
  Eigen::Array4f wx, wy;
  CatmullRomWeights(static_cast<float>(x - c), wx.data());
  CatmullRomWeights(static_cast<float>(y - r), wy.data());
  const float* row = &image(r - 1, c - 1);
  const Eigen::Index stride = image.cols();
  const Eigen::Map<const Eigen::Array4f> r0(row), r1(row + stride), r2(row + 2 * stride),
      r3(row + 3 * stride);
  return (wx * (wy(0) * r0 + wy(1) * r1 + wy(2) * r2 + wy(3) * r3)).sum();
}

// level(p) = a + b . (p - origin), least squares with one round of rejecting
// samples beyond 3 robust sigmas (clutter such as a printed label).
struct LevelPlane {
  Eigen::Vector3d coeffs = Eigen::Vector3d::Zero();
  Eigen::Vector2d origin = Eigen::Vector2d::Zero();
  Eigen::Matrix3d normal_inverse = Eigen::Matrix3d::Zero();  // (A^T A)^-1 of the final round
  // Samples of the final round (bytes: vector<bool>'s bit access was a third
  // of the fit's time).
  std::vector<unsigned char> use;
  Eigen::Vector3d Row(const Eigen::Vector2d& p) const { return {1.0, p.x() - origin.x(), p.y() - origin.y()}; }
  // Scalar form of coeffs.dot(Row(p)): the Eigen temporary went through the
  // stack in the rays' inner loop.
  double At(const Eigen::Vector2d& p) const {
    return (coeffs(0) + coeffs(1) * (p.x() - origin.x())) + coeffs(2) * (p.y() - origin.y());
  }
};

LevelPlane FitLevelPlane(const std::vector<Eigen::Vector2d>& at, const std::vector<double>& value,
                         const Eigen::Vector2d& origin) {
  LevelPlane plane;
  plane.origin = origin;
  plane.use.assign(at.size(), 1);
  for (int round = 0; round < 2; ++round) {
    // The normal equations' sums in registers: an Eigen 3x3 accumulator
    // round-trips through memory on every sample.
    double n = 0, sx = 0, sy = 0, sxx = 0, sxy = 0, syy = 0, sv = 0, sxv = 0, syv = 0;
    for (size_t i = 0; i < at.size(); ++i) {
      if (!plane.use[i]) continue;
      const double x = at[i].x() - origin.x(), y = at[i].y() - origin.y(), v = value[i];
      n += 1.0, sx += x, sy += y, sxx += x * x, sxy += x * y, syy += y * y;
      sv += v, sxv += x * v, syv += y * v;
    }
    Eigen::Matrix3d ata;
    ata << n, sx, sy, sx, sxx, sxy, sy, sxy, syy;
    plane.normal_inverse = ata.ldlt().solve(Eigen::Matrix3d::Identity());
    plane.coeffs = plane.normal_inverse * Eigen::Vector3d(sv, sxv, syv);
    if (round == 1) break;
    std::vector<double> abs_res(at.size());
    for (size_t i = 0; i < at.size(); ++i) abs_res[i] = std::abs(value[i] - plane.At(at[i]));
    const double threshold = std::max(3.0 * 1.4826 * Median(abs_res), 1e-6);
    for (size_t i = 0; i < at.size(); ++i) plane.use[i] = abs_res[i] <= threshold;
  }
  return plane;
}

// One pass of rays and what the noise propagation needs from it.
struct EdgePass {
  EllipseEdges edges;
  // The rays wholly on the image (boundary point and unit normal) and the
  // s ranges of the inside and outside plateaus along them.
  std::vector<Eigen::Vector2d> bases, normals;
  double in_lo = 0.0, in_hi = 0.0, out_lo = 0.0, out_hi = 0.0;
  // Per edge point: its ray (index into bases), the root's s, its ray's unit
  // direction and the profile's slope df/ds > 0 there (image units per px).
  std::vector<int> ray;
  std::vector<double> s_root;
  std::vector<Eigen::Vector2d> normal;
  std::vector<double> slope;
  double polarity = 1.0;
  // The level planes and the samples they were fitted to.
  LevelPlane inside, outside;
  std::vector<Eigen::Vector2d> in_at, out_at;
  // Pixel-noise variance at each level (image units^2) from the raw pixels of
  // the plateaus, and the levels (AddEdgeStatistics).
  double var_inside = 0.0, var_outside = 0.0;

  // f(s) along `ray`: rises through 0 at the edge whatever the polarity.
  // ProfileOnRay for s in [in_lo, out_hi], where the ray is on the image;
  // Profile anywhere (false off the image).
  double ProfileOnRay(const ImageF& image, size_t ray_index, double s) const {
    const Eigen::Vector2d p = bases[ray_index] + s * normals[ray_index];
    return polarity *
           (InterpolateOnImage(image, p.x(), p.y()) - 0.5 * (inside.At(p) + outside.At(p)));
  }
  bool Profile(const ImageF& image, size_t ray_index, double s, double* f) const {
    const Eigen::Vector2d p = bases[ray_index] + s * normals[ray_index];
    if (!InterpolationDomain(image, p.x(), p.y())) return false;
    *f = ProfileOnRay(image, ray_index, s);
    return true;
  }
};

// Robust variance of the raw pixels whose centres lie within `band` (s range
// along a ray) of some ray, about the level plane.
double PlateauPixelVariance(const ImageF& image, const std::vector<Eigen::Vector2d>& bases,
                            const std::vector<Eigen::Vector2d>& normals, double s_lo, double s_hi,
                            const LevelPlane& plane) {
  std::vector<double> abs_res;
  for (size_t k = 0; k < bases.size(); ++k) {
    for (double s = s_lo; s <= s_hi + 1e-9; s += 0.5) {
      const Eigen::Vector2d p = bases[k] + s * normals[k];
      const Eigen::Index c = std::lround(p.x()), r = std::lround(p.y());
      if (c < 0 || r < 0 || c >= image.cols() || r >= image.rows()) continue;
      const Eigen::Vector2d centre(static_cast<double>(c), static_cast<double>(r));
      const double s_pixel = (centre - bases[k]).dot(normals[k]);
      if (s_pixel < s_lo || s_pixel > s_hi) continue;  // nearer the edge than the plateau
      abs_res.push_back(std::abs(image(r, c) - plane.At(centre)));
    }
  }
  if (abs_res.empty()) return 0.0;
  const double sigma = 1.4826 * Median(abs_res);
  return sigma * sigma;
}

// The edge points of one pass along the normals of `rough`; the blur and
// noise statistics are left to AddEdgeStatistics (RefineEllipticalMark needs
// them for its last pass only).
EdgePass CastRays(const ImageF& image, const Ellipse& rough, const EllipseEdgeOptions& options) {
  EdgePass pass;
  EllipseEdges& edges = pass.edges;
  const double a = rough.SemiMajorPx(), b = rough.SemiMinorPx();
  const double perimeter = 2.0 * std::numbers::pi * std::sqrt(0.5 * (a * a + b * b));
  edges.num_rays = std::max(options.min_rays, static_cast<int>(std::ceil(perimeter / options.ray_spacing_px)));
  const double inner = std::min(options.ray_half_length_px, 0.5 * b);
  const double outer = options.ray_half_length_px;
  const double plateau_in = std::min(options.plateau_px, 0.5 * inner);
  pass.in_lo = -inner, pass.in_hi = -inner + plateau_in;
  pass.out_lo = outer - options.plateau_px, pass.out_hi = outer;

  // Rays (boundary point and normal) that lie wholly on the image.
  Eigen::Matrix2Xd boundary, boundary_normals;
  rough.SampleBoundary(edges.num_rays, &boundary, &boundary_normals);
  std::vector<Eigen::Vector2d>& bases = pass.bases;
  std::vector<Eigen::Vector2d>& normals = pass.normals;
  bases.reserve(static_cast<size_t>(edges.num_rays));
  normals.reserve(static_cast<size_t>(edges.num_rays));
  std::vector<double> in_value, out_value;
  for (int k = 0; k < edges.num_rays; ++k) {
    const Eigen::Vector2d base = boundary.col(k), normal = boundary_normals.col(k);
    // Every sample of the ray lies between its ends.
    const Eigen::Vector2d first = base + pass.in_lo * normal, last = base + pass.out_hi * normal;
    if (!InterpolationDomain(image, first.x(), first.y()) ||
        !InterpolationDomain(image, last.x(), last.y())) {
      ++edges.num_rays_off_image;
      continue;
    }
    for (double s = pass.in_lo; s <= pass.in_hi + 1e-9; s += options.plateau_step_px) {
      const Eigen::Vector2d p = base + s * normal;
      pass.in_at.push_back(p);
      in_value.push_back(InterpolateOnImage(image, p.x(), p.y()));
    }
    for (double s = pass.out_lo; s <= pass.out_hi + 1e-9; s += options.plateau_step_px) {
      const Eigen::Vector2d p = base + s * normal;
      pass.out_at.push_back(p);
      out_value.push_back(InterpolateOnImage(image, p.x(), p.y()));
    }
    bases.push_back(base);
    normals.push_back(normal);
  }
  if (bases.size() < 8) {
    edges.points_px.resize(2, 0);
    return pass;
  }
  pass.inside = FitLevelPlane(pass.in_at, in_value, rough.centre_px);
  pass.outside = FitLevelPlane(pass.out_at, out_value, rough.centre_px);
  edges.contrast = pass.outside.coeffs(0) - pass.inside.coeffs(0);
  pass.polarity = edges.contrast >= 0.0 ? 1.0 : -1.0;
  auto profile = [&](size_t ray, double s) { return pass.ProfileOnRay(image, ray, s); };

  std::vector<Eigen::Vector2d> points;
  points.reserve(bases.size());
  const double search_lo = pass.in_hi, search_hi = pass.out_lo;
  for (size_t ray = 0; ray < bases.size(); ++ray) {
    // Every upward crossing on the grid; keep the ray only if there is one.
    int crossings = 0;
    double lo = 0, hi = 0, f_lo = 0, f_hi = 0;
    double s_prev = search_lo, f_prev = profile(ray, s_prev);
    for (double s = search_lo + options.bracket_step_px; s <= search_hi + 1e-9;
         s += options.bracket_step_px) {
      const double f = profile(ray, s);
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
      const double f = profile(ray, s_root);
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
    // The slope at the root (the interpolant is C1; a short central
    // difference): how far pixel noise moves the crossing.
    constexpr double kH = 0.05;
    double f_before, f_after;
    if (!pass.Profile(image, ray, s_root - kH, &f_before) ||
        !pass.Profile(image, ray, s_root + kH, &f_after) || !(f_after > f_before)) {
      continue;
    }
    points.push_back(bases[ray] + s_root * normals[ray]);
    pass.ray.push_back(static_cast<int>(ray));
    pass.s_root.push_back(s_root);
    pass.normal.push_back(normals[ray]);
    pass.slope.push_back((f_after - f_before) / (2.0 * kH));
  }
  edges.points_px.resize(2, static_cast<Eigen::Index>(points.size()));
  for (size_t i = 0; i < points.size(); ++i) edges.points_px.col(static_cast<Eigen::Index>(i)) = points[i];
  return pass;
}

// The median blur of the pass's edge points and the plateaus' pixel noise.
void AddEdgeStatistics(const ImageF& image, EdgePass* pass) {
  EllipseEdges& edges = pass->edges;
  if (pass->bases.size() < 8) return;
  std::vector<double> sigmas;
  for (size_t i = 0; i < pass->ray.size(); ++i) {
    const size_t ray = static_cast<size_t>(pass->ray[i]);
    const double s_root = pass->s_root[i];
    const Eigen::Vector2d point = edges.points_px.col(static_cast<Eigen::Index>(i));
    double f_minus, f_plus;
    if (pass->Profile(image, ray, s_root - 0.5, &f_minus) &&
        pass->Profile(image, ray, s_root + 0.5, &f_plus) && f_plus > f_minus) {
      const double local_contrast = std::abs(pass->outside.At(point) - pass->inside.At(point));
      sigmas.push_back(local_contrast / (std::sqrt(2.0 * std::numbers::pi) * (f_plus - f_minus)));
    }
  }
  if (!sigmas.empty()) edges.edge_sigma_px = Median(sigmas);
  pass->var_inside = PlateauPixelVariance(image, pass->bases, pass->normals, pass->in_lo,
                                          pass->in_hi, pass->inside);
  pass->var_outside = PlateauPixelVariance(image, pass->bases, pass->normals, pass->out_lo,
                                           pass->out_hi, pass->outside);
  edges.pixel_noise_inside = std::sqrt(pass->var_inside);
  edges.pixel_noise_outside = std::sqrt(pass->var_outside);
}

// Adds weight * (the interpolation weights of (x, y)) to g over its 4 x 4
// pixels; g covers the image window starting at (x0, y0), `width` wide.
void AddInterpolationWeights(double x, double y, const Eigen::Vector2d& weight, Eigen::Index x0, Eigen::Index y0,
                             Eigen::Index width, std::vector<Eigen::Vector2d>* g) {
  const double fx = std::floor(x), fy = std::floor(y);
  double wx[4], wy[4];
  CatmullRomWeights(x - fx, wx);
  CatmullRomWeights(y - fy, wy);
  const Eigen::Index c = static_cast<Eigen::Index>(fx) - 1 - x0, r = static_cast<Eigen::Index>(fy) - 1 - y0;
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 4; ++j) (*g)[static_cast<size_t>((r + i) * width + c + j)] += wy[i] * wx[j] * weight;
  }
}

// Covariance of the fitted centre from the image noise, to first order: the
// centre is linear in the edge points' moves across the curve (the fit's
// centre_sensitivity S), each move is -(the profile's noise at the root) /
// slope, and that noise is the interpolated pixel noise minus the noise of the
// mid-level (the two level planes, themselves linear in their samples). So
// centre noise = sum_p g_p e_p over the pixels p, with var(e_p) the pixel
// noise at its level (shot + read noise is linear in the level; interpolated
// between the two plateaus' measured variances). Unlike the residual-based
// s^2 (J^T J)^-1, this counts the correlation of neighbouring edge points
// (they share pixels) and leaves out the fit's systematic misfit, which is
// not noise.
Eigen::Matrix2d CentreCovarianceFromNoise(const ImageF& image, const EdgePass& pass, const EllipseFit& fit) {
  const Eigen::Matrix2Xd& points = pass.edges.points_px;
  const Eigen::Index n = points.cols();
  // Window covering every stencil (edge points and plateau samples).
  Eigen::Vector2d lo = points.rowwise().minCoeff(), hi = points.rowwise().maxCoeff();
  for (const std::vector<Eigen::Vector2d>* at : {&pass.in_at, &pass.out_at}) {
    for (const Eigen::Vector2d& p : *at) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
  }
  const Eigen::Index x0 = static_cast<Eigen::Index>(std::floor(lo.x())) - 1;
  const Eigen::Index y0 = static_cast<Eigen::Index>(std::floor(lo.y())) - 1;
  const Eigen::Index width = static_cast<Eigen::Index>(std::floor(hi.x())) + 3 - x0;
  const Eigen::Index height = static_cast<Eigen::Index>(std::floor(hi.y())) + 3 - y0;
  std::vector<Eigen::Vector2d> g(static_cast<size_t>(width * height), Eigen::Vector2d::Zero());

  // k_i: centre move per unit of profile noise at point i.
  Eigen::Matrix<double, 2, 3> k_inside = Eigen::Matrix<double, 2, 3>::Zero(), k_outside = k_inside;
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Vector2d p = points.col(i);
    const Eigen::Vector2d across = (fit.ellipse.shape * (p - fit.ellipse.centre_px)).normalized();
    const Eigen::Vector2d k = -pass.polarity * fit.centre_sensitivity.col(i) * across.dot(pass.normal[static_cast<size_t>(i)]) /
                              pass.slope[static_cast<size_t>(i)];
    AddInterpolationWeights(p.x(), p.y(), k, x0, y0, width, &g);
    k_inside += k * pass.inside.Row(p).transpose();
    k_outside += k * pass.outside.Row(p).transpose();
  }
  // The mid-level's noise enters with weight -1/2 per plane.
  auto add_plane = [&](const LevelPlane& plane, const std::vector<Eigen::Vector2d>& at,
                       const Eigen::Matrix<double, 2, 3>& k_plane) {
    const Eigen::Matrix<double, 2, 3> m = -0.5 * k_plane * plane.normal_inverse;
    for (size_t s = 0; s < at.size(); ++s) {
      if (plane.use[s]) AddInterpolationWeights(at[s].x(), at[s].y(), m * plane.Row(at[s]), x0, y0, width, &g);
    }
  };
  add_plane(pass.inside, pass.in_at, k_inside);
  add_plane(pass.outside, pass.out_at, k_outside);
  const double level_in = pass.inside.coeffs(0), level_out = pass.outside.coeffs(0);
  const double var_slope = (pass.var_outside - pass.var_inside) / (level_out - level_in);
  const double var_floor = std::min(pass.var_inside, pass.var_outside);
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (Eigen::Index r = 0; r < height; ++r) {
    for (Eigen::Index c = 0; c < width; ++c) {
      const Eigen::Vector2d& gp = g[static_cast<size_t>(r * width + c)];
      if (gp.isZero()) continue;
      const double value = image(y0 + r, x0 + c);
      const double var = std::max(var_floor, pass.var_inside + var_slope * (value - level_in));
      cov += var * gp * gp.transpose();
    }
  }
  return cov;
}

}  // namespace

std::string EllipseEdgeOptions::Check() const {
  if (!(ray_half_length_px > 0.0)) return "ray_half_length_px must be > 0";
  if (!(plateau_px > 0.0 && plateau_px < ray_half_length_px)) {
    return "plateau_px must be in (0, ray_half_length_px)";
  }
  if (!(ray_spacing_px > 0.0)) return "ray_spacing_px must be > 0";
  if (!(plateau_step_px > 0.0 && plateau_step_px <= 1.0))
    return "plateau_step_px must be in (0, 1]";
  if (!(bracket_step_px > 0.0 && bracket_step_px <= 1.0))
    return "bracket_step_px must be in (0, 1]";
  if (min_rays < 8) return "min_rays must be >= 8";
  return {};
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
  double previous_moved_px = INFINITY;
  // Pass 1 along the rough normals, then along the fitted ones. Rays off the
  // edge put one side's plateau into the blur and pull the levels; the error
  // shrinks ~10x per pass (~70x on the demo's marks), so a few passes converge.
  for (int pass_index = 0; pass_index < options.max_passes; ++pass_index) {
    EdgePass pass = CastRays(image, guide, options.edges);
    const EllipseEdges& edges = pass.edges;
    if (edges.num_rays_off_image > 0) {
      mark.why_failed = "mark touches the image border";
      return mark;
    }
    mark.contrast = edges.contrast;
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
    // The moves shrink geometrically, so the passes still to come would move
    // the centre by about moved r / (1 - r) in all, r = moved / previous move.
    const double ratio = moved_px / previous_moved_px;
    const double to_come_px = ratio < 1.0 ? moved_px * ratio / (1.0 - ratio) : INFINITY;
    previous_moved_px = moved_px;
    guide = fit.ellipse;
    mark.ellipse = fit.ellipse;
    mark.rms_px = fit.rms_px;
    mark.num_inliers = fit.num_inliers;
    mark.num_passes = pass_index + 1;
    if ((pass_index > 0 && std::min(moved_px, to_come_px) < options.converged_px) ||
        pass_index + 1 == options.max_passes) {
      AddEdgeStatistics(image, &pass);
      mark.edge_sigma_px = edges.edge_sigma_px;
      mark.centre_cov_px2 = CentreCovarianceFromNoise(image, pass, fit);
      break;
    }
  }
  mark.sigma_px = std::sqrt(0.5 * mark.centre_cov_px2.trace());
  mark.ok = true;
  return mark;
}

}  // namespace omm
