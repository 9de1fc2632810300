// The planar scene of the mosaic stage: a flat part riding on the machine
// table under a fixed camera, seen in tiles taken at several table positions.
//
// Model (../../../shared/docs/design.md, "Planar mosaic"). A point P of the
// part's top surface (part frame: machine X, Y with the table at (0, 0), Z up,
// 0 on the top surface, mm) is at P + T_i when the table is at
// T_i = (x_i, y_i, 0). In the camera frame it is
//
//     p_cam = R (P + T_i) + t,       (R, t) = cam_from_part, "the plane's pose"
//
// and its pixel is q = project(p_cam; intrinsics) through the lens model.
// Unknowns: R (angle-axis r, rad), t (mm), each tile's true table position T_i
// (prior: the commanded position, isotropic sigma per axis), each track's
// P = (X, Y, 0) (2 DOF), and optionally the plates' poses and the intrinsics
// (prior: the calibration's mean and information matrix).
//
// What the data determine. Pixels are invariant to (a) shifting every P by d
// and t by -R d, d in the plane, and (b) any in-plane similarity of the table
// positions carried along by P, R and t (T -> s Rz T, P -> s Rz P,
// R -> R Rz^T, t -> s t: a central projection cannot see a global scale).
// (a) is a true gauge: the part-frame origin, fixed by PlaneGauge below.
// (b) is held by the table prior only: the table's axes fix the rotation
// about Z, the table's scale the metric scale, the mean commanded position the
// translation. So the adjusted table positions are better than commanded in
// every direction except those four, where they stay as good as the prior
// (with 9 tiles: 4 of 18 dimensions). A plate of known pitch is an independent
// scale.
//
// Plates. A group of marks with known relative geometry (the calibration
// plate lying face up on the part): mark m with plate coordinates (u, v)
// (board.h: x right along a row, y down a column, z into the plate) is at
//
//     P = (x, y, h) + s M(theta) (u, v),   M(theta) = [cos  sin; sin  -cos],
//
// M being the rotation by theta composed with the mirror that face-up lying
// implies (plate z = part -Z). Unknowns (x, y, theta) always; the height h of
// the marks above the top surface (plate thickness) if not given; the scale s
// (nominally 1) if PlaneBundleConfig::refine_plate_scale, which turns the plate
// from an extra metric reference into a check of the table's scale.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace omm {

// One observation of a track (a point of the part's top surface) in a tile.
struct TrackObservation {
  int tile = 0;   // index into PlaneBundleInput::commanded_table_pos_mm
  int track = 0;  // 0 .. num_tracks-1
  Eigen::Vector2d q_px = Eigen::Vector2d::Zero();
  // Nominal sigma / this observation's sigma (mrcal's convention): the
  // residual is weight * shape * (q - q_px) / observation_sigma_px; 0 drops it.
  double weight = 1.0;
  // The weight's shape (symmetric, 1 along its stiffest direction): a
  // template match on an edge is located across the edge, far less along it
  // (RegisterTiles). Identity: isotropic.
  Eigen::Matrix2d shape = Eigen::Matrix2d::Identity();
};

// The observation of `track` in `tile` at q_px whose error has covariance
// covariance_px2 (positive definite): weight and shape make its residual
// white, weight = observation_sigma_px / (the smaller sigma), shape =
// C^-1/2 scaled to 1 along the stiffest direction.
TrackObservation WhitenedObservation(int tile, int track, const Eigen::Vector2d& q_px,
                                     const Eigen::Matrix2d& covariance_px2,
                                     double observation_sigma_px);

// A plate of marks with known plate coordinates lying face up on the part.
struct PlateMarks {
  Eigen::Matrix2Xd mark_uv_mm;  // plate coordinates (u, v) of each mark, mm
  // Height of the marks above the part's top surface (plate thickness), mm;
  // estimated when absent.
  std::optional<double> height_mm;
};

struct PlateMarkObservation {
  int tile = 0;
  int plate = 0;  // index into PlaneBundleInput::plates
  int mark = 0;   // column of PlateMarks::mark_uv_mm
  Eigen::Vector2d q_px = Eigen::Vector2d::Zero();
  double weight = 1.0;  // as TrackObservation::weight
};

// Everything measured: observations and priors.
struct PlaneBundleInput {
  std::vector<Eigen::Vector2d> commanded_table_pos_mm;  // per tile (table.csv)
  double table_sigma_mm = 0.01;  // 1-sigma of each commanded coordinate
  // Tiles whose commanded position is not a prior (ascending): the features
  // contradicted it (pipeline/mosaic/table_prior_check.h). Each must be
  // placed by observations.
  std::vector<int> tiles_without_table_prior;
  int num_tracks = 0;
  std::vector<TrackObservation> observations;
  double observation_sigma_px = 0.1;  // 1-sigma of a weight-1 observation, px
  std::vector<PlateMarks> plates;
  std::vector<PlateMarkObservation> plate_observations;
  // Calibration information matrix (inverse covariance) of the intrinsics,
  // N x N; empty if not known. Needed to refine them. Positive definite over
  // the intrinsics not in intrinsics_held; their rows and columns are 0.
  Eigen::MatrixXd intrinsics_information;
  // Intrinsics the calibration held fixed (mrcal's splined models hold the
  // core fx, fy, cx, cy), ascending: they keep their prior mean when the
  // others are refined.
  std::vector<int> intrinsics_held;
  // The prior's mean (the calibrated intrinsics, N); empty: the initial
  // scene's intrinsics. Lets a solve start from refined intrinsics.
  Eigen::VectorXd intrinsics_prior_mean;
};

// How the part-frame origin (gauge (a) above) is fixed.
enum class PlaneGauge {
  // t_x = t_y = 0: the origin is the point of the top surface on the
  // camera's z axis (the ray to mrcal's (cx, cy)) with the table at (0, 0).
  kOriginOnOpticalAxis,
  // The track PlaneBundleConfig::gauge_track keeps its initial P.
  kFixedTrack,
};

// What is optimised (the "what" of the solve; PlaneBundleOptions is the "how").
struct PlaneBundleConfig {
  bool refine_plane_pose = true;       // false: R, t held at their initial values
  bool refine_table_positions = true;  // false: T_i held at their initial values
  bool refine_intrinsics = false;      // needs PlaneBundleInput::intrinsics_information
  bool refine_plate_scale = false;     // true: each plate's s is estimated
  PlaneGauge gauge = PlaneGauge::kOriginOnOpticalAxis;
  int gauge_track = -1;                // kFixedTrack only: a track index
  bool compute_covariance = true;      // PlaneScene::covariance
  std::vector<int> covariance_tracks;  // tracks whose 2 x 2 covariance is wanted

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

enum class RobustLoss { kTrivial, kHuber, kCauchy };
enum class LinearSolver { kSparseSchur, kDenseSchur };

// How the solve runs.
struct PlaneBundleOptions {
  RobustLoss loss = RobustLoss::kHuber;
  // Residual norm where the loss leaves the quadratic, px (of a weight-1
  // observation; the loss acts on weight * |q - q_px|, of every observation
  // but the first of a two-observation track: adapters/ceres/plane_bundle.h).
  double loss_scale_px = 0.5;
  // Points are eliminated by the Schur complement either way. Dense holds the
  // reduced system (6 + 2 per tile + 5 per plate + the refined intrinsics: a
  // few hundred) as one matrix, whose cells the elimination updates without
  // the sparse one's lookups and locks (lens-mismatch seed 284's final
  // adjustment, 164 intrinsics: 0.29 -> 0.25 s); sparse is for grids of
  // hundreds of tiles.
  LinearSolver linear_solver = LinearSolver::kDenseSchur;
  int max_iterations = 100;            // Levenberg-Marquardt iterations
  // Levenberg-Marquardt's initial trust region radius. The seeded or
  // warm-started scene is close and the problem nearly linear: from 1e8 the
  // first steps are Gauss-Newton's (the demo's solves: 2 iterations; Ceres'
  // 1e4 damped them to 5-7). A step that fails shrinks the region as before.
  double initial_trust_region_radius = 1e8;
  double function_tolerance = 1e-12;   // relative cost change to stop
  double gradient_tolerance = 1e-12;   // max-norm of the scaled gradient to stop
  double parameter_tolerance = 1e-10;  // relative step size to stop
  int num_threads = 2;                 // for the covariance's Jacobian (the solve uses one)
  // Largest acceptable inlier RMS reprojection error for a usable result, px.
  double max_usable_rms_px = 1.0;
  // Refined intrinsics of a lens with blocks (LensProjection::
  // IntrinsicsBlockStarts, a splined model's knots): each observation takes
  // the blocks its projection depends on within this distance of its initial
  // pixel, px. (The final adjustment's pixels moved < 0.2 px on
  // lens-mismatch.) One that needs more makes the solve run again with the
  // intrinsics in one block (PlaneBundleSummary::intrinsics_block_exits).
  double intrinsics_block_margin_px = 20.0;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// A plate's pose on the part (see the header comment).
struct PlatePose {
  double x_mm = 0.0;
  double y_mm = 0.0;
  double theta_rad = 0.0;
  double height_mm = 0.0;
  double scale = 1.0;
};

// Number of parameters of the joint covariance's vector (PlaneScene).
inline int PlaneSceneCovarianceSize(int num_tiles, int num_plates, int num_intrinsics) {
  return 6 + 2 * num_tiles + 5 * num_plates + num_intrinsics;
}

// The adjusted scene. Holds the initial values going into a solve and the
// adjusted ones coming out.
struct PlaneScene {
  Eigen::Vector3d cam_from_part_r = Eigen::Vector3d::Zero();     // angle-axis, rad
  Eigen::Vector3d cam_from_part_t_mm = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector2d> table_pos_mm;  // true table position per tile
  Eigen::Matrix2Xd track_xy_mm;               // P of each track (Z = 0)
  std::vector<PlatePose> plates;
  Eigen::VectorXd intrinsics;  // held unless PlaneBundleConfig::refine_intrinsics

  // After a solve: model minus observed pixel of each observation
  // (unweighted, px), in input order, weight-0 ones included (to spot
  // outliers); NaN where the lens cannot project.
  Eigen::Matrix2Xd residual_px;
  Eigen::Matrix2Xd plate_residual_px;

  // Joint covariance of the vector
  //   [r (3), t (3), T_0 (2), ..., T_{n-1} (2),
  //    per plate (x, y, theta, h, s), intrinsics (N)]
  // (PlaneSceneCovarianceSize): a parameter held constant has zero rows and
  // columns, t_x, t_y among them under kOriginOnOpticalAxis; so is the whole
  // intrinsics block unless refined. Empty if not computed. Units: rad, mm,
  // and the intrinsics' own.
  Eigen::MatrixXd covariance;
  // 2 x 2 covariance of P for each PlaneBundleConfig::covariance_tracks entry.
  std::vector<Eigen::Matrix2d> track_covariance_mm2;
};

// What a solve did.
struct PlaneBundleSummary {
  bool usable = false;
  std::string brief;  // one line: what happened, RMS, why unusable

  int num_observations = 0;  // used (weight > 0), tracks and plate marks
  int num_residuals = 0;
  int num_parameters = 0;    // free (tangent-space) parameters
  int iterations = 0;
  double initial_rms_px = 0.0;  // RMS of |q - q_px| over used observations
  double final_rms_px = 0.0;
  // Used observations whose final |q - q_px| exceeds 3 loss_scale_px (what
  // the robust loss discounted), and the RMS over the others: the usability
  // test reads this one, so a few gross mismatches do not condemn a solve.
  int num_outliers = 0;
  double inlier_rms_px = 0.0;
  // sqrt(chi^2 / degrees of freedom) of the whole cost: ~1 when the declared
  // sigmas are right; the covariance is NOT rescaled by it.
  double unit_weight_sigma = 0.0;
  std::vector<Eigen::Vector2d> table_adjustment_mm;  // adjusted minus commanded
  // Tiles with no used observation: held by their prior alone.
  std::vector<int> tiles_without_observations;
  double plane_tilt_deg = 0.0;  // angle between the camera's z axis and -Z
  bool covariance_ok = false;
  // Evaluations that needed intrinsics outside an observation's blocks
  // (PlaneBundleOptions::intrinsics_block_margin_px); if any, the solve was
  // run again from where it stopped with the intrinsics in one block.
  int intrinsics_block_exits = 0;
  double solve_seconds = 0.0;
  double covariance_seconds = 0.0;
};

// The intrinsics 0..num_intrinsics-1 not in `held` (ascending), in order.
std::vector<int> FreeIntrinsics(int num_intrinsics, const std::vector<int>& held);

// Empty if `input` fits `config` and `num_intrinsics`, else what is wrong.
std::string CheckPlaneBundleInput(const PlaneBundleInput& input,
                                  const PlaneBundleConfig& config, int num_intrinsics);

// The rotation matrix of an angle-axis vector (rad).
Eigen::Matrix3d RotationFromAngleAxis(const Eigen::Vector3d& r);

// Index of the intrinsics' first entry in PlaneScene::covariance's vector.
inline int PlaneSceneCovarianceIntrinsicsIndex(int num_tiles, int num_plates) {
  return PlaneSceneCovarianceSize(num_tiles, num_plates, 0);
}

// Index of plate `plate`'s first entry (x; then y, theta, h, s) in
// PlaneScene::covariance's vector.
inline int PlaneSceneCovariancePlateIndex(int num_tiles, int plate) {
  return PlaneSceneCovarianceSize(num_tiles, plate, 0);
}

// Angle between the camera's z axis and the part's -Z (the plane's tilt), deg.
double PlaneTiltDeg(const Eigen::Vector3d& cam_from_part_r);

}  // namespace omm
