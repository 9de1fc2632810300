// Values and 1-sigma uncertainties of circle features and of the distances and
// diameters measured between them, by linear propagation of every modelled
// source (design.md, "Measurement"; issue 5, "Uncertainty").
//
// A circle found in the mosaic has centre C = (cx, cy) and diameter D in the
// part frame (mm). Its error has two independent parts:
//  - edges: the edge fit's own noise (circle_measure.h), Cov_edge (3 x 3),
//    independent between features;
//  - scene: the mosaic draws the part where the adjusted scene theta puts it
//    (scene_sensitivity.h), so [cx, cy, D] moves by G d_theta with
//      G = [S(C); (2/M) sum_m e_m' S(C + D/2 e_m)]   (3 x size(theta)),
//    e_m the M rim directions (the fitted diameter is twice the mean radial
//    displacement of the rim), shared between features through Cov(theta),
//    the adjustment's joint covariance of plane pose, table positions and
//    (when refined with the calibration's covariance as prior) intrinsics.
// A value v = f(features) with gradient g_j (1 x 3) per feature j then has
//    Var(v) = a Cov(theta) a' + sum_j g_j Cov_edge,j g_j',   a = sum_j g_j G_j.
// Breakdown by source (reported beside sigma): calibration = a restricted to
// the intrinsics' block of Cov(theta); registration = the plane pose, table
// positions and plates' block; edges. The scene's cross terms between the two
// blocks make calibration^2 + registration^2 + edges^2 differ slightly from
// sigma^2, which includes them.
#pragma once

#include <optional>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/lens_projection.h"
#include "pipeline/core/plane_scene.h"

namespace omm {

struct CircleFeatureValue {
  Eigen::Vector2d centre_mm = Eigen::Vector2d::Zero();
  double diameter_mm = 0.0;
  Eigen::Matrix3d edge_covariance = Eigen::Matrix3d::Zero();  // of (cx, cy, D), mm^2
  Eigen::MatrixXd scene_sensitivity;                          // G: 3 x size(theta), rows cx, cy, D
};

// G of a circle (header comment) through the blended tiles that draw it
// (BlendedSceneSensitivity with the given imager size and blend band), with
// num_rim_points rim directions. nullopt if some point is seen by no tile.
std::optional<Eigen::MatrixXd> CircleSceneSensitivity(
    const LensProjection& lens, const PlaneScene& scene, const Eigen::Vector2d& centre_mm,
    double diameter_mm, int width_px, int height_px, double blend_band_px, int num_rim_points = 8);

struct SigmaBreakdown {
  double total_mm = 0.0;
  double calibration_mm = 0.0;   // intrinsics (0 when they were held)
  double registration_mm = 0.0;  // plane pose, table positions, plates
  double edges_mm = 0.0;         // edge fits
};

// One feature's part in a value: d value / d (cx, cy, D) of feature `feature`.
struct FeatureGradient {
  int feature = 0;
  Eigen::RowVector3d gradient = Eigen::RowVector3d::Zero();
};

class MeasurementPropagation {
 public:
  // scene_covariance: PlaneScene::covariance (size(theta) square, zero rows
  // for parameters held constant); intrinsics_index: where the intrinsics'
  // block starts in it (PlaneSceneCovarianceIntrinsicsIndex).
  MeasurementPropagation(std::vector<CircleFeatureValue> features, Eigen::MatrixXd scene_covariance,
                         int intrinsics_index);

  const std::vector<CircleFeatureValue>& features() const { return features_; }

  // Uncertainty of the value whose gradient is `terms`.
  SigmaBreakdown Propagate(const std::vector<FeatureGradient>& terms) const;

  // Centre-to-centre distance of features a and b, and its uncertainty.
  double Distance(int a, int b, SigmaBreakdown* sigma) const;
  // Diameter of feature a, and its uncertainty.
  double Diameter(int a, SigmaBreakdown* sigma) const;
  // 1-sigma of feature a's centre x and y.
  Eigen::Vector2d CentreSigma(int a) const;

 private:
  std::vector<CircleFeatureValue> features_;
  Eigen::MatrixXd scene_covariance_;
  int intrinsics_index_ = 0;
};

}  // namespace omm
