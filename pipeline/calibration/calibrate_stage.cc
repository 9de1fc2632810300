#include "pipeline/calibration/calibrate_stage.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <optional>
#include <sstream>
#include <string>

#include <fmt/format.h>

#include "adapters/mrcal/calibrate.h"
#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/uncertainty.h"
#include "pipeline/calibration/perspective_bias.h"
#include "pipeline/core/error.h"
#include "pipeline/core/fixed_point.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/core/statistics.h"
#include "pipeline/core/timing.h"

namespace omm {
namespace {

// The working model, and the smallest the lens choice takes (step 4).
constexpr const char* kWorkingLensModel = "LENSMODEL_OPENCV8";

using Clock = std::chrono::steady_clock;

CalibrationOptions SolveOptions(const CameraSpec& camera, int width_px, int height_px,
                                const std::string& lens_model,
                                const CalibrationStageOptions& options) {
  CalibrationOptions solve;
  solve.lens_model = lens_model;
  solve.focal_length_mm = camera.focal_length_mm;
  solve.pixel_pitch_um = camera.pixel_pitch_um;
  solve.width_px = width_px;
  solve.height_px = height_px;
  solve.optimize_calobject_warp = options.optimize_calobject_warp;
  solve.min_images = options.min_images;
  return solve;
}

// Each detection's perspective-bias corrections from the solve's camera and
// poses, num_threads images at a time (0.1 G instructions a round on the
// demo, between two solves that run on one core): zero for images the solve
// did not use, marks not observed, and images whose corrections could not be
// computed.
std::vector<Eigen::Matrix2Xd> BiasCorrections(const std::vector<PlateObservation>& detections,
                                              const BoardSpec& board,
                                              const CalibrationResult& solve, int num_threads) {
  std::map<std::string, Eigen::Isometry3d> pose_by_image;
  for (size_t i = 0; i < solve.record.images.size(); ++i) {
    pose_by_image[solve.record.images[i].image] = solve.cam_from_plate[i];
  }
  std::vector<Eigen::Matrix2Xd> delta(detections.size(),
                                      Eigen::Matrix2Xd::Zero(2, board.rows * board.cols));
  ParallelFor(static_cast<int>(detections.size()), num_threads, [&](int i) {
    const auto pose = pose_by_image.find(detections[i].image);
    if (!detections[i].usable || pose == pose_by_image.end()) return;
    Eigen::Matrix2Xd d;
    if (!PerspectiveBiasCorrections(board, solve.camera, pose->second, &d)) return;
    for (int m = 0; m < d.cols(); ++m) {
      if (detections[i].weight(m) > 0) delta[i].col(m) = d.col(m);
    }
  });
  return delta;
}

// The detections moved by their corrections (the bias removed).
std::vector<PlateObservation> WithCorrections(const std::vector<PlateObservation>& detections,
                                              const std::vector<Eigen::Matrix2Xd>& corrections) {
  std::vector<PlateObservation> corrected = detections;
  for (size_t i = 0; i < detections.size(); ++i) corrected[i].q_px += corrections[i];
  return corrected;
}

// Largest |before - after| over the marks that have a correction after (an
// image whose corrections could not be computed has none; it does not keep
// the rounds going).
double LargestChange(const std::vector<Eigen::Matrix2Xd>& before,
                     const std::vector<Eigen::Matrix2Xd>& after) {
  double change = 0.0;
  for (size_t i = 0; i < after.size(); ++i) {
    for (int m = 0; m < after[i].cols(); ++m) {
      if (after[i].col(m).isZero() || before[i].cols() != after[i].cols()) continue;
      change = std::max(change, (after[i].col(m) - before[i].col(m)).norm());
    }
  }
  return change;
}

// The rms and max size of the corrections over the marks that have one.
void SizeOfCorrections(const std::vector<Eigen::Matrix2Xd>& corrections,
                       BiasCorrectionSummary* bias) {
  double sum_sq = 0.0, max_px = 0.0;
  int count = 0;
  for (const Eigen::Matrix2Xd& image : corrections) {
    for (int m = 0; m < image.cols(); ++m) {
      const double size = image.col(m).norm();
      if (size == 0.0) continue;
      sum_sq += size * size;
      max_px = std::max(max_px, size);
      ++count;
    }
  }
  bias->rms_px = count > 0 ? std::sqrt(sum_sq / count) : 0.0;
  bias->max_px = max_px;
}

// All images' corrections in one vector, and back.
Eigen::VectorXd Flatten(const std::vector<Eigen::Matrix2Xd>& corrections) {
  Eigen::Index size = 0;
  for (const Eigen::Matrix2Xd& c : corrections) size += c.size();
  Eigen::VectorXd v(size);
  Eigen::Index at = 0;
  for (const Eigen::Matrix2Xd& c : corrections) {
    v.segment(at, c.size()) = c.reshaped();
    at += c.size();
  }
  return v;
}
std::vector<Eigen::Matrix2Xd> Unflatten(const Eigen::VectorXd& v,
                                        const std::vector<Eigen::Matrix2Xd>& shape) {
  std::vector<Eigen::Matrix2Xd> corrections = shape;
  Eigen::Index at = 0;
  for (Eigen::Matrix2Xd& c : corrections) {
    c = v.segment(at, c.size()).reshaped(2, c.cols());
    at += c.size();
  }
  return corrections;
}

// From *result, solved on *corrected (the detections plus *corrections): the
// corrections its camera and poses give; while they differ from those it was
// solved on by bias_settle_px or more, re-solve and repeat, up to
// max_bias_rounds re-solves. A settled solution needs no last solve to
// confirm it. A failed re-solve keeps the last consistent (observations,
// solve) triple. The first re-solve is on the corrections given; the later
// ones on AndersonStep's from the last two rounds: a splined model bends to
// each round's corrections, and their change shrank by only ~0.57 a round
// (lens-mismatch seed 341: 6 re-solves of the spline, now 3). A mark whose
// image gave no corrections gets none (as a plain round would give it), and
// a round whose change grew takes the plain step next.
void SettleBiasCorrection(const std::vector<PlateObservation>& detections, const BoardSpec& board,
                          const CalibrationOptions& solve_options,
                          const CalibrationStageOptions& options, CalibrationResult* result,
                          std::vector<PlateObservation>* corrected,
                          std::vector<Eigen::Matrix2Xd>* corrections, BiasCorrectionSummary* bias) {
  // The last re-solve's round: the corrections solved on, those it gave, and
  // their largest change (none before the first re-solve).
  std::optional<Eigen::VectorXd> previous_x, previous_g;
  double previous_change = std::numeric_limits<double>::infinity();
  for (int round = 0;; ++round) {
    std::vector<Eigen::Matrix2Xd> delta =
        BiasCorrections(detections, board, *result, options.num_threads);
    bias->last_change_px = LargestChange(*corrections, delta);
    if (bias->last_change_px < options.bias_settle_px || round == options.max_bias_rounds) break;
    const Eigen::VectorXd x = Flatten(*corrections), g = Flatten(delta);
    std::vector<Eigen::Matrix2Xd> next_x = delta;
    if (previous_x && bias->last_change_px < previous_change) {
      next_x = Unflatten(AndersonStep(*previous_x, *previous_g, x, g), delta);
      for (size_t i = 0; i < delta.size(); ++i)
        if (delta[i].isZero()) next_x[i].setZero();
    }
    std::vector<PlateObservation> round_corrected = WithCorrections(detections, next_x);
    CalibrationResult next = RefineCalibration(*result, round_corrected, solve_options);
    if (!next.usable) break;
    ++bias->rounds;
    previous_x = x, previous_g = g;
    previous_change = bias->last_change_px;
    *corrected = std::move(round_corrected);
    *corrections = std::move(next_x);
    *result = std::move(next);
  }
  SizeOfCorrections(*corrections, bias);
}

// The states of a solve: the lens model's parameters, each image's pose and
// the board's warp when it is solved for.
int NumStates(const CalibrationResult& result) {
  return LensModelNumParams(result.camera.lens_model) +
         6 * static_cast<int>(result.record.images.size()) +
         (result.record.problem.optimize_calobject_warp ? 2 : 0);
}

// The chessboard corners' 1-sigma, px: their scatter about `result`,
// corrected for its degrees of freedom. 0 if it has none.
double CornerScatterPx(const CalibrationResult& result) {
  Eigen::Matrix2Xd q_px, residual_px;
  ResidualVectors(result, &q_px, &residual_px);
  const Eigen::Index dof = 2 * residual_px.cols() - NumStates(result);
  return dof > 0 ? std::sqrt(residual_px.squaredNorm() / static_cast<double>(dof)) : 0.0;
}

// A chessboard's corners (`detections`, weighed by the detector's assumed
// chessboard_sigma_px) weighed by their scatter about *result instead, and
// *result solved again on them from its solution, with *corrected the
// observations it was solved on. Returns the sigma used; 0 (and *result,
// *corrected kept) when the solve has no degrees of freedom left or the
// re-solve fails.
double WeighCornersByScatter(const std::vector<PlateObservation>& detections,
                             const CalibrationOptions& solve_options,
                             const PlateDetectionOptions& detection, CalibrationResult* result,
                             std::vector<PlateObservation>* corrected) {
  const double sigma_px = CornerScatterPx(*result);
  if (!(sigma_px > 0.0)) return 0.0;
  std::vector<PlateObservation> weighed = detections;
  for (PlateObservation& observation : weighed) {
    if (!observation.usable) continue;
    for (Eigen::Index m = 0; m < observation.weight.size(); ++m) {
      if (!(observation.weight(m) > 0.0)) continue;  // not observed
      observation.sigma_px(m) = sigma_px;
      observation.weight(m) = MarkWeight(sigma_px, detection);
    }
  }
  CalibrationResult reweighed = RefineCalibration(*result, weighed, solve_options);
  if (!reweighed.usable) return 0.0;
  *corrected = std::move(weighed);
  *result = std::move(reweighed);
  return sigma_px;
}

// The observations' model settled on *result's camera and poses, *result
// solved again on them: a dot board's perspective-bias corrections
// (SettleBiasCorrection), a chessboard's corners weighed by their scatter
// (WeighCornersByScatter; *corner_sigma_px: the sigma they were given, left
// as it was when none could be).
void SettleObservations(const std::vector<PlateObservation>& detections, const BoardSpec& board,
                        const CalibrationOptions& solve_options,
                        const CalibrationStageOptions& options, CalibrationResult* result,
                        std::vector<PlateObservation>* corrected,
                        std::vector<Eigen::Matrix2Xd>* corrections, BiasCorrectionSummary* bias,
                        double* corner_sigma_px) {
  if (board.type == BoardType::kChessboard) {
    const double sigma_px =
        WeighCornersByScatter(detections, solve_options, options.detection, result, corrected);
    if (sigma_px > 0.0) *corner_sigma_px = sigma_px;
    return;
  }
  SettleBiasCorrection(detections, board, solve_options, options, result, corrected, corrections,
                       bias);
}

// Solve, then settle the observations' model (SettleObservations).
CalibrationResult SolveAndSettle(const std::vector<PlateObservation>& detections,
                                 const BoardSpec& board, const CalibrationOptions& solve_options,
                                 const CalibrationStageOptions& options,
                                 std::vector<PlateObservation>* corrected,
                                 std::vector<Eigen::Matrix2Xd>* corrections,
                                 BiasCorrectionSummary* bias, double* corner_sigma_px) {
  CalibrationResult result = CalibrateCamera(board, detections, solve_options);
  *corrected = detections;
  corrections->assign(detections.size(), Eigen::Matrix2Xd::Zero(2, board.rows * board.cols));
  if (!result.usable) return result;
  SettleObservations(detections, board, solve_options, options, &result, corrected, corrections,
                     bias, corner_sigma_px);
  return result;
}

std::vector<MarkOutlier> ListOutliers(const CalibrationResult& result, const BoardSpec& board) {
  std::vector<MarkOutlier> outliers;
  for (const SolveImage& image : result.record.images) {
    for (int m = 0; m < static_cast<int>(image.outlier.size()); ++m) {
      // Unobserved marks (weight 0) are flagged too; they are not outliers.
      if (!image.outlier[m] || image.weight(m) <= 0) continue;
      outliers.push_back({image.image, m / board.cols, m % board.cols, image.q_px.col(m)});
    }
  }
  return outliers;
}

LensCandidate ScoreCandidate(const std::string& lens_model, const CalibrationResult& result) {
  LensCandidate c;
  c.lens_model = lens_model;
  c.num_params = LensModelNumParams(lens_model);
  c.usable = result.usable;
  if (!result.usable) return c;
  c.rms_px = result.rms_px;
  c.num_measurements = 2 * result.num_observations_used;
  c.num_states = NumStates(result);
  const int dof = c.num_measurements - c.num_states;
  c.usable = dof > 0;
  c.sigma_px =
      dof > 0 ? result.rms_px * std::sqrt(static_cast<double>(c.num_measurements) / dof) : 0.0;
  return c;
}

// The F-test of a bigger model against a smaller one: with SSR = M rms^2 and
// P states, F = ((SSR_a - SSR_b) / (P_b - P_a)) / (SSR_b / (M - P_b)) is
// ~ chi2(P_b - P_a) / (P_b - P_a) when the extra parameters only fit noise.
// Significant above that distribution's upper point at z (Wilson-Hilferty).
bool ResidualsDropSignificantly(const LensCandidate& a, const LensCandidate& b, double z) {
  const double extra = b.num_states - a.num_states;
  if (extra <= 0 || b.num_measurements <= b.num_states) return b.sigma_px < a.sigma_px;
  const double ssr_a = a.rms_px * a.rms_px * a.num_measurements;
  const double ssr_b = b.rms_px * b.rms_px * b.num_measurements;
  const double f = ((ssr_a - ssr_b) / extra) / (ssr_b / (b.num_measurements - b.num_states));
  const double h = 2.0 / (9.0 * extra);
  const double critical = std::pow(1.0 - h + z * std::sqrt(h), 3);
  return f > critical;
}

// Whether the misfit the bigger model b removes, sqrt(sigma_a^2 - sigma_b^2),
// is at least `fraction` of the noise it leaves, sigma_b.
bool ResidualsDropMaterially(const LensCandidate& a, const LensCandidate& b, double fraction) {
  const double removed2 = a.sigma_px * a.sigma_px - b.sigma_px * b.sigma_px;
  return removed2 > 0 && removed2 >= fraction * fraction * b.sigma_px * b.sigma_px;
}

// The image's outermost pixel centres, about every step_px along each side.
Eigen::Matrix2Xd ImageBorderPx(int width_px, int height_px, double step_px) {
  const double w = width_px - 1.0, h = height_px - 1.0;
  const int nx = std::max(1, static_cast<int>(std::ceil(w / step_px)));
  const int ny = std::max(1, static_cast<int>(std::ceil(h / step_px)));
  Eigen::Matrix2Xd border(2, 2 * (nx + ny));
  int k = 0;
  for (int i = 0; i < nx; ++i) {  // top left to right, bottom right to left
    border.col(k++) << w * i / nx, 0.0;
    border.col(k++) << w * (nx - i) / nx, h;
  }
  for (int i = 0; i < ny; ++i) {  // right top to bottom, left bottom to top
    border.col(k++) << w, h * i / ny;
    border.col(k++) << 0.0, h * (ny - i) / ny;
  }
  return border;
}

// Why `camera` cannot serve the tiles, which use the whole image: a border
// pixel the lens maps to no ray (a splined model past the knots the marks
// constrained, found only in the mosaic stage otherwise, with no hint of the
// cause); empty if every border pixel maps. The lens choice widens the
// spline's knot field a little first (splined_max_widening), not to the
// image's corners: the knots no mark reaches are regularised to the
// undistorted lens (SplinedFieldDeg), a bias the covariance does not hold.
std::string UnmappedImageBorder(const CameraModel& camera,
                                const std::vector<PlateObservation>& observations) {
  constexpr double kStepPx = 8.0, kTolerancePx = 0.01;
  const std::optional<Eigen::Vector2d> unmapped = FirstUnmappedPixel(
      camera, ImageBorderPx(camera.width_px, camera.height_px, kStepPx), kTolerancePx);
  if (!unmapped) return "";
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(INFINITY), hi = -lo;
  for (const PlateObservation& o : observations) {
    if (!o.usable || o.q_px.cols() == 0) continue;
    lo = lo.cwiseMin(o.q_px.rowwise().minCoeff());
    hi = hi.cwiseMax(o.q_px.rowwise().maxCoeff());
  }
  return fmt::format(
      "{} does not map the whole image: no ray reaches pixel ({:.0f}, {:.0f}). The plate's marks "
      "reached x {:.0f}..{:.0f} and y {:.0f}..{:.0f} px of the {} x {} px image, and the lens is "
      "known only near them; the tiles use the whole image. Add calibration images that put the "
      "plate near the image's corners and edges",
      camera.lens_model, unmapped->x(), unmapped->y(), lo.x(), hi.x(), lo.y(), hi.y(),
      camera.width_px, camera.height_px);
}

// Step 5: the chosen spline `result` beyond the marks, guided by the working
// model's solve; kept only if the border still maps.
void ExtrapolateSpline(const CalibrationResult& working, double working_sigma_px,
                       const CalibrationUncertainty& uncertainty,
                       const std::vector<PlateObservation>& corrected,
                       const CalibrationStageOptions& options, CalibrationResult* result,
                       LensModelChoice* lens) {
  std::string why_not;
  const std::optional<CalibrationUncertainty> working_uncertainty =
      CalibrationUncertainty::Compute(working.record, 0.0, &why_not);
  if (!working_uncertainty) {
    lens->extrapolation.why_not = "no uncertainty of the working model: " + why_not;
    return;
  }
  SplineExtrapolation extrapolation = ExtrapolateSplineByParametric(
      result->camera, uncertainty, working.camera, *working_uncertainty, working_sigma_px,
      WorkingDistanceMm(*result), InlierMarksInCamera(*result), options.spline_extrapolation);
  if (extrapolation.applied) {
    CameraModel extrapolated = result->camera;
    extrapolated.intrinsics = extrapolation.intrinsics;
    if (const std::string unmapped = UnmappedImageBorder(extrapolated, corrected);
        !unmapped.empty()) {
      extrapolation.applied = false;
      extrapolation.why_not = "it would leave the border unmapped: " + unmapped;
    } else {
      result->camera.intrinsics = extrapolation.intrinsics;
      result->record.camera.intrinsics = extrapolation.intrinsics;
      lens->why += "; " + DescribeSplineExtrapolation(extrapolation, working_sigma_px,
                                                      options.spline_extrapolation);
    }
  }
  lens->extrapolation = std::move(extrapolation);
}

}  // namespace

void ResidualVectors(const CalibrationResult& result, Eigen::Matrix2Xd* q_px,
                     Eigen::Matrix2Xd* residual_px) {
  const BoardSpec& board = result.record.board;
  const Eigen::Matrix3Xd p_plate = BoardPoints(board);
  std::vector<Eigen::Vector2d> q, r;
  for (size_t i = 0; i < result.record.images.size(); ++i) {
    const SolveImage& image = result.record.images[i];
    Eigen::Matrix3Xd p_cam = result.cam_from_plate[i] * p_plate;
    if (result.record.problem.optimize_calobject_warp) {
      // mrcal's warp: z += x2 (1 - u^2) + y2 (1 - v^2), u, v in [-1, 1] over the board.
      const double half_x = 0.5 * (board.cols - 1) * board.pitch_mm;
      const double half_y = 0.5 * (board.rows - 1) * board.pitch_mm;
      Eigen::Matrix3Xd warped = p_plate;
      for (int m = 0; m < warped.cols(); ++m) {
        const double u = half_x > 0 ? warped(0, m) / half_x : 0.0;
        const double v = half_y > 0 ? warped(1, m) / half_y : 0.0;
        warped(2, m) +=
            result.calobject_warp(0) * (1 - u * u) + result.calobject_warp(1) * (1 - v * v);
      }
      p_cam = result.cam_from_plate[i] * warped;
    }
    Eigen::Matrix2Xd q_projected;
    if (!ProjectPoints(result.camera, p_cam, &q_projected)) continue;
    for (int m = 0; m < p_cam.cols(); ++m) {
      if (image.weight(m) <= 0 || image.outlier[m]) continue;
      q.push_back(image.q_px.col(m));
      r.push_back(q_projected.col(m) - image.q_px.col(m));
    }
  }
  q_px->resize(2, static_cast<Eigen::Index>(q.size()));
  residual_px->resize(2, static_cast<Eigen::Index>(r.size()));
  for (size_t k = 0; k < q.size(); ++k) {
    q_px->col(static_cast<Eigen::Index>(k)) = q[k];
    residual_px->col(static_cast<Eigen::Index>(k)) = r[k];
  }
}

std::string CalibrationStageOptions::Check() const {
  std::ostringstream what;
  if (const std::string d = detection.Check(); !d.empty()) what << "detection: " << d << "; ";
  if (num_threads < 1) what << "num_threads must be >= 1; ";
  if (max_bias_rounds < 0) what << "max_bias_rounds must be >= 0; ";
  if (!(bias_settle_px > 0)) what << "bias_settle_px must be > 0; ";
  if (splined_nx < 4) what << "splined_nx must be >= 4; ";
  if (!(splined_fov_margin > 0.5 && splined_fov_margin <= 1.5))
    what << "splined_fov_margin must be in (0.5, 1.5]; ";
  if (!(splined_max_widening >= 1.0 && splined_max_widening <= 2.0))
    what << "splined_max_widening must be in [1, 2]; ";
  if (!(lens_choice_significance_z > 0)) what << "lens_choice_significance_z must be > 0; ";
  if (!(lens_choice_min_misfit_fraction >= 0)) {
    what << "lens_choice_min_misfit_fraction must be >= 0; ";
  }
  if (min_images < 3) what << "min_images must be >= 3; ";
  if (uncertainty_grid_nx < 2 || uncertainty_grid_ny < 2)
    what << "uncertainty grid must be >= 2 x 2; ";
  std::string text = what.str();
  if (!text.empty()) text.resize(text.size() - 2);
  return text;
}

std::vector<PlateObservation> DetectPlates(const std::vector<NamedImage>& images,
                                           const BoardSpec& board,
                                           const PlateDetectionOptions& options, int num_threads) {
  std::vector<PlateObservation> detections(images.size());
  ParallelFor(static_cast<int>(images.size()), num_threads, [&](int i) {
    detections[i] = DetectPlate(images[i].image, board, options);
    detections[i].image = images[i].name;
  });
  return detections;
}

int SplinedFieldDeg(const CameraModel& camera, const std::vector<PlateObservation>& observations,
                    double fov_margin) {
  std::vector<Eigen::Vector2d> marks;
  for (const PlateObservation& o : observations) {
    if (!o.usable) continue;
    for (int m = 0; m < o.q_px.cols(); ++m) {
      if (o.weight(m) > 0) marks.push_back(o.q_px.col(m));
    }
  }
  Eigen::Matrix2Xd q(2, static_cast<Eigen::Index>(marks.size()));
  for (size_t k = 0; k < marks.size(); ++k) q.col(static_cast<Eigen::Index>(k)) = marks[k];
  Eigen::Matrix3Xd v;
  double half_angle_rad = 0.0;
  if (!marks.empty() && UnprojectPixels(camera, q, &v)) {
    for (Eigen::Index k = 0; k < v.cols(); ++k) {
      half_angle_rad = std::max(half_angle_rad, std::atan(std::abs(v(0, k) / v(2, k))));
    }
  } else {
    // A pinhole guess if the working camera cannot unproject the marks.
    half_angle_rad = std::atan(0.5 * camera.width_px / camera.intrinsics(0));
  }
  return std::max(1, static_cast<int>(
                         std::floor(2.0 * half_angle_rad * fov_margin * 180.0 / std::numbers::pi)));
}

std::string SplinedModel(const CameraModel& camera, int nx, int fov_x_deg) {
  const int ny =
      static_cast<int>(std::ceil(nx * static_cast<double>(camera.height_px) / camera.width_px));
  return fmt::format("LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx={}_Ny={}_fov_x_deg={}", nx,
                     std::max(ny, 4), fov_x_deg);
}

double WorkingDistanceMm(const CalibrationResult& result) {
  std::vector<double> distances;
  for (const Eigen::Isometry3d& pose : result.cam_from_plate)
    distances.push_back(pose.translation().norm());
  return Median(distances);
}

UncertaintySummary SummarizeUncertainty(const CalibrationUncertainty& uncertainty,
                                        const CameraModel& camera, double distance_mm, int grid_nx,
                                        int grid_ny) {
  UncertaintySummary summary;
  summary.distance_mm = distance_mm;
  const ImagerUncertainty over_imager =
      ProjectionUncertaintyOverImager(uncertainty, camera, distance_mm, grid_nx, grid_ny);
  summary.available = true;
  summary.typical_px = over_imager.typical_worst_stdev_px;
  summary.worst_px = over_imager.max_worst_stdev_px;
  summary.observed_sigma_px = uncertainty.observed_sigma_px();
  summary.grid_nx = grid_nx;
  summary.grid_ny = grid_ny;
  summary.grid_q_px = over_imager.q_px;
  summary.grid_worst_px.resize(static_cast<Eigen::Index>(over_imager.points.size()));
  for (size_t i = 0; i < over_imager.points.size(); ++i)
    summary.grid_worst_px(static_cast<Eigen::Index>(i)) = over_imager.points[i].worst_stdev_px;
  return summary;
}

UncertaintySummary SummarizeUncertainty(const SolveRecord& record, double distance_mm, int grid_nx,
                                        int grid_ny) {
  std::string why_not;
  const std::optional<CalibrationUncertainty> uncertainty =
      CalibrationUncertainty::Compute(record, 0.0, &why_not);
  if (!uncertainty) {
    UncertaintySummary summary;
    summary.distance_mm = distance_mm;
    summary.why_not = why_not;
    return summary;
  }
  return SummarizeUncertainty(*uncertainty, record.camera, distance_mm, grid_nx, grid_ny);
}

namespace {

// What the lens choice leaves besides the chosen solve.
struct LensChoiceOutcome {
  // The working model's solve and its residual sigma, kept when a spline is
  // chosen (step 5).
  std::optional<CalibrationResult> working_solve;
  double working_sigma_px = 0.0;
  // Why the camera cannot serve the tiles (UnmappedImageBorder), if checked:
  // it unprojects the whole border, slowly through a spline.
  std::optional<std::string> unmapped;
};

// Steps 3-4: the candidates solved on the working model's settled
// observations (*corrected), the chosen one settled again and a chosen
// spline widened while its border has a pixel no ray reaches. Updates
// *result, *corrected, *corrections and summary's lens, bias, corner sigma
// and choice time.
LensChoiceOutcome ChooseLensModel(const std::vector<PlateObservation>& detections,
                                  const BoardSpec& board, const CalibrationStageOptions& options,
                                  const std::string& working_model,
                                  CalibrationOptions solve_options, CalibrationResult* result,
                                  std::vector<PlateObservation>* corrected,
                                  std::vector<Eigen::Matrix2Xd>* corrections,
                                  CalibrationStageSummary* summary) {
  LensChoiceOutcome outcome;
  const Clock::time_point choice_start = Clock::now();
  const int sized_deg = SplinedFieldDeg(result->camera, *corrected, options.splined_fov_margin);
  constexpr int kSplined = 1;  // the candidates' index of the spline
  const std::vector<std::string> candidates = {
      kWorkingLensModel, SplinedModel(result->camera, options.splined_nx, sized_deg)};
  std::vector<CalibrationResult> solved;
  for (const std::string& model : candidates) {
    CalibrationOptions candidate_options = solve_options;
    candidate_options.lens_model = model;
    // The working model's candidate is `result`, solved on `corrected`
    // already (SettleObservations).
    solved.push_back(
        model == working_model ? *result : CalibrateCamera(board, *corrected, candidate_options));
    summary->lens.candidates.push_back(ScoreCandidate(model, solved.back()));
  }
  summary->lens.splined_fov_sized_deg = summary->lens.splined_fov_deg = sized_deg;
  // Candidates are listed by increasing parameter count. Starting from the
  // smallest usable one, a larger one replaces the current choice only if
  // its fit is better by more than its extra parameters explain by chance,
  // and by more than a trace of the noise.
  int chosen = -1;
  for (int k = 0; k < static_cast<int>(candidates.size()); ++k) {
    const LensCandidate& c = summary->lens.candidates[k];
    if (!c.usable) continue;
    if (chosen < 0 || (ResidualsDropSignificantly(summary->lens.candidates[chosen], c,
                                                  options.lens_choice_significance_z) &&
                       ResidualsDropMaterially(summary->lens.candidates[chosen], c,
                                               options.lens_choice_min_misfit_fraction))) {
      chosen = k;
    }
  }
  if (chosen >= 0) {
    const LensCandidate& c = summary->lens.candidates[chosen];
    summary->lens.lens_model = c.lens_model;
    summary->lens.why = fmt::format(
        "{} ({} parameters): residual sigma {:.4f} px (dof-corrected); no candidate with more "
        "parameters lowers the residuals beyond chance (F-test, z = {:.2f}) and by a misfit of "
        "{:.2f} of the noise or more",
        c.lens_model, c.num_params, c.sigma_px, options.lens_choice_significance_z,
        options.lens_choice_min_misfit_fraction);
    for (const LensCandidate& other : summary->lens.candidates) {
      if (&other != &c) {
        summary->lens.why +=
            fmt::format("; {} ({}) {:.4f} px", other.lens_model, other.num_params, other.sigma_px);
      }
    }
    if (c.lens_model != working_model) {
      *result = std::move(solved[chosen]);
      if (summary->lens.candidates[0].usable) {
        outcome.working_solve = std::move(solved[0]);
        outcome.working_sigma_px = summary->lens.candidates[0].sigma_px;
      }
    }
  }
  if (summary->lens.why.empty()) summary->lens.why = "no candidate solved; kept " + working_model;
  summary->lens_choice_seconds = SecondsSince(choice_start);
  if (summary->lens.lens_model != working_model) {
    // The observations settle again with the chosen model's camera and
    // poses (`result`, solved on the working model's observations): the
    // working model's bias corrections were off by up to 0.03 px on a
    // lens it cannot represent, and one recorrection left them moving by
    // as much; a chessboard's scatter about it was its misfit too.
    solve_options.lens_model = summary->lens.lens_model;
    SettleObservations(detections, board, solve_options, options, result, corrected, corrections,
                       &summary->bias, &summary->corner_sigma_px);
  }
  if (chosen == kSplined) {
    // The settled spline widened while its border has a pixel no ray
    // reaches (step 4), each wider one solved on the settled observations.
    const int max_deg = static_cast<int>(std::floor(sized_deg * options.splined_max_widening));
    CalibrationOptions wider_options = solve_options;
    outcome.unmapped = UnmappedImageBorder(result->camera, *corrected);
    while (summary->lens.splined_fov_deg < max_deg && !outcome.unmapped->empty()) {
      wider_options.lens_model =
          SplinedModel(result->camera, options.splined_nx, summary->lens.splined_fov_deg + 1);
      CalibrationResult wider = CalibrateCamera(board, *corrected, wider_options);
      if (!wider.usable) break;
      ++summary->lens.splined_fov_deg;
      summary->lens.lens_model = wider_options.lens_model;
      *result = std::move(wider);
      outcome.unmapped = UnmappedImageBorder(result->camera, *corrected);
    }
    if (summary->lens.splined_fov_deg > sized_deg) {
      summary->lens.why += fmt::format(
          "; its knot field widened from {} deg (sized for the marks) to {} deg so that every "
          "pixel of the image border maps: beyond the marks the lens is extrapolated, and "
          "calibration images near the image's corners would measure it",
          sized_deg, summary->lens.splined_fov_deg);
    }
  }
  return outcome;
}

}  // namespace

CalibrationStageSummary CalibrateFromDetections(const std::vector<PlateObservation>& detections,
                                                const BoardSpec& board, const CameraSpec& camera,
                                                int width_px, int height_px,
                                                const CalibrationStageOptions& options) {
  if (const std::string what = options.Check(); !what.empty()) {
    throw InputError("calibration stage options", what);
  }
  const Clock::time_point start = Clock::now();
  CalibrationStageSummary summary;
  summary.detections = detections;

  const int num_usable = static_cast<int>(std::count_if(
      detections.begin(), detections.end(), [](const PlateObservation& o) { return o.usable; }));
  if (num_usable < options.min_images) {
    summary.brief = fmt::format("{} usable calibration image(s) of {}, need at least {}",
                                num_usable, detections.size(), options.min_images);
    summary.total_seconds = SecondsSince(start);
    return summary;
  }

  // Working model for the bias rounds.
  const bool forced = camera.lens_model.has_value();
  const std::string working_model = forced ? *camera.lens_model : kWorkingLensModel;
  CalibrationOptions solve_options =
      SolveOptions(camera, width_px, height_px, working_model, options);
  if (const std::string what = solve_options.Check(); !what.empty()) {
    throw InputError("project.yaml: camera", what);
  }
  std::vector<PlateObservation> corrected;
  std::vector<Eigen::Matrix2Xd> corrections;
  CalibrationResult result = SolveAndSettle(detections, board, solve_options, options, &corrected,
                                            &corrections, &summary.bias, &summary.corner_sigma_px);
  if (!result.usable) {
    summary.brief = "calibration failed: " + result.brief;
    summary.result = std::move(result);
    summary.total_seconds = SecondsSince(start);
    return summary;
  }

  LensChoiceOutcome choice;
  summary.lens.lens_model = working_model;
  summary.lens.forced = forced;
  if (forced) {
    summary.lens.why = "forced by project.yaml camera.lens_model";
  } else if (!options.choose_lens_model) {
    summary.lens.why = "default (lens-model choice off)";
  } else {
    choice = ChooseLensModel(detections, board, options, working_model, solve_options, &result,
                             &corrected, &corrections, &summary);
  }

  if (!choice.unmapped) choice.unmapped = UnmappedImageBorder(result.camera, corrected);
  if (!choice.unmapped->empty()) {
    summary.brief = "calibration unusable: " + *choice.unmapped;
    if (summary.lens.splined_fov_sized_deg > 0 && summary.lens.lens_model != kWorkingLensModel) {
      summary.brief += fmt::format(
          " (its knot field widened from {} to {} deg; the lens choice widens it up to {:.2f} "
          "times)",
          summary.lens.splined_fov_sized_deg, summary.lens.splined_fov_deg,
          options.splined_max_widening);
    }
    summary.result = std::move(result);
    summary.total_seconds = SecondsSince(start);
    return summary;
  }
  // Computed once, at the solve's optimum: step 5 moves no mark's projection
  // by more than a fraction of its noise, and mrcal's regularisation is
  // linear in the control points, so it leaves J'J as it was.
  std::string why_no_uncertainty;
  const std::optional<CalibrationUncertainty> uncertainty =
      CalibrationUncertainty::Compute(result.record, 0.0, &why_no_uncertainty);
  if (choice.working_solve && options.extrapolate_spline_by_working_model) {
    if (uncertainty) {
      ExtrapolateSpline(*choice.working_solve, choice.working_sigma_px, *uncertainty, corrected,
                        options, &result, &summary.lens);
    } else {
      summary.lens.extrapolation.why_not = "no projection uncertainty: " + why_no_uncertainty;
    }
  }
  summary.observations = std::move(corrected);
  const double distance_mm = WorkingDistanceMm(result);
  if (uncertainty) {
    summary.uncertainty =
        SummarizeUncertainty(*uncertainty, result.camera, distance_mm,
                             options.uncertainty_grid_nx, options.uncertainty_grid_ny);
  } else {
    summary.uncertainty.distance_mm = distance_mm;
    summary.uncertainty.why_not = why_no_uncertainty;
  }
  summary.outliers = ListOutliers(result, board);
  ResidualVectors(result, &summary.residual_q_px, &summary.residual_px);
  summary.usable = true;
  const int num_rejected = static_cast<int>(detections.size()) - num_usable;
  const Eigen::Index num_residuals = summary.residual_px.cols();
  const double rms_px = num_residuals > 0
                            ? std::sqrt(summary.residual_px.squaredNorm() / (2.0 * num_residuals))
                            : 0.0;
  summary.brief = fmt::format(
      "{}: {} image(s) used, {} rejected, residual rms {:.4f} px (weighted {:.3f}), {} outlier "
      "mark(s)",
      result.camera.lens_model, num_usable, num_rejected, rms_px, result.rms_px,
      summary.outliers.size());
  if (summary.corner_sigma_px > 0.0) {
    summary.brief +=
        fmt::format(", corners' sigma {:.4f} px (their scatter)", summary.corner_sigma_px);
  }
  if (summary.uncertainty.available) {
    summary.brief +=
        fmt::format(", projection 1-sigma {:.4f} px typical, {:.4f} px worst at {:.0f} mm",
                    summary.uncertainty.typical_px, summary.uncertainty.worst_px,
                    summary.uncertainty.distance_mm);
  }
  summary.result = std::move(result);
  summary.total_seconds = SecondsSince(start);
  return summary;
}

CalibrationStageSummary RunCalibration(const std::vector<NamedImage>& images,
                                       const BoardSpec& board, const CameraSpec& camera,
                                       const CalibrationStageOptions& options) {
  if (const std::string what = options.Check(); !what.empty()) {
    throw InputError("calibration stage options", what);
  }
  const Clock::time_point start = Clock::now();
  const std::vector<PlateObservation> detections =
      DetectPlates(images, board, options.detection, options.num_threads);
  const double detection_seconds = SecondsSince(start);
  const int width_px = images.empty() ? 0 : images.front().image.width();
  const int height_px = images.empty() ? 0 : images.front().image.height();
  CalibrationStageSummary summary =
      CalibrateFromDetections(detections, board, camera, width_px, height_px, options);
  summary.detection_seconds = detection_seconds;
  summary.total_seconds = SecondsSince(start);
  return summary;
}

}  // namespace omm
