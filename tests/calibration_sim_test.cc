// The calibration stage on simulated projects with known truth (issue 3,
// "Accuracy"): the calibrated camera's projection against the true camera's
// over the whole imager at the working distance (rigid transform fitted,
// adapters/mrcal/projection_diff.h), the rejected images, the lens-model
// choice. Each project is rendered once per build tree (tests/sim_cache.h) and
// calibrated once per test process (ctest runs each TEST in its own).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <map>
#include <memory>
#include <optional>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/mrcal/calibrate.h"
#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/projection_diff.h"
#include "adapters/mrcal/uncertainty.h"
#include "adapters/opencv/image_io.h"
#include "adapters/opencv/opencv_calibration.h"
#include "adapters/project_io/project_reader.h"
#include "pipeline/calibration/calibrate_stage.h"
#include "pipeline/calibration/study.h"
#include "tests/sim_cache.h"

namespace omm {
namespace {

struct Calibrated {
  testing::CachedProject sim;
  Project project;
  CalibrationStageSummary summary;
  double distance_mm = 0.0;
  double truth_diff_px = 0.0;  // calibrated vs true projection, rms over the imager
  // OpenCvTruthDiffPx's, once asked for.
  mutable std::optional<double> opencv_truth_diff_px;
  // At each point of the uncertainty grid, the calibrated projection's
  // distance from the truth (after the rigid fit) over the stated
  // worst-direction 1-sigma there.
  Eigen::VectorXd truth_z;
};

// The RMS of the projects' truth_z, all their grid points pooled.
double PooledRmsZ(const std::vector<const Calibrated*>& calibrated) {
  double sum2 = 0.0;
  Eigen::Index n = 0;
  for (const Calibrated* c : calibrated) {
    sum2 += c->truth_z.squaredNorm();
    n += c->truth_z.size();
  }
  return n > 0 ? std::sqrt(sum2 / static_cast<double>(n)) : 0.0;
}

// One calibration per (preset, seed, images, board) per process.
const Calibrated& Calibrate(const std::string& preset, std::uint64_t seed,
                            int num_calib_images = 20, BoardType board = BoardType::kCaltab) {
  static std::map<std::string, std::unique_ptr<Calibrated>> cache;
  std::unique_ptr<Calibrated>& entry =
      cache[preset + std::to_string(seed) + "-" + std::to_string(num_calib_images) + "-" +
            BoardTypeName(board)];
  if (!entry) {
    entry = std::make_unique<Calibrated>();
    entry->sim = testing::SimulatedCalibration(preset, seed, num_calib_images, board);
    entry->project = LoadProject(entry->sim.project_dir);
    // The simulator's project.yaml names the lens model; these tests exercise
    // the stage's own choice, as for a project.yaml without camera.lens_model.
    entry->project.camera.lens_model.reset();
    std::vector<NamedImage> images;
    for (const auto& path : entry->project.calib_images)
      images.push_back({path.filename().string(), ReadGrayImage(path)});
    entry->summary = RunCalibration(images, *entry->project.board, entry->project.camera, {});
    EXPECT_TRUE(entry->summary.usable) << entry->summary.brief;
    entry->distance_mm = WorkingDistanceMm(entry->summary.result);
    entry->truth_diff_px = ProjectionDiffRms(entry->summary.result.camera,
                                             entry->sim.truth.camera.model, entry->distance_mm);
    if (entry->summary.usable && entry->summary.uncertainty.available) {
      // The error over the stage's uncertainty grid, in its sigmas.
      const UncertaintySummary& u = entry->summary.uncertainty;
      const ProjectionDiff diff =
          FitProjectionDiff(entry->summary.result.camera, entry->sim.truth.camera.model,
                            entry->distance_mm, u.grid_nx, u.grid_ny);
      entry->truth_z = diff.diff_px.cwiseQuotient(u.grid_worst_px);
    }
    std::cout << preset << "-" << seed << ": " << entry->summary.brief
              << "\n  lens: " << entry->summary.lens.why << "\n  bias rounds "
              << entry->summary.bias.rounds << ", rms " << entry->summary.bias.rms_px << " px, max "
              << entry->summary.bias.max_px << " px\n  vs truth at " << entry->distance_mm
              << " mm: " << entry->truth_diff_px << " px rms; " << entry->summary.total_seconds
              << " s (detection " << entry->summary.detection_seconds << " s, lens choice "
              << entry->summary.lens_choice_seconds << " s)\n";
    for (const LensCandidate& candidate : entry->summary.lens.candidates) {
      std::cout << "  candidate " << candidate.lens_model << ": rms " << candidate.rms_px
                << " px, sigma " << candidate.sigma_px << " px\n";
    }
  }
  return *entry;
}

// OpenCV's findCirclesGrid + calibrateCamera of the same images against the
// truth (rms over the imager, px): issue 3's baseline, for dot boards only
// (its findChessboardCorners took 60-150 s on a rendered image with the board
// partly outside it or absent, adapters/opencv/plate_detector.h). Made when
// first asked for: 1.5-2.5 s a project, which the tests that do not compare
// with it need not spend.
double OpenCvTruthDiffPx(const Calibrated& c) {
  if (!c.opencv_truth_diff_px) {
    std::vector<GrayImage> pixels;
    std::vector<std::string> names;
    for (const auto& path : c.project.calib_images) {
      pixels.push_back(ReadGrayImage(path));
      names.push_back(path.filename().string());
    }
    const OpenCvCalibration opencv = OpenCvCalibrate(pixels, names, *c.project.board);
    EXPECT_TRUE(opencv.usable) << opencv.brief;
    c.opencv_truth_diff_px =
        opencv.usable ? ProjectionDiffRms(opencv.camera, c.sim.truth.camera.model, c.distance_mm)
                      : INFINITY;
    std::cout << "  OpenCV: " << opencv.brief << "; vs truth " << *c.opencv_truth_diff_px
              << " px rms (" << opencv.detection_seconds + opencv.solve_seconds << " s)\n";
  }
  return *c.opencv_truth_diff_px;
}

// Our solve of the same bias-corrected observations with a fixed lens model,
// scored against the truth.
double FixedModelTruthDiff(const Calibrated& c, const std::string& lens_model) {
  CalibrationOptions options;
  options.lens_model = lens_model;
  options.focal_length_mm = c.project.camera.focal_length_mm;
  options.pixel_pitch_um = c.project.camera.pixel_pitch_um;
  options.width_px = c.project.image_width_px;
  options.height_px = c.project.image_height_px;
  const CalibrationResult result =
      CalibrateCamera(*c.project.board, c.summary.observations, options);
  EXPECT_TRUE(result.usable) << result.brief;
  const double diff = ProjectionDiffRms(result.camera, c.sim.truth.camera.model, c.distance_mm);
  std::cout << "  fixed " << lens_model << ": rms " << result.rms_px << " px, " << diff
            << " px vs truth\n";
  return diff;
}

TEST(CalibrationOnSimulatedProjects, DemoProjectionMatchesTheTruth) {
  const Calibrated& c = Calibrate("demo", 1);
  ASSERT_TRUE(c.summary.usable);
  EXPECT_LE(c.truth_diff_px, 0.007);
  // Issue 3's "Checked by": at most 0.75x OpenCV's on the same images.
  EXPECT_LE(c.truth_diff_px, 0.75 * OpenCvTruthDiffPx(c));
  // The stage's own uncertainty is of the size of the error it makes.
  EXPECT_TRUE(c.summary.uncertainty.available);
  EXPECT_LT(c.summary.uncertainty.typical_px, 0.02);
}

// The stated projection uncertainty covers the error the calibration makes,
// over the whole imager, the corners the plates never reach included. With
// the worst-direction sigma as the unit, an honest uncertainty gives a
// pooled RMS of at most sqrt(2) (|e|^2 / sigma_max^2 <= chi2 with 2 dof);
// one project's error field is a few random parameters, so a project alone
// scatters widely and the bound is on four pooled. Over demo seeds 1, 2, 5,
// 7, 9, 11 and 13 a project's mean z^2 was 1.55 +- 1.9 (caltab) and
// 1.76 +- 1.05 (chessboard): four pooled stay under ~1.9 in RMS at 97.5 %,
// hence 2. Measured: caltab 0.88, chessboard 1.22 on these seeds; 2.24 for
// the caltab when the lens choice could take OPENCV4 (its extrapolation
// into the corners biased, its sigma there small), 11-42 per project for
// chessboards weighed by the detector's assumed 0.1 px (calibrate_stage.h).
TEST(CalibrationOnSimulatedProjects, StatedUncertaintyCoversTheErrorOverTheImager) {
  for (BoardType board : {BoardType::kCaltab, BoardType::kChessboard}) {
    std::vector<const Calibrated*> calibrated;
    for (std::uint64_t seed : {2, 5, 7, 9}) {
      const Calibrated& c = Calibrate("demo", seed, 20, board);
      ASSERT_TRUE(c.summary.usable) << BoardTypeName(board) << " " << seed;
      ASSERT_TRUE(c.summary.uncertainty.available);
      EXPECT_EQ(c.summary.result.camera.lens_model, "LENSMODEL_OPENCV8") << c.summary.lens.why;
      calibrated.push_back(&c);
    }
    const double rms_z = PooledRmsZ(calibrated);
    std::printf("%s: pooled rms of error / stated sigma %.2f\n", BoardTypeName(board), rms_z);
    EXPECT_LE(rms_z, 2.0) << BoardTypeName(board);
  }
}

// The chessboard is searched in a reduced image first (1600 x 1200 px
// images: a quarter, by default, or at the scale expected_pitch_px gives):
// cornerSubPix at full size then takes the corners to where a search of the
// whole image leads it (up to the board's 180-degree turn, which SB may
// return at one scale and not at another; the calibration takes either).
// Partial and absent boards are refused either way.
TEST(CalibrationOnSimulatedProjects, ChessboardCornersFromAReducedSearchAreTheFullSizeOnes) {
  const testing::CachedProject sim =
      testing::SimulatedProject("demo", 2, 20, false, {}, BoardType::kChessboard);
  const Project project = LoadProject(sim.project_dir);
  PlateDetectionOptions coarse, at_pitch, whole;
  at_pitch.chessboard_min_square_px = 7.0;
  whole.chessboard_min_search_side_px = 1 << 30;
  // Largest corner difference, the turned order (corner i is n - 1 - i) too.
  const auto difference = [](const Eigen::Matrix2Xd& a, const Eigen::Matrix2Xd& b) {
    return std::min((a - b).cwiseAbs().maxCoeff(),
                    (a - b.rowwise().reverse()).cwiseAbs().maxCoeff());
  };
  int num_full = 0, num_at_an_eighth = 0;
  for (const CalibImageTruth& image : sim.truth.calib_images) {
    const GrayImage pixels = ReadGrayImage(sim.project_dir / "calib" / image.image);
    const PlateObservation b = DetectPlate(pixels, *project.board, whole);
    // The squares' size on this image (~50-70 px on the demo), from the
    // whole-image search: with a 7 px minimum the search at that pitch is at
    // an eighth where they are 56 px or more, else at a quarter.
    if (b.usable) {
      at_pitch.expected_pitch_px = (b.q_px.col(1) - b.q_px.col(0)).norm();
      num_at_an_eighth += at_pitch.expected_pitch_px >= 56.0;
    }
    for (const PlateDetectionOptions& options : {coarse, at_pitch}) {
      const PlateObservation a = DetectPlate(pixels, *project.board, options);
      if (image.kind != CalibImageTruth::Kind::kFull) {
        EXPECT_FALSE(a.usable) << image.image;
        EXPECT_FALSE(b.usable) << image.image;
        continue;
      }
      ASSERT_TRUE(a.usable && b.usable) << image.image << ": " << a.why_rejected << b.why_rejected;
      EXPECT_LT(difference(a.q_px, b.q_px), 1e-3) << image.image;
    }
    num_full += b.usable;
  }
  EXPECT_EQ(num_full, 18);
  EXPECT_GT(num_at_an_eighth, 0);
}

// On a lens OPENCV8 cannot represent, the corners' scatter about the
// working OPENCV8 solve is mostly its misfit (~1.6 px): they are weighed
// again by their scatter about the splined model chosen, their noise.
TEST(CalibrationOnSimulatedProjects, LensMismatchChessboardCornersAreWeighedByTheChosenModel) {
  const Calibrated& c = Calibrate("lens-mismatch", 2, 20, BoardType::kChessboard);
  ASSERT_TRUE(c.summary.usable) << c.summary.brief;
  EXPECT_NE(c.summary.result.camera.lens_model.find("SPLINED"), std::string::npos)
      << c.summary.lens.why;
  // Rendered corners scatter by ~0.02 px about the truth (demo seeds 2-13).
  EXPECT_GT(c.summary.corner_sigma_px, 0.0);
  EXPECT_LT(c.summary.corner_sigma_px, 0.05);
  for (const PlateObservation& o : c.summary.observations) {
    if (o.usable) {
      EXPECT_DOUBLE_EQ(o.sigma_px.maxCoeff(), c.summary.corner_sigma_px) << o.image;
    }
  }
}

// A circles grid (the caltab's dots without its frame) calibrates as the
// caltab does from the same poses: the same dots, so the same solve but for
// the dots the frame's edge disturbs (within 1.3 % on demo seeds 1-13), and
// it meets issue 3's bound against OpenCV on its images as the caltab does.
TEST(CalibrationOnSimulatedProjects, CirclesGridCalibratesAsTheCaltab) {
  const Calibrated& circles = Calibrate("demo", 2, 20, BoardType::kCircles);
  const Calibrated& caltab = Calibrate("demo", 2, 20, BoardType::kCaltab);
  ASSERT_TRUE(circles.summary.usable);
  EXPECT_EQ(circles.summary.result.record.images.size(), 18u);
  EXPECT_NEAR(circles.truth_diff_px, caltab.truth_diff_px, 0.05 * caltab.truth_diff_px);
  EXPECT_LE(circles.truth_diff_px, 0.75 * OpenCvTruthDiffPx(circles));
}

TEST(CalibrationOnSimulatedProjects, PartlyVisibleAndPlateAbsentImagesAreRejectedWithReasons) {
  const Calibrated& c = Calibrate("demo", 1);
  std::map<std::string, const PlateObservation*> by_name;
  for (const PlateObservation& o : c.summary.detections) by_name[o.image] = &o;
  int num_not_full = 0;
  for (const CalibImageTruth& image : c.sim.truth.calib_images) {
    ASSERT_TRUE(by_name.count(image.image)) << image.image;
    const PlateObservation& o = *by_name[image.image];
    if (image.kind == CalibImageTruth::Kind::kFull) {
      EXPECT_TRUE(o.usable) << image.image << ": " << o.why_rejected;
    } else {
      ++num_not_full;
      EXPECT_FALSE(o.usable) << image.image << " (" << CalibImageKindName(image.kind) << ")";
      EXPECT_FALSE(o.why_rejected.empty()) << image.image;
    }
  }
  EXPECT_EQ(num_not_full, 2);
}

// The leaner fixed models, which the choice no longer takes, as a baseline.
TEST(CalibrationOnSimulatedProjects, DemoLensChoiceIsNotWorseThanTheBestFixedModel) {
  const Calibrated& c = Calibrate("demo", 1);
  double best = 1e9;
  for (const char* model : {"LENSMODEL_OPENCV4", "LENSMODEL_OPENCV5", "LENSMODEL_OPENCV8"}) {
    best = std::min(best, FixedModelTruthDiff(c, model));
  }
  // "Noise": the chosen model's own projection 1-sigma, typical over the imager.
  EXPECT_LE(c.truth_diff_px, best + c.summary.uncertainty.typical_px)
      << "chose " << c.summary.result.camera.lens_model;
}

TEST(CalibrationOnSimulatedProjects, LensMismatchChoosesASplinedModelSeveralTimesBetter) {
  const Calibrated& c = Calibrate("lens-mismatch", 1);
  ASSERT_TRUE(c.summary.usable);
  EXPECT_NE(c.summary.result.camera.lens_model.find("SPLINED"), std::string::npos)
      << c.summary.lens.why;
  const double opencv5 = FixedModelTruthDiff(c, "LENSMODEL_OPENCV5");
  const double opencv8 = FixedModelTruthDiff(c, "LENSMODEL_OPENCV8");
  // Issue 3's "Checked by": at most 0.3x OpenCV's on such a lens; and our
  // own OPENCV5/8 solves of the same observations do no better than OpenCV.
  EXPECT_LE(c.truth_diff_px, 0.3 * OpenCvTruthDiffPx(c));
  EXPECT_LE(c.truth_diff_px, 0.3 * std::min(opencv5, opencv8));
}

// Few images leave the lens's corners to extrapolation: the splined
// candidate must still solve there (with 14 images, 12 usable, its solve once
// diverged from an OPENCV8 seed, and OPENCV4, then a candidate, was chosen
// at 1.9 px residual sigma).
TEST(CalibrationOnSimulatedProjects, LensMismatchWithFewImagesStillChoosesASplinedModel) {
  const Calibrated& c = Calibrate("lens-mismatch", 103, 14);
  ASSERT_TRUE(c.summary.usable);
  EXPECT_NE(c.summary.result.camera.lens_model.find("SPLINED"), std::string::npos)
      << c.summary.lens.why;
  // Over the whole imager, corners the marks never reached included (these
  // dominate here): still better than OpenCV's and our own OPENCV5 solve (an
  // OPENCV8 fit folds over there: its difference is NaN).
  EXPECT_LT(c.truth_diff_px, OpenCvTruthDiffPx(c));
  EXPECT_LT(c.truth_diff_px, FixedModelTruthDiff(c, "LENSMODEL_OPENCV5"));
}

// Eight images (six usable) of lens-mismatch seed 243 leave the lower left
// of the image without marks: the plate reached x 141..1433 and y 136..981 px
// of 1600 x 1200. The splined model the choice needs there (OPENCV8: 1.48 px
// residual sigma), sized for the marks (26 deg), maps no ray to that corner,
// which the true lens does; the tiles use the whole image. Not widened
// (splined_max_widening 1), the stage must fail and say where the marks
// reached, not hand the mosaic a camera whose border misses the part; with
// the default widening the spline maps the whole border.
TEST(CalibrationOnSimulatedProjects, LensThatTheMarksDoNotCoverToTheCornersIsWidenedOrFails) {
  const testing::CachedProject sim = testing::SimulatedCalibration("lens-mismatch", 243, 8);
  Project project = LoadProject(sim.project_dir);
  project.camera.lens_model.reset();
  std::vector<NamedImage> images;
  for (const auto& path : project.calib_images)
    images.push_back({path.filename().string(), ReadGrayImage(path)});
  CalibrationStageOptions not_widened;
  not_widened.splined_max_widening = 1.0;
  const CalibrationStageSummary summary =
      RunCalibration(images, *project.board, project.camera, not_widened);
  EXPECT_FALSE(summary.usable);
  EXPECT_NE(summary.result.camera.lens_model.find("SPLINED"), std::string::npos);
  EXPECT_NE(summary.brief.find("does not map the whole image"), std::string::npos) << summary.brief;
  EXPECT_NE(summary.brief.find("x 141..1433 and y 136..981 px"), std::string::npos)
      << summary.brief;
  EXPECT_NE(summary.brief.find("widened from 26 to 26 deg; the lens choice widens it up to 1.00"),
            std::string::npos)
      << summary.brief;
  // The true lens maps every border pixel; the calibrated one not.
  Eigen::Matrix2Xd corners(2, 4);
  corners << 0, 1599, 0, 1599, 0, 0, 1199, 1199;
  EXPECT_FALSE(FirstUnmappedPixel(sim.truth.camera.model, corners, 0.01).has_value());
  EXPECT_TRUE(FirstUnmappedPixel(summary.result.camera, corners, 0.01).has_value());

  const CalibrationStageSummary widened =
      RunCalibration(images, *project.board, project.camera, {});
  ASSERT_TRUE(widened.usable) << widened.brief;
  EXPECT_GT(widened.lens.splined_fov_deg, widened.lens.splined_fov_sized_deg);
  EXPECT_FALSE(FirstUnmappedPixel(widened.result.camera, corners, 0.01).has_value());
}

// Lens-mismatch seed 315 (20 images, 18 usable: the plate reached y 1038 of
// 1200 px): the spline sized for the marks (27 deg) folds before the image's
// lower right corner, which the tiles use, and failed the run. Its knot
// field is widened until every border pixel maps: the camera then maps the
// corners the true lens maps, and over the whole imager it is still closer
// to the truth than OpenCV's calibration of the same images.
TEST(CalibrationOnSimulatedProjects, SplineThatLeavesTheBorderUnmappedIsWidened) {
  const Calibrated& c = Calibrate("lens-mismatch", 315);
  ASSERT_TRUE(c.summary.usable) << c.summary.brief;
  EXPECT_NE(c.summary.result.camera.lens_model.find("SPLINED"), std::string::npos);
  EXPECT_GT(c.summary.lens.splined_fov_deg, c.summary.lens.splined_fov_sized_deg);
  EXPECT_LE(c.summary.lens.splined_fov_deg,
            CalibrationStageOptions{}.splined_max_widening * c.summary.lens.splined_fov_sized_deg);
  EXPECT_NE(c.summary.lens.why.find("knot field widened"), std::string::npos) << c.summary.lens.why;
  EXPECT_NE(c.summary.result.camera.lens_model.find("fov_x_deg=" +
                                                    std::to_string(c.summary.lens.splined_fov_deg)),
            std::string::npos);
  Eigen::Matrix2Xd corners(2, 4);
  corners << 0, 1599, 0, 1599, 0, 0, 1199, 1199;
  EXPECT_FALSE(FirstUnmappedPixel(c.summary.result.camera, corners, 0.01).has_value());
  EXPECT_LT(c.truth_diff_px, OpenCvTruthDiffPx(c));
}

// Lens-mismatch seed 341 (20 images): after the lens choice the spline's
// perspective-bias corrections changed by only ~0.57 of the last change a
// round (0.016, 0.011, 0.006, 0.0034, 0.0020, 0.0011, 0.0006 px), and plain
// re-solving took 6 re-solves of the spline after OPENCV8's one. Extrapolated
// from the last two rounds (AndersonStep) they settle in 3. (That fixed
// point's accuracy is the other tests' subject: AndersonStep's tests reach
// known fixed points, and MeasureRun's 35 projects, splined ones included,
// are measured against their truth after the same settle.)
TEST(CalibrationOnSimulatedProjects, SplinedBiasCorrectionsSettleInFewReSolves) {
  const Calibrated& c = Calibrate("lens-mismatch", 341);
  ASSERT_TRUE(c.summary.usable) << c.summary.brief;
  EXPECT_NE(c.summary.result.camera.lens_model.find("SPLINED"), std::string::npos);
  EXPECT_LT(c.summary.bias.last_change_px, CalibrationStageOptions{}.bias_settle_px);
  EXPECT_LE(c.summary.bias.rounds, 4);  // 1 with OPENCV8 + 3 with the spline (7 plain)
}

// Lens-mismatch seed 341 (20 images; the marks reached x 127..1461 and y
// 128..1076 px of 1600 x 1200): beyond the marks mrcal's regularisation pulls
// the spline toward the bare stereographic projection, and over the whole
// imager it was 1.28 px RMS from the truth, OpenCV's calibration 1.00 px.
// Following the OPENCV8 fit where that fit's 1-sigma is the smaller, 0.47 px;
// the marks' projections stay put. (Over 14 lens-mismatch seeds, 281-286 and
// 341-348, the ratio to OpenCV's went from 0.46 to 0.30 on average, 0.19-1.28
// to 0.18-0.47.)
TEST(CalibrationOnSimulatedProjects, SplineBeyondTheMarksFollowsTheWorkingModelsFit) {
  const Calibrated& c = Calibrate("lens-mismatch", 341);
  ASSERT_TRUE(c.summary.usable) << c.summary.brief;
  ASSERT_TRUE(c.summary.lens.extrapolation.applied) << c.summary.lens.extrapolation.why_not;
  CalibrationStageOptions mrcal_only;
  mrcal_only.extrapolate_spline_by_working_model = false;
  const CalibrationStageSummary plain = CalibrateFromDetections(
      c.summary.detections, *c.project.board, c.project.camera, c.project.image_width_px,
      c.project.image_height_px, mrcal_only);
  ASSERT_TRUE(plain.usable) << plain.brief;
  const double plain_diff_px =
      ProjectionDiffRms(plain.result.camera, c.sim.truth.camera.model, c.distance_mm);
  std::cout << "over the imager vs truth: " << c.truth_diff_px << " px, mrcal's extrapolation "
            << plain_diff_px << " px, OpenCV " << OpenCvTruthDiffPx(c) << " px\n";
  EXPECT_LT(c.truth_diff_px, 0.5 * plain_diff_px);
  EXPECT_LT(c.truth_diff_px, 0.6 * OpenCvTruthDiffPx(c));

  // The inlier marks through both cameras, from the same solved poses.
  const Eigen::Matrix3Xd marks = InlierMarksInCamera(c.summary.result);
  Eigen::Matrix2Xd q, q_plain;
  ASSERT_TRUE(ProjectPoints(c.summary.result.camera, marks, &q));
  ASSERT_TRUE(ProjectPoints(plain.result.camera, marks, &q_plain));
  const Eigen::VectorXd change = (q - q_plain).colwise().norm();
  const double max_change_px = change.maxCoeff();
  const double rms_change_px = std::sqrt(change.squaredNorm() / static_cast<double>(change.size()));
  std::cout << "marks moved by " << rms_change_px << " px rms, " << max_change_px
            << " px at most; observed sigma " << c.summary.uncertainty.observed_sigma_px << "\n";
  // Far below the marks' noise: 0.0008 px rms, 0.010 px at most (at the
  // outermost marks, where the spline's own 1-sigma grows).
  EXPECT_LT(rms_change_px, 0.05 * c.summary.uncertainty.observed_sigma_px);
  EXPECT_LT(max_change_px, 0.5 * c.summary.uncertainty.observed_sigma_px);
}

TEST(CalibrationOnSimulatedProjects, ImageCountStudyFindsWhereMoreImagesOnlyAverageNoise) {
  const Calibrated& c = Calibrate("demo", 1);
  const auto uncertainty = CalibrationUncertainty::Compute(c.summary.result.record);
  ASSERT_TRUE(uncertainty);
  const Eigen::VectorXd sigma =
      uncertainty->IntrinsicsCovariance().diagonal().cwiseMax(0.0).cwiseSqrt();
  const ImageCountStudy study =
      StudyImageCount(c.summary.observations, *c.project.board, c.project.camera,
                      c.summary.result.camera, sigma, {});
  ASSERT_TRUE(study.usable) << study.brief;
  std::cout << study.brief << "\n";
  ASSERT_EQ(study.num_images.front(), 3);
  ASSERT_EQ(study.num_images.back(), 18);
  // With 3 images the focal length scatters far more than noise averaging
  // predicts (the rule's premise), and the rule finds a count in between.
  const StudyParameter& f = study.parameters[0];
  ASSERT_EQ(f.name, "fx");
  EXPECT_GT(f.spread[0], 2.0 * f.spread_ideal[0]);
  EXPECT_GT(study.suffices_from, 3);
  EXPECT_LE(study.suffices_from, 16);
}

}  // namespace
}  // namespace omm
