#include "pipeline/mosaic/plate_on_part.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <sstream>
#include <utility>

#include <fmt/format.h>
#include <Eigen/Dense>
#include <Eigen/Geometry>

#include "adapters/ceres/plane_bundle.h"
#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/mrcal_lens_projection.h"
#include "pipeline/calibration/perspective_bias.h"
#include "pipeline/core/error.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/core/timing.h"
#include "pipeline/mosaic/orthorectify.h"
#include "pipeline/mosaic/plane_seed.h"
#include "pipeline/mosaic/working_distance.h"

namespace omm {

std::string PlateOnPartOptions::Check() const {
  for (const std::string& e : {detection.Check(), refinement.Check()}) {
    if (!e.empty()) return e;
  }
  if (height_mm && !std::isfinite(*height_mm)) return "height_mm must be finite";
  if (!(border_margin_px >= 0)) return "border_margin_px must be >= 0";
  if (!(max_offset_px > 0)) return "max_offset_px must be > 0";
  if (!(min_mark_sigma_px > 0)) return "min_mark_sigma_px must be > 0";
  if (num_threads < 1) return "num_threads must be >= 1";
  return {};
}

std::string FinalAdjustmentOptions::Check() const {
  if (std::string e = bundle.Check(); !e.empty()) return e;
  if (!(plate_outlier_sigmas > 0)) return "plate_outlier_sigmas must be > 0";
  if (!(extrapolation_px_per_px >= 0)) return "extrapolation_px_per_px must be >= 0";
  if (!(min_corner_sigma_px > 0)) return "min_corner_sigma_px must be > 0";
  if (!(min_dot_sigma_px > 0)) return "min_dot_sigma_px must be > 0";
  return {};
}

namespace {

using Clock = std::chrono::steady_clock;

// cam_from_plate with the table at table_pos_mm (plane_scene.h's plate model
// with s = 1: plate (u, v, w) -> (x, y, h) + [M(theta) 0; 0 -1] (u, v, w)).
Eigen::Isometry3d CamFromPlate(const PlaneScene& scene, const PlatePose& plate,
                               const Eigen::Vector2d& table_pos_mm) {
  const double c = std::cos(plate.theta_rad), s = std::sin(plate.theta_rad);
  Eigen::Isometry3d part_from_plate = Eigen::Isometry3d::Identity();
  part_from_plate.linear() << c, s, 0, s, -c, 0, 0, 0, -1;
  part_from_plate.translation() << plate.x_mm + table_pos_mm.x(), plate.y_mm + table_pos_mm.y(),
      plate.height_mm;
  Eigen::Isometry3d cam_from_part = Eigen::Isometry3d::Identity();
  cam_from_part.linear() = RotationFromAngleAxis(scene.cam_from_part_r);
  cam_from_part.translation() = scene.cam_from_part_t_mm;
  return cam_from_part * part_from_plate;
}

// Centroid of the pixels darker than the local mid-level within radius + 2 px
// of the current estimate, a few passes from `predicted`: pulls a prediction
// a few px off (an unknown plate height) onto the dot.
Eigen::Vector2d DarkCentroid(const ImageF& image, const Eigen::Vector2d& predicted,
                             double radius_px, double reach_px) {
  const int x0 = static_cast<int>(std::floor(predicted.x() - radius_px - reach_px));
  const int y0 = static_cast<int>(std::floor(predicted.y() - radius_px - reach_px));
  const int size = static_cast<int>(std::ceil(2 * (radius_px + reach_px))) + 1;
  const auto window = image.block(y0, x0, size, size);
  const float threshold = 0.5f * (window.minCoeff() + window.maxCoeff());
  Eigen::Vector2d centre = predicted;
  const double r2 = (radius_px + 2) * (radius_px + 2);
  for (int pass = 0; pass < 4; ++pass) {
    Eigen::Vector2d sum = Eigen::Vector2d::Zero();
    double count = 0;
    for (int y = y0; y < y0 + size; ++y) {
      for (int x = x0; x < x0 + size; ++x) {
        if (image(y, x) >= threshold) continue;
        const Eigen::Vector2d p(x, y);
        if ((p - centre).squaredNorm() > r2) continue;
        sum += p;
        ++count;
      }
    }
    if (count == 0) break;
    centre = sum / count;
  }
  return centre;
}

// The registered input with the plate's observations and marks added.
PlaneBundleInput WithPlate(const PlaneBundleInput& registered, const PlateOnPart& plate) {
  PlaneBundleInput input = registered;
  input.plates = {plate.marks};
  input.plate_observations = plate.observations;
  return input;
}

// Each plate mark weighed as having sigma_px (0: keep its own sigma), then
// widened outside the calibration's measured region (IntrinsicsPrior's
// header: hypot(sigma, extrapolation_px_per_px * distance)). Returns how many
// marks were widened.
int WeighPlateMarks(const Eigen::Matrix2Xd& measured_region_px, double extrapolation_px_per_px,
                    double observation_sigma_px, double sigma_px,
                    std::vector<PlateMarkObservation>* observations) {
  int num_outside = 0;
  for (PlateMarkObservation& obs : *observations) {
    if (sigma_px > 0) obs.weight = observation_sigma_px / sigma_px;
    const double own_sigma_px = observation_sigma_px / obs.weight;
    if (measured_region_px.cols() == 0) continue;
    const double d = DistanceOutsideConvexPolygon(measured_region_px, obs.q_px);
    if (!(d > 0)) continue;
    ++num_outside;
    obs.weight = observation_sigma_px / std::hypot(own_sigma_px, extrapolation_px_per_px * d);
  }
  return num_outside;
}

// The plate marks' residuals inside the measured region (all if it is
// empty; those outside carry the lens's extrapolation error): the sum of
// their squared norms, px^2, and how many marks.
struct InsideResiduals {
  double sum_sq = 0.0;
  int count = 0;
};
InsideResiduals ResidualsInsideRegion(const std::vector<PlateMarkObservation>& observations,
                                      const Eigen::Matrix2Xd& residual_px,
                                      const Eigen::Matrix2Xd& measured_region_px) {
  InsideResiduals inside;
  for (Eigen::Index n = 0; n < residual_px.cols(); ++n) {
    if (measured_region_px.cols() > 0 &&
        DistanceOutsideConvexPolygon(measured_region_px,
                                     observations[static_cast<size_t>(n)].q_px) > 0)
      continue;
    inside.sum_sq += residual_px.col(n).squaredNorm();
    ++inside.count;
  }
  return inside;
}

}  // namespace

double PlatePitchOnPartPx(const BoardSpec& board, const CameraModel& camera,
                          const PlaneScene& scene) {
  const std::optional<double> distance_mm =
      AxisDistanceMm(scene.cam_from_part_r, scene.cam_from_part_t_mm);
  return distance_mm ? board.pitch_mm * std::abs(camera.intrinsics(0)) / *distance_mm : 0.0;
}

std::vector<std::vector<int>> BoardMarkOrders(const BoardSpec& board) {
  const int rows = board.rows, cols = board.cols;
  const auto order = [&](const std::function<int(int, int)>& detected_of) {
    std::vector<int> o(static_cast<size_t>(rows * cols));
    for (int r = 0; r < rows; ++r) {
      for (int c = 0; c < cols; ++c) o[static_cast<size_t>(r * cols + c)] = detected_of(r, c);
    }
    return o;
  };
  std::vector<std::vector<int>> orders = {order([&](int r, int c) { return r * cols + c; })};
  if (board.type == BoardType::kCaltab) return orders;  // its triangle fixes the order
  orders.push_back(order([&](int r, int c) { return (rows - 1 - r) * cols + (cols - 1 - c); }));
  if (rows == cols) {
    orders.push_back(order([&](int r, int c) { return c * cols + (rows - 1 - r); }));
    orders.push_back(order([&](int r, int c) { return (cols - 1 - c) * cols + r; }));
  }
  return orders;
}

int AlignMarkOrder(const BoardSpec& board, const CameraModel& camera, const PlaneScene& scene,
                   int reference_tile, const PlateObservation& reference, int tile,
                   PlateObservation* observation) {
  // The reference's marks on the part plane Z = 0 (the plate's height
  // neglected), then in `tile`.
  const Eigen::Matrix3d rot = RotationFromAngleAxis(scene.cam_from_part_r);
  const Eigen::Vector3d& t = scene.cam_from_part_t_mm;
  Eigen::Matrix3Xd rays;
  if (!UnprojectPixels(camera, reference.q_px, &rays)) return 0;
  const Eigen::Vector3d shift(scene.table_pos_mm[tile].x() - scene.table_pos_mm[reference_tile].x(),
                              scene.table_pos_mm[tile].y() - scene.table_pos_mm[reference_tile].y(),
                              0.0);
  Eigen::Matrix3Xd p_cam(3, rays.cols());
  for (Eigen::Index m = 0; m < rays.cols(); ++m) {
    // p = lambda ray with (R' (p - t)).z = 0, moved by the tables' difference.
    const Eigen::Vector3d ray_part = rot.transpose() * rays.col(m);
    const double lambda = (rot.transpose() * t).z() / ray_part.z();
    p_cam.col(m) = lambda * rays.col(m) + rot * shift;
  }
  Eigen::Matrix2Xd predicted;
  if (!ProjectPoints(camera, p_cam, &predicted)) return 0;

  const std::vector<std::vector<int>> orders = BoardMarkOrders(board);
  int best = 0;
  double best_cost = INFINITY;
  for (size_t k = 0; k < orders.size(); ++k) {
    double cost = 0.0;
    for (Eigen::Index m = 0; m < predicted.cols(); ++m) {
      const int d = orders[k][static_cast<size_t>(m)];
      if (reference.weight(m) > 0 && observation->weight(d) > 0)
        cost += (observation->q_px.col(d) - predicted.col(m)).squaredNorm();
    }
    if (cost < best_cost) {
      best_cost = cost;
      best = static_cast<int>(k);
    }
  }
  if (best == 0) return 0;
  const PlateObservation detected = *observation;
  for (Eigen::Index m = 0; m < detected.q_px.cols(); ++m) {
    const int d = orders[static_cast<size_t>(best)][static_cast<size_t>(m)];
    observation->q_px.col(m) = detected.q_px.col(d);
    observation->weight(m) = detected.weight(d);
    observation->sigma_px(m) = detected.sigma_px(d);
  }
  return best;
}

namespace {

// Step 3 in a tile where the plate is cut: every mark predicted through
// cam_from_plate and located there (a dot's ellipse fitted, a chessboard's
// corner refined as DetectPlate refines it) into *q_px and *sigma_px, which
// stay 0 where it is not found.
void LocateMarksOfACutPlate(const ImageF& tile, const BoardSpec& board, const CameraModel& camera,
                            const PlaneScene& scene, const Eigen::Isometry3d& cam_from_plate,
                            const PlateOnPartOptions& options, Eigen::Matrix2Xd* q_px,
                            Eigen::VectorXd* sigma_px) {
  const int num_marks = static_cast<int>(q_px->cols());
  const bool dots = board.type != BoardType::kChessboard;
  const Eigen::Matrix3d rot = RotationFromAngleAxis(scene.cam_from_part_r);
  const double radius_mm = 0.5 * board.dot_diameter_mm;
  const Eigen::Matrix3Xd p_cam = cam_from_plate * BoardPoints(board);
  if ((p_cam.row(2).array() <= 0).any()) return;
  Eigen::Matrix2Xd predicted;
  Eigen::MatrixXd dq_dp, dq_dintrinsics;
  if (!ProjectPoints(camera, p_cam, &predicted, &dq_dp, &dq_dintrinsics)) return;
  // Marks the lens folds into a far tile's image are not in it.
  const std::vector<bool> folded = FoldedIntoTheImage(camera, p_cam, predicted, 0.0);
  if (!dots) {
    // The corners' spacing: the image of one pitch along the plate's x.
    const double spacing_px =
        (dq_dp.block<2, 3>(0, 0) * cam_from_plate.linear().col(0) * board.pitch_mm).norm();
    Eigen::Matrix2Xd refined;
    std::vector<bool> found;
    RefineChessboardCorners(tile, predicted, spacing_px, options.border_margin_px,
                            options.max_offset_px, &refined, &found);
    for (int m = 0; m < num_marks; ++m) {
      if (!found[static_cast<size_t>(m)] || folded[static_cast<size_t>(m)]) continue;
      q_px->col(m) = refined.col(m);
      (*sigma_px)(m) = std::max(options.detection.chessboard_sigma_px, options.min_mark_sigma_px);
    }
    return;
  }
  for (int m = 0; m < num_marks; ++m) {
    if (folded[static_cast<size_t>(m)]) continue;
    // The dot's image: the circle through the local affine of the plane.
    const Eigen::Matrix2d j =
        dq_dp.block<2, 3>(2 * Eigen::Index{m}, 0) * rot.leftCols<2>() * radius_mm;
    const Eigen::Matrix2d shape = (j * j.transpose()).inverse();
    Ellipse rough;
    rough.centre_px = predicted.col(m);
    rough.shape = shape;
    const double a = rough.SemiMajorPx(), b = rough.SemiMinorPx();
    const double reach = a + options.max_offset_px + options.refinement.edges.ray_half_length_px +
                         options.border_margin_px;
    const Eigen::Vector2d c = predicted.col(m);
    if (c.x() - reach < 0 || c.y() - reach < 0 || c.x() + reach > camera.width_px - 1 ||
        c.y() + reach > camera.height_px - 1)
      continue;
    rough.centre_px = DarkCentroid(tile, c, a, options.max_offset_px);
    const MarkFit fit = RefineEllipticalMark(tile, rough, options.refinement);
    if (!fit.ok || (fit.ellipse.centre_px - c).norm() > options.max_offset_px ||
        std::abs(fit.ellipse.SemiMajorPx() / a - 1) > 0.2 ||
        std::abs(fit.ellipse.SemiMinorPx() / b - 1) > 0.2)
      continue;
    q_px->col(m) = fit.ellipse.centre_px;
    (*sigma_px)(m) = std::max(fit.sigma_px, options.min_mark_sigma_px);
  }
}

}  // namespace

namespace {

// Step 1: the whole plates in the tiles, searched at the scale the
// registered scene gives a plate lying on the part (a chessboard is then
// searched at one scale: where it is absent, as it mostly is, the whole image
// took 0.35 s per tile), their marks numbered as in the first whole one.
struct WholePlates {
  std::vector<PlateObservation> observations;  // per tile
  int num_reordered = 0;                       // tiles whose marks were renumbered
};

WholePlates DetectWholePlates(const std::vector<ImageF>& tiles, const BoardSpec& board,
                              const CameraModel& camera, const PlaneScene& registered_scene,
                              const PlateOnPartOptions& options) {
  const int num_tiles = static_cast<int>(tiles.size());
  PlateDetectionOptions detection = options.detection;
  detection.expected_pitch_px = PlatePitchOnPartPx(board, camera, registered_scene);
  WholePlates plates;
  std::vector<PlateObservation>& whole = plates.observations;
  whole.resize(num_tiles);
  ParallelFor(num_tiles, options.num_threads, [&](int i) {
    GrayImage image;
    image.pixels = tiles[i];
    whole[i] = DetectPlate(image, board, detection);
  });
  const auto first_whole =
      std::find_if(whole.begin(), whole.end(), [](const PlateObservation& o) { return o.usable; });
  for (int i = static_cast<int>(first_whole - whole.begin()) + 1; i < num_tiles; ++i) {
    if (!whole[i].usable) continue;
    const int reference = static_cast<int>(first_whole - whole.begin());
    if (AlignMarkOrder(board, camera, registered_scene, reference, *first_whole, i, &whole[i]) != 0)
      ++plates.num_reordered;
  }
  return plates;
}

// Step 4: the perspective bias of a tile's mark centres (those of sigma > 0)
// taken out, with the plate's pose in that tile; the largest correction, px.
double CorrectPerspectiveBias(const BoardSpec& board, const CameraModel& camera,
                              const Eigen::Isometry3d& cam_from_plate,
                              const Eigen::VectorXd& sigma_px, Eigen::Matrix2Xd* q_px) {
  if ((sigma_px.array() <= 0).all()) return 0.0;
  Eigen::Matrix2Xd delta;
  if (!PerspectiveBiasCorrections(board, camera, cam_from_plate, &delta)) return 0.0;
  double largest = 0.0;
  for (Eigen::Index m = 0; m < sigma_px.size(); ++m) {
    if (sigma_px(m) <= 0) continue;
    q_px->col(m) += delta.col(m);
    largest = std::max(largest, delta.col(m).norm());
  }
  return largest;
}

// The plate's height above the part: given, estimated where two tiles or
// more see it, else unknown (taken as 0, and then the plate is no scale
// reference).
void SetPlateHeight(const std::optional<double>& given_mm, int num_seen, PlateOnPart* result) {
  if (given_mm) {
    result->marks.height_mm = *given_mm;
    result->height_source = "given";
  } else if (num_seen >= 2) {
    result->marks.height_mm.reset();
    result->height_source = "estimated (seen in " + std::to_string(num_seen) + " tiles)";
  } else {
    result->marks.height_mm = 0.0;
    result->scale_reference = false;
    result->height_source =
        "unknown: seen in one tile only, where the plate's height and the scale are confounded; "
        "taken as 0, the plate checks the table's scale but does not set it "
        "(mosaic.plate_height_mm sets it)";
  }
}

}  // namespace

PlateOnPart FindPlateOnPart(const std::vector<ImageF>& tiles, const BoardSpec& board,
                            const CameraModel& camera, const PlaneBundleInput& registered_input,
                            const PlaneScene& registered_scene, const PlateOnPartOptions& options) {
  if (const std::string e = options.Check(); !e.empty())
    throw InputError("", "plate on the part: " + e);
  if (tiles.size() != registered_scene.table_pos_mm.size())
    throw InputError("",
                     "plate on the part: tiles and the scene's table positions differ in number");
  const Clock::time_point start = Clock::now();
  const int num_tiles = static_cast<int>(tiles.size());
  PlateOnPart result;
  result.marks.mark_uv_mm = BoardPoints(board).topRows<2>();
  result.marks_per_tile.assign(num_tiles, 0);

  // 1. Whole plates, at the scale the registered scene gives a plate lying
  // on the part (a chessboard is then searched at one scale: where it is
  // absent, as it mostly is, the whole image took 0.35 s per tile).
  const WholePlates whole_plates =
      DetectWholePlates(tiles, board, camera, registered_scene, options);
  const std::vector<PlateObservation>& whole = whole_plates.observations;
  const int num_marks = static_cast<int>(result.marks.mark_uv_mm.cols());
  // Per tile and mark: the located centre and its sigma (sigma 0: not seen).
  std::vector<Eigen::Matrix2Xd> q_px(num_tiles, Eigen::Matrix2Xd::Zero(2, num_marks));
  std::vector<Eigen::VectorXd> sigma_px(num_tiles, Eigen::VectorXd::Zero(num_marks));
  for (int i = 0; i < num_tiles; ++i) {
    if (!whole[i].usable) continue;
    result.whole_in_tiles.push_back(i);
    for (int m = 0; m < num_marks; ++m) {
      if (whole[i].weight(m) <= 0) continue;
      q_px[i].col(m) = whole[i].q_px.col(m);
      sigma_px[i](m) = std::max(whole[i].sigma_px(m), options.min_mark_sigma_px);
    }
  }
  if (result.whole_in_tiles.empty()) {
    result.brief = "no plate on the part: the whole plate is in no tile";
    result.seconds = SecondsSince(start);
    return result;
  }

  // 2. The plate's pose on the part from the whole plates (the seed's fit).
  const auto observations_of = [&](int tile) {
    std::vector<PlateMarkObservation> obs;
    for (int m = 0; m < num_marks; ++m) {
      if (sigma_px[tile](m) > 0) obs.push_back({tile, 0, m, q_px[tile].col(m), 1.0});
    }
    return obs;
  };
  {
    PlateOnPart whole_only = result;
    whole_only.marks.height_mm = options.height_mm.value_or(0.0);
    for (int i : result.whole_in_tiles) {
      for (const PlateMarkObservation& o : observations_of(i)) whole_only.observations.push_back(o);
    }
    PlaneScene seeded;
    const PlaneSeedSummary seed =
        SeedPlaneScene(camera, WithPlate(registered_input, whole_only), &seeded);
    if (!seed.ok) {
      result.brief = "plate on the part not used: seeding its pose failed: " + seed.why_failed;
      result.seconds = SecondsSince(start);
      return result;
    }
    result.initial_pose = seeded.plates[0];
  }

  // 3. Marks predicted where the plate is cut.
  for (int i = 0; i < num_tiles; ++i) {
    if (whole[i].usable) continue;
    LocateMarksOfACutPlate(
        tiles[i], board, camera, registered_scene,
        CamFromPlate(registered_scene, result.initial_pose, registered_scene.table_pos_mm[i]),
        options, &q_px[i], &sigma_px[i]);
  }

  // 4. Perspective bias of every centre, with the tile's plate pose.
  for (int i = 0; i < num_tiles; ++i) {
    result.max_bias_correction_px = std::max(
        result.max_bias_correction_px,
        CorrectPerspectiveBias(
            board, camera,
            CamFromPlate(registered_scene, result.initial_pose, registered_scene.table_pos_mm[i]),
            sigma_px[i], &q_px[i]));
  }

  for (int i = 0; i < num_tiles; ++i) {
    for (int m = 0; m < num_marks; ++m) {
      if (sigma_px[i](m) <= 0) continue;
      result.observations.push_back(
          {i, 0, m, q_px[i].col(m), registered_input.observation_sigma_px / sigma_px[i](m)});
      ++result.marks_per_tile[i];
    }
    if (result.marks_per_tile[i] > 0) result.seen_in_tiles.push_back(i);
  }
  const int num_seen = static_cast<int>(result.seen_in_tiles.size());
  result.scale_reference = true;
  SetPlateHeight(options.height_mm, num_seen, &result);
  result.found = true;
  result.sigma_assumed = board.type == BoardType::kChessboard;
  std::ostringstream brief;
  brief << "plate on the part: whole in " << result.whole_in_tiles.size() << " tile(s), "
        << result.observations.size() << " marks in " << num_seen << " tile(s); height "
        << result.height_source;
  if (whole_plates.num_reordered > 0)
    brief << "; the marks renumbered in " << whole_plates.num_reordered
          << " tile(s) to match the first's";
  result.brief = brief.str();
  result.seconds = SecondsSince(start);
  return result;
}

IntrinsicsPrior IntrinsicsPriorFromCovariance(const Eigen::MatrixXd& covariance) {
  IntrinsicsPrior prior;
  if (covariance.rows() == 0 || covariance.rows() != covariance.cols()) {
    prior.why_held = "no intrinsics covariance";
    return prior;
  }
  if (!covariance.allFinite()) {
    prior.why_held = "the calibration's intrinsics covariance is not finite";
    return prior;
  }
  std::vector<int> held;
  for (int k = 0; k < covariance.rows(); ++k) {
    if (covariance.row(k).isZero() && covariance.col(k).isZero()) held.push_back(k);
  }
  const std::vector<int> free = FreeIntrinsics(static_cast<int>(covariance.rows()), held);
  const Eigen::VectorXd variance = covariance.diagonal()(free);
  if (free.empty() || !(variance.array() > 0).all()) {
    prior.why_held = free.empty() ? "the calibration held every intrinsic"
                                  : "the calibration's intrinsics covariance has a zero variance";
    return prior;
  }
  // Inverted as a correlation matrix: the parameters' scales differ by ~1e7
  // (focal length vs high-order distortions).
  const Eigen::VectorXd inv_sigma = variance.cwiseSqrt().cwiseInverse();
  const Eigen::MatrixXd correlation =
      inv_sigma.asDiagonal() * covariance(free, free) * inv_sigma.asDiagonal();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(correlation);
  // A rational lens model's parameters are nearly redundant: the calibration
  // determines some combinations to ~1e-7 of their marginal sigmas
  // (correlation eigenvalues ~1e-15, at the rounding level). Their
  // information is capped at kMaxConditioning times the weakest direction's
  // (a sigma of 1e-3 of the marginal ones): the tiles' features determine
  // those combinations far better than that anyway (on the demo the scale
  // sigma and the intrinsics' change agree to 1e-5 between caps of 1e4 and
  // 1e12), and an uncapped prior makes Levenberg-Marquardt crawl (20
  // iterations instead of 8). The capped prior is weaker, never stronger,
  // than the calibration's: the covariance stays conservative.
  constexpr double kMaxConditioning = 1e6;
  const double lambda_max = eigen.eigenvalues().maxCoeff();
  if (eigen.info() != Eigen::Success || !(eigen.eigenvalues().minCoeff() > -1e-9 * lambda_max)) {
    prior.why_held = "the calibration's intrinsics covariance is not positive semi-definite";
    return prior;
  }
  const Eigen::VectorXd lambda = eigen.eigenvalues().cwiseMax(lambda_max / kMaxConditioning);
  const Eigen::MatrixXd inv_correlation =
      eigen.eigenvectors() * lambda.cwiseInverse().asDiagonal() * eigen.eigenvectors().transpose();
  const Eigen::MatrixXd information =
      inv_sigma.asDiagonal() * inv_correlation * inv_sigma.asDiagonal();
  prior.information = Eigen::MatrixXd::Zero(covariance.rows(), covariance.cols());
  prior.information(free, free) = 0.5 * (information + information.transpose());
  prior.held = held;
  return prior;
}

Eigen::Matrix2Xd ConvexHull(const Eigen::Matrix2Xd& points_px) {
  if (points_px.cols() < 3) return {};
  // Andrew's monotone chain.
  std::vector<Eigen::Vector2d> p(points_px.cols());
  for (Eigen::Index k = 0; k < points_px.cols(); ++k) p[k] = points_px.col(k);
  std::sort(p.begin(), p.end(), [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y());
  });
  const auto cross = [](const Eigen::Vector2d& o, const Eigen::Vector2d& a,
                        const Eigen::Vector2d& b) {
    return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
  };
  std::vector<Eigen::Vector2d> hull;
  for (int pass = 0; pass < 2; ++pass) {
    const size_t start = hull.size();
    for (const Eigen::Vector2d& q : p) {
      while (hull.size() >= start + 2 && cross(hull[hull.size() - 2], hull.back(), q) <= 0)
        hull.pop_back();
      hull.push_back(q);
    }
    hull.pop_back();  // the next chain's first point
    std::reverse(p.begin(), p.end());
  }
  if (hull.size() < 3) return {};
  Eigen::Matrix2Xd out(2, static_cast<Eigen::Index>(hull.size()));
  for (size_t k = 0; k < hull.size(); ++k) out.col(static_cast<Eigen::Index>(k)) = hull[k];
  return out;
}

double DistanceOutsideConvexPolygon(const Eigen::Matrix2Xd& polygon_px,
                                    const Eigen::Vector2d& q_px) {
  if (InsideConvexPolygon(polygon_px, q_px)) return 0.0;
  double distance = std::numeric_limits<double>::infinity();
  const Eigen::Index n = polygon_px.cols();
  for (Eigen::Index k = 0; k < n; ++k) {
    const Eigen::Vector2d a = polygon_px.col(k), ab = polygon_px.col((k + 1) % n) - a;
    const double t = std::clamp((q_px - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
    distance = std::min(distance, (q_px - a - t * ab).norm());
  }
  return distance;
}

bool InsideConvexPolygon(const Eigen::Matrix2Xd& polygon_px, const Eigen::Vector2d& q_px) {
  const Eigen::Index n = polygon_px.cols();
  for (Eigen::Index k = 0; k < n; ++k) {
    const Eigen::Vector2d a = polygon_px.col(k), b = polygon_px.col((k + 1) % n);
    if ((b.x() - a.x()) * (q_px.y() - a.y()) - (b.y() - a.y()) * (q_px.x() - a.x()) < 0)
      return false;
  }
  return n >= 3;
}

double TableScaleSigmaPpm(const std::vector<Eigen::Vector2d>& commanded_table_pos_mm,
                          const Eigen::MatrixXd& scene_covariance) {
  const int n = static_cast<int>(commanded_table_pos_mm.size());
  if (scene_covariance.rows() < 6 + 2 * n) return 0.0;
  // Scale of the fit T ~ s C + d about the means: s = sum (C_i - mean) . T_i / sum |C_i - mean|^2,
  // linear in T with gradient g.
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const Eigen::Vector2d& c : commanded_table_pos_mm) mean += c / n;
  double spread = 0;
  Eigen::VectorXd g(2 * n);
  for (int i = 0; i < n; ++i) {
    g.segment<2>(2 * Eigen::Index{i}) = commanded_table_pos_mm[i] - mean;
    spread += g.segment<2>(2 * Eigen::Index{i}).squaredNorm();
  }
  if (!(spread > 0)) return 0.0;
  g /= spread;
  const double variance = g.dot(scene_covariance.block(6, 6, 2 * n, 2 * n) * g);
  return std::sqrt(std::max(0.0, variance)) * 1e6;
}

namespace {

// Misread marks of the plate (beyond plate_outlier_sigmas) dropped from
// result->input and the scene solved again from `from`. Empty, or why the
// plate is not used (most of its marks outliers).
std::string DropPlateOutliers(const LensProjection& lens, const PlaneBundleConfig& config,
                              const FinalAdjustmentOptions& options, PlaneScene from,
                              FinalAdjustment* result) {
  const double sigma = result->input.observation_sigma_px;
  const std::vector<PlateMarkObservation>& observations = result->input.plate_observations;
  std::vector<PlateMarkObservation> kept;
  int num_dropped = 0;
  for (size_t n = 0; n < observations.size(); ++n) {
    const PlateMarkObservation& obs = observations[n];
    const Eigen::Vector2d res = result->scene.plate_residual_px.col(static_cast<Eigen::Index>(n));
    if (res.allFinite() && res.norm() * obs.weight <= options.plate_outlier_sigmas * sigma) {
      kept.push_back(obs);
    } else {
      ++num_dropped;
    }
  }
  result->plate_outliers += num_dropped;
  if (2 * kept.size() < observations.size()) {
    return std::to_string(num_dropped) + " of " + std::to_string(observations.size()) +
           " marks are outliers";
  }
  if (num_dropped > 0) {
    result->input.plate_observations = kept;
    result->scene = std::move(from);
    result->summary = SolvePlaneBundle(lens, result->input, config, options.bundle, &result->scene);
  }
  return {};
}

// The plate marks' scatter about the solve in *result, px: inside the
// calibration's measured region, over its degrees of freedom, 2 per mark
// less the plate's free parameters (the scene's are shared with the tracks
// and neglected). 0 where there are none.
double MarkScatterPx(const FinalAdjustment& result, const PlateOnPart& plate,
                     const PlaneBundleConfig& config, const Eigen::Matrix2Xd& measured_region_px) {
  const int num_plate_parameters =
      3 + (plate.marks.height_mm.has_value() ? 0 : 1) + (config.refine_plate_scale ? 1 : 0);
  const InsideResiduals inside = ResidualsInsideRegion(
      result.input.plate_observations, result.scene.plate_residual_px, measured_region_px);
  const int dof = 2 * inside.count - num_plate_parameters;
  return dof > 0 && std::isfinite(inside.sum_sq) ? std::sqrt(inside.sum_sq / dof) : 0.0;
}

// The plate's check on the table's scale, from a usable solve with its
// covariance: the plate's own scale where it is free (a plate that only
// checks), else its scale released to first order (it agrees with a second
// solve to 1e-4 ppm on the demos). Not ok without a plate.
PlateScaleCheck ScaleCheckOf(const LensProjection& lens, const FinalAdjustment& result,
                             bool plate_found, bool scale_free, const PlaneBundleOptions& bundle,
                             int plate_index) {
  PlateScaleCheck check;
  if (scale_free) {
    const int s = plate_index + 4;
    check.ok = true;
    check.scale_minus_1_ppm = (result.scene.plates[0].scale - 1) * 1e6;
    check.sigma_ppm = std::sqrt(std::max(0.0, result.scene.covariance(s, s))) * 1e6;
  } else if (plate_found) {
    const PlateScaleRelease release =
        ReleasePlateScale(lens, result.input, bundle, result.scene, 0);
    check.ok = release.ok;
    check.scale_minus_1_ppm = release.scale_minus_1 * 1e6;
    check.sigma_ppm = release.sigma * 1e6;
  }
  return check;
}

}  // namespace

FinalAdjustment AdjustWithPlateAndPrior(const CameraModel& camera,
                                        const PlaneBundleInput& registered_input,
                                        const PlaneScene& registered_scene,
                                        const PlateOnPart& plate, const IntrinsicsPrior& prior,
                                        const FinalAdjustmentOptions& options) {
  if (const std::string e = options.Check(); !e.empty())
    throw InputError("", "final adjustment: " + e);
  if (registered_scene.intrinsics.size() != camera.intrinsics.size())
    throw InputError("", "final adjustment: the scene's intrinsics do not fit the camera");
  const Clock::time_point start = Clock::now();
  // Plate 0's (x, y, theta, h, s) in the covariance's vector.
  const int plate_index =
      PlaneSceneCovariancePlateIndex(static_cast<int>(registered_scene.table_pos_mm.size()), 0);
  FinalAdjustment result;
  result.intrinsics_refined = prior.information.size() > 0;
  result.input = plate.found ? WithPlate(registered_input, plate) : registered_input;
  result.plate_outside_region =
      WeighPlateMarks(prior.measured_region_px, options.extrapolation_px_per_px,
                      result.input.observation_sigma_px, 0.0, &result.input.plate_observations);
  if (result.intrinsics_refined) {
    result.input.intrinsics_information = prior.information;
    result.input.intrinsics_held = prior.held;
    result.input.intrinsics_prior_mean = registered_scene.intrinsics;
  }
  PlaneBundleConfig config;
  config.refine_intrinsics = result.intrinsics_refined;
  config.compute_covariance = options.compute_covariance;
  // A plate that only checks: its scale free in the final solve already.
  config.refine_plate_scale = plate.found && !plate.scale_reference;
  if (const std::string e =
          CheckPlaneBundleInput(result.input, config, static_cast<int>(camera.intrinsics.size()));
      !e.empty())
    throw InputError("", "final adjustment: " + e);

  const MrcalLensProjection lens(camera);
  PlaneScene initial = registered_scene;
  initial.covariance.resize(0, 0);
  if (plate.found) initial.plates = {plate.initial_pose};
  result.scene = initial;
  result.summary = SolvePlaneBundle(lens, result.input, config, options.bundle, &result.scene);

  std::string why_not_used;
  if (plate.found && result.summary.usable)
    why_not_used = DropPlateOutliers(lens, config, options, initial, &result);
  if (plate.found && why_not_used.empty() && result.summary.usable) {
    // The marks weighed by their scatter about this solve, solved again from
    // it, and screened again at that sigma. With the detector's assumed 0.1
    // px, rendered corners that scatter by ~0.02 px counted 1/25 of what they
    // are worth, and the plate's scale was stated ~28 ppm where its errors
    // spread by ~14 (14 demo projects with a chessboard on the part); dots
    // at their floor of 0.01 px, which scatter by ~0.005, stated 5-6 ppm
    // where the errors spread by 3.5 (13 demo and plate-on-part projects).
    const double scatter_px = MarkScatterPx(result, plate, config, prior.measured_region_px);
    if (scatter_px > 0) {
      result.mark_sigma_px = std::max(
          scatter_px, plate.sigma_assumed ? options.min_corner_sigma_px : options.min_dot_sigma_px);
      WeighPlateMarks(prior.measured_region_px, options.extrapolation_px_per_px,
                      result.input.observation_sigma_px, result.mark_sigma_px,
                      &result.input.plate_observations);
      result.summary = SolvePlaneBundle(lens, result.input, config, options.bundle, &result.scene);
      if (result.summary.usable)
        why_not_used = DropPlateOutliers(lens, config, options, result.scene, &result);
    }
  }
  if (options.rescale_observation_sigma && why_not_used.empty() && result.summary.usable &&
      result.summary.unit_weight_sigma > 1.0) {
    result.observation_sigma_scale = result.summary.unit_weight_sigma;
    result.input.observation_sigma_px *= result.observation_sigma_scale;
    result.summary = SolvePlaneBundle(lens, result.input, config, options.bundle, &result.scene);
  }
  if (plate.found && !result.summary.usable) why_not_used = result.summary.brief;
  if (!why_not_used.empty()) {
    FinalAdjustment without = AdjustWithPlateAndPrior(camera, registered_input, registered_scene,
                                                      PlateOnPart{}, prior, options);
    without.plate_not_used = why_not_used;
    without.seconds = SecondsSince(start);
    return without;
  }
  if (result.intrinsics_refined && result.summary.usable) {
    // The tiles use the whole image: refined intrinsics whose lens folds
    // short of its border (a spline moved past the knots its marks
    // constrained) cannot render them, so the calibration's are kept.
    CameraModel refined = camera;
    refined.intrinsics = result.scene.intrinsics;
    if (const std::optional<Eigen::Vector2d> q = FirstUnmappedTileBorderPixel(refined)) {
      IntrinsicsPrior held;
      held.measured_region_px = prior.measured_region_px;
      held.why_held = fmt::format(
          "refined, they would map no ray to pixel ({:.0f}, {:.0f}) of the image border, which "
          "the tiles use",
          q->x(), q->y());
      FinalAdjustment with_held =
          AdjustWithPlateAndPrior(camera, registered_input, registered_scene, plate, held, options);
      with_held.intrinsics_held_why = held.why_held;
      with_held.seconds = SecondsSince(start);
      return with_held;
    }
  }
  // Ceres' diagonal blocks are symmetric to rounding only; the saved matrix
  // is exactly.
  result.scene.covariance =
      (0.5 * (result.scene.covariance + result.scene.covariance.transpose())).eval();
  if (plate.found) {
    const InsideResiduals inside = ResidualsInsideRegion(
        result.input.plate_observations, result.scene.plate_residual_px, prior.measured_region_px);
    result.plate_rms_px = inside.count > 0 ? std::sqrt(inside.sum_sq / inside.count) : 0.0;
    result.plate_height_mm = result.scene.plates[0].height_mm;
    const int h = plate_index + 3;
    if (result.scene.covariance.rows() > h)
      result.plate_height_sigma_mm = std::sqrt(std::max(0.0, result.scene.covariance(h, h)));
  }
  result.scale_sigma_ppm =
      TableScaleSigmaPpm(registered_input.commanded_table_pos_mm, result.scene.covariance);

  if (result.summary.usable && result.summary.covariance_ok) {
    result.scale_check = ScaleCheckOf(lens, result, plate.found, config.refine_plate_scale,
                                      options.bundle, plate_index);
  }
  result.seconds = SecondsSince(start);
  return result;
}

}  // namespace omm
