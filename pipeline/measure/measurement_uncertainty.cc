#include "pipeline/measure/measurement_uncertainty.h"

#include <cassert>
#include <cmath>
#include <numbers>
#include <utility>

#include "pipeline/measure/scene_sensitivity.h"

namespace omm {
namespace {

double QuadraticForm(const Eigen::RowVectorXd& a, const Eigen::MatrixXd& covariance,
                     Eigen::Index begin, Eigen::Index size) {
  if (size <= 0) return 0.0;
  const Eigen::RowVectorXd part = a.segment(begin, size);
  return part * covariance.block(begin, begin, size, size) * part.transpose();
}

double Sqrt(double variance) { return std::sqrt(std::max(variance, 0.0)); }

}  // namespace

std::optional<Eigen::MatrixXd> CircleSceneSensitivity(
    const LensProjection& lens, const PlaneScene& scene, const Eigen::Vector2d& centre_mm,
    double diameter_mm, int width_px, int height_px, double blend_band_px, int num_rim_points) {
  assert(num_rim_points >= 3);
  const auto centre =
      BlendedSceneSensitivity(lens, scene, centre_mm, width_px, height_px, blend_band_px);
  if (!centre) return std::nullopt;
  Eigen::MatrixXd g = Eigen::MatrixXd::Zero(3, centre->cols());
  g.topRows<2>() = *centre;
  for (int m = 0; m < num_rim_points; ++m) {
    const double angle = 2.0 * std::numbers::pi * m / num_rim_points;
    const Eigen::Vector2d direction(std::cos(angle), std::sin(angle));
    const auto rim = BlendedSceneSensitivity(lens, scene, centre_mm + 0.5 * diameter_mm * direction,
                                             width_px, height_px, blend_band_px);
    if (!rim) return std::nullopt;
    g.row(2) += (2.0 / num_rim_points) * direction.transpose() * *rim;
  }
  return g;
}

MeasurementPropagation::MeasurementPropagation(std::vector<CircleFeatureValue> features,
                                               Eigen::MatrixXd scene_covariance,
                                               int intrinsics_index)
    : features_(std::move(features)),
      scene_covariance_(std::move(scene_covariance)),
      intrinsics_index_(intrinsics_index) {
  for ([[maybe_unused]] const CircleFeatureValue& f : features_) {
    assert(f.scene_sensitivity.rows() == 3 &&
           f.scene_sensitivity.cols() == scene_covariance_.rows());
  }
  assert(intrinsics_index_ >= 0 && intrinsics_index_ <= scene_covariance_.rows());
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
  const double scene = n > 0 ? double(a * scene_covariance_ * a.transpose()) : 0.0;
  SigmaBreakdown sigma;
  sigma.calibration_mm =
      Sqrt(QuadraticForm(a, scene_covariance_, intrinsics_index_, n - intrinsics_index_));
  sigma.registration_mm = Sqrt(QuadraticForm(a, scene_covariance_, 0, intrinsics_index_));
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
