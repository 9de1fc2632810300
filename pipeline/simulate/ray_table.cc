#include "pipeline/simulate/ray_table.h"

#include <algorithm>
#include <cmath>
#include <thread>

#include "adapters/mrcal/lens.h"

namespace omm {
namespace {

// Catmull-Rom interpolation in a grid of rays (x/z, y/z), node (i, j) at
// pixel (x0 + i step, y0 + j step), stored at j * nx + i; its error is
// O(step^3) of the lens's smooth map. A point takes the 4 x 4 nodes around
// it, so the grid has one node of padding beyond the points on every side.
class RayGrid {
 public:
  // The grid covering [x_min, x_min + width] x [y_min, y_min + height] with
  // nodes `step` apart and the padding; rays to be filled in.
  RayGrid(double x_min, double y_min, double width, double height, double step)
      : x0_(x_min - step),
        y0_(y_min - step),
        step_(step),
        nx_(static_cast<int>(std::ceil(width / step)) + 3),
        ny_(static_cast<int>(std::ceil(height / step)) + 3),
        rays_(2, static_cast<Eigen::Index>(nx_) * ny_) {}

  int nx() const { return nx_; }
  int ny() const { return ny_; }
  Eigen::Vector2d NodePixel(int i, int j) const { return {x0_ + i * step_, y0_ + j * step_}; }
  Eigen::Matrix2Xd& rays() { return rays_; }

  // The interpolant along one image row y = q_y: the grid's columns combined
  // with the row's weights once, so that each point of the row costs one
  // 4-tap interpolation. Reused for row after row (Set).
  class Row {
   public:
    explicit Row(const RayGrid& grid) : grid_(grid), value_(grid.nx_), d_dy_(grid.nx_) {}

    void Set(double q_y) {
      const RayGrid& g = grid_;
      const double fy = (q_y - g.y0_) / g.step_;
      // Nodes iy .. iy + 3 around q_y, q_y between iy + 1 and iy + 2.
      const int iy = std::clamp(static_cast<int>(std::floor(fy)) - 1, 0, g.ny_ - 4);
      double wy[4], dwy[4];
      Weights(fy - iy - 1, wy, dwy);
      for (int i = 0; i < g.nx_; ++i) {
        Eigen::Vector2d value = Eigen::Vector2d::Zero(), d_dy = value;
        for (int b = 0; b < 4; ++b) {
          const auto node = g.rays_.col((iy + b) * g.nx_ + i);
          value += wy[b] * node;
          d_dy += dwy[b] * node;
        }
        value_[i] = value;
        d_dy_[i] = d_dy / g.step_;
      }
    }

    // The interpolated ray at pixel (q_x, q_y) and, if dxy_dq is not null,
    // its derivative d(x, y)/dq (the interpolant's own: close to the inverse
    // of the lens's dq/d(x, y)).
    Eigen::Vector2d At(double q_x, Eigen::Matrix2d* dxy_dq = nullptr) const {
      const RayGrid& g = grid_;
      const double fx = (q_x - g.x0_) / g.step_;
      const int ix = std::clamp(static_cast<int>(std::floor(fx)) - 1, 0, g.nx_ - 4);
      double wx[4], dwx[4];
      Weights(fx - ix - 1, wx, dwx);
      Eigen::Vector2d sum = Eigen::Vector2d::Zero();
      for (int a = 0; a < 4; ++a) sum += wx[a] * value_[ix + a];
      if (dxy_dq) {
        Eigen::Vector2d d_dx = Eigen::Vector2d::Zero(), d_dy = d_dx;
        for (int a = 0; a < 4; ++a) {
          d_dx += dwx[a] * value_[ix + a];
          d_dy += wx[a] * d_dy_[ix + a];
        }
        dxy_dq->col(0) = d_dx / g.step_;
        dxy_dq->col(1) = d_dy;
      }
      return sum;
    }

   private:
    const RayGrid& grid_;
    std::vector<Eigen::Vector2d> value_, d_dy_;  // per grid column
  };

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

  double x0_, y0_, step_;
  int nx_, ny_;
  Eigen::Matrix2Xd rays_;
};

struct RowsResult {
  bool ok = true;
  double max_initial_residual_px = 0.0;
  double max_residual_px = 0.0;
};

// Runs work(begin, end, &result) over [0, count) split into num_threads
// ranges, and merges their results.
template <typename Work>
RowsResult InParallel(int count, int num_threads, const Work& work) {
  num_threads = std::clamp(num_threads, 1, std::max(1, count));
  std::vector<RowsResult> results(num_threads);
  std::vector<std::thread> threads;
  for (int t = 0; t < num_threads; ++t) {
    const int begin = count * t / num_threads, end = count * (t + 1) / num_threads;
    threads.emplace_back([&, t, begin, end] { work(begin, end, &results[t]); });
  }
  for (std::thread& thread : threads) thread.join();
  RowsResult merged;
  for (const RowsResult& r : results) {
    merged.ok = merged.ok && r.ok;
    merged.max_initial_residual_px =
        std::max(merged.max_initial_residual_px, r.max_initial_residual_px);
    merged.max_residual_px = std::max(merged.max_residual_px, r.max_residual_px);
  }
  return merged;
}

// Rays of the fine grid's node rows [row_begin, row_end): interpolated in the
// coarse grid, then refined by the fixed-point step, one node row per batch.
void RefineNodeRows(const CameraModel& camera, const RayGrid& coarse, int refine_steps,
                    int row_begin, int row_end, RayGrid* fine, RowsResult* result) {
  const int n = fine->nx();
  Eigen::Matrix2Xd q_target(2, n), q(2, n);
  Eigen::Matrix3Xd p(3, n);
  std::vector<Eigen::Matrix2d> dxy_dq(n);
  RayGrid::Row coarse_row(coarse);
  for (int j = row_begin; j < row_end; ++j) {
    coarse_row.Set(fine->NodePixel(0, j).y());
    for (int i = 0; i < n; ++i) {
      q_target.col(i) = fine->NodePixel(i, j);
      p.col(i) << coarse_row.At(q_target(0, i), &dxy_dq[i]), 1.0;
    }
    for (int step = 0; step < refine_steps; ++step) {
      if (!ProjectPoints(camera, p, &q)) {
        result->ok = false;
        return;
      }
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector2d e = q_target.col(i) - q.col(i);
        if (step == 0) {
          result->max_initial_residual_px = std::max(result->max_initial_residual_px, e.norm());
          if (!std::isfinite(e.norm())) result->ok = false;
        }
        p.col(i).head<2>() += dxy_dq[i] * e;
      }
    }
    fine->rays().middleCols(static_cast<Eigen::Index>(j) * n, n) = p.topRows<2>();
  }
}

// Interpolates the supersamples and Gauss points of rect rows [row_begin,
// row_end) in the fine grid, and checks every check_every_rows-th row by
// projecting it.
void FillRows(const CameraModel& camera, const RayGrid& fine, int check_every_rows, int row_begin,
              int row_end, RayTable* table, RowsResult* result) {
  const PixelRect& rect = table->rect;
  const int s = table->supersampling;
  const int per_pixel = s * s;
  RayGrid::Row fine_row(fine);
  std::vector<Eigen::Vector2d> base(rect.width);
  for (int r = row_begin; r < row_end; ++r) {
    const int row = rect.y0 + r;
    for (int sy = 0; sy < s; ++sy) {
      fine_row.Set(table->SamplePixel(0, row, 0, sy).y());
      for (int c = 0; c < rect.width; ++c) {
        const std::size_t pixel = table->PixelIndex(r, c);
        for (int sx = 0; sx < s; ++sx) {
          const Eigen::Vector2d ray = fine_row.At(table->SamplePixel(rect.x0 + c, row, sx, sy).x());
          if (sy == 0 && sx == 0) {
            base[c] = ray;
            table->base_xy[2 * pixel] = ray.x();
            table->base_xy[2 * pixel + 1] = ray.y();
          }
          const std::size_t sample = pixel * per_pixel + sy * s + sx;
          table->offset_xy[2 * sample] = static_cast<float>(ray.x() - base[c].x());
          table->offset_xy[2 * sample + 1] = static_cast<float>(ray.y() - base[c].y());
        }
      }
    }
    for (int j = 0; j < 2; ++j) {
      fine_row.Set(RayTable::GaussPixel(0, row, 2 * j).y());
      for (int c = 0; c < rect.width; ++c) {
        const std::size_t pixel = table->PixelIndex(r, c);
        for (int i = 0; i < 2; ++i) {
          const Eigen::Vector2d ray = fine_row.At(RayTable::GaussPixel(rect.x0 + c, row, i).x());
          table->gauss_offset_xy[8 * pixel + 2 * (2 * j + i)] =
              static_cast<float>(ray.x() - base[c].x());
          table->gauss_offset_xy[8 * pixel + 2 * (2 * j + i) + 1] =
              static_cast<float>(ray.y() - base[c].y());
        }
      }
    }
    if (r % check_every_rows != 0) continue;
    // Check the rays as stored, offsets rounded to float.
    const int per_check = per_pixel + 4;
    const int n = rect.width * per_check;
    Eigen::Matrix3Xd p(3, n);
    Eigen::Matrix2Xd q_target(2, n), q;
    for (int c = 0; c < rect.width; ++c) {
      for (int k = 0; k < per_pixel; ++k) {
        p.col(c * per_check + k) << table->Ray(r, c, k), 1.0;
        q_target.col(c * per_check + k) = table->SamplePixel(rect.x0 + c, row, k % s, k / s);
      }
      for (int k = 0; k < 4; ++k) {
        p.col(c * per_check + per_pixel + k) << table->GaussRay(r, c, k), 1.0;
        q_target.col(c * per_check + per_pixel + k) = RayTable::GaussPixel(rect.x0 + c, row, k);
      }
    }
    if (!ProjectPoints(camera, p, &q)) {
      result->ok = false;
      return;
    }
    for (int i = 0; i < n; ++i) {
      const double residual = (q.col(i) - q_target.col(i)).norm();
      if (!std::isfinite(residual)) result->ok = false;
      result->max_residual_px = std::max(result->max_residual_px, residual);
    }
  }
}

}  // namespace

std::string RayTableOptions::Check() const {
  if (supersampling < 1 || supersampling > 16) return "supersampling must be in 1..16";
  if (coarse_step_px < 1) return "coarse_step_px must be >= 1";
  if (fine_step_px <= 0) return "fine_step_px must be > 0";
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

  // Both grids cover the supersamples' extent [x0 - 1/2, x0 + width - 1/2].
  const double x_min = rect.x0 - 0.5, y_min = rect.y0 - 0.5;
  RayGrid coarse(x_min, y_min, rect.width, rect.height, options.coarse_step_px);
  Eigen::Matrix2Xd q_nodes(2, static_cast<Eigen::Index>(coarse.nx()) * coarse.ny());
  for (int j = 0; j < coarse.ny(); ++j) {
    for (int i = 0; i < coarse.nx(); ++i) q_nodes.col(j * coarse.nx() + i) = coarse.NodePixel(i, j);
  }
  Eigen::Matrix3Xd v_nodes;
  if (!UnprojectPixels(camera, q_nodes, &v_nodes) || !v_nodes.allFinite()) return table;
  coarse.rays() = v_nodes.topRows<2>();

  RayGrid fine(x_min, y_min, rect.width, rect.height, options.fine_step_px);
  const RowsResult nodes =
      InParallel(fine.ny(), options.num_threads, [&](int begin, int end, RowsResult* result) {
        RefineNodeRows(camera, coarse, options.refine_steps, begin, end, &fine, result);
      });
  if (!nodes.ok) return table;

  const std::size_t num_pixels = static_cast<std::size_t>(rect.width) * rect.height;
  table.base_xy.resize(2 * num_pixels);
  table.offset_xy.resize(2 * num_pixels * table.SamplesPerPixel());
  table.gauss_offset_xy.resize(8 * num_pixels);
  const RowsResult rows =
      InParallel(rect.height, options.num_threads, [&](int begin, int end, RowsResult* result) {
        FillRows(camera, fine, options.check_every_rows, begin, end, &table, result);
      });
  summary->ok = rows.ok;
  summary->max_initial_residual_px = nodes.max_initial_residual_px;
  summary->max_residual_px = rows.max_residual_px;
  summary->num_rays = num_pixels * table.SamplesPerPixel();
  return table;
}

}  // namespace omm
