#include "pipeline/measure/measurement_uncertainty.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <numbers>
#include <utility>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include "pipeline/core/statistics.h"
#include "pipeline/measure/scene_sensitivity.h"

namespace omm {
namespace {

double Sqrt(double variance) { return std::sqrt(std::max(variance, 0.0)); }

// G from S at the centre and num_rim_points rim points (header comment);
// point_sensitivity(P) is S(P) or nullopt.
template <typename PointSensitivity>
std::optional<Eigen::MatrixXd> CircleSensitivity(const PointSensitivity& point_sensitivity,
                                                 const Eigen::Vector2d& centre_mm,
                                                 double diameter_mm, int num_rim_points) {
  assert(num_rim_points >= 3);
  const std::optional<Eigen::MatrixXd> centre = point_sensitivity(centre_mm);
  if (!centre) return std::nullopt;
  Eigen::MatrixXd g = Eigen::MatrixXd::Zero(3, centre->cols());
  g.topRows<2>() = *centre;
  for (int m = 0; m < num_rim_points; ++m) {
    const double angle = 2.0 * std::numbers::pi * m / num_rim_points;
    const Eigen::Vector2d direction(std::cos(angle), std::sin(angle));
    const auto rim = point_sensitivity(centre_mm + 0.5 * diameter_mm * direction);
    if (!rim) return std::nullopt;
    g.row(2) += (2.0 / num_rim_points) * direction.transpose() * *rim;
  }
  return g;
}

}  // namespace

std::optional<Eigen::MatrixXd> CircleSceneSensitivity(
    const LensProjection& lens, const PlaneScene& scene, const Eigen::Vector2d& centre_mm,
    double diameter_mm, int width_px, int height_px, double blend_band_px, int num_rim_points) {
  return CircleSensitivity(
      [&](const Eigen::Vector2d& p) {
        return BlendedSceneSensitivity(lens, scene, p, width_px, height_px, blend_band_px);
      },
      centre_mm, diameter_mm, num_rim_points);
}

std::optional<Eigen::MatrixXd> TileCircleSceneSensitivity(const LensProjection& lens,
                                                          const PlaneScene& scene, int tile,
                                                          const Eigen::Vector2d& centre_mm,
                                                          double diameter_mm, int num_rim_points) {
  return CircleSensitivity(
      [&](const Eigen::Vector2d& p) { return SceneSensitivity(lens, scene, tile, p); }, centre_mm,
      diameter_mm, num_rim_points);
}

CombinedCircle CombineCircleViews(const std::vector<CircleFeatureValue>& views,
                                  const Eigen::MatrixXd& scene_covariance,
                                  double shared_edge_fraction, double consistency_probability) {
  assert(!views.empty());
  assert(shared_edge_fraction >= 0.0 && shared_edge_fraction < 1.0);
  const int n = static_cast<int>(views.size());
  const Eigen::Index num_theta = views[0].scene_sensitivity.cols();
  // The views stacked: values, edge covariance (header comment), scene sensitivity.
  Eigen::VectorXd x(3 * n);
  Eigen::MatrixXd edge(3 * n, 3 * n), g(3 * n, num_theta);
  std::vector<Eigen::Matrix3d> roots(n);  // C_v^1/2
  for (int v = 0; v < n; ++v) {
    x.segment<3>(3 * v) << views[v].centre_mm, views[v].diameter_mm;
    g.middleRows(3 * v, 3) = views[v].scene_sensitivity;
    roots[v] =
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(views[v].edge_covariance).operatorSqrt();
  }
  for (int v = 0; v < n; ++v) {
    for (int u = 0; u < n; ++u) {
      edge.block<3, 3>(3 * v, 3 * u) =
          u == v ? views[v].edge_covariance
                 : Eigen::Matrix3d(shared_edge_fraction * roots[v] * roots[u]);
    }
  }
  // x = A x_stack, A_v = (sum_u C_u^-1)^-1 C_v^-1.
  Eigen::Matrix3d information = Eigen::Matrix3d::Zero();
  for (const CircleFeatureValue& view : views) information += view.edge_covariance.inverse();
  const Eigen::Matrix3d inverse_information = information.inverse();
  Eigen::MatrixXd a(3, 3 * n);
  for (int v = 0; v < n; ++v)
    a.middleCols<3>(3 * v) = inverse_information * views[v].edge_covariance.inverse();
  CombinedCircle combined;
  CircleFeatureValue& value = combined.value;
  const Eigen::Vector3d mean = a * x;
  value.centre_mm = mean.head<2>();
  value.diameter_mm = mean.z();
  value.edge_covariance = a * edge * a.transpose();
  value.scene_sensitivity = a * g;
  if (n == 1) return combined;

  // The differences from view 0, D x_stack, and their covariance (header comment).
  const int m = 3 * (n - 1);
  Eigen::MatrixXd diff = Eigen::MatrixXd::Zero(m, 3 * n);
  for (int v = 1; v < n; ++v) {
    diff.block<3, 3>(3 * (v - 1), 0) = -Eigen::Matrix3d::Identity();
    diff.block<3, 3>(3 * (v - 1), 3 * v) = Eigen::Matrix3d::Identity();
  }
  const Eigen::VectorXd d = diff * x;
  Eigen::MatrixXd cov = diff * edge * diff.transpose();
  if (scene_covariance.size() > 0) {
    const Eigen::MatrixXd dg = diff * g;
    cov += dg * scene_covariance * dg.transpose();
  }
  // Centres and diameters apart: their disagreements have different causes
  // (the tiles' relative registration; the rim's edges), and one should not
  // inflate the other.
  const auto test = [&](const std::vector<int>& components) {
    ViewAgreement agreement;
    std::vector<Eigen::Index> rows;
    for (int v = 1; v < n; ++v)
      for (const int c : components) rows.push_back(3 * (v - 1) + c);
    const Eigen::VectorXd dv = d(rows);
    agreement.dof = static_cast<int>(rows.size());
    agreement.chi2 = dv.dot(cov(rows, rows).ldlt().solve(dv));
    agreement.consistent =
        agreement.chi2 <= ChiSquareQuantile(consistency_probability, agreement.dof);
    // Views that disagree beyond their covariances carry an error none of
    // them models (registration off between the tiles, a texture flaw on one
    // rim): the mean stays, as no view can be singled out, and the edge
    // covariance grows by the observed scatter (the Birge ratio chi2 / dof),
    // so the sigma covers the disagreement instead of hiding it.
    if (!agreement.consistent) agreement.inflation = agreement.chi2 / agreement.dof;
    return agreement;
  };
  combined.centre = test({0, 1});
  combined.diameter = test({2});
  const Eigen::Vector3d scale(std::sqrt(combined.centre.inflation),
                              std::sqrt(combined.centre.inflation),
                              std::sqrt(combined.diameter.inflation));
  value.edge_covariance = scale.asDiagonal() * value.edge_covariance * scale.asDiagonal();
  return combined;
}

MeasurementPropagation::MeasurementPropagation(std::vector<CircleFeatureValue> features,
                                               Eigen::MatrixXd scene_covariance, ScenePriors priors)
    : features_(std::move(features)),
      scene_covariance_(std::move(scene_covariance)),
      priors_(std::move(priors)) {
  for ([[maybe_unused]] const CircleFeatureValue& f : features_) {
    assert(f.scene_sensitivity.rows() == 3 &&
           f.scene_sensitivity.cols() == scene_covariance_.rows());
  }
  [[maybe_unused]] const Eigen::Index n = scene_covariance_.rows();
  assert(priors_.intrinsics_index >= 0 && priors_.intrinsics_index <= n);
  assert(PlaneSceneCovarianceSize(priors_.num_tiles, 0, 0) <= priors_.intrinsics_index);
  assert(priors_.intrinsics_information.size() == 0 ||
         priors_.intrinsics_information.rows() == n - priors_.intrinsics_index);
  assert(priors_.table_sigma_mm > 0.0 || priors_.num_tiles == 0);
}

SigmaBreakdown MeasurementPropagation::Propagate(const std::vector<FeatureGradient>& terms) const {
  const Eigen::Index n = scene_covariance_.rows();
  Eigen::RowVectorXd a = Eigen::RowVectorXd::Zero(n);
  double edges = 0.0;
  for (const FeatureGradient& term : terms) {
    const CircleFeatureValue& f = features_[term.feature];
    a += term.gradient * f.scene_sensitivity;
    edges += term.gradient * f.edge_covariance * term.gradient.transpose();
  }
  // The sources' parts b' H_s b (header comment).
  const Eigen::VectorXd b = scene_covariance_ * a.transpose();
  const double scene = a.dot(b);
  const int table_index = PlaneSceneCovarianceSize(0, 0, 0);  // T_0, after r and t
  double table = 0.0;
  for (int i = 0; i < priors_.num_tiles; ++i) {
    const std::vector<int>& unprior = priors_.tiles_without_table_prior;
    if (std::find(unprior.begin(), unprior.end(), i) != unprior.end()) continue;
    table += b.segment<2>(table_index + 2 * i).squaredNorm() /
             (priors_.table_sigma_mm * priors_.table_sigma_mm);
  }
  double calibration = 0.0;
  if (priors_.intrinsics_information.size() > 0) {
    const auto b_intrinsics = b.tail(n - priors_.intrinsics_index);
    calibration = b_intrinsics.dot(priors_.intrinsics_information * b_intrinsics);
  }
  SigmaBreakdown sigma;
  sigma.calibration_mm = Sqrt(calibration);
  sigma.table_mm = Sqrt(table);
  sigma.registration_mm = Sqrt(scene - table - calibration);
  sigma.edges_mm = Sqrt(edges);
  sigma.total_mm = Sqrt(scene + edges);
  return sigma;
}

double MeasurementPropagation::Distance(int a, int b, SigmaBreakdown* sigma) const {
  const Eigen::Vector2d delta = features_[a].centre_mm - features_[b].centre_mm;
  const double distance = delta.norm();
  if (sigma) {
    const Eigen::Vector2d u =
        distance > 0.0 ? Eigen::Vector2d(delta / distance) : Eigen::Vector2d::Zero();
    *sigma = Propagate(
        {{a, Eigen::RowVector3d(u.x(), u.y(), 0.0)}, {b, Eigen::RowVector3d(-u.x(), -u.y(), 0.0)}});
  }
  return distance;
}

double MeasurementPropagation::Diameter(int a, SigmaBreakdown* sigma) const {
  if (sigma) *sigma = Propagate({{a, Eigen::RowVector3d(0.0, 0.0, 1.0)}});
  return features_[a].diameter_mm;
}

Eigen::Vector2d MeasurementPropagation::CentreSigma(int a) const {
  return {Propagate({{a, Eigen::RowVector3d(1.0, 0.0, 0.0)}}).total_mm,
          Propagate({{a, Eigen::RowVector3d(0.0, 1.0, 0.0)}}).total_mm};
}

}  // namespace omm
