#include "pipeline/mosaic/plane_adjustment.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include "pipeline/core/error.h"
#include "pipeline/mosaic/synthetic_plane.h"

namespace omm {
namespace {

// Raw pixel footprint at the part: 390 mm * 4.485 um / 12 mm (2667 px focal).
constexpr double kMmPerPx = 390.0 / 2667.0;

Eigen::Matrix3d Rotation(const Eigen::Vector3d& r) {
  return Eigen::AngleAxisd(r.norm(), r.normalized()).toRotationMatrix();
}

double RotationErrorRad(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return Eigen::AngleAxisd(Rotation(a).transpose() * Rotation(b)).angle();
}

// The table positions stacked (x0, y0, x1, y1, ...).
Eigen::VectorXd Stack(const std::vector<Eigen::Vector2d>& v) {
  Eigen::VectorXd out(2 * v.size());
  for (size_t i = 0; i < v.size(); ++i) out.segment<2>(2 * i) = v[i];
  return out;
}

// The table-prior-only modes (plane_scene.h, (b)): translation in x, y,
// rotation about Z and scale about the table origin, as columns (2n x 4).
Eigen::MatrixXd SimilarityModes(const std::vector<Eigen::Vector2d>& commanded) {
  Eigen::MatrixXd modes(2 * commanded.size(), 4);
  for (size_t i = 0; i < commanded.size(); ++i) {
    const Eigen::Vector2d c = commanded[i];
    modes.block<2, 4>(2 * i, 0) << 1.0, 0.0, -c.y(), c.x(), 0.0, 1.0, c.x(), c.y();
  }
  return modes;
}

// Per-axis RMS (px) of the pixels at which the adjusted scene puts the truth
// track points against their true pixels, over every tile that sees them.
// The truth points are first mapped into the adjusted part frame by the
// least-squares fit of `dof` = 2 (translation: the origin gauge) or 4 (plus
// rotation and scale: the table-prior-only modes) parameters from truth P to
// adjusted P.
double MosaicRmsPx(const SyntheticPlane& s, const PlaneScene& adjusted, int dof) {
  const Eigen::Index n = s.truth.track_xy_mm.cols();
  // Fit adjusted ~ a + [c -d; d c] truth (c = 1, d = 0 for dof 2).
  Eigen::MatrixXd a(2 * n, dof);
  Eigen::VectorXd b(2 * n);
  for (Eigen::Index k = 0; k < n; ++k) {
    const Eigen::Vector2d p = s.truth.track_xy_mm.col(k);
    a.block(2 * k, 0, 2, 2).setIdentity();
    if (dof == 4) a.block<2, 2>(2 * k, 2) << p.x(), -p.y(), p.y(), p.x();
    b.segment<2>(2 * k) = adjusted.track_xy_mm.col(k) - (dof == 2 ? p : Eigen::Vector2d::Zero());
  }
  const Eigen::VectorXd fit = a.colPivHouseholderQr().solve(b);
  double sum_sq = 0.0;
  int count = 0;
  for (Eigen::Index k = 0; k < n; ++k) {
    const Eigen::Vector2d p = s.truth.track_xy_mm.col(k);
    Eigen::Vector2d mapped = fit.head<2>() + p;
    if (dof == 4) mapped = fit.head<2>() + Eigen::Vector2d(fit[2] * p.x() - fit[3] * p.y(),
                                                           fit[3] * p.x() + fit[2] * p.y());
    for (size_t i = 0; i < s.truth.table_pos_mm.size(); ++i) {
      const Eigen::Vector2d q_true = ProjectPartPoint(s.camera, s.truth, {p.x(), p.y(), 0.0},
                                                      s.truth.table_pos_mm[i]);
      if (q_true.x() < 0 || q_true.y() < 0 || q_true.x() > 1599 || q_true.y() > 1199) continue;
      const Eigen::Vector2d q_adj = ProjectPartPoint(
          s.camera, adjusted, {mapped.x(), mapped.y(), 0.0}, adjusted.table_pos_mm[i]);
      sum_sq += (q_adj - q_true).squaredNorm();
      count += 2;
    }
  }
  return std::sqrt(sum_sq / count);
}

PlaneAdjustment Adjust(const SyntheticPlane& s, const PlaneBundleConfig& config = {}) {
  return AdjustPlaneScene(s.camera, s.input, config, PlaneBundleOptions{});
}

// How many observations each track has.
std::vector<int> ObservationsPerTrack(const PlaneBundleInput& input) {
  std::vector<int> num_obs(input.num_tracks, 0);
  for (const TrackObservation& obs : input.observations) ++num_obs[obs.track];
  return num_obs;
}

// (e) The seed needs no knowledge of the camera's rotation about its axis,
// its tilt or distance; the adjustment converges from it.
TEST(PlaneAdjustment, SeedAndSolveConvergeForAnyRotationAboutTheAxis) {
  for (double rotation_deg : {0.0, 75.0, 150.0, 225.0, 300.0, 359.0}) {
    SyntheticPlaneOptions options;
    options.rotation_about_axis_deg = rotation_deg;
    options.tilt_deg = 5.0;
    options.tilt_azimuth_deg = rotation_deg * 0.7;
    options.distance_mm = 420.0;  // not the nominal 390: the seed must find it
    options.num_tracks = 600;
    const SyntheticPlane s = MakeSyntheticPlane(options);
    const PlaneAdjustment a = Adjust(s);
    SCOPED_TRACE("rotation about the axis " + std::to_string(rotation_deg) + " deg");
    ASSERT_TRUE(a.seed.ok) << a.seed.why_failed;
    // Seed: within the table's noise of the truth (0.02 mm table errors tilt
    // and scale the tile-to-tile motion by ~1e-4).
    EXPECT_NEAR(a.seed.distance_mm, 420.0, 0.01 * 420.0);
    EXPECT_NEAR(a.seed.tilt_deg, 5.0, 0.2);
    // Adjusted: the pose is limited by the table prior's rotation mode,
    // ~0.02 mm / 430 mm = 5e-5 rad (plane_scene.h); 3e-4 rad is 6 sigma.
    ASSERT_TRUE(a.summary.usable) << a.summary.brief;
    EXPECT_LT(RotationErrorRad(a.scene.cam_from_part_r, s.truth.cam_from_part_r), 3e-4);
    // Converged to the noise: sqrt(2) * 0.07 px = 0.099 px for pure noise.
    EXPECT_LT(a.summary.final_rms_px, 0.11);
  }
}

// (e) for a strip: the table moved along one line only (a long part seen in
// one row or one column of tiles, or along a diagonal of the machine). The
// seed reads the plane from that one motion (the tilt from how the image
// motion's size varies over the image) and takes the part frame's Z towards
// the camera, which one motion cannot tell; the adjustment converges from
// it to the scene, not its mirror image. Also with a tile taken twice at
// one place (a pair that moved by 0 says nothing of the motion).
TEST(PlaneAdjustment, AStripOfTilesSeedsAndSolves) {
  struct Strip {
    int cols, rows;
    double angle_deg;
    int repeated_tile;  // taken twice, or -1
  };
  for (const Strip strip : {Strip{3, 1, 0.0, -1}, Strip{1, 3, 0.0, -1}, Strip{4, 1, 30.0, -1},
                            Strip{2, 1, -120.0, -1}, Strip{3, 1, 60.0, 1}}) {
    for (double rotation_deg : {20.0, 200.0}) {
      SyntheticPlaneOptions options;
      options.num_cols = strip.cols;
      options.num_rows = strip.rows;
      options.grid_angle_deg = strip.angle_deg;
      options.repeated_tile = strip.repeated_tile;
      options.rotation_about_axis_deg = rotation_deg;
      options.tilt_deg = 4.0;
      options.tilt_azimuth_deg = 0.7 * rotation_deg + 10.0;
      options.distance_mm = 420.0;
      options.num_tracks = 600;
      const SyntheticPlane s = MakeSyntheticPlane(options);
      const PlaneAdjustment a = Adjust(s);
      SCOPED_TRACE(std::to_string(strip.cols) + " x " + std::to_string(strip.rows) + " at " +
                   std::to_string(strip.angle_deg) + " deg, camera turned " +
                   std::to_string(rotation_deg) + " deg, tile taken twice " +
                   std::to_string(strip.repeated_tile));
      ASSERT_TRUE(a.seed.ok) << a.seed.why_failed;
      EXPECT_NEAR(a.seed.distance_mm, 420.0, 0.01 * 420.0);
      // As from a grid (40 noise draws: 0.009 deg RMS from one motion as
      // from two).
      EXPECT_NEAR(a.seed.tilt_deg, 4.0, 0.2);
      ASSERT_TRUE(a.summary.usable) << a.summary.brief;
      // The table prior holds the rotation about Z to sigma / sqrt(sum of
      // |T_i - mean T|^2) (plane_scene.h): the bound is 6 of that.
      const std::vector<Eigen::Vector2d>& commanded = s.input.commanded_table_pos_mm;
      Eigen::Vector2d mean = Eigen::Vector2d::Zero();
      for (const Eigen::Vector2d& t : commanded) mean += t / static_cast<double>(commanded.size());
      double spread2 = 0.0;
      for (const Eigen::Vector2d& t : commanded) spread2 += (t - mean).squaredNorm();
      const double bound_rad = 6.0 * options.table_sigma_mm / std::sqrt(spread2);
      EXPECT_LT(RotationErrorRad(a.scene.cam_from_part_r, s.truth.cam_from_part_r), bound_rad);
      EXPECT_LT(a.summary.final_rms_px, 0.11);
      // The part's points where the truth has them, up to the similarity the
      // table prior holds (their mirror image fits the images as well).
      EXPECT_LT(MosaicRmsPx(s, a.scene, 4), 0.01);
    }
  }
}

// Two tiles taken at one table position show no motion: nothing to seed
// the plane from, said by name.
TEST(PlaneAdjustment, TilesAtOneTablePositionFailTheSeedByName) {
  SyntheticPlaneOptions options;
  options.num_cols = options.num_rows = 1;
  options.repeated_tile = 0;
  options.num_tracks = 300;
  const PlaneAdjustment a = Adjust(MakeSyntheticPlane(options));
  EXPECT_FALSE(a.seed.ok);
  EXPECT_NE(a.seed.why_failed.find("all taken at one table position"), std::string::npos)
      << a.seed.why_failed;
  EXPECT_FALSE(a.summary.usable);
}

// (a) The images pin every direction of the table positions except the four
// the table prior alone holds, so adjusted - actual must be the projection of
// (commanded - actual) onto those four modes, up to the images' own noise.
TEST(PlaneAdjustment, TablePositionsKeepOnlyThePriorsSimilarityError) {
  const SyntheticPlane s = MakeSyntheticPlane(SyntheticPlaneOptions{});
  const PlaneAdjustment a = Adjust(s);
  ASSERT_TRUE(a.summary.usable) << a.summary.brief;
  const Eigen::VectorXd actual = Stack(s.truth.table_pos_mm);
  const Eigen::VectorXd prior_error = Stack(s.input.commanded_table_pos_mm) - actual;
  const Eigen::VectorXd adjusted_error = Stack(a.scene.table_pos_mm) - actual;
  const Eigen::MatrixXd modes = SimilarityModes(s.input.commanded_table_pos_mm);
  const Eigen::VectorXd expected = modes * modes.colPivHouseholderQr().solve(prior_error);
  // The images' share of the adjusted positions' uncertainty: predicted
  // covariance minus the prior's projected one (sigma^2 P, P the projector).
  const Eigen::MatrixXd projector =
      modes * (modes.transpose() * modes).inverse() * modes.transpose();
  const Eigen::MatrixXd image_cov =
      a.scene.covariance.block(6, 6, 18, 18) -
      s.input.table_sigma_mm * s.input.table_sigma_mm * projector;
  const double image_sigma_mm = std::sqrt(image_cov.diagonal().maxCoeff());
  EXPECT_LT(image_sigma_mm, 0.002);  // the images register tiles to ~1/100 px
  EXPECT_LT((adjusted_error - expected).cwiseAbs().maxCoeff(), 4.0 * image_sigma_mm);
  // And so, as a projection, never worse than commanded; in expectation
  // sqrt(4/18) = 0.47 of it.
  EXPECT_LT(adjusted_error.norm(), prior_error.norm());
  std::cout << "table error RMS: commanded " << prior_error.norm() / std::sqrt(18.0)
            << " mm, adjusted " << adjusted_error.norm() / std::sqrt(18.0)
            << " mm, image-noise sigma " << image_sigma_mm << " mm\n";
}

// (b) Truth points through the adjusted scene against truth, in raw pixels.
TEST(PlaneAdjustment, MosaicAgreesWithTruth) {
  const SyntheticPlane s = MakeSyntheticPlane(SyntheticPlaneOptions{});
  const PlaneAdjustment a = Adjust(s);
  ASSERT_TRUE(a.summary.usable) << a.summary.brief;
  PlaneBundleConfig commanded_only;
  commanded_only.refine_table_positions = false;
  const PlaneAdjustment c = Adjust(s, commanded_only);
  const double adjusted_gauge = MosaicRmsPx(s, a.scene, 2);
  const double adjusted_similarity = MosaicRmsPx(s, a.scene, 4);
  const double commanded_gauge = MosaicRmsPx(s, c.scene, 2);
  std::cout << "mosaic vs truth, per-axis RMS px: commanded positions " << commanded_gauge
            << "; adjusted " << adjusted_gauge << " (origin removed), " << adjusted_similarity
            << " (origin, rotation about Z and scale removed)\n";
  // Predicted RMS of the table-prior-only rotation and scale: each of sigma
  // ~ sigma_table / sqrt(sum |T_i|^2) = 0.02 / 429 = 4.7e-5 times the points'
  // RMS distance from the table origin (~150 mm) = 0.007 mm = 0.048 px: the
  // floor the table prior sets (the plate test lifts it). Beyond it, the
  // tiles agree to the images' noise.
  EXPECT_LT(adjusted_similarity, 0.01);
  EXPECT_LT(adjusted_gauge, 0.6 * commanded_gauge);
  EXPECT_GT(commanded_gauge, 0.08);  // the baseline really is off
}

// (c) The predicted covariance describes the scatter over noise draws (table
// errors and pixel noise redrawn, the scene fixed).
TEST(PlaneAdjustment, CovarianceMatchesScatter) {
  // N = 60 draws of d = 22 parameters (r, t_z, 9 T_i): the mean Mahalanobis
  // chi^2 / d has sd sqrt(2 / (d N)) = 0.039 if the covariance is right; the
  // band [0.85, 1.15] is +-3.8 sd. The pooled normalised errors (1320, within
  // a draw correlated) get the same band on their sd.
  constexpr int kDraws = 60;
  std::vector<int> index = {0, 1, 2, 5};
  for (int k = 6; k < 24; ++k) index.push_back(k);
  const int d = static_cast<int>(index.size());
  double chi2_sum = 0.0, z_sq_sum = 0.0;
  for (int draw = 0; draw < kDraws; ++draw) {
    SyntheticPlaneOptions options;
    options.noise_seed = 1000 + draw;
    options.num_tracks = 600;
    const SyntheticPlane s = MakeSyntheticPlane(options);
    const PlaneAdjustment a = Adjust(s);
    ASSERT_TRUE(a.summary.usable) << a.summary.brief;
    Eigen::VectorXd error(d);
    Eigen::MatrixXd cov(d, d);
    Eigen::VectorXd estimate(24), truth(24);
    estimate << a.scene.cam_from_part_r, a.scene.cam_from_part_t_mm, Stack(a.scene.table_pos_mm);
    truth << s.truth.cam_from_part_r, s.truth.cam_from_part_t_mm, Stack(s.truth.table_pos_mm);
    for (int m = 0; m < d; ++m) {
      error[m] = estimate[index[m]] - truth[index[m]];
      for (int n = 0; n < d; ++n) cov(m, n) = a.scene.covariance(index[m], index[n]);
    }
    chi2_sum += error.dot(cov.ldlt().solve(error));
    z_sq_sum += (error.array() / cov.diagonal().array().sqrt()).square().sum();
  }
  const double mean_chi2_per_dof = chi2_sum / (kDraws * d);
  const double pooled_sd = std::sqrt(z_sq_sum / (kDraws * d));
  std::cout << "mean chi2/dof " << mean_chi2_per_dof << ", pooled normalised sd " << pooled_sd
            << "\n";
  EXPECT_GT(mean_chi2_per_dof, 0.85);
  EXPECT_LT(mean_chi2_per_dof, 1.15);
  EXPECT_GT(pooled_sd, 0.85);
  EXPECT_LT(pooled_sd, 1.15);
}

// (f) The plate as a check of the table's scale: estimated with its own
// scale, it must read 1 + kappa when the table's commands are too long by
// kappa (the scene is in the table's units), and 1 when they are right,
// within its predicted sigma (which includes the table's own random scale,
// ~4.7e-5).
TEST(PlaneAdjustment, PlateScaleAgreesWithTheTables) {
  for (double kappa : {0.0, 3e-4}) {
    SyntheticPlaneOptions options;
    options.with_plate = true;
    options.table_scale_error = kappa;
    const SyntheticPlane s = MakeSyntheticPlane(options);
    PlaneBundleConfig config;
    config.refine_plate_scale = true;
    const PlaneAdjustment a = Adjust(s, config);
    SCOPED_TRACE("table scale error " + std::to_string(kappa));
    ASSERT_TRUE(a.summary.usable) << a.summary.brief;
    ASSERT_EQ(a.scene.plates.size(), 1u);
    const int offset = 6 + 2 * 9;
    const double sigma_scale = std::sqrt(a.scene.covariance(offset + 4, offset + 4));
    const double sigma_height = std::sqrt(a.scene.covariance(offset + 3, offset + 3));
    std::cout << "kappa " << kappa << ": plate scale " << a.scene.plates[0].scale << " +- "
              << sigma_scale << ", height " << a.scene.plates[0].height_mm << " +- "
              << sigma_height << " mm\n";
    EXPECT_LT(sigma_scale, 1e-4);  // sharp enough to see a 3e-4 table error
    EXPECT_NEAR(a.scene.plates[0].scale, 1.0 + kappa, 3.0 * sigma_scale);
    EXPECT_NEAR(a.scene.plates[0].height_mm, options.plate_height_mm, 3.0 * sigma_height);
  }
}

// (f) The plate as a metric reference: with its pitch exact, it pulls a table
// whose scale is wrong towards the truth. The table prior is not told the
// error is systematic, so the result is the information-weighted mean of the
// table's scale (sigma ~4.7e-5) and the plate's (~2.4e-5 alone): about 0.2 of
// the commanded error remains.
TEST(PlaneAdjustment, PlateOfKnownPitchFixesTheScale) {
  SyntheticPlaneOptions options;
  options.with_plate = true;
  options.table_scale_error = 3e-4;
  const SyntheticPlane s = MakeSyntheticPlane(options);
  const PlaneAdjustment a = Adjust(s);
  ASSERT_TRUE(a.summary.usable) << a.summary.brief;
  // Scale of the adjusted table positions against the actual ones.
  const Eigen::VectorXd actual = Stack(s.truth.table_pos_mm);
  const double scale = Stack(a.scene.table_pos_mm).dot(actual) / actual.squaredNorm();
  const double commanded_scale = Stack(s.input.commanded_table_pos_mm).dot(actual) /
                                 actual.squaredNorm();
  std::cout << "table scale vs actual: commanded " << commanded_scale - 1.0
            << ", adjusted with the plate " << scale - 1.0 << "\n";
  EXPECT_NEAR(commanded_scale - 1.0, 3e-4, 1.5e-4);  // 3e-4 plus the random scale
  EXPECT_LT(std::abs(scale - 1.0), 0.5 * std::abs(commanded_scale - 1.0));
}

// (g) A tile without observations is held by its prior alone, and flagged.
TEST(PlaneAdjustment, UnobservedTileIsHeldByItsPriorAndFlagged) {
  SyntheticPlaneOptions options;
  options.empty_tile = 0;  // a corner
  const SyntheticPlane s = MakeSyntheticPlane(options);
  const PlaneAdjustment a = Adjust(s);
  ASSERT_TRUE(a.summary.usable) << a.summary.brief;
  EXPECT_EQ(a.summary.tiles_without_observations, std::vector<int>{0});
  EXPECT_LT((a.scene.table_pos_mm[0] - s.input.commanded_table_pos_mm[0]).norm(), 1e-9);
  const double var = s.input.table_sigma_mm * s.input.table_sigma_mm;
  EXPECT_NEAR(a.scene.covariance(6, 6), var, 1e-6 * var);
  EXPECT_NEAR(a.scene.covariance(7, 7), var, 1e-6 * var);
  EXPECT_LT(a.scene.covariance.block(6, 8, 2, 16).cwiseAbs().maxCoeff(), 1e-6 * var);
}

// Structure: held blocks come back bit-identical; bad input is the caller's.
TEST(PlaneAdjustment, HeldBlocksAreUntouchedAndBadInputThrows) {
  SyntheticPlaneOptions options;
  options.num_tracks = 300;
  const SyntheticPlane s = MakeSyntheticPlane(options);
  PlaneBundleConfig config;
  config.refine_table_positions = false;
  const PlaneAdjustment a = Adjust(s, config);
  ASSERT_TRUE(a.summary.usable) << a.summary.brief;
  for (size_t i = 0; i < 9; ++i) {
    EXPECT_EQ(a.scene.table_pos_mm[i], s.input.commanded_table_pos_mm[i]);
  }
  EXPECT_EQ(a.scene.intrinsics, s.camera.intrinsics);
  EXPECT_EQ(a.scene.cam_from_part_t_mm.head<2>(), Eigen::Vector2d::Zero());  // the gauge
  EXPECT_EQ(a.scene.covariance(3, 3), 0.0);
  EXPECT_EQ(a.summary.num_observations, static_cast<int>(s.input.observations.size()));
  EXPECT_EQ(a.scene.residual_px.cols(), static_cast<Eigen::Index>(s.input.observations.size()));

  PlaneBundleConfig bad;
  bad.refine_intrinsics = true;  // without an information matrix
  EXPECT_THROW(Adjust(s, bad), InputError);
}

// The gauge is a choice: holding one track instead of t_x, t_y changes the
// part-frame origin only. Gauge-invariant quantities (table positions, R)
// agree; the points differ by one common shift.
TEST(PlaneAdjustment, GaugeChoiceMovesOnlyTheOrigin) {
  SyntheticPlaneOptions options;
  options.num_tracks = 600;
  const SyntheticPlane s = MakeSyntheticPlane(options);
  const PlaneAdjustment axis = Adjust(s);
  PlaneBundleConfig config;
  config.gauge = PlaneGauge::kFixedTrack;
  config.gauge_track = 17;
  config.covariance_tracks = {17, 18};
  const PlaneAdjustment fixed = Adjust(s, config);
  ASSERT_TRUE(axis.summary.usable && fixed.summary.usable) << fixed.summary.brief;
  // Both stop at the solver's tolerances, ~1e-7 mm apart: 1e-6 mm is 1e-4 of
  // the positions' sigma and far below any real difference.
  for (size_t i = 0; i < 9; ++i) {
    EXPECT_LT((axis.scene.table_pos_mm[i] - fixed.scene.table_pos_mm[i]).norm(), 1e-6);
  }
  EXPECT_LT(RotationErrorRad(axis.scene.cam_from_part_r, fixed.scene.cam_from_part_r), 1e-8);
  const Eigen::Vector2d shift = fixed.scene.track_xy_mm.col(0) - axis.scene.track_xy_mm.col(0);
  EXPECT_LT(((fixed.scene.track_xy_mm - axis.scene.track_xy_mm).colwise() - shift)
                .cwiseAbs()
                .maxCoeff(),
            1e-6);
  // The held track has zero covariance; its neighbour a proper one.
  ASSERT_EQ(fixed.scene.track_covariance_mm2.size(), 2u);
  EXPECT_EQ(fixed.scene.track_covariance_mm2[0].norm(), 0.0);
  EXPECT_GT(fixed.scene.track_covariance_mm2[1].determinant(), 0.0);
}

// Intrinsics refined under the calibration's prior: the camera handed in is
// the truth plus a draw from that prior; the posterior must be tighter than
// the prior and the truth inside it.
TEST(PlaneAdjustment, IntrinsicsRefinedUnderTheCalibrationPrior) {
  SyntheticPlaneOptions options;
  options.num_tracks = 1500;
  SyntheticPlane s = MakeSyntheticPlane(options);
  Eigen::VectorXd sigma(12);
  sigma << 0.5, 0.5, 0.4, 0.4, 2e-4, 5e-4, 2e-5, 2e-5, 1e-3, 1e-3, 1e-3, 1e-3;
  s.input.intrinsics_information = sigma.array().square().inverse().matrix().asDiagonal();
  CameraModel calibrated = s.camera;
  Eigen::VectorXd draw(12);
  draw << 0.8, -1.2, 0.3, 1.5, -0.4, 0.9, 1.1, -0.7, 0.2, -1.3, 0.6, -0.5;  // N(0,1)-like
  calibrated.intrinsics += sigma.cwiseProduct(draw);
  PlaneBundleConfig config;
  config.refine_intrinsics = true;
  const PlaneAdjustment a = AdjustPlaneScene(calibrated, s.input, config, PlaneBundleOptions{});
  ASSERT_TRUE(a.summary.usable) << a.summary.brief;
  const Eigen::MatrixXd posterior = a.scene.covariance.bottomRightCorner(12, 12);
  for (int k = 0; k < 12; ++k) EXPECT_LE(posterior(k, k), sigma[k] * sigma[k] * (1 + 1e-9));
  const Eigen::VectorXd error = a.scene.intrinsics - s.camera.intrinsics;
  // chi^2 with 12 dof: 99.9 % below 32.9.
  EXPECT_LT(error.dot(posterior.ldlt().solve(error)), 32.9);
  EXPECT_LT(a.summary.final_rms_px, 0.11);
}

// Robust loss: gross mismatches (5-30 px) on 5 % of the tracks seen in >= 3
// tiles must not move the scene. (On a 2-tile track one gross outlier cannot
// be told from its partner: TwoTileMismatchesDoNotStallTheSolve.)
TEST(PlaneAdjustment, GrossOutliersAreDownWeighted) {
  SyntheticPlaneOptions options;
  options.num_tracks = 1500;
  const SyntheticPlane clean = MakeSyntheticPlane(options);
  SyntheticPlane s = clean;
  const std::vector<int> num_obs = ObservationsPerTrack(s.input);
  int num_outliers = 0;
  std::vector<bool> spoiled(s.input.num_tracks, false);
  for (size_t n = 0; n < s.input.observations.size(); ++n) {
    TrackObservation& obs = s.input.observations[n];
    if (num_obs[obs.track] < 3 || spoiled[obs.track] || obs.track % 20 != 0) continue;
    obs.q_px += Eigen::Vector2d(5.0 + n % 25, -3.0);
    spoiled[obs.track] = true;
    ++num_outliers;
  }
  ASSERT_GT(num_outliers, 10);
  const PlaneAdjustment a = Adjust(s);
  const PlaneAdjustment b = Adjust(clean);
  PlaneBundleOptions least_squares;
  least_squares.loss = RobustLoss::kTrivial;
  const PlaneAdjustment c = AdjustPlaneScene(s.camera, s.input, {}, least_squares);
  ASSERT_TRUE(a.summary.usable) << a.summary.brief;
  // Huber at 0.5 px caps each outlier's pull at 0.5 px instead of its 5-30
  // px; these outliers all push one way, the worst case. Per tile, ~1/20 of
  // the observations pull 0.5 px: ~0.025 px = 0.004 mm; least squares moves
  // ~25x more.
  double huber_shift = 0.0, least_squares_shift = 0.0;
  for (size_t i = 0; i < 9; ++i) {
    huber_shift = std::max(huber_shift, (a.scene.table_pos_mm[i] - b.scene.table_pos_mm[i]).norm());
    least_squares_shift =
        std::max(least_squares_shift, (c.scene.table_pos_mm[i] - b.scene.table_pos_mm[i]).norm());
  }
  std::cout << "max table shift by " << num_outliers << " outliers: Huber " << huber_shift
            << " mm, least squares " << least_squares_shift << " mm\n";
  EXPECT_LT(huber_shift, 0.005);
  EXPECT_LT(huber_shift, 0.2 * least_squares_shift);
  int flagged = 0;  // the outliers show in their residuals
  for (Eigen::Index n = 0; n < a.scene.residual_px.cols(); ++n) {
    flagged += a.scene.residual_px.col(n).norm() > 3.0;
  }
  EXPECT_EQ(flagged, num_outliers);
  EXPECT_EQ(a.summary.num_outliers, num_outliers);
  EXPECT_LT(a.summary.inlier_rms_px, 0.11);
}

// A track seen in two tiles whose observations disagree by more than twice
// the loss scale (a mismatch, or a lens model off by a pixel at the image's
// edge, as in lens-mismatch's first solve): with both residuals robust, both
// sat on Huber's linear branch pulling opposite ways, a segment of near-equal
// minima that Levenberg-Marquardt crawled along (100 iterations here, the
// limit). The first observation's residual has no loss: the point is unique.
TEST(PlaneAdjustment, TwoTileMismatchesDoNotStallTheSolve) {
  SyntheticPlaneOptions options;
  options.num_tracks = 1500;
  const SyntheticPlane clean = MakeSyntheticPlane(options);
  SyntheticPlane s = clean;
  const std::vector<int> num_obs = ObservationsPerTrack(s.input);
  std::vector<bool> spoiled(s.input.num_tracks, false);
  int num_spoiled = 0;
  for (TrackObservation& obs : s.input.observations) {
    if (num_obs[obs.track] != 2 || spoiled[obs.track] || obs.track % 10 != 0) continue;
    // 1.2-2.4 px, beyond twice the 0.5 px loss scale; the second observation
    // of the track is left alone.
    const double angle = 0.7 * obs.track;
    obs.q_px += (1.2 + 0.1 * (obs.track % 13)) * Eigen::Vector2d(std::cos(angle), std::sin(angle));
    spoiled[obs.track] = true;
    ++num_spoiled;
  }
  ASSERT_GT(num_spoiled, 20);
  const PlaneAdjustment a = Adjust(s);
  const PlaneAdjustment b = Adjust(clean);
  std::cout << num_spoiled << " two-tile tracks spoiled: " << a.summary.brief
            << "; unspoiled: " << b.summary.iterations << " it\n";
  ASSERT_TRUE(a.summary.usable) << a.summary.brief;  // NO_CONVERGENCE is unusable
  // 2 iterations unspoiled. A spoiled pair's point converges linearly (the
  // loss's weights are re-fitted each iteration): by scale / discrepancy < 1/2
  // per iteration, so the 1e-5 from a first step of ~0.1 mm to the parameter
  // tolerance (~1e-6 mm here) takes at most 17.
  EXPECT_LE(a.summary.iterations, 20);
  // Each pair's pull is capped at the loss scale (0.5 px, ~0.07 mm) per
  // residual and the pulls point every way; 81 of ~1500 tracks. As with the
  // gross outliers above: within 0.005 mm of the unspoiled solve, and the
  // mosaic within the table prior's floor (MosaicAgreesWithTruth).
  double max_shift = 0.0;
  for (size_t i = 0; i < 9; ++i)
    max_shift = std::max(max_shift, (a.scene.table_pos_mm[i] - b.scene.table_pos_mm[i]).norm());
  std::cout << "max table shift " << max_shift << " mm\n";
  EXPECT_LT(max_shift, 0.005);
  EXPECT_LT(MosaicRmsPx(s, a.scene, 4), 0.01);
}

// A reprocessed capture is compared byte for byte: repeated solves of one
// problem agree to the bit, the covariance too. (Ceres' threads summed in
// their order, and it laid out the plate's and the intrinsics' blocks by
// address: the last bits differed from solve to solve.)
TEST(PlaneAdjustment, RepeatedSolvesAgreeToTheBit) {
  SyntheticPlaneOptions options;
  options.num_tracks = 1500;
  options.with_plate = true;
  SyntheticPlane s = MakeSyntheticPlane(options);
  Eigen::VectorXd sigma(12);
  sigma << 0.5, 0.5, 0.4, 0.4, 2e-4, 5e-4, 2e-5, 2e-5, 1e-3, 1e-3, 1e-3, 1e-3;
  s.input.intrinsics_information = sigma.array().square().inverse().matrix().asDiagonal();
  PlaneBundleConfig config;
  config.refine_intrinsics = true;
  const PlaneAdjustment first = Adjust(s, config);
  ASSERT_TRUE(first.summary.usable) << first.summary.brief;
  for (int repeat = 1; repeat <= 3; ++repeat) {
    SCOPED_TRACE("repeat " + std::to_string(repeat));
    const PlaneAdjustment again = Adjust(s, config);
    EXPECT_EQ(again.summary.iterations, first.summary.iterations);
    EXPECT_TRUE(again.scene.cam_from_part_r == first.scene.cam_from_part_r);
    EXPECT_TRUE(again.scene.cam_from_part_t_mm == first.scene.cam_from_part_t_mm);
    EXPECT_TRUE(again.scene.table_pos_mm == first.scene.table_pos_mm);
    EXPECT_TRUE(again.scene.track_xy_mm == first.scene.track_xy_mm);
    ASSERT_EQ(again.scene.plates.size(), 1u);
    EXPECT_EQ(again.scene.plates[0].x_mm, first.scene.plates[0].x_mm);
    EXPECT_EQ(again.scene.plates[0].y_mm, first.scene.plates[0].y_mm);
    EXPECT_EQ(again.scene.plates[0].theta_rad, first.scene.plates[0].theta_rad);
    EXPECT_EQ(again.scene.plates[0].height_mm, first.scene.plates[0].height_mm);
    EXPECT_TRUE(again.scene.intrinsics == first.scene.intrinsics);
    EXPECT_TRUE(again.scene.covariance == first.scene.covariance);
  }
}

}  // namespace
}  // namespace omm
