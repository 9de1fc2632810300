#include "pipeline/simulate/ray_table.h"

#include <algorithm>
#include <cmath>
#include <thread>

#include "adapters/mrcal/lens.h"

namespace omm {
namespace {

// Catmull-Rom interpolation in a grid of unprojected rays with one node of
// padding on every side; its error is O(step^4) of the lens's smooth map.
class CoarseRays {
 public:
  CoarseRays(double x_min, double y_min, double step, int nx, int ny, Eigen::Matrix3Xd v)
      : x_min_(x_min), y_min_(y_min), step_(step), nx_(nx), ny_(ny), v_(std::move(v)) {}

  // Node positions: (x_min + i step, y_min + j step), i in [-1, nx - 2], j in [-1, ny - 2].
  static Eigen::Matrix2Xd Nodes(double x_min, double y_min, double step, int nx, int ny) {
    Eigen::Matrix2Xd q(2, nx * ny);
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i)
        q.col(j * nx + i) << x_min + (i - 1) * step, y_min + (j - 1) * step;
    }
    return q;
  }

  // The interpolated ray (x/z, y/z) at pixel q, and its derivative d(x, y)/dq
  // (the interpolant's own: close to the inverse of the lens's dq/d(x, y)).
  Eigen::Vector2d At(const Eigen::Vector2d& q, Eigen::Matrix2d* dxy_dq) const {
    const double fx = (q.x() - x_min_) / step_, fy = (q.y() - y_min_) / step_;
    // Nodes ix .. ix + 3 around q, q between ix + 1 and ix + 2.
    const int ix = std::clamp(static_cast<int>(std::floor(fx)) - 1, 0, nx_ - 4);
    const int iy = std::clamp(static_cast<int>(std::floor(fy)) - 1, 0, ny_ - 4);
    double wx[4], wy[4], dwx[4], dwy[4];
    Weights(fx - ix - 1, wx, dwx);
    Weights(fy - iy - 1, wy, dwy);
    Eigen::Vector2d sum = Eigen::Vector2d::Zero(), d_dx = sum, d_dy = sum;
    for (int b = 0; b < 4; ++b) {
      Eigen::Vector2d row = Eigen::Vector2d::Zero(), d_row = row;
      for (int a = 0; a < 4; ++a) {
        const auto node = v_.col((iy + b) * nx_ + ix + a).head<2>();
        row += wx[a] * node;
        d_row += dwx[a] * node;
      }
      sum += wy[b] * row;
      d_dx += wy[b] * d_row;
      d_dy += dwy[b] * row;
    }
    dxy_dq->col(0) = d_dx / step_;
    dxy_dq->col(1) = d_dy / step_;
    return sum;
  }

 private:
  // Catmull-Rom weights of the four nodes and their derivatives in t.
  static void Weights(double t, double w[4], double dw[4]) {
    const double t2 = t * t, t3 = t2 * t;
    w[0] = 0.5 * (-t3 + 2 * t2 - t);
    w[1] = 0.5 * (3 * t3 - 5 * t2 + 2);
    w[2] = 0.5 * (-3 * t3 + 4 * t2 + t);
    w[3] = 0.5 * (t3 - t2);
    dw[0] = 0.5 * (-3 * t2 + 4 * t - 1);
    dw[1] = 0.5 * (9 * t2 - 10 * t);
    dw[2] = 0.5 * (-9 * t2 + 8 * t + 1);
    dw[3] = 0.5 * (3 * t2 - 2 * t);
  }

  double x_min_, y_min_, step_;
  int nx_, ny_;
  Eigen::Matrix3Xd v_;
};

struct RowsResult {
  bool ok = true;
  double max_initial_residual_px = 0.0;
  double max_residual_px = 0.0;
};

// Refines the supersamples of rect rows [row_begin, row_end) in place.
RowsResult RefineRows(const CameraModel& camera, const CoarseRays& coarse,
                      const RayTableOptions& options, int row_begin, int row_end, RayTable* table) {
  RowsResult result;
  const PixelRect& rect = table->rect;
  const int s = table->supersampling;
  const int per_pixel = s * s;
  const int n = rect.width * per_pixel;  // one pixel row's supersamples per batch
  Eigen::Matrix2Xd q_target(2, n), q(2, n);
  Eigen::Matrix3Xd p(3, n);
  std::vector<Eigen::Matrix2d> dxy_dq(n);
  for (int r = row_begin; r < row_end; ++r) {
    const int row = rect.y0 + r;
    for (int c = 0; c < rect.width; ++c) {
      for (int k = 0; k < per_pixel; ++k) {
        const int i = c * per_pixel + k;
        q_target.col(i) = table->SamplePixel(rect.x0 + c, row, k % s, k / s);
        p.col(i) << coarse.At(q_target.col(i), &dxy_dq[i]), 1.0;
      }
    }
    for (int step = 0; step < options.refine_steps; ++step) {
      if (!ProjectPoints(camera, p, &q)) {
        result.ok = false;
        return result;
      }
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector2d e = q_target.col(i) - q.col(i);
        if (step == 0) {
          result.max_initial_residual_px = std::max(result.max_initial_residual_px, e.norm());
          if (!std::isfinite(e.norm())) result.ok = false;
        }
        p.col(i).head<2>() += dxy_dq[i] * e;
      }
    }
    for (int c = 0; c < rect.width; ++c) {
      const std::size_t pixel = table->PixelIndex(r, c);
      const Eigen::Vector2d base = p.col(c * per_pixel).head<2>();
      table->base_xy[2 * pixel] = base.x();
      table->base_xy[2 * pixel + 1] = base.y();
      for (int k = 0; k < per_pixel; ++k) {
        const std::size_t sample = pixel * per_pixel + k;
        table->offset_xy[2 * sample] = static_cast<float>(p(0, c * per_pixel + k) - base.x());
        table->offset_xy[2 * sample + 1] = static_cast<float>(p(1, c * per_pixel + k) - base.y());
      }
    }
    if (r % options.check_every_rows == 0) {
      // Check the rays as stored, offsets rounded to float.
      for (int c = 0; c < rect.width; ++c) {
        for (int k = 0; k < per_pixel; ++k) p.col(c * per_pixel + k) << table->Ray(r, c, k), 1.0;
      }
      if (!ProjectPoints(camera, p, &q)) {
        result.ok = false;
        return result;
      }
      for (int i = 0; i < n; ++i) {
        const double residual = (q.col(i) - q_target.col(i)).norm();
        if (!std::isfinite(residual)) result.ok = false;
        result.max_residual_px = std::max(result.max_residual_px, residual);
      }
    }
  }
  return result;
}

}  // namespace

std::string RayTableOptions::Check() const {
  if (supersampling < 1 || supersampling > 16) return "supersampling must be in 1..16";
  if (coarse_step_px < 1) return "coarse_step_px must be >= 1";
  if (refine_steps < 0) return "refine_steps must be >= 0";
  if (check_every_rows < 1) return "check_every_rows must be >= 1";
  if (num_threads < 1) return "num_threads must be >= 1";
  return "";
}

RayTable ComputeRayTable(const CameraModel& camera, const PixelRect& rect,
                         const RayTableOptions& options, RayTableSummary* summary) {
  RayTable table;
  table.rect = rect;
  table.supersampling = options.supersampling;
  *summary = RayTableSummary();
  if (rect.width <= 0 || rect.height <= 0) return table;

  // Coarse nodes cover the supersamples' extent [x0 - 1/2, x0 + width - 1/2]
  // with one node of padding on each side for the cubic.
  const double step = options.coarse_step_px;
  const double x_min = rect.x0 - 0.5, y_min = rect.y0 - 0.5;
  const int nx = static_cast<int>(std::ceil(rect.width / step)) + 3;
  const int ny = static_cast<int>(std::ceil(rect.height / step)) + 3;
  Eigen::Matrix3Xd v_nodes;
  if (!UnprojectPixels(camera, CoarseRays::Nodes(x_min, y_min, step, nx, ny), &v_nodes) ||
      !v_nodes.allFinite()) {
    return table;
  }
  // The padding is part of the grid: interpolation uses nodes -1 .. nx - 2.
  const CoarseRays coarse(x_min - step, y_min - step, step, nx, ny, std::move(v_nodes));

  const std::size_t num_pixels = static_cast<std::size_t>(rect.width) * rect.height;
  table.base_xy.resize(2 * num_pixels);
  table.offset_xy.resize(2 * num_pixels * table.SamplesPerPixel());
  const int num_threads = std::min(options.num_threads, rect.height);
  std::vector<RowsResult> results(num_threads);
  std::vector<std::thread> threads;
  for (int t = 0; t < num_threads; ++t) {
    const int begin = rect.height * t / num_threads, end = rect.height * (t + 1) / num_threads;
    threads.emplace_back([&, t, begin, end] {
      results[t] = RefineRows(camera, coarse, options, begin, end, &table);
    });
  }
  for (std::thread& thread : threads) thread.join();

  summary->ok = true;
  for (const RowsResult& r : results) {
    summary->ok = summary->ok && r.ok;
    summary->max_initial_residual_px =
        std::max(summary->max_initial_residual_px, r.max_initial_residual_px);
    summary->max_residual_px = std::max(summary->max_residual_px, r.max_residual_px);
  }
  summary->num_rays = num_pixels * table.SamplesPerPixel();
  return table;
}

}  // namespace omm
