#include "pipeline/mosaic/ortho_lens_table.h"

#include <algorithm>
#include <cassert>
#include <cmath>

#include "adapters/mrcal/lens.h"

namespace omm {

std::string LensTableOptions::Check() const {
  if (!(node_spacing_px > 0.0)) return "node_spacing_px must be > 0";
  if (!(max_error_px > 0.0)) return "max_error_px must be > 0";
  if (!(margin_px >= 0.0)) return "margin_px must be >= 0";
  return "";
}

Eigen::Matrix2Xd RectangleBorderPx(const Eigen::Vector2d& min_px, const Eigen::Vector2d& max_px,
                                   int per_side) {
  const double x0 = min_px.x(), y0 = min_px.y(), x1 = max_px.x(), y1 = max_px.y();
  Eigen::Matrix2Xd border(2, 4 * per_side);
  for (int k = 0; k < per_side; ++k) {
    const double s = static_cast<double>(k) / per_side;
    border.col(k) = Eigen::Vector2d(x0 + s * (x1 - x0), y0);
    border.col(per_side + k) = Eigen::Vector2d(x1, y0 + s * (y1 - y0));
    border.col(2 * per_side + k) = Eigen::Vector2d(x1 - s * (x1 - x0), y1);
    border.col(3 * per_side + k) = Eigen::Vector2d(x0, y1 - s * (y1 - y0));
  }
  return border;
}

namespace {

// Range of normalised rays over the image border pushed out by margin_px.
// Where the lens maps no ray to a margin pixel (mrcal leaves NaN: a splined
// model beyond the knots its marks constrained, a radial polynomial past its
// fold), the image border's ray there, pushed out by margin_px / f, stands
// in; the table reaches on by extrapolating the projection. False if no
// border pixel unprojects.
bool RayRange(const CameraModel& camera, double margin_px, Eigen::Vector2d* u_min,
              Eigen::Vector2d* u_max) {
  constexpr int kPerSide = 64;
  const Eigen::Vector2d last(camera.width_px - 1, camera.height_px - 1);
  const Eigen::Matrix2Xd margin = RectangleBorderPx(
      Eigen::Vector2d::Constant(-margin_px), last + Eigen::Vector2d::Constant(margin_px), kPerSide);
  const Eigen::Matrix2Xd border = RectangleBorderPx(Eigen::Vector2d::Zero(), last, kPerSide);
  const Eigen::Vector2d focal(camera.intrinsics[0], camera.intrinsics[1]);
  const auto normalised = [&](const Eigen::Matrix2Xd& q, Eigen::Matrix2Xd* u) {
    Eigen::Matrix3Xd v;
    if (!UnprojectPixels(camera, q, &v)) v.setConstant(3, q.cols(), NAN);
    *u = v.topRows<2>().array().rowwise() / v.row(2).array();
  };
  Eigen::Matrix2Xd u, u_border;
  normalised(margin, &u);
  *u_min = Eigen::Vector2d::Constant(INFINITY);
  *u_max = -*u_min;
  bool any = false;
  for (Eigen::Index k = 0; k < u.cols(); ++k) {
    Eigen::Vector2d uk = u.col(k);
    if (!uk.allFinite()) {
      if (u_border.cols() == 0) normalised(border, &u_border);
      uk = u_border.col(k) + (margin.col(k) - border.col(k)).cwiseQuotient(focal);
      if (!uk.allFinite()) continue;
    }
    *u_min = u_min->cwiseMin(uk);
    *u_max = u_max->cwiseMax(uk);
    any = true;
  }
  return any;
}

}  // namespace

LensTable BuildLensTable(const CameraModel& camera, const LensTableOptions& options) {
  assert(options.Check().empty());
  Eigen::Vector2d u_min, u_max;
  LensTable table;
  if (!RayRange(camera, options.margin_px, &u_min, &u_max)) return table;
  const Eigen::Vector2d focal(camera.intrinsics[0], camera.intrinsics[1]);

  double spacing_px = options.node_spacing_px;
  for (int attempt = 0; attempt < 5; ++attempt, spacing_px *= 0.5) {
    const Eigen::Vector2d step = Eigen::Vector2d::Constant(spacing_px).cwiseQuotient(focal);
    // One node outside the range on each side for Catmull-Rom's support, one
    // more for rounding.
    table.u0_ = u_min - 2.0 * step;
    table.nx_ = static_cast<int>(std::ceil((u_max.x() - u_min.x()) / step.x())) + 5;
    table.ny_ = static_cast<int>(std::ceil((u_max.y() - u_min.y()) / step.y())) + 5;
    table.inv_step_ = step.cwiseInverse();
    table.node_spacing_px_ = spacing_px;

    const int n = table.nx_ * table.ny_;
    Eigen::Matrix3Xd p(3, n);
    for (int j = 0; j < table.ny_; ++j) {
      for (int i = 0; i < table.nx_; ++i) {
        p.col(j * table.nx_ + i) << table.u0_.x() + i * step.x(), table.u0_.y() + j * step.y(), 1.0;
      }
    }
    Eigen::Matrix2Xd q;
    const bool ok = ProjectPoints(camera, p, &q);
    assert(ok);
    (void)ok;
    table.nodes_.assign(q.data(), q.data() + 2 * n);

    // Check points: the centre and the two edge midpoints of every inner cell.
    std::vector<Eigen::Vector2d> check;
    for (int j = 1; j + 2 < table.ny_; ++j) {
      for (int i = 1; i + 2 < table.nx_; ++i) {
        for (const auto& [dx, dy] : {std::pair{0.5, 0.5}, {0.5, 0.0}, {0.0, 0.5}}) {
          check.emplace_back(table.u0_.x() + (i + dx) * step.x(),
                             table.u0_.y() + (j + dy) * step.y());
        }
      }
    }
    Eigen::Matrix3Xd pc(3, check.size());
    for (size_t k = 0; k < check.size(); ++k) pc.col(k) << check[k], 1.0;
    Eigen::Matrix2Xd qc;
    const bool ok_check = ProjectPoints(camera, pc, &qc);
    assert(ok_check);
    (void)ok_check;
    double max_error = 0.0;
    for (size_t k = 0; k < check.size(); ++k) {
      Eigen::Vector2d q_interp;
      if (table.Project(check[k], &q_interp)) {
        max_error = std::max(max_error, (q_interp - qc.col(k)).norm());
      }
    }
    table.max_error_px_ = max_error;
    if (max_error <= options.max_error_px) break;
  }
  return table;
}

}  // namespace omm
