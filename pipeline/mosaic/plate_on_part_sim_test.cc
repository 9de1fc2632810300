// The plate on the part and the intrinsics prior on rendered demo projects
// (the caltab lying on the part; tests/sim_cache.h), against the simulator's
// truth. The camera is calibrated from the project's own calib/ images, so
// the intrinsics prior is the real one (mrcal's covariance of that solve).
//
// Scored: the located marks against their true pixels; the scale of the
// adjusted table positions against the actual ones (least-squares
// similarity), with and without the plate, against the reported sigma; the
// plate's height (truth 0: printed flat) against its sigma; the scale check
// against the table-only scale error; the intrinsics' change under the prior
// in calibration sigmas; scene.json's round trip of the joint covariance.
#include <cmath>
#include <cstdio>
#include <memory>
#include <stdexcept>
#include <utility>

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/uncertainty.h"
#include "adapters/opencv/image_io.h"
#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/scene_json.h"
#include "pipeline/calibration/calibrate_stage.h"
#include "pipeline/mosaic/plate_on_part.h"
#include "pipeline/mosaic/register_tiles.h"
#include "pipeline/mosaic/synthetic_plane.h"
#include "tests/sim_cache.h"

namespace omm {
namespace {

// Seed 2's registration fails at the time of writing (the image-motion
// consensus, not the plate); a failed registration fails the suite's setup.
constexpr int kSeeds[] = {1, 3, 4};

struct Case {
  int seed = 0;
  SimulationTruth truth;
  CameraModel camera;  // calibrated from calib/
  Eigen::MatrixXd intrinsics_covariance;
  IntrinsicsPrior prior;
  TileRegistration registration;
  PlateOnPart plate;
  FinalAdjustment with_plate, without_plate;
  // The plate's height given (project.yaml mosaic.plate_height_mm: 0, the truth).
  PlateOnPart plate_given_height;
  FinalAdjustment with_given_height;
};

Case RunCase(int seed, BoardType board = BoardType::kCaltab) {
  Case c;
  c.seed = seed;
  const testing::CachedProject cached =
      board == BoardType::kCaltab ? testing::SimulatedProject("demo", seed)
                                  : testing::SimulatedProject("demo", seed, 20, false, {}, board);
  c.truth = cached.truth;
  const Project project = LoadProject(cached.project_dir);
  std::vector<NamedImage> calib;
  for (const std::filesystem::path& path : project.calib_images)
    calib.push_back({path.filename().string(), ReadGrayImage(path)});
  const CalibrationStageSummary calibration =
      RunCalibration(calib, *project.board, project.camera, CalibrationStageOptions{});
  EXPECT_TRUE(calibration.usable) << calibration.brief;
  c.camera = calibration.result.camera;
  const std::optional<CalibrationUncertainty> uncertainty =
      CalibrationUncertainty::Compute(calibration.result.record);
  EXPECT_TRUE(uncertainty.has_value());
  c.intrinsics_covariance = uncertainty->IntrinsicsCovariance();
  c.prior = IntrinsicsPriorFromCovariance(c.intrinsics_covariance);

  std::vector<ImageF> tiles;
  std::vector<Eigen::Vector2d> commanded;
  for (const TilePosition& tile : project.tiles) {
    tiles.push_back(ReadGrayImage(project.TilePath(tile.image)).pixels);
    commanded.push_back(tile.table_pos_mm);
  }
  RegisterTilesOptions options;
  options.compute_covariance = false;
  c.registration = RegisterTiles(tiles, commanded, project.table_sigma_mm, c.camera, options);
  if (!c.registration.usable)
    throw std::runtime_error("seed " + std::to_string(seed) + ": " + c.registration.brief);
  c.plate = FindPlateOnPart(tiles, *project.board, c.camera, c.registration.input,
                            c.registration.scene, PlateOnPartOptions{});
  FinalAdjustmentOptions final_options;
  final_options.bundle = options.bundle;
  c.with_plate = AdjustWithPlateAndPrior(c.camera, c.registration.input, c.registration.scene,
                                         c.plate, c.prior, final_options);
  c.without_plate = AdjustWithPlateAndPrior(c.camera, c.registration.input, c.registration.scene,
                                            PlateOnPart{}, c.prior, final_options);
  PlateOnPartOptions given;
  given.height_mm = 0.0;
  c.plate_given_height = FindPlateOnPart(tiles, *project.board, c.camera, c.registration.input,
                                         c.registration.scene, given);
  c.with_given_height =
      AdjustWithPlateAndPrior(c.camera, c.registration.input, c.registration.scene,
                              c.plate_given_height, c.prior, final_options);
  std::printf("seed %d: %s\n  %s (%.2f s)\n  final %s (%.2f s)\n", seed,
              c.registration.brief.c_str(), c.plate.brief.c_str(), c.plate.seconds,
              c.with_plate.summary.brief.c_str(), c.with_plate.seconds);
  return c;
}

class PlateOnPartSim : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    cases_ = new std::vector<Case>;
    for (int seed : kSeeds) cases_->push_back(RunCase(seed));
  }
  static void TearDownTestSuite() { delete cases_; }
  static const std::vector<Case>& Cases() { return *cases_; }

 private:
  static std::vector<Case>* cases_;
};
std::vector<Case>* PlateOnPartSim::cases_ = nullptr;

// The located marks' errors against their true pixels (the truth camera,
// the actual table position, part_from_plate): rms and largest, px.
std::pair<double, double> MarkErrorsPx(const Case& c) {
  double sum_sq = 0, max_px = 0;
  for (const PlateMarkObservation& obs : c.plate.observations) {
    Eigen::Isometry3d part_at_table = Eigen::Isometry3d::Identity();
    part_at_table.translation().head<2>() = c.truth.tiles[obs.tile].actual_mm;
    const Eigen::Vector3d p_cam = c.truth.cam_from_part * part_at_table * *c.truth.part_from_plate *
                                  Eigen::Vector3d(c.plate.marks.mark_uv_mm(0, obs.mark),
                                                  c.plate.marks.mark_uv_mm(1, obs.mark), 0);
    Eigen::Matrix2Xd q;
    EXPECT_TRUE(ProjectPoints(c.truth.camera.model, Eigen::Matrix3Xd(p_cam), &q));
    const double e = (obs.q_px - q.col(0)).norm();
    sum_sq += e * e;
    max_px = std::max(max_px, e);
  }
  return {std::sqrt(sum_sq / c.plate.observations.size()), max_px};
}

// Every located mark (whole plates and marks predicted where the plate is
// cut, perspective bias corrected) against its true pixel.
TEST_F(PlateOnPartSim, MarksAgreeWithTheTruth) {
  for (const Case& c : Cases()) {
    SCOPED_TRACE("seed " + std::to_string(c.seed));
    ASSERT_TRUE(c.plate.found) << c.plate.brief;
    ASSERT_TRUE(c.truth.part_from_plate.has_value());
    EXPECT_GE(c.plate.whole_in_tiles.size(), 1u);
    const auto [rms, max_px] = MarkErrorsPx(c);
    std::printf(
        "seed %d: %zu marks in %zu tiles (whole in %zu): error rms %.4f px, max %.4f px; "
        "largest bias correction %.4f px\n",
        c.seed, c.plate.observations.size(), c.plate.seen_in_tiles.size(),
        c.plate.whole_in_tiles.size(), rms, max_px, c.plate.max_bias_correction_px);
    // Measured 0.0045-0.0063 px rms, 0.013 px at most (the calibration's
    // marks fit to 0.004 px rms): the bounds leave 1.6x and 2.3x for other
    // seeds; an uncorrected perspective bias alone would add up to 0.011 px.
    EXPECT_LT(rms, 0.01);
    EXPECT_LT(max_px, 0.03);
    // The final adjustment weighs the dots by their scatter: the sigma per
    // axis their errors show (rms over two axes), within what the scene's
    // own errors and the estimate's few % add (their floor, 0.01 px, was
    // twice that, and the plate's scale sigma ~1.6 times its errors' spread).
    ASSERT_TRUE(c.with_plate.summary.usable) << c.with_plate.summary.brief;
    std::printf("seed %d: dots weighed by their scatter: sigma %.4f px, truth %.4f px\n", c.seed,
                c.with_plate.mark_sigma_px, rms / std::sqrt(2.0));
    EXPECT_NEAR(c.with_plate.mark_sigma_px, rms / std::sqrt(2.0), 0.25 * rms / std::sqrt(2.0));
  }
}

// The scale of the mosaic: with the plate, the adjusted table positions'
// scale error is within 3 of its reported sigma and within kBoundPpm; the
// plate sharpens the scale several times over the table alone.
TEST_F(PlateOnPartSim, PlateFixesTheScale) {
  // 15 ppm over the demo's ~430 mm diagonal is 6.5 um, 0.045 raw px: inside
  // issue 5's 0.05 raw-px budget for a distance with the scale alone.
  constexpr double kBoundPpm = 15.0;
  for (const Case& c : Cases()) {
    SCOPED_TRACE("seed " + std::to_string(c.seed));
    ASSERT_TRUE(c.with_plate.summary.usable) << c.with_plate.summary.brief;
    ASSERT_TRUE(c.without_plate.summary.usable) << c.without_plate.summary.brief;
    std::vector<Eigen::Vector2d> actual;
    for (const TileTruth& tile : c.truth.tiles) actual.push_back(tile.actual_mm);
    const double with = ScaleErrorPpm(c.with_plate.scene.table_pos_mm, actual);
    const double without = ScaleErrorPpm(c.without_plate.scene.table_pos_mm, actual);
    std::printf("seed %d: scale error with the plate %.2f +- %.2f ppm, without %.2f +- %.2f ppm\n",
                c.seed, with, c.with_plate.scale_sigma_ppm, without,
                c.without_plate.scale_sigma_ppm);
    EXPECT_LT(std::abs(with), 3 * c.with_plate.scale_sigma_ppm);
    EXPECT_LT(std::abs(with), kBoundPpm);
    EXPECT_LT(std::abs(without), 3 * c.without_plate.scale_sigma_ppm);
    EXPECT_LT(c.with_plate.scale_sigma_ppm, 0.25 * c.without_plate.scale_sigma_ppm);
  }
}

// A given height (the truth, 0) is held, and the scale is then a little
// sharper than with the height estimated.
TEST_F(PlateOnPartSim, GivenHeightIsHeld) {
  for (const Case& c : Cases()) {
    SCOPED_TRACE("seed " + std::to_string(c.seed));
    const FinalAdjustment& a = c.with_given_height;
    ASSERT_TRUE(a.summary.usable) << a.summary.brief;
    EXPECT_EQ(c.plate_given_height.height_source, "given");
    EXPECT_EQ(a.plate_height_mm, 0.0);
    EXPECT_EQ(a.plate_height_sigma_mm, 0.0);
    std::vector<Eigen::Vector2d> actual;
    for (const TileTruth& tile : c.truth.tiles) actual.push_back(tile.actual_mm);
    const double error = ScaleErrorPpm(a.scene.table_pos_mm, actual);
    std::printf("seed %d: height given: scale error %.2f +- %.2f ppm (estimated: +- %.2f)\n",
                c.seed, error, a.scale_sigma_ppm, c.with_plate.scale_sigma_ppm);
    EXPECT_LT(std::abs(error), 3 * a.scale_sigma_ppm);
    EXPECT_LE(a.scale_sigma_ppm, c.with_plate.scale_sigma_ppm);
  }
}

// Height (the simulator prints the plate flat: 0) and the scale check.
TEST_F(PlateOnPartSim, HeightAndScaleCheckAgreeWithTheTruth) {
  for (const Case& c : Cases()) {
    SCOPED_TRACE("seed " + std::to_string(c.seed));
    const FinalAdjustment& a = c.with_plate;
    ASSERT_TRUE(a.scale_check.ok);
    std::vector<Eigen::Vector2d> actual;
    for (const TileTruth& tile : c.truth.tiles) actual.push_back(tile.actual_mm);
    const double table_only = ScaleErrorPpm(c.without_plate.scene.table_pos_mm, actual);
    std::printf(
        "seed %d: height %s: %.4f +- %.4f mm; check s-1 %.2f +- %.2f ppm (table-only "
        "scale error %.2f ppm); plate rms %.4f px, %d outliers\n",
        c.seed, c.plate.height_source.c_str(), a.plate_height_mm, a.plate_height_sigma_mm,
        a.scale_check.scale_minus_1_ppm, a.scale_check.sigma_ppm, table_only, a.plate_rms_px,
        a.plate_outliers);
    if (c.plate.seen_in_tiles.size() >= 2) {
      EXPECT_FALSE(c.plate.marks.height_mm.has_value());
      EXPECT_LT(std::abs(a.plate_height_mm), 3 * a.plate_height_sigma_mm);
      EXPECT_LT(a.plate_height_sigma_mm, 0.01);
    } else {
      EXPECT_EQ(a.plate_height_mm, 0.0);
    }
    // s - 1 is the table-only scale error seen against the plate; the two
    // differ by the plate's own noise, the check's variance minus the
    // table-only one.
    const double plate_noise = std::sqrt(std::max(
        0.0, std::pow(a.scale_check.sigma_ppm, 2) - std::pow(c.without_plate.scale_sigma_ppm, 2)));
    EXPECT_NEAR(a.scale_check.scale_minus_1_ppm, table_only, 3 * plate_noise + 1.0);
    EXPECT_LT(std::abs(a.scale_check.scale_minus_1_ppm), 3 * a.scale_check.sigma_ppm);
  }
}

// The intrinsics under the calibration's prior move by at most ~3 of their
// calibration sigmas, the covariance is joint (intrinsics correlated with the
// pose and the table), and scene.json carries it and the prior bit for bit.
TEST_F(PlateOnPartSim, IntrinsicsPriorAndJointCovarianceRoundTrip) {
  for (const Case& c : Cases()) {
    SCOPED_TRACE("seed " + std::to_string(c.seed));
    const FinalAdjustment& a = c.with_plate;
    ASSERT_TRUE(a.intrinsics_refined) << c.prior.why_held;
    const Eigen::VectorXd sigma = c.intrinsics_covariance.diagonal().cwiseSqrt();
    const Eigen::VectorXd change = (a.scene.intrinsics - c.camera.intrinsics).cwiseQuotient(sigma);
    std::printf("seed %d: intrinsics change / calibration sigma: max %.2f\n", c.seed,
                change.cwiseAbs().maxCoeff());
    EXPECT_LT(change.cwiseAbs().maxCoeff(), 3.0);
    const int num_tiles = static_cast<int>(c.truth.tiles.size());
    const int k0 = PlaneSceneCovarianceSize(num_tiles, 1, 0);
    const int n = static_cast<int>(c.camera.intrinsics.size());
    ASSERT_EQ(a.scene.covariance.rows(), k0 + n);
    EXPECT_GT(a.scene.covariance.block(0, k0, k0, n).cwiseAbs().maxCoeff(), 0.0);
    for (int k = 0; k < n; ++k)
      EXPECT_LE(a.scene.covariance(k0 + k, k0 + k), sigma[k] * sigma[k] * 1.001);

    SavedScene saved;
    saved.scene = a.scene;
    saved.scene.track_xy_mm.resize(2, 0);
    for (int i = 0; i < num_tiles; ++i) {
      saved.tile_images.push_back(c.truth.tiles[i].image);
      saved.commanded_table_pos_mm.push_back(c.truth.tiles[i].commanded_mm);
    }
    saved.table_sigma_mm = a.input.table_sigma_mm;
    saved.lens_model = c.camera.lens_model;
    saved.intrinsics_refined = true;
    saved.intrinsics_information = a.input.intrinsics_information;
    const SavedScene back = SceneFromJson(SceneToJson(saved), "test");
    EXPECT_EQ(back.scene.covariance, a.scene.covariance);
    EXPECT_EQ(back.intrinsics_information, a.input.intrinsics_information);
    EXPECT_EQ(back.scene.intrinsics, a.scene.intrinsics);
    EXPECT_EQ(back.scene.plates[0].height_mm, a.scene.plates[0].height_mm);
    EXPECT_TRUE(back.intrinsics_refined);
  }
}

// A chessboard on the part, whole in one tile: its corners are followed into
// the tiles that cut it (cornerSubPix from the registered scene's
// prediction), so that its height is estimated and its pitch sets the scale;
// whole in one tile alone it could only check the table's (demo seed 2 with
// a chessboard, rendered as the caltab's demo).
TEST(PlateOnPartChessboard, CornersFollowedWhereTilesCutItSetTheScale) {
  const Case c = RunCase(2, BoardType::kChessboard);
  ASSERT_TRUE(c.plate.found) << c.plate.brief;
  ASSERT_EQ(c.plate.whole_in_tiles.size(), 1u);
  EXPECT_GE(c.plate.seen_in_tiles.size(), 2u);
  EXPECT_TRUE(c.plate.scale_reference);
  const auto [rms, max_px] = MarkErrorsPx(c);
  std::printf("%zu corners in %zu tiles: error rms %.4f px, max %.4f px\n",
              c.plate.observations.size(), c.plate.seen_in_tiles.size(), rms, max_px);
  // Well inside the detector's assumed sigma (PlateDetectionOptions::
  // chessboard_sigma_px, 0.1 px).
  EXPECT_LT(rms, 0.05);
  EXPECT_LT(max_px, 0.1);
  ASSERT_TRUE(c.with_plate.summary.usable) << c.with_plate.summary.brief;
  // The final adjustment weighs them by their scatter instead: the sigma per
  // axis their errors against the truth show (rms over two axes), within
  // what the scene's own errors and the estimate's ~5 % add.
  const double truth_sigma_px = rms / std::sqrt(2.0);
  std::printf("corners weighed by their scatter: sigma %.4f px, truth %.4f px\n",
              c.with_plate.mark_sigma_px, truth_sigma_px);
  EXPECT_NEAR(c.with_plate.mark_sigma_px, truth_sigma_px, 0.25 * truth_sigma_px);
  std::vector<Eigen::Vector2d> actual;
  for (const TileTruth& tile : c.truth.tiles) actual.push_back(tile.actual_mm);
  const double with = ScaleErrorPpm(c.with_plate.scene.table_pos_mm, actual);
  std::printf("scale error with the chessboard %.2f +- %.2f ppm, without %.2f ppm sigma\n", with,
              c.with_plate.scale_sigma_ppm, c.without_plate.scale_sigma_ppm);
  EXPECT_LT(std::abs(with), 3 * c.with_plate.scale_sigma_ppm);
  EXPECT_LT(c.with_plate.scale_sigma_ppm, c.without_plate.scale_sigma_ppm);
}

// The plate lying on the part (the demo preset's), searched for in every tile
// at the pitch PlatePitchOnPartPx gives for the true scene, as
// FindPlateOnPart does with the registered one: that pitch is the marks'
// spacing the tile shows (within the tilt's and the lens's few percent), and
// the plate is found in the same tiles, at the same marks, as by a search
// without it (the whole tile too, for the chessboard), and refused in the
// others, with a chessboard and a circles grid.
TEST(PlateOnPartPitch, PlateAtItsExpectedPitchIsFoundAsWithout) {
  for (BoardType board_type : {BoardType::kChessboard, BoardType::kCircles}) {
    SCOPED_TRACE(BoardTypeName(board_type));
    const testing::CachedProject sim =
        testing::SimulatedProject("demo", 2, 20, false, {}, board_type);
    const Project project = LoadProject(sim.project_dir);
    const BoardSpec& board = *project.board;
    PlaneScene scene;
    const Eigen::AngleAxisd rotation(sim.truth.cam_from_part.rotation());
    scene.cam_from_part_r = rotation.angle() * rotation.axis();
    scene.cam_from_part_t_mm = sim.truth.cam_from_part.translation();
    PlateDetectionOptions at_pitch, without;
    at_pitch.expected_pitch_px = PlatePitchOnPartPx(board, sim.truth.camera.model, scene);
    without.chessboard_min_search_side_px = 1 << 30;
    int num_found = 0;
    for (const TilePosition& tile : project.tiles) {
      const GrayImage pixels = ReadGrayImage(project.TilePath(tile.image));
      const PlateObservation a = DetectPlate(pixels, board, at_pitch);
      const PlateObservation b = DetectPlate(pixels, board, without);
      ASSERT_EQ(a.usable, b.usable)
          << tile.image << ": " << a.why_rejected << " / " << b.why_rejected;
      if (!a.usable) continue;
      ++num_found;
      const Eigen::Matrix2Xd& q = b.q_px;
      EXPECT_NEAR((q.col(1) - q.col(0)).norm() / at_pitch.expected_pitch_px, 1.0, 0.05)
          << tile.image;
      EXPECT_LT(std::min((a.q_px - q).cwiseAbs().maxCoeff(),
                         (a.q_px - q.rowwise().reverse()).cwiseAbs().maxCoeff()),
                1e-3)
          << tile.image;
    }
    EXPECT_GE(num_found, 1);
  }
}

}  // namespace
}  // namespace omm
