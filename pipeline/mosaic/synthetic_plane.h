// Synthetic truth for the planar adjustment's tests (test support only): a
// flat part under a LENSMODEL_OPENCV8 camera (1600 x 1200, fx ~2667, some
// distortion: the 12 mm lens, 4.5 um pixels), tiles on a grid of table
// positions, random part points projected exactly and then perturbed.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/camera.h"
#include "pipeline/core/plane_scene.h"

namespace omm {

struct SyntheticPlaneOptions {
  std::uint64_t scene_seed = 1;  // camera pose noise-free truth: the part points
  std::uint64_t noise_seed = 2;  // table errors and observation noise
  double rotation_about_axis_deg = 37.0;  // camera about its z axis vs machine X
  double tilt_deg = 3.0;                  // plane tilt
  double tilt_azimuth_deg = 60.0;         // direction of the tilt axis in the plane
  double distance_mm = 390.0;             // camera centre to the plane, along z
  // Tiles on a num_cols x num_rows grid about the origin, T = (ix step_x,
  // iy step_y) with ix in -(num_cols - 1) / 2 .. (num_cols - 1) / 2 (iy
  // alike), turned by grid_angle_deg about Z. One row or column: a strip.
  int num_cols = 3, num_rows = 3;
  double step_x_mm = 140.0;
  double step_y_mm = 105.0;
  double grid_angle_deg = 0.0;
  double table_sigma_mm = 0.02;  // actual = commanded + N(0, sigma) per axis
  // Commanded = actual * (1 + table_scale_error): a systematic encoder scale.
  double table_scale_error = 0.0;
  double observation_sigma_px = 0.07;
  int num_tracks = 1500;  // tracks seen in >= 2 tiles
  int empty_tile = -1;    // if >= 0, that tile's observations are dropped
  int repeated_tile = -1;  // if >= 0, that tile is taken once more (last), same commanded place
  bool with_plate = false;  // a 7 x 7, 12.5 mm caltab lying on the part
  double plate_height_mm = 3.0;
};

struct SyntheticPlane {
  CameraModel camera;  // the truth camera (= the calibrated one here)
  PlaneScene truth;    // R, t (t_x = t_y = 0: the gauge), ACTUAL T_i, P, plate pose
  PlaneBundleInput input;
};

SyntheticPlane MakeSyntheticPlane(const SyntheticPlaneOptions& options);

// Pixel of part point (x, y, z) with the table at table_pos_mm through scene
// and camera (scene.intrinsics are ignored: camera's are used).
Eigen::Vector2d ProjectPartPoint(const CameraModel& camera, const PlaneScene& scene,
                                 const Eigen::Vector3d& part_mm,
                                 const Eigen::Vector2d& table_pos_mm);

// Scale of the least-squares similarity fit of `adjusted` to `actual` table
// positions, minus 1, ppm: the scale error a mosaic built on `adjusted` has.
double ScaleErrorPpm(const std::vector<Eigen::Vector2d>& adjusted,
                     const std::vector<Eigen::Vector2d>& actual);

}  // namespace omm
