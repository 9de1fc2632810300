// The calibration stage: calibration-plate images in, a calibrated camera with
// its uncertainty out. Pure: images and specs in memory, no files (the runner,
// pipeline/orchestration/calibrate_stage.cc, reads and writes them).
//
// Steps:
//  1. Plate detection in every image (adapters/opencv/plate_detector.h,
//     num_threads at a time); an image that fails is rejected with the
//     detector's reason and never used.
//  2. A first mrcal solve (adapters/mrcal/calibrate.h) with the working lens
//     model: the user's, else LENSMODEL_OPENCV8 (flexible enough that its
//     poses and camera predict the marks' ellipses well).
//  3. Perspective bias (pipeline/calibration/perspective_bias.h): the centre of
//     each imaged dot is not the image of the dot's centre. The corrections
//     are computed from the DETECTED centres with the latest camera and poses,
//     and the solve repeated from the last solution (RefineCalibration) until
//     the corrections the solution gives differ by less than bias_settle_px
//     from those it was solved on (they depend on the pose only to second
//     order, so one round suffices with OPENCV8; a splined model, which bends
//     to each round's corrections, takes more: from the second re-solve on,
//     the corrections solved on are extrapolated from the last two rounds,
//     pipeline/core/fixed_point.h) or max_bias_rounds re-solves are
//     reached. A chessboard's corners have no such bias, but no sigma
//     either (cornerSubPix gives none): the detector's assumed
//     chessboard_sigma_px is replaced by their scatter about this first
//     solve (its dof-corrected RMS), the weights set from it (MarkWeight),
//     and the solve repeated from its solution. With the assumed 0.1 px,
//     rendered corners that scatter by 0.017 px got weight 0.2, which made
//     mrcal's regularisation of the distortions 25 times stronger than for
//     dots of that precision: on a demo-preset chessboard (an OPENCV8 truth,
//     seed 2) the OPENCV8 fit came 0.035 px RMS from the truth over the
//     imager at a stated 0.007 px; weighed by their scatter, 0.007 px.
//  4. Lens model (when the user forced none), by the structure of the
//     residuals: each candidate (the working model OPENCV8, and a splined
//     stereographic model sized for the observed marks, SplinedFieldDeg) is
//     solved on all images; its residual sigma corrected for the degrees of
//     freedom is sigma = rms sqrt(M / (M - P)) (M measurements, P states). A
//     model that cannot represent the lens leaves systematic residuals far
//     above the detection noise; one that can leaves the noise. The splined
//     model replaces OPENCV8 only if an F-test says its residual drop is
//     more than its extra parameters would give on noise alone (the
//     extra-sum-of-squares test, an approximation for the splined model) and
//     the misfit it removes, sqrt(sigma_8^2 - sigma_s^2), is at least
//     lens_choice_min_misfit_fraction of the noise it leaves. If it is
//     chosen, the bias corrections settle again with it (step 3's rounds
//     from its solve), or a chessboard's corners are weighed again by their
//     scatter about it (about OPENCV8 it held OPENCV8's misfit too). A
//     chosen spline that, settled, maps no ray to some pixel of the image
//     border (its outermost patches extrapolated past a fold), which the
//     tiles use, is solved again on the settled observations with its knot
//     field widened a degree at a time, up to splined_max_widening of the
//     data-sized field; the first that maps the whole border is kept, and
//     beyond that factor the stage fails.
//     Lens-mismatch seed 315 (20 images, marks reaching y 1038 of 1200 px)
//     failed the run at the sized 27 deg and maps from 29, its measurements
//     then as far from the truth as the same seed's other presets' (worst
//     0.155 raw px; markers 0.174, sparse texture 0.177: that seed's table
//     scale); with a chessboard, seed 295 failed at 26 deg and maps from 29
//     (worst 0.053 raw px); six usable images of seed 243 map from 27 deg
//     instead of 26 (worst 0.079 raw px, rms z 0.84; the mosaic moves the
//     extrapolated intrinsics by 5.8 sigma). A forced field 3 deg wider
//     than the chosen one on seeds 312, 314 and 316 moved their worst
//     measurement error by at most 0.009 raw px.
//     Why no smaller model than OPENCV8: a leaner one (OPENCV4, OPENCV5)
//     often fits the marks to the noise, so an F-test keeps it, but it
//     extrapolates into the corners the plates do not reach with a bias its
//     stiff, small sigma does not cover: on demo seeds 2, 5, 7 and 9 the
//     error over the imager was 2.24 of the stated sigma (pooled RMS; 86 of
//     192 grid points beyond 3 sigma on seed 7) where OPENCV8 gives 0.88,
//     and OPENCV8 was closer to the truth on seeds 1, 5, 7 (seed 7: 0.0105 ->
//     0.0034 px RMS). Why the misfit fraction: with chessboards on an
//     OPENCV8 lens the splined model passed the F-test by a hair (removing
//     0.15 of the noise) and then extrapolated 0.7-1.3 px off in the corners
//     (seeds 5, 9, 13); a lens the parametric model cannot represent leaves
//     far more (lens-mismatch: 1.6 px against the splined model's 0.04).
//     Why not cross-validation between halves (tried in an earlier revision):
//     it compares the halves over the WHOLE imager, where the plates rarely
//     reach the corners; each half extrapolates there on its own, so it
//     scores extrapolation rather than fit (on the lens-mismatch preset it
//     ranked the splined model last, 4.2 px, while that model is 5x closer to
//     the truth than OPENCV8), and it costs 24+ solves instead of 2.
//  5. A chosen spline beyond the marks (pipeline/calibration/
//     spline_extrapolation.h): where its projection 1-sigma exceeds that of
//     the working model's fit of the same images (its misfit and its own
//     uncertainty), it follows that fit; the marks' projections move by a
//     small fraction of their noise (the change at the marks is reported).
//     mrcal's regularisation pulled the corners the plates never reached
//     toward the bare stereographic projection.
//  6. Projection uncertainty over the imager (adapters/mrcal/uncertainty.h) at
//     the working distance, the median distance of the plates' centres from the
//     camera: typical (median over the imager) and worst (max) of mrcal's
//     worst-direction stdev.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "adapters/opencv/plate_detector.h"
#include "pipeline/calibration/spline_extrapolation.h"
#include "pipeline/core/board.h"
#include "pipeline/core/calibration_result.h"
#include "pipeline/core/image.h"
#include "pipeline/core/plate_observation.h"
#include "pipeline/core/project.h"

namespace omm {

struct CalibrationStageOptions {
  PlateDetectionOptions detection;
  int num_threads = 2;  // threads for the detection and the perspective-bias corrections

  // Perspective-bias rounds (correction + re-solve) after the first solve,
  // and again after a change of lens model.
  int max_bias_rounds = 10;
  // Settled when no correction differs by this much from the one solved on, px.
  double bias_settle_px = 0.001;

  // Lens-model choice (only when camera.lens_model is not given).
  bool choose_lens_model = true;    // false: the working model OPENCV8, no candidate solved
  int splined_nx = 10;              // knots across (Ny from the imager's aspect ratio)
  double splined_fov_margin = 0.9;  // the spline's fov_x is the marks' horizontal extent times this
  // A spline sized so that maps no ray to some pixel of the image border is
  // solved again with its field widened a degree at a time, up to this
  // factor of the data-sized one (step 4).
  double splined_max_widening = 1.2;
  // A bigger model is chosen only if its residuals drop beyond chance at this
  // one-sided normal quantile (2.326: 1% false choices) ...
  double lens_choice_significance_z = 2.326;
  // ... and if the misfit it removes, sqrt(sigma_small^2 - sigma_big^2), is
  // at least this fraction of the noise it leaves (step 4).
  double lens_choice_min_misfit_fraction = 0.5;
  // A chosen spline follows the working model's fit where it is the less
  // sure of the two (step 5); false: mrcal's own extrapolation.
  bool extrapolate_spline_by_working_model = true;
  SplineExtrapolationOptions spline_extrapolation;

  // Calibration solve.
  bool optimize_calobject_warp = false;
  int min_images = 4;

  // Projection-uncertainty grid over the imager.
  int uncertainty_grid_nx = 16;
  int uncertainty_grid_ny = 12;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// One calibration image in memory.
struct NamedImage {
  std::string name;  // file name in calib/
  GrayImage image;
};

// One candidate lens model's solve on all images.
struct LensCandidate {
  std::string lens_model;
  int num_params = 0;  // intrinsics
  bool usable = false;
  double rms_px = 0.0;       // mrcal's rms reprojection error
  int num_measurements = 0;  // M: 2 x inlier marks
  int num_states = 0;        // P: intrinsics + 6 per plate (+ warp)
  double sigma_px = 0.0;     // rms sqrt(M / (M - P))
};

// Why the lens model is what it is.
struct LensModelChoice {
  std::string lens_model;
  bool forced = false;                    // the user's camera.lens_model
  std::vector<LensCandidate> candidates;  // when the stage chose
  std::string why;                        // one line for the report
  // The splined candidate's knot field, as sized for the marks and as solved
  // (wider when the first left some border pixel unmapped), deg; 0: none.
  int splined_fov_sized_deg = 0;
  int splined_fov_deg = 0;
  // A chosen spline beyond the marks, guided by the working model's fit
  // (step 5).
  SplineExtrapolation extrapolation;
};

struct BiasCorrectionSummary {
  int rounds = 0;  // re-solves on corrected marks, over both settlings (each <= max_bias_rounds)
  double rms_px = 0.0;  // size of the corrections solved on, over all observed marks
  double max_px = 0.0;
  // Largest difference between the corrections the final solution gives and
  // those it was solved on.
  double last_change_px = 0.0;
};

struct UncertaintySummary {
  bool available = false;
  std::string why_not;             // when !available
  double distance_mm = 0.0;        // where it was evaluated (range along the ray)
  double typical_px = 0.0;         // median over the imager, worst-direction stdev
  double worst_px = 0.0;           // max over the imager
  double observed_sigma_px = 0.0;  // input noise estimated from the residuals
  // The grid the summary was taken over (grid_nx x grid_ny pixels spanning
  // the imager, row-major, x fastest) and the worst-direction stdev at each:
  // what the uncertainty map draws, px.
  int grid_nx = 0, grid_ny = 0;
  Eigen::Matrix2Xd grid_q_px;
  Eigen::VectorXd grid_worst_px;
};

struct MarkOutlier {
  std::string image;
  int row = 0, col = 0;
  Eigen::Vector2d q_px = Eigen::Vector2d::Zero();  // the observed (corrected) centre
};

struct CalibrationStageSummary {
  bool usable = false;
  std::string brief;  // one line: model, images used/rejected, rms, uncertainty

  // Every image's detection, in input order (q_px as detected, uncorrected).
  std::vector<PlateObservation> detections;
  // The observations of the final solve (bias-corrected), input order.
  std::vector<PlateObservation> observations;
  CalibrationResult result;  // the final solve
  LensModelChoice lens;
  BiasCorrectionSummary bias;
  UncertaintySummary uncertainty;
  std::vector<MarkOutlier> outliers;
  // Residual vectors (project(pose * mark) - observed) of every inlier mark of
  // the final solve, for plots: pixel and residual, px.
  Eigen::Matrix2Xd residual_q_px;
  Eigen::Matrix2Xd residual_px;

  // A chessboard's corners' 1-sigma as estimated from their scatter about
  // the solve (step 3), px; 0 for dots, or when it could not be estimated
  // (then they keep the detector's assumed chessboard_sigma_px).
  double corner_sigma_px = 0.0;
  double detection_seconds = 0.0;
  double lens_choice_seconds = 0.0;
  double total_seconds = 0.0;
};

// Detects the plate in every image, num_threads at a time. Output in input
// order, each named.
std::vector<PlateObservation> DetectPlates(const std::vector<NamedImage>& images,
                                           const BoardSpec& board,
                                           const PlateDetectionOptions& options, int num_threads);

// Steps 2-5 on detections (usable or not): the stage without the pixels.
// `camera` gives the nominal optics (seed) and the forced lens model.
// Throws InputError on bad options; a data failure is a summary with !usable.
CalibrationStageSummary CalibrateFromDetections(const std::vector<PlateObservation>& detections,
                                                const BoardSpec& board, const CameraSpec& camera,
                                                int width_px, int height_px,
                                                const CalibrationStageOptions& options);

// The whole stage. Images must all have one size.
CalibrationStageSummary RunCalibration(const std::vector<NamedImage>& images,
                                       const BoardSpec& board, const CameraSpec& camera,
                                       const CalibrationStageOptions& options);

// The splined model's knot field sized for the DATA, deg: twice the largest
// horizontal angle off the axis of any observed mark (unprojected through
// the working `camera`) times fov_margin. Why not the lens's whole field:
// mrcal's regularisation pulls every spline coefficient that no observation
// constrains towards zero (a bare stereographic lens), so knots beyond the
// plates' reach make the imager's rim the lens WITHOUT its distortion (tens
// of px off on a strongly distorted lens). With the knots inside the
// observed region every coefficient is fitted to marks, and the rim is
// extrapolated by the outermost spline patches, continuing the fitted
// distortion. (Measured on the lens-mismatch preset, seed 1, marks reaching
// 140 px from the imager's edges: against the truth over the whole imager,
// 10x8 knots over 28 deg: 0.30 px rms; the same over 30-39 deg: 0.9-1.8 px.)
int SplinedFieldDeg(const CameraModel& camera, const std::vector<PlateObservation>& observations,
                    double fov_margin);

// The splined stereographic model of order 3 with nx knots across fov_x_deg,
// Ny = Nx * H / W rounded up (at least 4).
std::string SplinedModel(const CameraModel& camera, int nx, int fov_x_deg);

// Residual vectors project(pose * mark) - observed of every inlier mark of a
// solve (unweighted, px), and the observed pixels (2 x num_inliers each).
void ResidualVectors(const CalibrationResult& result, Eigen::Matrix2Xd* q_px,
                     Eigen::Matrix2Xd* residual_px);

// Median distance of the plates' centres from the camera, mm.
double WorkingDistanceMm(const CalibrationResult& result);

// The uncertainty summary of a finished solve at `distance_mm`, or of its
// computed uncertainty projected through `camera`.
UncertaintySummary SummarizeUncertainty(const SolveRecord& record, double distance_mm, int grid_nx,
                                        int grid_ny);
UncertaintySummary SummarizeUncertainty(const CalibrationUncertainty& uncertainty,
                                        const CameraModel& camera, double distance_mm, int grid_nx,
                                        int grid_ny);

}  // namespace omm
