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
// Breakdown by source (reported beside sigma), into independent parts whose
// squares sum to sigma^2. The adjustment's Cov(theta) is (J'J)^-1 with
//    J'J = H_images + H_table + H_calibration,
// the information of the image observations (tracks, plate marks), of the
// table prior (I / sigma_T^2 on each T_i) and of the calibration's prior on
// the intrinsics. To first order the adjusted theta errs by Cov(theta) times
// the sum of each source's J'W eps, so a's scene variance a Cov(theta) a' =
// b' J'J b, b = Cov(theta) a', splits into the sources' b' H_s b:
// calibration, table, registration (the images: the rest), and edges. Not
// the blocks' marginal a_s Cov_ss a_s': intrinsics and plane distance are
// strongly correlated, and those parts alone exceeded sigma.
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

// The same for a circle drawn by tile `tile` alone (a patch of that tile,
// ortho_patch.h): SceneSensitivity of that tile at the centre and rim.
std::optional<Eigen::MatrixXd> TileCircleSceneSensitivity(const LensProjection& lens,
                                                          const PlaneScene& scene, int tile,
                                                          const Eigen::Vector2d& centre_mm,
                                                          double diameter_mm,
                                                          int num_rim_points = 8);

// One circle measured in several pictures (tiles), combined. Each view v is
// x_v = (cx, cy, D) with edge covariance C_v and scene sensitivity G_v.
// The pictures' noise and sampling are independent, but they show the same
// surface: the texture at the rim moves every view's edges alike. So the
// views' edge errors are modelled as correlated by a `shared_edge_fraction`
// rho: Cov(e_u, e_v) = rho C_u^1/2 C_v^1/2 (u != v; symmetric roots). The
// combination
//     x = sum_v A_v x_v,   A_v = (sum_u C_u^-1)^-1 C_v^-1
// has edge covariance A Cov(e) A' ((sum_u C_u^-1)^-1 for rho = 0) and scene
// sensitivity sum_v A_v G_v (x moves with the views it averages).
//
// Consistency: the differences x_v - x_0 (v >= 1), 3 (n - 1) values, have
// the covariance of the stacked views' edge errors and of the scene's part
// (G_v - G_0) Cov(theta) (G_u - G_0)', mapped through the differences. The
// centres' and the diameters' rows are tested apart, each chi-square
// against its `consistency_probability` quantile; a part whose views
// disagree has its edge covariance (rows and columns) scaled by chi2 / dof.
struct ViewAgreement {
  double chi2 = 0.0;  // of the views' differences (0 for one view)
  int dof = 0;        // (views - 1) x 2 for the centre, x 1 for the diameter
  bool consistent = true;
  double inflation = 1.0;  // chi2 / dof when not consistent, else 1
};

struct CombinedCircle {
  CircleFeatureValue value;
  ViewAgreement centre;
  ViewAgreement diameter;
};

// Preconditions: views non-empty, every edge covariance positive definite,
// scene sensitivities of one size (scene_covariance's, or it is empty),
// shared_edge_fraction in [0, 1), consistency_probability in (0.97575, 1).
CombinedCircle CombineCircleViews(const std::vector<CircleFeatureValue>& views,
                                  const Eigen::MatrixXd& scene_covariance,
                                  double shared_edge_fraction, double consistency_probability);

// total^2 = calibration^2 + registration^2 + table^2 + edges^2.
struct SigmaBreakdown {
  double total_mm = 0.0;
  double calibration_mm = 0.0;   // the calibration's noise (0 when the intrinsics were held)
  double registration_mm = 0.0;  // the noise of the tiles' matches and plate marks
  double table_mm = 0.0;         // the table positions' random errors
  double edges_mm = 0.0;         // edge fits
};

// The adjustment's priors (the information they add to J'J, header comment).
struct ScenePriors {
  int num_tiles = 0;            // T_i in the scene vector
  double table_sigma_mm = 0.0;  // of each commanded coordinate
  std::vector<int> tiles_without_table_prior;  // whose prior the adjustment left out
  // The intrinsics' first index in the scene vector
  // (PlaneSceneCovarianceIntrinsicsIndex) and the calibration prior's
  // information over them (N x N; empty if they were held).
  int intrinsics_index = 0;
  Eigen::MatrixXd intrinsics_information;
};

// One feature's part in a value: d value / d (cx, cy, D) of feature `feature`.
struct FeatureGradient {
  int feature = 0;
  Eigen::RowVector3d gradient = Eigen::RowVector3d::Zero();
};

class MeasurementPropagation {
 public:
  // scene_covariance: PlaneScene::covariance (size(theta) square, zero rows
  // for parameters held constant); priors: the adjustment's that produced it.
  MeasurementPropagation(std::vector<CircleFeatureValue> features, Eigen::MatrixXd scene_covariance,
                         ScenePriors priors);

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
  ScenePriors priors_;
};

}  // namespace omm
