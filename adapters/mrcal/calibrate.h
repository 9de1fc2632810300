// The camera calibration solve: mrcal 2.2's mrcal_optimize on plate
// observations, seeded and staged the way mrcal-calibrate-cameras does it.
//
// Model (mrcal's "vanilla" calibration): one camera at the reference frame,
// plate i at pose cam_from_plate_i ("frames_toref"), mark m of the plate at
// BoardPoints(board).col(m) (plus mrcal's calobject warp if enabled). The
// residual of mark m in image i is weight_im * (project(cam_from_plate_i *
// p_m; intrinsics) - q_im), minimised over the intrinsics, the plate poses and
// the warp, with mrcal's regularisation terms and outlier rejection.
//
// Seed (our own code, after mrcal's calibration.py: seed_stereographic and
// estimate_monocular_calobject_poses_Rt_tocam):
//   - intrinsics core: fx = fy = focal_length / pixel_pitch, (cx, cy) the
//     imager centre; distortions 0;
//   - each plate pose from the DLT homography between the plate and the
//     pinhole-normalised marks, H ~ [r1 r2 t], orthonormalised by SVD.
// Stages (mrcal-calibrate-cameras): (1) frames only, (2) core + frames, both
// without distortions, regularisation or outlier rejection; (3) everything
// with regularisation; (4) everything with outlier rejection (and the warp if
// asked). A LENSMODEL_SPLINED_STEREOGRAPHIC_* model is seeded from a full
// LENSMODEL_OPENCV4 solve: its core from OPENCV4's, its knots fitted linearly
// to OPENCV4's projection over the imager, its poses and outliers carried over;
// its core is then held fixed, as mrcal-calibrate-cameras does.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/board.h"
#include "pipeline/core/calibration_result.h"
#include "pipeline/core/plate_observation.h"

namespace omm {

struct CalibrationOptions {
  // mrcal lens-model name, fully configured (camera.h).
  std::string lens_model = "LENSMODEL_OPENCV8";
  // Nominal optics, the seed of the focal length in pixels.
  double focal_length_mm = 12.0;
  double pixel_pitch_um = 4.485;
  // Imager size, px. Required.
  int width_px = 0;
  int height_px = 0;
  // Solve for mrcal's 2-parameter plate flex (off by default: a flat plate).
  bool optimize_calobject_warp = false;
  // mrcal's outlier rejection in the final stage.
  bool apply_outlier_rejection = true;
  // mrcal's regularisation terms (its default, keeps the solve well posed).
  bool apply_regularization = true;
  // Fewer usable images than this is a data failure (result not usable).
  int min_images = 4;

  // Empty if the options are usable, else what is wrong.
  std::string Check() const;
};

// Calibrates. Observations with !usable are listed in images_not_used.
// Throws InputError if options.Check() fails or an observation's shape does
// not match the board; too few usable images or a failed solve is a result
// with usable == false.
CalibrationResult CalibrateCamera(const BoardSpec& board,
                                  const std::vector<PlateObservation>& observations,
                                  const CalibrationOptions& options);

// The final stage (4) again, from `previous`'s solution, on observations
// that moved a little (the perspective-bias rounds): each image of
// previous.record takes the observation of its name (InputError if there is
// none, or it is not usable; others are not added), its outliers are found
// afresh, previous's images_not_used are kept, a splined model's core stays
// held (the solve from the seed would
// take OPENCV4's again). A splined model converges slowly, linearly in its
// last ~100 iterations, so a start near the minimum saves about a third
// (lens-mismatch seed 284: 0.13 s a round against 0.20 s from the seed).
// Throws as CalibrateCamera.
CalibrationResult RefineCalibration(const CalibrationResult& previous,
                                    const std::vector<PlateObservation>& observations,
                                    const CalibrationOptions& options);

// The seed alone: a SolveRecord with options.lens_model, the nominal core,
// zero distortions and homography plate poses; usable observations only.
// Exposed so a reference implementation can start from the same point.
SolveRecord SeedCalibration(const BoardSpec& board,
                            const std::vector<PlateObservation>& observations,
                            const CalibrationOptions& options);

// Plate pose from one image's marks by DLT homography through a pinhole
// (fx = fy = focal_px, centre c_px), ignoring distortion. Marks with
// weight <= 0 are skipped. Returns rt_cam_from_plate; false if fewer than 4
// marks or a degenerate homography.
bool PlatePoseFromHomography(const Eigen::Matrix3Xd& p_plate, const Eigen::Matrix2Xd& q_px,
                             const Eigen::VectorXd& weight, double focal_px,
                             const Eigen::Vector2d& c_px, Vector6d* rt_cam_from_plate);

// Re-evaluates a record's residuals (no optimisation): per-image rms and
// outlier counts, overall rms. Used by CalibrateCamera and for reprocessing.
CalibrationResult SummarizeSolve(const SolveRecord& record);

}  // namespace omm
