// Whether the part is where the calibration saw its plate: the camera is
// focused for one working distance and calibrated there, so the part plane
// the adjustment places far outside the calibration plate's distances says
// the metric scale is wrong. The table positions are the scale (only T / d
// is observed), so table.csv in other units than mm (cm, inches, um) shows
// as the part 10x or 25x too far or too near, and every feature is then
// looked for at the wrong size.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace omm {

// Where the optical axis meets the plane z = 0 of a frame posed by
// (r, t) = cam_from_frame (angle-axis, mm): that point's z in the camera
// frame. Empty if the axis runs parallel to the plane or meets it behind
// the camera.
std::optional<double> AxisDistanceMm(const Eigen::Vector3d& cam_from_frame_r,
                                     const Eigen::Vector3d& cam_from_frame_t_mm);

struct WorkingDistanceOptions {
  // The part may be this many times nearer than the nearest plate pose or
  // farther than the farthest: depth of field allows no more, while a units
  // error gives 10 or 25.
  double max_ratio = 2.0;

  std::string Check() const;  // empty if valid, else what is wrong
};

struct WorkingDistanceCheck {
  bool ok = false;  // the part's distance and at least one plate's known
  double part_mm = 0.0;
  double calibration_min_mm = 0.0, calibration_max_mm = 0.0;
  bool consistent = true;
};

// The part plane's axis distance against the calibration plate poses'
// (each an (r, t) of cam_from_plate).
WorkingDistanceCheck CheckWorkingDistance(
    const Eigen::Vector3d& cam_from_part_r, const Eigen::Vector3d& cam_from_part_t_mm,
    const std::vector<Eigen::Matrix<double, 6, 1>>& rt_cam_from_plates,
    const WorkingDistanceOptions& options);

}  // namespace omm
