#include "adapters/mrcal/mrcal_lens_projection.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "adapters/mrcal/mrcal_c.h"

namespace omm {

struct MrcalLensProjection::Lens {
  mrcal_lensmodel_t model;
  // Splined models (order 2 or 3; 0 for the others): the knot grid and its
  // spacing in the stereographic u = 2 p_xy / (|p| + p_z), knots per unit u.
  int order = 0;
  int nx = 0;
  int ny = 0;
  double segments_per_u = 0.0;
  // Each row of knots in this many blocks of about order + 2 knots each, so
  // that a point's order + 1 (+ margin) knots of a row fall in one or two.
  // Per knot, Ceres' Schur eliminator spent more on its many small blocks
  // than it saved (lens-mismatch, Nx = 10: blocks of 1, 2, 3, 5, 10 knots took
  // 0.85, 0.41, 0.4, 0.25, 0.29 s in the final adjustment's solve).
  int blocks_per_row = 1;
};

MrcalLensProjection::MrcalLensProjection(CameraModel camera) : camera_(std::move(camera)) {
  auto lens = std::make_shared<Lens>();
  if (mrcal_lensmodel_from_name(&lens->model, camera_.lens_model.c_str()) &&
      mrcal_lensmodel_type_is_valid(lens->model.type) &&
      mrcal_lensmodel_num_params(&lens->model) == camera_.intrinsics.size()) {
    if (lens->model.type == MRCAL_LENSMODEL_SPLINED_STEREOGRAPHIC) {
      const auto& config = lens->model.LENSMODEL_SPLINED_STEREOGRAPHIC__config;
      std::vector<double> ux(config.Nx), uy(config.Ny);
      if (config.Nx >= 2 && mrcal_knots_for_splined_models(ux.data(), uy.data(), &lens->model)) {
        lens->order = config.order;
        lens->nx = config.Nx;
        lens->ny = config.Ny;
        lens->segments_per_u = 1.0 / (ux[1] - ux[0]);
        lens->blocks_per_row = (lens->nx + lens->order + 1) / (lens->order + 2);
      }
    }
    lens_ = std::move(lens);
  }
}

int MrcalLensProjection::NumIntrinsics() const {
  return static_cast<int>(camera_.intrinsics.size());
}

bool MrcalLensProjection::Project(const Eigen::Vector3d& p_cam, const double* intrinsics,
                                  Eigen::Vector2d* q_px, Matrix23d* dq_dp,
                                  RowMajorMatrix2Xd* dq_dintrinsics) const {
  // mrcal_project on the one point, the lens model parsed once: the Ceres
  // costs call this per residual (ProjectPoints' parsing and buffers were
  // half of its cost). With one point mrcal's dq_dp is right without
  // dq_dintrinsics (lens.cc's caveat is about the points after the first).
  if (lens_ == nullptr) return false;
  mrcal_point3_t dq_dp_rows[2];
  if (dq_dintrinsics != nullptr) {
    dq_dintrinsics->resize(2, NumIntrinsics());
    dq_dintrinsics->setZero();
  }
  if (!mrcal_project(
          reinterpret_cast<mrcal_point2_t*>(q_px->data()), dq_dp != nullptr ? dq_dp_rows : nullptr,
          dq_dintrinsics != nullptr ? dq_dintrinsics->data() : nullptr,
          reinterpret_cast<const mrcal_point3_t*>(p_cam.data()), 1, &lens_->model, intrinsics))
    return false;
  if (dq_dp != nullptr) {
    for (int i = 0; i < 2; ++i)
      for (int k = 0; k < 3; ++k) (*dq_dp)(i, k) = dq_dp_rows[i].xyz[k];
  }
  return true;
}

std::vector<int> MrcalLensProjection::IntrinsicsBlockStarts() const {
  if (lens_ == nullptr || lens_->order == 0) return {0, NumIntrinsics()};
  std::vector<int> starts = {0};
  for (int y = 0; y < lens_->ny; ++y)
    for (int j = 0; j < lens_->blocks_per_row; ++j)
      starts.push_back(4 + 2 * (y * lens_->nx + j * lens_->nx / lens_->blocks_per_row));
  starts.push_back(NumIntrinsics());
  return starts;
}

std::vector<int> MrcalLensProjection::IntrinsicsBlocksNear(const Eigen::Vector3d& p_cam,
                                                           const double* intrinsics,
                                                           double radius_px) const {
  // mrcal's _project_point_splined: q = (u + delta(u)) f + c with the
  // stereographic u = 2 p_xy / (|p| + p_z); delta at knot coordinate
  // i = u segments_per_u + (N - 1) / 2 uses the knots i0 - 1 .. i0 + order - 1,
  // i0 = (int) i (cubic) or (int) (i + 1/2) (quadratic), clamped to the grid.
  // radius_px is radius_px / f in u, to first order.
  if (lens_ == nullptr || lens_->order == 0)
    return LensProjection::IntrinsicsBlocksNear(p_cam, intrinsics, radius_px);
  const double scale = 2.0 / (p_cam.norm() + p_cam.z());
  const Eigen::Array2d i = p_cam.head<2>().array() * scale * lens_->segments_per_u +
                           0.5 * Eigen::Array2d(lens_->nx - 1, lens_->ny - 1);
  const Eigen::Array2d margin =
      radius_px * lens_->segments_per_u / Eigen::Array2d(intrinsics[0], intrinsics[1]).abs();
  if (!(i + margin).allFinite())
    return LensProjection::IntrinsicsBlocksNear(p_cam, intrinsics, radius_px);
  const double shift = lens_->order == 3 ? 0.0 : 0.5;
  const auto first_i0 = [&](double x, int n) {
    return static_cast<int>(std::clamp(std::floor(x + shift), 1.0, double(n - lens_->order)));
  };
  const int x0 = first_i0(i.x() - margin.x(), lens_->nx) - 1;
  const int x1 = first_i0(i.x() + margin.x(), lens_->nx) + lens_->order - 1;
  const int y0 = first_i0(i.y() - margin.y(), lens_->ny) - 1;
  const int y1 = first_i0(i.y() + margin.y(), lens_->ny) + lens_->order - 1;
  // Knot x is in block j of its row for j nx / blocks_per_row <= x.
  const auto block_of = [&](int x) { return ((x + 1) * lens_->blocks_per_row - 1) / lens_->nx; };
  std::vector<int> blocks = {0};
  for (int y = y0; y <= y1; ++y)
    for (int j = block_of(x0); j <= block_of(x1); ++j)
      blocks.push_back(1 + y * lens_->blocks_per_row + j);
  return blocks;
}

}  // namespace omm
