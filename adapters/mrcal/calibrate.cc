#include "adapters/mrcal/calibrate.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <Eigen/Dense>
#include <Eigen/Geometry>

#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/mrcal_problem.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

constexpr const char* kSplinedPrefix = "LENSMODEL_SPLINED_STEREOGRAPHIC";
// A splined solve starts from this model's fit, its knots fitted to it over
// the whole imager. Not OPENCV8: on a lens it cannot represent, fitted to few
// images, its rational terms fold over beyond the marks (lens-mismatch seed
// 103 with 12 images: the splined solve from it diverged to NaN; seed 102
// converged to a worse minimum, 0.0083 against 0.0078 px).
constexpr const char* kSplinedSeedModel = "LENSMODEL_OPENCV4";

bool IsSplined(const std::string& lens_model) { return lens_model.rfind(kSplinedPrefix, 0) == 0; }

// Hartley normalisation: x_n = T x has centroid 0 and mean distance sqrt(2).
Eigen::Matrix3d NormalizingTransform(const std::vector<Eigen::Vector2d>& points) {
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  double spread = 0.0;
  for (const auto& p : points) spread += (p - mean).norm();
  spread /= static_cast<double>(points.size());
  const double s = std::sqrt(2.0) / std::max(spread, 1e-12);
  Eigen::Matrix3d T;
  T << s, 0, -s * mean.x(), 0, s, -s * mean.y(), 0, 0, 1;
  return T;
}

void ThrowIfMisshapen(const BoardSpec& board, const PlateObservation& observation) {
  const int n = board.rows * board.cols;
  if (observation.q_px.cols() != n || observation.weight.size() != n) {
    std::ostringstream what;
    what << "plate observation has " << observation.q_px.cols() << " marks and "
         << observation.weight.size() << " weights, expected " << n << " for a " << board.rows
         << "x" << board.cols << " board";
    throw InputError(observation.image, what.str());
  }
}

CalibrationProblem StageProblem(bool core, bool distortions, bool regularization,
                                bool outliers, bool warp) {
  CalibrationProblem problem;
  problem.optimize_intrinsics_core = core;
  problem.optimize_intrinsics_distortions = distortions;
  problem.optimize_frames = true;
  problem.optimize_calobject_warp = warp;
  problem.apply_regularization = regularization;
  problem.apply_outlier_rejection = outliers;
  return problem;
}

// One mrcal_optimize on the record, in place. A splined lens's solve is
// brought to mrcal's optimum first (ConvergeByGaussNewton): there
// mrcal_optimize's Gauss-Newton steps along a weakly determined direction
// (the plate poses turning together about the camera while the spline
// follows) shrink by ~0.85 each, and on lens-mismatch seed 284 its three
// solves took 116, 64 and 56 iterations (0.55 s) while the cost changed in
// its sixth digit. Searched along, the steps get there in 35, 24 and 14
// (0.17 s), and mrcal_optimize then stops within 4 ms; the reports'
// values moved by at most 0.04 sigma.
void Solve(SolveRecord* record) {
  mrcal_internal::Problem problem = mrcal_internal::ToProblem(*record);
  if (IsSplined(record->camera.lens_model)) mrcal_internal::ConvergeByGaussNewton(&problem);
  mrcal_internal::Optimize(&problem);
  mrcal_internal::UpdateRecord(problem, record);
}

// mrcal-calibrate-cameras' sequence from a seed with zero distortions.
void SolveStaged(const CalibrationOptions& options, bool optimize_core, SolveRecord* record) {
  record->problem = StageProblem(false, false, false, false, false);
  Solve(record);
  if (optimize_core) {
    record->problem = StageProblem(true, false, false, false, false);
    Solve(record);
  }
  record->problem = StageProblem(optimize_core, true, options.apply_regularization, false, false);
  Solve(record);
  record->problem = StageProblem(optimize_core, true, options.apply_regularization,
                                 options.apply_outlier_rejection, options.optimize_calobject_warp);
  Solve(record);
}

// Knots of a splined model reproducing `reference`'s projection over its imager
// with `reference`'s core. The projection is linear in the knots, so one
// least-squares step is exact; a tiny ridge keeps the knots no sample sees at 0.
Eigen::VectorXd FitSplinedIntrinsics(const CameraModel& reference, const std::string& lens_model) {
  const int n_params = LensModelNumParams(lens_model);
  const int nx = 40, ny = 30;
  Eigen::Matrix2Xd q_px(2, nx * ny);
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      q_px.col(j * nx + i) << i * (reference.width_px - 1.0) / (nx - 1),
          j * (reference.height_px - 1.0) / (ny - 1);
    }
  }
  Eigen::Matrix3Xd v;
  Eigen::VectorXd intrinsics = Eigen::VectorXd::Zero(n_params);
  intrinsics.head<4>() = reference.intrinsics.head<4>();
  if (!UnprojectPixels(reference, q_px, &v)) return intrinsics;
  CameraModel splined{lens_model, intrinsics, reference.width_px, reference.height_px};
  Eigen::Matrix2Xd q0;
  Eigen::MatrixXd dq_dintrinsics;
  if (!ProjectPoints(splined, v, &q0, nullptr, &dq_dintrinsics)) return intrinsics;
  const Eigen::MatrixXd A = dq_dintrinsics.rightCols(n_params - 4);
  const Eigen::VectorXd r = Eigen::Map<const Eigen::VectorXd>(q_px.data(), q_px.size()) -
                            Eigen::Map<const Eigen::VectorXd>(q0.data(), q0.size());
  Eigen::MatrixXd AtA = A.transpose() * A;
  AtA.diagonal().array() += 1e-9 * AtA.diagonal().maxCoeff();
  intrinsics.tail(n_params - 4) = AtA.ldlt().solve(A.transpose() * r);
  return intrinsics;
}

std::string Brief(const CalibrationResult& result) {
  std::ostringstream brief;
  brief.precision(3);
  brief << result.camera.lens_model << ": " << result.record.images.size() << " images, rms "
        << result.rms_px << " px, " << result.num_observations_used << " marks used, "
        << result.num_outliers << " outliers";
  return brief.str();
}

}  // namespace

std::string CalibrationOptions::Check() const {
  std::ostringstream what;
  if (!IsValidLensModel(lens_model)) what << "lens_model '" << lens_model << "' is not a configured mrcal lens model; ";
  if (!(focal_length_mm > 0.0)) what << "focal_length_mm must be > 0; ";
  if (!(pixel_pitch_um > 0.0)) what << "pixel_pitch_um must be > 0; ";
  if (width_px <= 0 || height_px <= 0) what << "width_px and height_px must be > 0; ";
  if (min_images < 2) what << "min_images must be >= 2; ";
  return what.str();
}

bool PlatePoseFromHomography(const Eigen::Matrix3Xd& p_plate, const Eigen::Matrix2Xd& q_px,
                             const Eigen::VectorXd& weight, double focal_px,
                             const Eigen::Vector2d& c_px, Vector6d* rt_cam_from_plate) {
  std::vector<Eigen::Vector2d> plate, image;
  for (int m = 0; m < q_px.cols(); ++m) {
    if (!(weight[m] > 0.0)) continue;
    plate.push_back(p_plate.col(m).head<2>());
    image.push_back((q_px.col(m) - c_px) / focal_px);
  }
  const int n = static_cast<int>(plate.size());
  if (n < 4) return false;
  const Eigen::Matrix3d T_plate = NormalizingTransform(plate);
  const Eigen::Matrix3d T_image = NormalizingTransform(image);
  Eigen::MatrixXd A(2 * n, 9);
  for (int k = 0; k < n; ++k) {
    const Eigen::Vector3d x = T_plate * plate[k].homogeneous();
    const Eigen::Vector3d u = T_image * image[k].homogeneous();
    A.row(2 * k) << x.transpose(), 0, 0, 0, -u.x() * x.transpose();
    A.row(2 * k + 1) << 0, 0, 0, x.transpose(), -u.y() * x.transpose();
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeFullV);
  const Eigen::VectorXd h = svd.matrixV().col(8);
  Eigen::Matrix3d H;
  H << h.segment<3>(0).transpose(), h.segment<3>(3).transpose(), h.segment<3>(6).transpose();
  H = T_image.inverse() * H * T_plate;
  // H ~ [r1 r2 t]: scale so the rotation columns are unit, sign so the plate
  // is in front of the camera.
  const double norm = 0.5 * (H.col(0).norm() + H.col(1).norm());
  if (!(norm > 0.0)) return false;
  H /= norm;
  if (H(2, 2) < 0.0) H = -H;
  Eigen::Matrix3d R;
  R << H.col(0), H.col(1), H.col(0).cross(H.col(1));
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd_R(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
  R = svd_R.matrixU() * svd_R.matrixV().transpose();
  if (R.determinant() < 0.0) return false;
  const Eigen::AngleAxisd angle_axis(R);
  rt_cam_from_plate->head<3>() = angle_axis.angle() * angle_axis.axis();
  rt_cam_from_plate->tail<3>() = H.col(2);
  return true;
}

SolveRecord SeedCalibration(const BoardSpec& board,
                            const std::vector<PlateObservation>& observations,
                            const CalibrationOptions& options) {
  if (const std::string what = options.Check(); !what.empty()) {
    throw InputError("calibration options", what);
  }
  SolveRecord record;
  record.board = board;
  record.camera.lens_model = options.lens_model;
  record.camera.width_px = options.width_px;
  record.camera.height_px = options.height_px;
  const double focal_px = options.focal_length_mm / (options.pixel_pitch_um * 1e-3);
  const Eigen::Vector2d c_px(0.5 * (options.width_px - 1), 0.5 * (options.height_px - 1));
  record.camera.intrinsics = Eigen::VectorXd::Zero(LensModelNumParams(options.lens_model));
  record.camera.intrinsics.head<4>() << focal_px, focal_px, c_px.x(), c_px.y();
  const Eigen::Matrix3Xd p_plate = BoardPoints(board);
  for (const PlateObservation& observation : observations) {
    if (!observation.usable) continue;
    ThrowIfMisshapen(board, observation);
    SolveImage image;
    image.image = observation.image;
    image.q_px = observation.q_px;
    image.weight = observation.weight;
    image.outlier.resize(observation.weight.size());
    for (int m = 0; m < observation.weight.size(); ++m) {
      image.outlier[m] = !(observation.weight[m] > 0.0);
    }
    if (!PlatePoseFromHomography(p_plate, image.q_px, image.weight, focal_px, c_px,
                                 &image.rt_cam_from_plate)) {
      continue;
    }
    record.images.push_back(std::move(image));
  }
  return record;
}

CalibrationResult SummarizeSolve(const SolveRecord& record) {
  CalibrationResult result;
  result.record = record;
  result.camera = record.camera;
  result.calobject_warp = record.calobject_warp;
  const mrcal_internal::Problem problem = mrcal_internal::ToProblem(record);
  Eigen::VectorXd x;
  Eigen::SparseMatrix<double, Eigen::RowMajor> J;
  if (!mrcal_internal::EvaluateCallback(problem, &x, &J)) {
    result.brief = "mrcal_optimizer_callback failed";
    return result;
  }
  const int n_marks = record.board.rows * record.board.cols;
  double sum_sq = 0.0;
  for (size_t i = 0; i < record.images.size(); ++i) {
    const SolveImage& image = record.images[i];
    ImageResidual residual;
    residual.image = image.image;
    double image_sum_sq = 0.0;
    for (int m = 0; m < n_marks; ++m) {
      if (image.outlier[m]) {
        if (image.weight[m] > 0.0) ++residual.num_outliers;
        continue;
      }
      image_sum_sq += x.segment<2>(2 * (i * n_marks + m)).squaredNorm();
      ++residual.num_inliers;
    }
    residual.rms_px =
        residual.num_inliers ? std::sqrt(image_sum_sq / (2.0 * residual.num_inliers)) : 0.0;
    sum_sq += image_sum_sq;
    result.num_observations_used += residual.num_inliers;
    result.num_outliers += residual.num_outliers;
    result.per_image.push_back(residual);
    const double angle = image.rt_cam_from_plate.head<3>().norm();
    Eigen::Isometry3d cam_from_plate = Eigen::Isometry3d::Identity();
    if (angle > 0.0) {
      cam_from_plate.linear() =
          Eigen::AngleAxisd(angle, image.rt_cam_from_plate.head<3>() / angle).toRotationMatrix();
    }
    cam_from_plate.translation() = image.rt_cam_from_plate.tail<3>();
    result.cam_from_plate.push_back(cam_from_plate);
  }
  result.rms_px =
      result.num_observations_used ? std::sqrt(sum_sq / (2.0 * result.num_observations_used)) : 0.0;
  result.usable = result.num_observations_used > 0 && std::isfinite(result.rms_px);
  result.brief = Brief(result);
  return result;
}

CalibrationResult RefineCalibration(const CalibrationResult& previous,
                                    const std::vector<PlateObservation>& observations,
                                    const CalibrationOptions& options) {
  if (const std::string what = options.Check(); !what.empty()) {
    throw InputError("calibration options", what);
  }
  SolveRecord record = previous.record;
  for (SolveImage& image : record.images) {
    const auto observation =
        std::find_if(observations.begin(), observations.end(),
                     [&](const PlateObservation& o) { return o.image == image.image; });
    if (observation == observations.end() || !observation->usable) {
      throw InputError(image.image, "RefineCalibration: no usable observation of an image of the "
                                    "earlier solve");
    }
    ThrowIfMisshapen(record.board, *observation);
    image.q_px = observation->q_px;
    image.weight = observation->weight;
    for (int m = 0; m < image.weight.size(); ++m) image.outlier[m] = !(image.weight[m] > 0.0);
  }
  record.problem = StageProblem(!IsSplined(record.camera.lens_model), true,
                                options.apply_regularization, options.apply_outlier_rejection,
                                options.optimize_calobject_warp);
  Solve(&record);
  CalibrationResult result = SummarizeSolve(record);
  result.images_not_used = previous.images_not_used;
  return result;
}

CalibrationResult CalibrateCamera(const BoardSpec& board,
                                  const std::vector<PlateObservation>& observations,
                                  const CalibrationOptions& options) {
  if (const std::string what = options.Check(); !what.empty()) {
    throw InputError("calibration options", what);
  }
  SolveRecord record;
  if (IsSplined(options.lens_model)) {
    CalibrationOptions seed_options = options;
    seed_options.lens_model = kSplinedSeedModel;
    record = SeedCalibration(board, observations, seed_options);
    if (static_cast<int>(record.images.size()) >= options.min_images) {
      SolveStaged(seed_options, true, &record);
      record.camera.intrinsics = FitSplinedIntrinsics(record.camera, options.lens_model);
      record.camera.lens_model = options.lens_model;
      record.problem = StageProblem(false, true, options.apply_regularization,
                                    options.apply_outlier_rejection,
                                    options.optimize_calobject_warp);
      Solve(&record);
    }
  } else {
    record = SeedCalibration(board, observations, options);
    if (static_cast<int>(record.images.size()) >= options.min_images) {
      SolveStaged(options, true, &record);
    }
  }
  CalibrationResult result;
  if (static_cast<int>(record.images.size()) < options.min_images) {
    result.record = record;
    result.brief = "too few usable plate images: " + std::to_string(record.images.size()) +
                   " < " + std::to_string(options.min_images);
  } else {
    result = SummarizeSolve(record);
  }
  for (const PlateObservation& observation : observations) {
    bool used = false;
    for (const SolveImage& image : record.images) used = used || image.image == observation.image;
    if (!used) result.images_not_used.push_back(observation.image);
  }
  return result;
}

}  // namespace omm
