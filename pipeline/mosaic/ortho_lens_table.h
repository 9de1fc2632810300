// The lens projection as a lookup table, for mapping millions of mosaic pixels.
//
// The map from a mosaic pixel to a tile pixel is a composition
//     (col, row) -> p_cam (affine: orthorectify.h) -> u = (x/z, y/z) -> q = L(u),
// where only L, the lens model's projection of the normalised ray u, is
// costly (mrcal_project). L does not depend on the tile, so one table serves
// every tile: L is projected exactly (ProjectPoints) at the nodes of a regular
// grid over the normalised rays the image sees, and evaluated elsewhere by
// bicubic Catmull-Rom interpolation of the node values (separable, 4 x 4 nodes;
// it reproduces quadratics exactly, so its error is O(h^3 L''')).
//
// Error bound. The interpolation error of a smooth L is largest in the middle
// of a cell, so BuildLensTable projects every cell's centre and edge midpoints
// exactly and records the largest deviation; while it exceeds
// `max_error_px` the spacing is halved. At a 16 px spacing it is 5e-7 px for
// the simulator's OPENCV8 12 mm lens and 5e-5 px for its splined lens
// (orthorectify_test.cc checks it against exact projections at random rays).
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/camera.h"
#include "pipeline/mosaic/ortho_sampling.h"

namespace omm {

struct LensTableOptions {
  double node_spacing_px = 16.0;  // initial node spacing, in pixels (u spacing * fx)
  double max_error_px = 0.001;    // largest acceptable interpolation error, px
  // Rays outside the image are covered up to this margin, px (the resampler
  // interpolates between nodes up to ~3 x 8 px beyond the pixels it samples).
  double margin_px = 32.0;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

class LensTable {
 public:
  LensTable() = default;

  // Pixel of normalised ray u = (x/z, y/z). False if u is outside the table
  // (then q_px is untouched).
  bool Project(const Eigen::Vector2d& u, Eigen::Vector2d* q_px) const {
    const double fx = (u.x() - u0_.x()) * inv_step_.x();
    const double fy = (u.y() - u0_.y()) * inv_step_.y();
    // Catmull-Rom needs nodes i-1 .. i+2.
    if (!(fx >= 1.0 && fy >= 1.0 && fx < nx_ - 2.0 && fy < ny_ - 2.0)) return false;
    const int ix = static_cast<int>(fx), iy = static_cast<int>(fy);
    double wx[4], wy[4];
    CatmullRomWeights(fx - ix, wx);
    CatmullRomWeights(fy - iy, wy);
    double qx = 0.0, qy = 0.0;
    for (int j = 0; j < 4; ++j) {
      const double* node = &nodes_[2 * ((iy - 1 + j) * nx_ + ix - 1)];
      double rx = 0.0, ry = 0.0;
      for (int i = 0; i < 4; ++i) {
        rx += wx[i] * node[2 * i];
        ry += wx[i] * node[2 * i + 1];
      }
      qx += wy[j] * rx;
      qy += wy[j] * ry;
    }
    *q_px = {qx, qy};
    return true;
  }

  int num_nodes() const { return nx_ * ny_; }
  double node_spacing_px() const { return node_spacing_px_; }
  // Largest |interpolated - exact| over every cell's centre and edge midpoints, px.
  double max_error_px() const { return max_error_px_; }

 private:
  friend LensTable BuildLensTable(const CameraModel&, const LensTableOptions&);

  Eigen::Vector2d u0_ = Eigen::Vector2d::Zero();        // ray of node (0, 0)
  Eigen::Vector2d inv_step_ = Eigen::Vector2d::Zero();  // 1 / node spacing in u
  int nx_ = 0, ny_ = 0;
  std::vector<double> nodes_;  // q of node (i, j) at 2 (j nx + i), px
  double node_spacing_px_ = 0.0;
  double max_error_px_ = 0.0;
};

// Points along the border of the rectangle [min_px, max_px], per_side on
// each side, evenly spaced, clockwise (x right, y down) from min_px.
Eigen::Matrix2Xd RectangleBorderPx(const Eigen::Vector2d& min_px, const Eigen::Vector2d& max_px,
                                   int per_side);

// Builds the table over the rays of the image (plus options.margin_px): the
// image border pushed out by the margin is unprojected to find their range
// (where the lens maps no ray to a margin pixel, the border's ray pushed out
// by margin / f stands in). Precondition: options.Check() is empty and the
// camera projects (a valid mrcal model). If the bound cannot be met at 1/16
// of the initial spacing the table is returned anyway; max_error_px() says
// how good it is. Empty (Project always false) if no border pixel
// unprojects.
LensTable BuildLensTable(const CameraModel& camera, const LensTableOptions& options = {});

}  // namespace omm
