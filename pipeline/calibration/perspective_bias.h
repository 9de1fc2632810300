// Perspective bias of circular marks: the centre of the imaged ellipse is not
// the image of the circle's centre.
//
// Model. A circle of radius rho on the plate (z = 0) around mark centre m
// images, through a pinhole, as an ellipse whose centre is offset from the
// projection of m towards the vanishing line, by ~ rho^2 * (tilt-dependent
// terms) / distance^2: a few hundredths of a pixel for the demo plate at 35 deg.
// With lens distortion the image is not even a conic. The correction is
// computed, not modelled: with a pose cam_from_plate and a camera (from a first
// calibration solve), project `boundary_points` points of each mark's circle
// through the lens model, fit the SAME ellipse as the detector
// (pipeline/core/ellipse_fit.h, FitEllipse) and shift the measured centre by
//     delta = project(m) - centre(fit(project(circle))).
// A second solve on the corrected centres then sees (nearly) unbiased marks;
// the correction depends on the pose only to second order, so one iteration
// is enough (cf. Heikkila, "Geometric camera calibration using circular
// control points", PAMI 2000, who fits the conic directly instead).
#pragma once

#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "pipeline/core/board.h"
#include "pipeline/core/camera.h"
#include "pipeline/core/plate_observation.h"

namespace omm {

struct PerspectiveBiasOptions {
  int boundary_points = 64;  // points on each mark's circle

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// delta (px, 2 x rows*cols, BoardPoints' order) to ADD to each measured
// ellipse centre. Zero for chessboards (point marks have no bias). False if a
// mark cannot be projected (behind the camera or outside mrcal's domain).
bool PerspectiveBiasCorrections(const BoardSpec& board, const CameraModel& camera,
                                const Eigen::Isometry3d& cam_from_plate, Eigen::Matrix2Xd* delta_px,
                                const PerspectiveBiasOptions& options = {});

// `observation` with q_px += delta for every observed mark (weight > 0).
// Returns the observation unchanged if it is not usable or the corrections
// cannot be computed.
PlateObservation CorrectPerspectiveBias(const PlateObservation& observation, const BoardSpec& board,
                                        const CameraModel& camera, const Eigen::Isometry3d& cam_from_plate,
                                        const PerspectiveBiasOptions& options = {});

}  // namespace omm
