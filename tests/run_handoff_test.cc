// `omm run` hands the mosaic to the measure stage in memory (and writes
// mosaic.png on another thread); `omm measure` alone reads the file back.
// Both must measure the same pixels: on a rendered demo project, the measure
// stage rerun alone on the run's out/ reproduces every feature and
// measurement bit for bit (slow: needs a render). An out/ whose scene is not
// the mosaic's is refused.
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/report_json.h"
#include "pipeline/core/error.h"
#include "pipeline/orchestration/run_project.h"
#include "tests/sim_cache.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

// The rendered demo (seed 101) copied into `dir` and run whole (`omm run`).
fs::path RunDemo(const testing::TempDir& dir) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 101, 14);
  const fs::path project_dir = dir.path() / "demo";
  testing::CopyProject(sim.project_dir, project_dir);
  RunProject(LoadProject(project_dir), RunOptions{});
  return project_dir;
}

// What `stage` run alone on project_dir throws as InputError, or "no error".
std::string ErrorOfStageAlone(const fs::path& project_dir, Stage stage) {
  RunOptions alone;
  alone.stages = {stage};
  try {
    RunProject(LoadProject(project_dir), alone);
  } catch (const InputError& e) {
    return e.what();
  }
  return "no error";
}

TEST(RunHandoff, MeasureAloneReproducesTheRunExactly) {
  testing::TempDir dir;
  const fs::path project_dir = RunDemo(dir);
  const Report run = ReadReportJson(project_dir / "out" / "report.json");
  // The camera the mosaic used is named where it stays (out/), not where the
  // run staged it.
  ASSERT_TRUE(run.mosaic.has_value());
  const std::string* camera = AsString(Member(run.mosaic->extra, "camera"));
  ASSERT_NE(camera, nullptr);
  EXPECT_EQ(*camera, (project_dir / "out" / "camera.cameramodel").string());
  RunOptions measure_only;
  measure_only.stages = {Stage::kMeasure};
  RunProject(LoadProject(project_dir), measure_only);
  const Report alone = ReadReportJson(project_dir / "out" / "report.json");

  ASSERT_TRUE(run.features && alone.features && run.measurements && alone.measurements);
  ASSERT_EQ(run.features->size(), alone.features->size());
  int num_found = 0;
  for (size_t i = 0; i < run.features->size(); ++i) {
    const FeatureReport& a = (*run.features)[i];
    const FeatureReport& b = (*alone.features)[i];
    EXPECT_EQ(a.error, b.error) << a.name;
    EXPECT_EQ(a.centre_mm, b.centre_mm) << a.name;
    EXPECT_EQ(a.diameter_mm, b.diameter_mm) << a.name;
    EXPECT_EQ(a.centre_sigma_mm, b.centre_sigma_mm) << a.name;
    EXPECT_EQ(a.diameter_sigma_mm, b.diameter_sigma_mm) << a.name;
    num_found += a.centre_mm.has_value();
  }
  ASSERT_EQ(run.measurements->size(), alone.measurements->size());
  int num_made = 0;
  for (size_t i = 0; i < run.measurements->size(); ++i) {
    const MeasurementReport& a = (*run.measurements)[i];
    const MeasurementReport& b = (*alone.measurements)[i];
    EXPECT_EQ(a.value_mm, b.value_mm) << a.name;
    EXPECT_EQ(a.sigma_mm, b.sigma_mm) << a.name;
    num_made += a.value_mm.has_value();
  }
  // Not a comparison of two empty lists: the demo's holes are all found.
  EXPECT_EQ(num_found, static_cast<int>(run.features->size()));
  EXPECT_EQ(num_made, static_cast<int>(run.measurements->size()));
}

// `omm run` prepares the mosaic's tiles (PrepareTiles) on other threads
// while it calibrates; `omm mosaic` alone prepares them itself. The calibrate
// stage starts the preparation when the mosaic follows, and the mosaic alone
// on the run's out/ reproduces the run's mosaic, scene and COLMAP model bit
// for bit.
TEST(RunHandoff, MosaicAloneReproducesTheRunsTilesPreparedDuringCalibration) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 101, 14);
  testing::TempDir dir;
  const fs::path project_dir = dir.path() / "demo";
  testing::CopyProject(sim.project_dir, project_dir);
  RunOptions run;
  run.num_threads = 2;
  bool prepared_during_calibration = false;
  run.runner = [&](Stage stage, StageContext& context) {
    RunStage(stage, context);
    if (stage == Stage::kCalibrate) prepared_during_calibration = context.mosaic_tiles.valid();
  };
  RunProject(LoadProject(project_dir), run);
  EXPECT_TRUE(prepared_during_calibration);
  const fs::path out = project_dir / "out";
  const std::vector<fs::path> files = {"mosaic.png",        "mosaic.pgw",
                                       "mosaic/scene.json", "colmap/cameras.txt",
                                       "colmap/images.txt", "colmap/points3D.txt"};
  std::vector<std::string> by_run;
  for (const fs::path& file : files) by_run.push_back(testing::ReadTextFile(out / file));

  RunOptions mosaic_only;
  mosaic_only.stages = {Stage::kMosaic};
  mosaic_only.num_threads = 2;
  RunProject(LoadProject(project_dir), mosaic_only);
  for (size_t k = 0; k < files.size(); ++k) {
    EXPECT_FALSE(by_run[k].empty()) << files[k];
    // Not EXPECT_EQ: a mosaic printed twice would drown the message.
    EXPECT_TRUE(testing::ReadTextFile(out / files[k]) == by_run[k]) << files[k] << " differs";
  }
}

// `omm measure` alone on an out/ that mixes runs (hand-edited, or files
// copied from another run; changed inputs are caught earlier by their hash):
// the tiles alone on the mosaic's grid would be rendered from a scene that
// did not make the mosaic. It names scene.json, says what to do, and leaves
// out/ as it was.
TEST(RunHandoff, MeasureAloneRefusesAMosaicItsSceneDidNotMake) {
  testing::TempDir dir;
  const fs::path project_dir = RunDemo(dir);
  const fs::path report_path = project_dir / "out" / "report.json";
  const auto measure_error = [&] { return ErrorOfStageAlone(project_dir, Stage::kMeasure); };

  // report.json's mosaic moved by ten pixels (a hand edit, or a mix of runs).
  const Report original = ReadReportJson(report_path);
  Report moved = original;
  moved.mosaic->origin_mm.x() += 10 * moved.mosaic->gsd_mm;
  WriteReportJson(report_path, moved);
  const std::string moved_text = testing::ReadTextFile(report_path);
  std::string error = measure_error();
  EXPECT_NE(error.find("scene.json"), std::string::npos) << error;
  EXPECT_NE(error.find("but report.json says"), std::string::npos) << error;
  EXPECT_NE(error.find("rerun `omm mosaic`"), std::string::npos) << error;
  EXPECT_EQ(testing::ReadTextFile(report_path), moved_text);

  // scene.json's first two tiles swapped (a scene from another run).
  WriteReportJson(report_path, original);
  const fs::path scene_path = project_dir / "out" / "mosaic" / "scene.json";
  testing::ReplaceInFile(scene_path, "\"tile_r0c0.png\"", "\"tile_r0c1.png.tmp\"");
  testing::ReplaceInFile(scene_path, "\"tile_r0c1.png\"", "\"tile_r0c0.png\"");
  testing::ReplaceInFile(scene_path, "\"tile_r0c1.png.tmp\"", "\"tile_r0c1.png\"");
  error = measure_error();
  EXPECT_NE(error.find("scene.json: made from the tiles tile_r0c1.png, tile_r0c0.png,"),
            std::string::npos)
      << error;
  EXPECT_NE(error.find("table.csv lists tile_r0c0.png, tile_r0c1.png,"), std::string::npos)
      << error;
  EXPECT_NE(error.find("rerun `omm mosaic`"), std::string::npos) << error;
}

// `omm run` after the CMM's values arrived (cmm.csv added to a measured
// project) reruns the measure stage alone, on the calibration and mosaic in
// out/, and reports the same values as the first run, now with their
// deviations; the one the CMM got 0.1 mm wrong is flagged. A stage run alone does not take an
// earlier stage's outputs whose inputs changed since: after a calibration image was removed, `omm
// mosaic` refuses out/camera.cameramodel and `omm measure` the mosaic, and
// out/ stays as it was.
TEST(RunHandoff, StagesRerunOnlyWhenTheirInputsChanged) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 101, 14);
  testing::TempDir dir;
  const fs::path project_dir = dir.path() / "demo";
  testing::CopyProject(sim.project_dir, project_dir);
  const std::string cmm = testing::ReadTextFile(project_dir / "cmm.csv");
  fs::remove(project_dir / "cmm.csv");
  RunOptions run;
  run.reuse_current_stages = true;
  const RunSummary first = RunProject(LoadProject(project_dir), run);
  ASSERT_EQ(first.stages_run.size(), 3u);

  // One value 0.1 mm off (a typo in the CMM's report): flagged.
  ASSERT_EQ(cmm.rfind("name,value_mm,sigma_mm\ndist_hole_01_hole_14,390.0178,", 0), 0u);
  testing::WriteTextFile(project_dir / "cmm.csv", cmm);
  testing::ReplaceInFile(project_dir / "cmm.csv", ",390.0178,", ",390.1178,");
  const testing::LogCapture log;
  const RunSummary second = RunProject(LoadProject(project_dir), run);
  EXPECT_EQ(second.stages_run, std::vector<Stage>{Stage::kMeasure});
  ASSERT_TRUE(first.report.measurements && second.report.measurements);
  ASSERT_EQ(first.report.measurements->size(), second.report.measurements->size());
  for (size_t i = 0; i < first.report.measurements->size(); ++i) {
    const MeasurementReport& a = (*first.report.measurements)[i];
    const MeasurementReport& b = (*second.report.measurements)[i];
    ASSERT_TRUE(a.value_mm.has_value()) << a.name;
    EXPECT_EQ(a.value_mm, b.value_mm) << a.name;
    EXPECT_EQ(a.sigma_mm, b.sigma_mm) << a.name;
    EXPECT_FALSE(a.cmm_mm.has_value()) << a.name;
    ASSERT_TRUE(b.cmm_mm.has_value() && b.deviation_mm && b.deviation_combined_sigma) << b.name;
    const bool typo = b.name == "dist_hole_01_hole_14";
    EXPECT_EQ(AsBool(Member(b.extra, "beyond_3_sigma")), std::optional<bool>(typo)) << b.name;
    if (typo) {
      EXPECT_NEAR(*b.deviation_mm, -0.1, 0.01);
    }
  }
  // The run's warning judges it against both sigmas.
  EXPECT_NE(log.Text().find("measure: dist_hole_01_hole_14 deviates from the CMM by -0.09"),
            std::string::npos)
      << log.Text();
  EXPECT_NE(log.Text().find("sigma, the CMM's included)"), std::string::npos);

  const fs::path report_path = project_dir / "out" / "report.json";
  const std::string report_before = testing::ReadTextFile(report_path);
  fs::remove(project_dir / "calib" / "calib_01.png");
  const std::string mosaic_error = ErrorOfStageAlone(project_dir, Stage::kMosaic);
  EXPECT_NE(mosaic_error.find("camera.cameramodel: calibrated from other calib/"),
            std::string::npos)
      << mosaic_error;
  EXPECT_EQ(testing::ReadTextFile(report_path), report_before);
  // Nor does the measure stage take the mosaic made with that camera.
  const std::string measure_error = ErrorOfStageAlone(project_dir, Stage::kMeasure);
  EXPECT_NE(measure_error.find("its mosaic is from other inputs"), std::string::npos)
      << measure_error;
  EXPECT_EQ(testing::ReadTextFile(report_path), report_before);
}

// The command line: `omm run` again on an unchanged project keeps every
// stage and `omm run --force` reruns them all (the mosaic's timings are
// new); `omm batch` says which stages of a project it reran after a CMM
// value was dropped, and that it reran none after a comment was added, and
// `omm batch --force` reruns them all (its child runs `omm run --force`).
TEST(RunHandoff, OmmRunKeepsCurrentStagesAndForceRerunsThem) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 101, 14);
  testing::TempDir dir;
  const fs::path project_dir = dir.path() / "demo";
  testing::CopyProject(sim.project_dir, project_dir);
  const fs::path report_path = project_dir / "out" / "report.json";
  const auto mosaic_seconds = [&] {
    const Report report = ReadReportJson(report_path);
    const auto* timings = AsObject(Member(report.mosaic->extra, "timings_s"));
    return timings ? AsNumber(Member(*timings, "total")) : std::nullopt;
  };
  ASSERT_EQ(testing::RunOmm("run " + project_dir.string()).exit_code, 0);
  const std::optional<double> first = mosaic_seconds();
  ASSERT_TRUE(first.has_value());

  const testing::CommandResult again = testing::RunOmm("run " + project_dir.string());
  EXPECT_EQ(again.exit_code, 0) << again.output;
  EXPECT_NE(again.output.find("nothing to run: calibrate, mosaic, measure current"),
            std::string::npos)
      << again.output;
  EXPECT_EQ(mosaic_seconds(), first);

  const testing::CommandResult forced = testing::RunOmm("run --force " + project_dir.string());
  EXPECT_EQ(forced.exit_code, 0) << forced.output;
  EXPECT_NE(forced.output.find("calibrate, mosaic, measure done in"), std::string::npos)
      << forced.output;
  const std::optional<double> second = mosaic_seconds();
  EXPECT_NE(second, first) << "the mosaic stage was not rerun";

  // One CMM value fewer: the batch's child reruns the measure stage alone.
  const std::string cmm = testing::ReadTextFile(project_dir / "cmm.csv");
  const size_t last_line = cmm.rfind('\n', cmm.size() - 2);
  ASSERT_NE(last_line, std::string::npos);
  testing::WriteTextFile(project_dir / "cmm.csv", cmm.substr(0, last_line + 1));
  const testing::CommandResult batch = testing::RunOmm("batch " + project_dir.string());
  EXPECT_EQ(batch.exit_code, 0) << batch.output;
  EXPECT_NE(batch.output.find("ok (reran measure; calibrate, mosaic current)"), std::string::npos)
      << batch.output;
  EXPECT_EQ(mosaic_seconds(), second);

  // A comment added to project.yaml changes the inputs' hash but no stage's:
  // the child runs and keeps every stage.
  testing::WriteTextFile(project_dir / "project.yaml",
                         testing::ReadTextFile(project_dir / "project.yaml") + "# checked\n");
  const testing::CommandResult commented = testing::RunOmm("batch " + project_dir.string());
  EXPECT_EQ(commented.exit_code, 0) << commented.output;
  EXPECT_NE(commented.output.find("ok (all stages current, none rerun)"), std::string::npos)
      << commented.output;
  EXPECT_EQ(mosaic_seconds(), second);

  const testing::CommandResult batch_forced =
      testing::RunOmm("batch --force " + project_dir.string());
  EXPECT_EQ(batch_forced.exit_code, 0) << batch_forced.output;
  EXPECT_NE(batch_forced.output.find(" ok\n"), std::string::npos) << batch_forced.output;
  EXPECT_NE(mosaic_seconds(), second) << "the mosaic stage was not rerun";
}

}  // namespace
}  // namespace omm
