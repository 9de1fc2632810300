// Test support: synthetic plate observations, pure math (no rendering).
// A truth camera (LENSMODEL_OPENCV8, 1600 x 1200, fx ~ 2667 px: a 12 mm lens
// on 4.485 um pixels, off-centre principal point, that lens's distortion) sees
// the 7 x 7 plate from `num_images` poses at ~390 mm, tilted 10-35 deg about a
// random in-plane axis, spread over the field; the marks' projections get
// i.i.d. Gaussian noise. Everything is seeded.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "adapters/mrcal/calibrate.h"
#include "pipeline/core/board.h"
#include "pipeline/core/calibration_result.h"
#include "pipeline/core/camera.h"
#include "pipeline/core/plate_observation.h"

namespace omm::testing {

CameraModel TruthCamera();

// mrcal's cubic splined model with 10 x 8 knots (what lens-mismatch's
// calibration picks, fov 38 deg: knots ~255 px apart) over the 12 mm camera's
// core; the knots' offsets up to 1e-3 in u (~3 px).
CameraModel SplinedCamera();

struct SyntheticPlates {
  std::vector<Vector6d> rt_cam_from_plate;      // truth poses
  std::vector<Eigen::Matrix2Xd> q_truth_px;     // noise-free marks
  // The observations for a given noise draw: q_truth + N(0, sigma^2).
  std::vector<PlateObservation> Observe(double noise_px, uint32_t seed) const;
};

// Solve options for these plates: `lens_model` on the cameras' 1600 x 1200
// imager, the rest default.
CalibrationOptions SyntheticSolveOptions(const std::string& lens_model);

// Poses whose every mark lands at least 20 px inside the imager.
SyntheticPlates MakeSyntheticPlates(const BoardSpec& board, const CameraModel& camera,
                                    int num_images, double distance_mm, uint32_t seed);

}  // namespace omm::testing
