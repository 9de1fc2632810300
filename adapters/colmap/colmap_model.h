// The adjusted planar scene as a COLMAP sparse model (TEXT format: cameras.txt,
// images.txt, points3D.txt; https://colmap.github.io/format.html), so COLMAP's
// tools (model_analyzer, the GUI, model_converter) open it.
//
// World frame = the part frame (mm). Tile i sees a part point P at
// p_cam = R (P + T_i) + t, so its COLMAP pose (cam_from_world) is rotation R,
// translation R T_i + t. Points3D are the tracks (X, Y, 0) with their used
// observations (weight > 0) as tracks of (image, point2D index); a track needs
// two. ERROR is the mean reprojection error of the point's observations, px.
//
// Camera. One camera. COLMAP puts pixel (0, 0) at the corner of the top-left
// pixel, omm at its centre: cx, cy and every point2D get + 0.5 here (and
// nowhere else). Lens models: LENSMODEL_PINHOLE -> PINHOLE, LENSMODEL_OPENCV4
// -> OPENCV, LENSMODEL_OPENCV5 and _OPENCV8 -> FULL_OPENCV (same polynomial, the
// parameters in the same order; k4..k6 = 0 for OPENCV5). Any other mrcal model
// (splined, CAHVOR, ...) has no COLMAP equivalent: the camera is written as the
// PINHOLE core (fx, fy, cx, cy) and every observation as its undistorted pixel
// f u + c (u = the unprojected ray), reported in the summary.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/plane_scene.h"

namespace omm {

struct ColmapExportSummary {
  std::string camera_model;  // COLMAP's name: PINHOLE, OPENCV, FULL_OPENCV
  bool undistorted = false;  // true: the lens had no COLMAP equivalent (see above)
  int num_images = 0;
  int num_points = 0;
  int num_observations = 0;
  // Mean over points of their ERROR (what `colmap model_analyzer` reports), px.
  double mean_point_error_px = 0.0;
  std::string brief;
};

// Writes the model into `dir` (created if missing; the three files are each
// written through a temporary file and a rename). image_names: one per tile,
// in the scene's order. observations: the adjustment's input, with
// scene.track_xy_mm holding its tracks. Throws InputError if the input does
// not fit or a file cannot be written.
ColmapExportSummary WriteColmapModel(const std::filesystem::path& dir, const CameraModel& camera,
                                     const PlaneScene& scene,
                                     const std::vector<TrackObservation>& observations,
                                     const std::vector<std::string>& image_names);

}  // namespace omm
