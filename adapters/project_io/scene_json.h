// The mosaic stage's adjusted scene as JSON (out/mosaic/scene.json, format
// `omm-scene/1`), for the measure stage: the plane pose, the true table
// positions, their joint covariance and which tile image each belongs to.
//
// Layout (lengths mm, angles rad; plane_scene.h's model p_cam = R (P + T_i) + t):
//
// {
//   "format": "omm-scene/1",
//   "cam_from_part": {"r": [rx, ry, rz], "t": [tx, ty, tz]},   // angle-axis, mm
//   "table_sigma_mm": 0.02,
//   "tiles": [{"image": "tile_r0c0.png", "commanded_mm": [x, y],
//              "adjusted_mm": [x, y], "held_by_prior": false}],
//   "plates": [{"x_mm": .., "y_mm": .., "theta_rad": .., "height_mm": .., "scale": ..}],
//   "lens_model": "LENSMODEL_OPENCV8",   // of the intrinsics below
//   "intrinsics": [...],        // the intrinsics the scene was solved with
//   "intrinsics_refined": true, // refined under the calibration's covariance as a
//                               // prior: the covariance's intrinsics block is then
//                               // joint with the rest; false: held at the
//                               // calibration's values, that block is zero
//   "rms_px": 0.03,             // the adjustment's RMS reprojection error
//   "intrinsics_information": {"size": N, "values": [N x N, row-major]},
//                               // the calibration prior's information matrix the
//                               // intrinsics were refined under; null if held
//   "covariance": {"size": N, "values": [N x N, row-major]}   // or null
// }
// The covariance is PlaneScene::covariance: the vector
// [r (3), t (3), T_0 (2), ..., T_{n-1} (2), per plate (x, y, theta, h, s),
// intrinsics (N)], rad, mm and the intrinsics' own units; a parameter held
// constant has zero rows and columns. Tracks are not
// saved (the COLMAP export in out/colmap/ has them). Numbers are written with
// round-trip precision.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/plane_scene.h"

namespace omm {

inline constexpr const char* kSceneFormat = "omm-scene/1";

// What the measure stage needs of the mosaic's registration.
struct SavedScene {
  PlaneScene scene;  // pose, table_pos_mm, plates, intrinsics, covariance (no tracks)
  std::vector<std::string> tile_images;                 // per tile, file name in tiles/
  std::vector<Eigen::Vector2d> commanded_table_pos_mm;  // per tile (table.csv)
  std::vector<int> tiles_held_by_prior;                 // no feature kept: table prior only
  std::vector<int> tiles_without_table_prior;  // ascending: the features contradicted table.csv
  // The sigma the table priors were weighed by: table.sigma_mm, or the
  // scatter estimated where the data contradict it (mosaic_stage.cc).
  double table_sigma_mm = 0.0;
  double rms_px = 0.0;
  std::string lens_model;           // of scene.intrinsics ("" in files without it)
  bool intrinsics_refined = false;  // false in files without the key
  // The prior the intrinsics were refined under (PlaneBundleInput::
  // intrinsics_information, N x N); empty unless intrinsics_refined.
  Eigen::MatrixXd intrinsics_information;
};

std::string SceneToJson(const SavedScene& saved);

// Parses SceneToJson's text. Throws InputError naming `where` and the key on
// malformed input (sizes that do not agree included).
SavedScene SceneFromJson(const std::string& text, const std::string& where);

// File versions; the write goes through a temporary file and a rename.
void WriteSceneJson(const SavedScene& saved, const std::filesystem::path& path);
SavedScene ReadSceneJson(const std::filesystem::path& path);

}  // namespace omm
