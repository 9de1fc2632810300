#include "pipeline/mosaic/working_distance.h"

#include <algorithm>
#include <cassert>
#include <cmath>

#include "pipeline/core/plane_scene.h"

namespace omm {

std::optional<double> AxisDistanceMm(const Eigen::Vector3d& cam_from_frame_r,
                                     const Eigen::Vector3d& cam_from_frame_t_mm) {
  // The plane's normal n in the camera frame and a point t on it: the axis
  // point (0, 0, z) has n . ((0, 0, z) - t) = 0.
  const Eigen::Vector3d n = RotationFromAngleAxis(cam_from_frame_r).col(2);
  if (std::abs(n.z()) < 1e-9) return std::nullopt;
  const double z = n.dot(cam_from_frame_t_mm) / n.z();
  if (!(z > 0.0)) return std::nullopt;
  return z;
}

std::string WorkingDistanceOptions::Check() const {
  if (!(max_ratio > 1.0)) return "max_ratio must be > 1";
  return "";
}

WorkingDistanceCheck CheckWorkingDistance(
    const Eigen::Vector3d& cam_from_part_r, const Eigen::Vector3d& cam_from_part_t_mm,
    const std::vector<Eigen::Matrix<double, 6, 1>>& rt_cam_from_plates,
    const WorkingDistanceOptions& options) {
  assert(options.Check().empty());
  WorkingDistanceCheck check;
  const std::optional<double> part = AxisDistanceMm(cam_from_part_r, cam_from_part_t_mm);
  std::vector<double> plates;
  for (const Eigen::Matrix<double, 6, 1>& rt : rt_cam_from_plates) {
    if (const std::optional<double> z = AxisDistanceMm(rt.head<3>(), rt.tail<3>())) {
      plates.push_back(*z);
    }
  }
  if (!part || plates.empty()) return check;
  check.ok = true;
  check.part_mm = *part;
  check.calibration_min_mm = *std::min_element(plates.begin(), plates.end());
  check.calibration_max_mm = *std::max_element(plates.begin(), plates.end());
  check.consistent = check.part_mm * options.max_ratio >= check.calibration_min_mm &&
                     check.part_mm <= options.max_ratio * check.calibration_max_mm;
  return check;
}

}  // namespace omm
