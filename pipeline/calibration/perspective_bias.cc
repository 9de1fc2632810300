#include "pipeline/calibration/perspective_bias.h"

#include <cmath>
#include <numbers>

#include "adapters/mrcal/lens.h"
#include "pipeline/core/ellipse_fit.h"

namespace omm {

std::string PerspectiveBiasOptions::Check() const {
  if (boundary_points < 8) return "boundary_points must be >= 8";
  return {};
}

bool PerspectiveBiasCorrections(const BoardSpec& board, const CameraModel& camera,
                                const Eigen::Isometry3d& cam_from_plate, Eigen::Matrix2Xd* delta_px,
                                const PerspectiveBiasOptions& options) {
  const Eigen::Matrix3Xd marks = BoardPoints(board);
  const int n = static_cast<int>(marks.cols());
  delta_px->setZero(2, n);
  if (board.type == BoardType::kChessboard) return true;
  const double radius_mm = 0.5 * board.dot_diameter_mm;
  const int m = options.boundary_points;
  // All marks' centres and boundaries in one projection call.
  Eigen::Matrix3Xd p_plate(3, n * (m + 1));
  for (int i = 0; i < n; ++i) {
    p_plate.col(i * (m + 1)) = marks.col(i);
    for (int k = 0; k < m; ++k) {
      const double t = 2.0 * std::numbers::pi * k / m;
      p_plate.col(i * (m + 1) + 1 + k) = marks.col(i) + radius_mm * Eigen::Vector3d(std::cos(t), std::sin(t), 0.0);
    }
  }
  const Eigen::Matrix3Xd p_cam = cam_from_plate * p_plate;
  if ((p_cam.row(2).array() <= 0.0).any()) return false;
  Eigen::Matrix2Xd q_px;
  if (!ProjectPoints(camera, p_cam, &q_px)) return false;
  EllipseFitOptions fit_options;
  fit_options.max_rejection_rounds = 0;  // exact points: nothing to reject
  for (int i = 0; i < n; ++i) {
    const EllipseFit fit = FitEllipse(q_px.middleCols(i * (m + 1) + 1, m), fit_options);
    if (!fit.ok) return false;
    delta_px->col(i) = q_px.col(i * (m + 1)) - fit.ellipse.centre_px;
  }
  return true;
}

PlateObservation CorrectPerspectiveBias(const PlateObservation& observation, const BoardSpec& board,
                                        const CameraModel& camera, const Eigen::Isometry3d& cam_from_plate,
                                        const PerspectiveBiasOptions& options) {
  if (!observation.usable) return observation;
  Eigen::Matrix2Xd delta_px;
  if (!PerspectiveBiasCorrections(board, camera, cam_from_plate, &delta_px, options)) return observation;
  PlateObservation corrected = observation;
  for (int i = 0; i < corrected.q_px.cols(); ++i) {
    if (corrected.weight(i) > 0.0) corrected.q_px.col(i) += delta_px.col(i);
  }
  return corrected;
}

}  // namespace omm
