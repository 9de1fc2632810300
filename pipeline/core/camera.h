// The camera as the pipeline knows it: a mrcal lens model and its parameters.
//
// Conventions (shared by the whole pipeline):
// - Pixel coordinates q_px = (x, y): x to the right, y down, (0, 0) at the
//   CENTRE of the top-left pixel (mrcal's and OpenCV's convention; COLMAP puts
//   it at (0.5, 0.5), converted in adapters/colmap only).
// - Camera frame: x right, y down, z forward along the optical axis, mm.
// - Rigid transforms are named target_from_source (cam_from_plate maps plate
//   points into the camera frame); rotations are Eigen rotation matrices or
//   angle-axis vectors in radians (mrcal's "r" of an rt pose).
#pragma once

#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace omm {

struct CameraModel {
  // mrcal lens-model name, fully configured, e.g. "LENSMODEL_OPENCV8" or
  // "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_fov_x_deg=50".
  std::string lens_model;
  // mrcal's parameter vector: fx, fy, cx, cy (px), then the distortions in
  // mrcal's order for that model.
  Eigen::VectorXd intrinsics;
  int width_px = 0;
  int height_px = 0;
  // Where the calibration measured the lens (2 x N polygon, px; empty if not
  // known): the convex hull of the calibration's inlier marks, written as
  // mrcal's `valid_intrinsics_region`. A model read from a file has mrcal's
  // polygon, which mrcal's tools draw where the projection uncertainty is low.
  Eigen::Matrix2Xd valid_region_px;
};

}  // namespace omm
