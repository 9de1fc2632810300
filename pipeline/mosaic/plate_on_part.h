// The mosaic's final adjustment: the calibration plate lying on the part as an
// independent metric scale, and the calibration's intrinsics covariance as a
// prior, so that the scene's covariance is joint over the plane pose, the
// table positions, the plate and the intrinsics.
//
// Why. The table prior alone fixes the mosaic's scale and its rotation about
// Z (pipeline/core/plane_scene.h, invariance (b)): with n tiles of sigma s_T
// per axis, the scale's sigma is ~ s_T / sqrt(sum |T_i - mean|^2), ~50 ppm for
// the demo's 9 tiles at 0.02 mm, i.e. ~0.02 mm on a 430 mm distance. A plate
// of known pitch seen in the tiles is a metric reference to a few ppm.
//
// Finding the plate (FindPlateOnPart). DetectPlate (adapters/opencv) finds the
// whole plate in a tile and identifies its marks. Its pose on the part is the
// seed's Procrustes fit (plane_seed.h) of those marks; through the registered
// scene every mark is then predicted in every other tile, and marks that lie
// wholly inside a tile where the plate is cut by the border are located there:
// a dot by the centroid of the dark pixels around the prediction (a few
// passes), then the sub-pixel ellipse fit (pipeline/core/subpixel_edges.h); a
// chessboard's corner by cv::cornerSubPix from the prediction, with the
// detector's window (RefineChessboardCorners). Every dot's centre is corrected
// for the perspective bias of a circle's image (pipeline/calibration/
// perspective_bias.h) with the tile's plate pose.
//
// Height of the marks above the top surface (the plate's thickness). Given
// (PlateOnPartOptions::height_mm, project.yaml mosaic.plate_height_mm), it is
// held. Seen in >= 2 tiles, the plate moves by T / (d - h) in the image while
// the surface moves by T / d (d the camera's distance): the difference
// determines h, which is then estimated (its sigma is in the covariance), and
// the plate's own motion in pitch units gives the scale whatever h is. Seen
// in one tile only, its image size depends on (d - h) / s (s the table's
// scale): height and scale are confounded, and a plate of unknown thickness
// (3 mm at 390 mm: 0.8 %) must not set the scale. Its height is then taken as
// 0 and it only checks the table's scale (scale_reference = false): s - 1
// holds h / (d - h) besides the table's own scale error.
//
// Scale check. The final solve holds the plate's scale at 1 (its pitch is the
// metric reference); the scale s released measures the table's scale
// relative to the plate: s - 1 and its sigma (both in ppm), to first order
// from the final solve's covariance (ReleasePlateScale, adapters/ceres), so
// it needs FinalAdjustmentOptions::compute_covariance. Without
// scale_reference the final solve has s free already.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "adapters/opencv/plate_detector.h"
#include "pipeline/core/board.h"
#include "pipeline/core/camera.h"
#include "pipeline/core/image.h"
#include "pipeline/core/plane_scene.h"

namespace omm {

struct PlateOnPartOptions {
  PlateDetectionOptions detection;   // DetectPlate, whole plates
  MarkRefinementOptions refinement;  // marks predicted in the other tiles
  // Height of the marks above the part's top surface, mm; unset: estimated if
  // the plate is seen in >= 2 tiles, else unknown (the plate only checks).
  std::optional<double> height_mm;
  // A predicted mark is searched if its ellipse plus this margin lies inside
  // the image, px.
  double border_margin_px = 6.0;
  // A located mark further than this from its prediction is not the mark, px.
  double max_offset_px = 10.0;
  // Floor of a mark centre's 1-sigma: the fit's own sigma leaves out the
  // model's systematic misfit, px.
  double min_mark_sigma_px = 0.01;
  int num_threads = 2;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// The plate as the bundle adjustment takes it (one plate, index 0).
struct PlateOnPart {
  bool found = false;
  std::string brief;  // one line: where, how many marks, height source
  PlateMarks marks;   // the board's marks; height_mm as PlateOnPartOptions says
  std::vector<PlateMarkObservation> observations;
  PlatePose initial_pose;           // seed of the plate's pose on the part
  std::vector<int> whole_in_tiles;  // DetectPlate found the whole plate
  std::vector<int> seen_in_tiles;   // >= 1 mark located (whole tiles included)
  std::vector<int> marks_per_tile;  // per tile
  // The plate's pitch sets the mosaic's scale; false when its height is
  // unknown and confounded with the scale (seen in one tile, no height given).
  bool scale_reference = false;
  // A chessboard's corners: cv::cornerSubPix gives them no sigma, so they
  // carry the detector's assumed chessboard_sigma_px until the final
  // adjustment weighs them by their scatter (AdjustWithPlateAndPrior).
  bool sigma_assumed = false;
  std::string height_source;            // "given", "estimated (seen in N tiles)", "unknown: ..."
  double max_bias_correction_px = 0.0;  // largest perspective-bias shift applied
  double seconds = 0.0;
};

// The spacing (px) of `board`'s marks lying on the part, as the camera sees
// them where its optical axis meets the part plane (f / distance): what
// DetectPlate is told to expect in the tiles (expected_pitch_px). 0 if the
// axis does not meet the plane in front of the camera.
double PlatePitchOnPartPx(const BoardSpec& board, const CameraModel& camera,
                          const PlaneScene& scene);

// The orders in which DetectPlate may return one board's marks: the board's
// turns that map its mark grid onto itself (the identity; a half turn unless
// the board has an orientation mark, as the caltab's triangle; quarter turns
// too for a square grid). Mirror images are not among them: DetectPlate
// returns proper orders. Each order o lists, for every board mark m, the
// detected index o[m] that is mark m under that turn.
std::vector<std::vector<int>> BoardMarkOrders(const BoardSpec& board);

// `observation`, the whole plate found in tile `tile`, in the order of
// `reference`, the same plate found in tile `reference_tile`: of
// BoardMarkOrders, the one under which its marks fall where the reference's,
// carried through the part plane of `scene` into tile `tile`, predict them
// (the plate's height neglected: it shifts all marks alike, by a few px,
// where a turn moves them by up to the plate's size). Two tiles see the
// plate turned alike, but a symmetric board's detector may still number
// it from either end in each. Returns the order applied (0: the identity,
// also when no mark can be carried).
int AlignMarkOrder(const BoardSpec& board, const CameraModel& camera, const PlaneScene& scene,
                   int reference_tile, const PlateObservation& reference, int tile,
                   PlateObservation* observation);

// Finds `board` lying on the part in `tiles` (gray, the camera's size), using
// the registered scene (RegisterTiles' input and adjusted scene) to predict
// marks where the plate is cut. found == false (brief says why) if no tile
// sees the whole plate. Throws InputError for invalid options.
PlateOnPart FindPlateOnPart(const std::vector<ImageF>& tiles, const BoardSpec& board,
                            const CameraModel& camera, const PlaneBundleInput& registered_input,
                            const PlaneScene& registered_scene, const PlateOnPartOptions& options);

// The calibration's information on the intrinsics: the inverse of their
// covariance (CalibrationUncertainty::IntrinsicsCovariance, N x N) over the
// parameters the calibration refined; those it held (a zero row and column:
// mrcal's splined models hold the core) are listed in `held` and get zero
// rows and columns. Empty information (with why_held) when none can be
// refined: every parameter held, or a covariance that is not positive
// semi-definite. Combinations the calibration determines beyond a 1e6
// conditioning of the correlation matrix (a rational model's near
// redundancy) get that much information only: a weaker prior, never a
// stronger one (the .cc says why).
//
// The region where the calibration saw marks (measured_region_px, set by the
// caller from the solve record, for a splined lens). Outside it a spline is
// extrapolated by mrcal's regularisation, and the covariance holds only the
// noise, not that extrapolation's error. Measured on lens-mismatch with the
// plate on the part, seed 203: 52-79 px left of the marks the spline is
// 0.19-0.73 px off at a stated 0.01-0.14 px (1.2 px at 144 px); the final
// adjustment's refinement leaves 0.05-0.15 px there, and the 10 plate marks
// in that margin alone moved the plate's height by 20 um (10 sigma), so the
// mosaic's scale by -55 ppm at a stated 7. The final adjustment widens the
// sigma of plate marks outside the region by that error
// (FinalAdjustmentOptions::extrapolation_px_per_px).
struct IntrinsicsPrior {
  Eigen::MatrixXd information;  // N x N, positive definite over the free ones, or empty
  std::vector<int> held;        // ascending
  std::string why_held;         // set when information is empty
  // Convex polygon, counter-clockwise, px (2 x K); empty: unknown, the lens
  // is trusted everywhere.
  Eigen::Matrix2Xd measured_region_px;
};
IntrinsicsPrior IntrinsicsPriorFromCovariance(const Eigen::MatrixXd& covariance);

// Convex hull of `points_px` (2 x N), counter-clockwise, without collinear
// vertices; empty if the points span no area.
Eigen::Matrix2Xd ConvexHull(const Eigen::Matrix2Xd& points_px);

// Whether q lies inside (or on) a counter-clockwise convex polygon.
bool InsideConvexPolygon(const Eigen::Matrix2Xd& polygon_px, const Eigen::Vector2d& q_px);

// Distance from q to a counter-clockwise convex polygon (0 inside), px.
double DistanceOutsideConvexPolygon(const Eigen::Matrix2Xd& polygon_px,
                                    const Eigen::Vector2d& q_px);

struct FinalAdjustmentOptions {
  PlaneBundleOptions bundle;
  bool compute_covariance = true;  // the joint covariance (PlaneScene::covariance)
  // Plate observations whose residual exceeds this many of their sigmas are
  // dropped and the scene solved again (a mark misread, a speck on the plate).
  double plate_outlier_sigmas = 5.0;
  // Observations that scatter more than declared (the solve's unit-weight
  // sigma above 1: weak texture's matches) widen the covariance: their
  // sigma is scaled by it and the scene solved again; the priors (table,
  // intrinsics) keep their declared sigmas. Never narrowed.
  bool rescale_observation_sigma = true;
  // The lens's error outside IntrinsicsPrior::measured_region_px, per px of
  // distance from it: a plate mark d px outside has sigma
  // hypot(its own, extrapolation_px_per_px * d). The upper end of what
  // lens-mismatch-203 showed (0.004-0.009 px/px, header above). Marks just
  // outside keep most of their weight, marks 100 px out are worth ~1 %.
  double extrapolation_px_per_px = 0.01;
  // Floors of the sigma a plate's marks get from their scatter, px: a
  // chessboard's corners (PlateOnPart::sigma_assumed), whose scatter leaves
  // out the model's systematic misfit, and dots, whose ellipse fits say
  // ~0.002 px on clean renders (their errors: 0.0032-0.0045 px per axis).
  double min_corner_sigma_px = 0.01;
  double min_dot_sigma_px = 0.002;

  std::string Check() const;
};

// The table's scale relative to the plate (s free).
struct PlateScaleCheck {
  bool ok = false;
  double scale_minus_1_ppm = 0.0;  // s - 1: > 0 when the table reads more than it moved
  double sigma_ppm = 0.0;
};

struct FinalAdjustment {
  PlaneScene scene;        // joint covariance over [r, t, T_i, plate, intrinsics]
  PlaneBundleInput input;  // the registration's, plus the plate and the prior
  PlaneBundleSummary summary;
  bool intrinsics_refined = false;
  // Set when the prior would have refined the intrinsics but the
  // adjustment held them (the refined lens would not map the whole image).
  std::string intrinsics_held_why;
  // 1-sigma of the mosaic's scale from the covariance: of the scale of the
  // least-squares similarity fit of the adjusted to the commanded table
  // positions, ppm (0 if no covariance).
  double scale_sigma_ppm = 0.0;
  // Plate (if found): residual RMS of its used marks inside the measured
  // region (all if there is none), px; observations dropped as outliers;
  // height and its sigma (0 if held), mm.
  double plate_rms_px = 0.0;
  int plate_outliers = 0;
  double plate_height_mm = 0.0;
  double plate_height_sigma_mm = 0.0;
  // Plate observations outside the calibration's measured region
  // (IntrinsicsPrior::measured_region_px), their sigma widened.
  int plate_outside_region = 0;
  // The sigma a plate's marks were weighed by, from their scatter about the
  // solve, px; 0 when none could be estimated (the marks kept their own).
  double mark_sigma_px = 0.0;
  PlateScaleCheck scale_check;
  // Set when a found plate was left out (its solve unusable, or most of its
  // marks outliers: not the plate it seemed): the scene is the one without it.
  std::string plate_not_used;
  // The factor the observations' sigma was scaled by (1: as declared).
  double observation_sigma_scale = 1.0;
  double seconds = 0.0;
};

// Adjusts the registered scene once more with the plate (if plate.found) and
// the intrinsics prior (if prior.information is set), warm-started from
// `registered_scene`, whose intrinsics must be the calibration's. A plate is
// solved with its marks' own sigma first (dots: their ellipse fits', floored
// by PlateOnPartOptions::min_mark_sigma_px; corners: assumed); the marks are
// then weighed by their scatter about that solve (dof-corrected, floored by
// min_corner_sigma_px or min_dot_sigma_px) and the scene solved again, as
// the calibration stage weighs them. Refined intrinsics whose lens maps no
// ray to some point of the tiles' sampled border
// (FirstUnmappedTileBorderPixel) are not kept: the scene is solved again with
// the calibration's held (intrinsics_held_why). Data failures come back in
// summary (usable, brief); throws InputError for invalid options or sizes.
FinalAdjustment AdjustWithPlateAndPrior(const CameraModel& camera,
                                        const PlaneBundleInput& registered_input,
                                        const PlaneScene& registered_scene,
                                        const PlateOnPart& plate, const IntrinsicsPrior& prior,
                                        const FinalAdjustmentOptions& options);

// sigma of the similarity scale of `table_pos` (the scene's adjusted table
// positions) about the commanded ones, from the scene covariance's table
// block; ppm.
double TableScaleSigmaPpm(const std::vector<Eigen::Vector2d>& commanded_table_pos_mm,
                          const Eigen::MatrixXd& scene_covariance);

}  // namespace omm
