#include "pipeline/orchestration/run_project.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <future>
#include <memory>
#include <thread>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "adapters/opencv/image_io.h"
#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/report_json.h"
#include "pipeline/core/error.h"
#include "pipeline/orchestration/input_hash.h"
#include "pipeline/orchestration/stage.h"
#include "pipeline/orchestration/version.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;
using ::testing::HasSubstr;

namespace omm {
namespace {

class RunProjectTest : public ::testing::Test {
 protected:
  void SetUp() override {
    testing::WriteTinyProject(testing::TinyProject(dir_.path() / "job"));
    project_ = LoadProject(dir_.path() / "job");
  }

  fs::path Out(const std::string& name) const { return project_.OutDir() / name; }

  // Leftover staging directories in out/.
  int StagingDirs() const {
    int count = 0;
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(project_.OutDir(), ec)) {
      count += entry.path().filename().string().rfind(".staging-", 0) == 0;
    }
    return count;
  }

  testing::TempDir dir_;
  Project project_;
};

// A stand-in for the real stages: each writes a file and fills its section.
void FakeStage(Stage stage, StageContext& context, const std::string& content) {
  switch (stage) {
    case Stage::kCalibrate:
      testing::WriteTextFile(context.staging_dir / "camera.cameramodel", content);
      context.report.calibration = CalibrationReport{"LENSMODEL_OPENCV8", 0.1, 2, {}, {}};
      break;
    case Stage::kMosaic: {
      // The calibration is read through Input(): this run's or out/'s.
      EXPECT_FALSE(context.Input("camera.cameramodel").empty());
      testing::WriteTextFile(context.staging_dir / "mosaic.png", content);
      testing::WriteTextFile(context.staging_dir / kSceneName, content);
      context.report.mosaic = MosaicReport{};
      context.report.mosaic->file = "mosaic.png";
      break;
    }
    case Stage::kMeasure: {
      MeasurementReport made;
      made.name = "A_to_B";
      made.value_mm = 202.6;
      context.report.measurements = std::vector<MeasurementReport>{made};
      break;
    }
  }
}

// Every image the stages see (calib/ and tiles/, decoded by LoadProject or
// read from its file) is linearized with camera.gamma: the tiny project's
// 128 / 255 gray at gamma 0.5 is its square.
TEST_F(RunProjectTest, ProjectImagesAreLinearizedWithTheCameraGamma) {
  const float stored = 128.0f / 255.0f;
  const fs::path& calib = project_.calib_images.front();
  const fs::path tile = project_.TilePath(project_.tiles.front().image);
  EXPECT_FLOAT_EQ(ProjectGrayImage(project_, nullptr, calib).pixels(0, 0), stored);
  project_.camera.gamma = 0.5;
  EXPECT_FLOAT_EQ(ProjectGrayImage(project_, nullptr, calib).pixels(0, 0), stored * stored);
  EXPECT_FLOAT_EQ(ProjectGrayImage(project_, nullptr, tile).pixels(0, 0), stored * stored);
  ASSERT_TRUE(project_.images);
  EXPECT_FLOAT_EQ(
      ProjectGrayImage(project_, project_.images->calib.front().image.get(), calib).pixels(0, 0),
      stored * stored);
}

// 12-bit samples in a 16-bit file are read over 4095: full scale is 1
// exactly, as saturation is told.
TEST_F(RunProjectTest, ProjectImagesAreScaledToTheirSamplesBits) {
  StoredImage image{2, 1, 16, std::vector<std::uint8_t>(4)};
  const std::uint16_t samples[2] = {4095, 2048};
  std::memcpy(image.samples.data(), samples, sizeof(samples));
  project_.sample_bits = 12;
  const ImageF pixels = ProjectGrayImage(project_, &image, "twelve.png").pixels;
  EXPECT_EQ(pixels(0, 0), 1.0f);
  EXPECT_FLOAT_EQ(pixels(0, 1), 2048.0f / 4095.0f);
  project_.sample_bits = 16;
  EXPECT_FLOAT_EQ(ProjectGrayImage(project_, &image, "twelve.png").pixels(0, 0),
                  4095.0f / 65535.0f);
}

// A run given the project (moved in) frees the images LoadProject decoded
// as soon as no later stage reads them: each calib image once the
// calibration has searched it, the tiles once the mosaic stage has their
// gray images (on 2 threads the calibration starts the mosaic's
// preparation after its search; it converts the tiles but keeps none).
TEST_F(RunProjectTest, DecodedImagesAreFreedOnceNoLaterStageReadsThem) {
  for (const int num_threads : {1, 2}) {
    SCOPED_TRACE(num_threads);
    Project moved = LoadProject(project_.dir);
    ASSERT_TRUE(moved.images);
    std::vector<std::weak_ptr<const StoredImage>> calib, tiles;
    for (const LoadedImage& image : moved.images->calib) calib.push_back(image.image);
    for (const LoadedImage& image : moved.images->tiles) tiles.push_back(image.image);
    const auto num_freed = [](const std::vector<std::weak_ptr<const StoredImage>>& images) {
      return static_cast<size_t>(
          std::count_if(images.begin(), images.end(), [](const auto& i) { return i.expired(); }));
    };
    RunOptions options;
    options.num_threads = num_threads;
    options.runner = [&](Stage stage, StageContext& context) {
      switch (stage) {
        case Stage::kCalibrate:
          EXPECT_EQ(num_freed(calib), 0u);
          EXPECT_EQ(context.calib_decoded.size(), calib.size());
          // The real calibration: it finds no plate in the tiny project's
          // images, but has searched each of them.
          EXPECT_THROW(RunOptions{}.runner(stage, context), StageFailedError);
          EXPECT_EQ(num_freed(calib), calib.size());
          EXPECT_EQ(num_freed(tiles), 0u);
          EXPECT_EQ(context.mosaic_tiles.valid(), num_threads > 1);
          break;
        case Stage::kMosaic:
          EXPECT_EQ(num_freed(tiles), 0u);
          context.tiles = std::make_shared<const std::vector<ImageF>>();
          break;
        case Stage::kMeasure: EXPECT_EQ(num_freed(tiles), tiles.size()); break;
      }
      FakeStage(stage, context, "v1");
    };
    RunProject(std::move(moved), options);
  }
  // Without the calibration, no stage reads the calib images.
  Project moved = LoadProject(project_.dir);
  std::vector<std::weak_ptr<const StoredImage>> calib;
  for (const LoadedImage& image : moved.images->calib) calib.push_back(image.image);
  RunOptions options;
  options.stages = {Stage::kMosaic, Stage::kMeasure};
  options.runner = [&](Stage stage, StageContext& context) {
    EXPECT_TRUE(context.calib_decoded.empty());
    for (const auto& image : calib) EXPECT_TRUE(image.expired());
    FakeStage(stage, context, "v1");
  };
  RunProject(std::move(moved), options);
}

TEST_F(RunProjectTest, FailedStageStopsTheRunAndLeavesNoOut) {
  try {
    RunProject(project_, RunOptions{});  // the tiny project's calib images are plain gray
    FAIL() << "the run passed a failed stage";
  } catch (const StageFailedError& e) {
    EXPECT_EQ(e.stage(), Stage::kCalibrate);
    EXPECT_THAT(e.what(), ::testing::HasSubstr("plate not found"));
  }
  EXPECT_FALSE(fs::exists(project_.OutDir()));
}

TEST_F(RunProjectTest, SuccessfulRunCommitsOutputsAndReport) {
  RunOptions options;
  options.runner = [](Stage stage, StageContext& context) { FakeStage(stage, context, "v1"); };
  const RunSummary summary = RunProject(project_, options);
  EXPECT_EQ(summary.report_path, Out("report.json"));
  EXPECT_EQ(summary.stages_run.size(), 3u);
  EXPECT_EQ(testing::ReadTextFile(Out("camera.cameramodel")), "v1");
  EXPECT_EQ(testing::ReadTextFile(Out("mosaic.png")), "v1");
  EXPECT_NE(testing::ReadTextFile(Out("measurements.csv")).find("\ntiny,A_to_B,"),
            std::string::npos);
  EXPECT_TRUE(fs::exists(Out("features.csv")));
  const Report report = ReadReportJson(Out("report.json"));
  EXPECT_EQ(report.project, "tiny");
  EXPECT_EQ(report.software_version, SoftwareVersion());
  EXPECT_EQ(report.inputs_sha256, HashProjectInputs(project_));
  EXPECT_TRUE(report.calibration && report.mosaic && report.measurements);
  EXPECT_EQ(StagingDirs(), 0);
  EXPECT_TRUE(ReportIsCurrent(project_));
}

TEST_F(RunProjectTest, FailureKeepsTheEarlierOutputsExactly) {
  RunOptions options;
  options.runner = [](Stage stage, StageContext& context) { FakeStage(stage, context, "v1"); };
  RunProject(project_, options);
  const std::string report_before = testing::ReadTextFile(Out("report.json"));

  // The second run writes new outputs in calibrate, then fails in mosaic.
  options.runner = [](Stage stage, StageContext& context) {
    FakeStage(stage, context, "v2");
    if (stage == Stage::kMosaic) throw StageFailedError(stage, "tiles do not overlap");
  };
  EXPECT_THROW(RunProject(project_, options), StageFailedError);
  EXPECT_EQ(testing::ReadTextFile(Out("report.json")), report_before);
  EXPECT_EQ(testing::ReadTextFile(Out("camera.cameramodel")), "v1");
  EXPECT_EQ(testing::ReadTextFile(Out("mosaic.png")), "v1");
  EXPECT_EQ(StagingDirs(), 0);
}

// The progress callback hears once more after the last stage, before out/
// is replaced: what it throws then (a stop asked late) leaves the earlier
// outputs as they were.
TEST_F(RunProjectTest, AStopAfterTheLastStageKeepsTheEarlierOutputs) {
  RunOptions options;
  options.runner = [](Stage stage, StageContext& context) { FakeStage(stage, context, "v1"); };
  RunProject(project_, options);
  const std::string report_before = testing::ReadTextFile(Out("report.json"));

  struct Stop {};
  options.runner = [](Stage stage, StageContext& context) { FakeStage(stage, context, "v2"); };
  options.progress = [](int, int, const std::string&) { throw Stop{}; };
  EXPECT_THROW(RunProject(project_, options), Stop);
  EXPECT_EQ(testing::ReadTextFile(Out("report.json")), report_before);
  EXPECT_EQ(testing::ReadTextFile(Out("camera.cameramodel")), "v1");
  EXPECT_EQ(StagingDirs(), 0);
}

// A file a stage leaves to a background thread is in out/ once the run
// returns, however late it is written; if its write fails, the run fails and
// out/ keeps the earlier outputs.
TEST_F(RunProjectTest, BackgroundWritesAreCommittedOrFailTheRun) {
  RunOptions options;
  options.runner = [](Stage stage, StageContext& context) {
    FakeStage(stage, context, "v1");
    if (stage != Stage::kMosaic) return;
    const fs::path path = context.staging_dir / "mosaic.png";
    context.pending_writes.push_back(std::async(std::launch::async, [path] {
      std::this_thread::sleep_for(std::chrono::milliseconds(300));
      testing::WriteTextFile(path, "written late");
    }));
  };
  RunProject(project_, options);
  EXPECT_EQ(testing::ReadTextFile(Out("mosaic.png")), "written late");
  const std::string report_before = testing::ReadTextFile(Out("report.json"));

  options.runner = [](Stage stage, StageContext& context) {
    FakeStage(stage, context, "v2");
    if (stage != Stage::kMosaic) return;
    context.pending_writes.push_back(std::async(
        std::launch::async, [] { throw InputError("out/mosaic.png", "cannot write image"); }));
  };
  EXPECT_THROW(RunProject(project_, options), InputError);
  EXPECT_EQ(testing::ReadTextFile(Out("report.json")), report_before);
  EXPECT_EQ(testing::ReadTextFile(Out("camera.cameramodel")), "v1");
  EXPECT_EQ(testing::ReadTextFile(Out("mosaic.png")), "written late");
  EXPECT_EQ(StagingDirs(), 0);
}

TEST_F(RunProjectTest, InputErrorInAStageKeepsOutUntouched) {
  RunOptions options;
  options.runner = [](Stage, StageContext& context) {
    testing::WriteTextFile(context.staging_dir / "camera.cameramodel", "partial");
    throw InputError("calib/calib_01.png", "cannot decode image");
  };
  EXPECT_THROW(RunProject(project_, options), InputError);
  EXPECT_FALSE(fs::exists(project_.OutDir()));
}

TEST_F(RunProjectTest, SingleStageRunKeepsEarlierSectionsAndDropsLaterOnes) {
  RunOptions options;
  options.runner = [](Stage stage, StageContext& context) { FakeStage(stage, context, "v1"); };
  RunProject(project_, options);

  options.stages = {Stage::kMosaic};
  options.runner = [](Stage stage, StageContext& context) { FakeStage(stage, context, "v2"); };
  const RunSummary summary = RunProject(project_, options);
  EXPECT_TRUE(summary.report.calibration.has_value());    // from the earlier run
  EXPECT_TRUE(summary.report.mosaic.has_value());         // rerun
  EXPECT_FALSE(summary.report.measurements.has_value());  // stale, dropped
  EXPECT_EQ(testing::ReadTextFile(Out("mosaic.png")), "v2");
  EXPECT_EQ(testing::ReadTextFile(Out("camera.cameramodel")), "v1");
  EXPECT_FALSE(ReportIsCurrent(project_));  // measure has not run on it
  // The report's tables say so too: no measurement row is left from the first run.
  EXPECT_EQ(testing::ReadTextFile(Out("measurements.csv")).find("A_to_B"), std::string::npos);
}

// `omm run` keeps the stages whose inputs are unchanged: a new CMM value
// reruns the measure stage alone, on the earlier stages' outputs in out/.
TEST_F(RunProjectTest, ReuseKeepsTheCurrentStagesAndRerunsTheRest) {
  RunOptions options;
  options.reuse_current_stages = true;
  // Each run keeps what StagesRunWouldKeep (`omm batch`'s note) says beforehand.
  const auto run = [&] {
    const Project project = LoadProject(project_.dir);
    const std::vector<Stage> foreseen = StagesRunWouldKeep(project, options.mosaic_features);
    RunSummary summary = RunProject(project, options);
    EXPECT_EQ(foreseen, options.reuse_current_stages ? summary.stages_kept : foreseen);
    return summary;
  };
  options.runner = [](Stage stage, StageContext& context) { FakeStage(stage, context, "v1"); };
  EXPECT_EQ(run().stages_run.size(), 3u);  // nothing in out/ yet

  testing::ReplaceInFile(project_.dir / "cmm.csv", "202.6033", "202.6034");
  options.runner = [](Stage stage, StageContext& context) { FakeStage(stage, context, "v2"); };
  RunSummary summary = run();
  EXPECT_EQ(summary.stages_run, std::vector<Stage>{Stage::kMeasure});
  EXPECT_EQ(summary.stages_kept, (std::vector<Stage>{Stage::kCalibrate, Stage::kMosaic}));
  EXPECT_THAT(summary.Brief(), HasSubstr("measure done in"));
  EXPECT_THAT(summary.Brief(), HasSubstr("(calibrate, mosaic current, kept)"));
  EXPECT_EQ(testing::ReadTextFile(Out("camera.cameramodel")), "v1");
  EXPECT_EQ(testing::ReadTextFile(Out("mosaic.png")), "v1");
  EXPECT_TRUE(summary.report.calibration && summary.report.mosaic && summary.report.measurements);
  EXPECT_TRUE(ReportIsCurrent(LoadProject(project_.dir)));

  // Nothing changed: nothing runs.
  summary = run();
  EXPECT_TRUE(summary.stages_run.empty());
  EXPECT_EQ(summary.stages_kept.size(), 3u);
  EXPECT_THAT(summary.Brief(), HasSubstr("nothing to run"));

  // A tile's table position changed: the mosaic and the measure rerun.
  testing::ReplaceInFile(project_.dir / "table.csv", "108.6", "108.7");
  summary = run();
  EXPECT_EQ(summary.stages_run, (std::vector<Stage>{Stage::kMosaic, Stage::kMeasure}));
  EXPECT_EQ(testing::ReadTextFile(Out("mosaic.png")), "v2");
  EXPECT_EQ(testing::ReadTextFile(Out("camera.cameramodel")), "v1");

  // Another omm's results are not kept.
  const std::string version = SoftwareVersion();
  testing::ReplaceInFile(Out("report.json"), "\"" + version + "\"", "\"0.1.0+0123456789ab\"");
  EXPECT_EQ(run().stages_run.size(), 3u);
  EXPECT_EQ(testing::ReadTextFile(Out("camera.cameramodel")), "v2");

  // Without reuse (`omm run --force`) every stage runs.
  options.reuse_current_stages = false;
  EXPECT_EQ(run().stages_run.size(), 3u);

  // A file of a current stage's results deleted from out/: that stage
  // reruns, and the report is no longer current (`omm batch` reruns it).
  options.reuse_current_stages = true;
  fs::remove(Out("mosaic/scene.json"));
  EXPECT_FALSE(ReportIsCurrent(LoadProject(project_.dir)));
  summary = run();
  EXPECT_EQ(summary.stages_run, (std::vector<Stage>{Stage::kMosaic, Stage::kMeasure}));
  fs::remove(Out("camera.cameramodel"));
  EXPECT_EQ(run().stages_run.size(), 3u);
}

// A stage run alone builds on the earlier stages' sections only while their
// inputs are unchanged: after a calibration image changed, the mosaic stage
// finds no calibration in the report and every stage's results in out/
// named stale (the real one then refuses out/camera.cameramodel), and its
// report has no calibration.
TEST_F(RunProjectTest, AStageRunAloneSeesNoEarlierSectionWhoseInputsChanged) {
  RunOptions options;
  options.runner = [](Stage stage, StageContext& context) { FakeStage(stage, context, "v1"); };
  RunProject(project_, options);
  WriteGrayImage(project_.calib_images[0], ImageF::Constant(24, 32, 0.25f), 8);
  bool calibration_seen = true;
  std::vector<Stage> stale;
  options.stages = {Stage::kMosaic};
  options.runner = [&](Stage stage, StageContext& context) {
    calibration_seen = context.report.calibration.has_value();
    stale = context.stale_in_out;
    FakeStage(stage, context, "v2");
  };
  const RunSummary summary = RunProject(LoadProject(project_.dir), options);
  EXPECT_FALSE(calibration_seen);
  EXPECT_EQ(stale, (std::vector<Stage>{Stage::kCalibrate, Stage::kMosaic, Stage::kMeasure}));
  EXPECT_FALSE(summary.report.calibration.has_value());
  EXPECT_EQ(summary.report.stage_inputs_sha256.count("calibrate"), 0u);
  EXPECT_EQ(summary.report.stage_inputs_sha256.count("mosaic"), 1u);
  EXPECT_FALSE(summary.report.measurements.has_value());
}

TEST_F(RunProjectTest, ReportIsNotCurrentAfterAnInputChanges) {
  RunOptions options;
  options.runner = [](Stage stage, StageContext& context) { FakeStage(stage, context, "v1"); };
  RunProject(project_, options);
  ASSERT_TRUE(ReportIsCurrent(project_));
  testing::ReplaceInFile(project_.dir / "table.csv", "108.6", "108.7");
  EXPECT_FALSE(ReportIsCurrent(project_));
}

// An archive processed by another build (another source revision) is rerun
// by `omm batch`: its report is not current.
TEST_F(RunProjectTest, ReportOfAnotherOmmRevisionIsNotCurrent) {
  RunOptions options;
  options.runner = [](Stage stage, StageContext& context) { FakeStage(stage, context, "v1"); };
  RunProject(project_, options);
  ASSERT_TRUE(ReportIsCurrent(project_));
  const std::string version = SoftwareVersion();
  ASSERT_NE(version.find('+'), std::string::npos) << version;  // the revision is in it
  testing::ReplaceInFile(Out("report.json"), "\"" + version + "\"", "\"0.1.0+0123456789ab\"");
  EXPECT_FALSE(ReportIsCurrent(project_));
}

TEST_F(RunProjectTest, StagingOfADeadProcessIsRemoved) {
  fs::create_directories(Out(".staging-4194303") / "half");  // above any live pid here
  RunOptions options;
  options.runner = [](Stage stage, StageContext& context) { FakeStage(stage, context, "v1"); };
  RunProject(project_, options);
  EXPECT_EQ(StagingDirs(), 0);
}

// What `omm batch` calls after the runs it stopped: a dead run's staging
// goes, and out/ with it when nothing else is there; a live one's stays.
TEST_F(RunProjectTest, RemoveStaleStagingLeavesNoEmptyOutAndKeepsLiveRuns) {
  fs::create_directories(Out(".staging-4194303") / "half");
  RemoveStaleStaging(project_.OutDir());
  EXPECT_FALSE(fs::exists(project_.OutDir()));
  const fs::path live = Out(".staging-" + std::to_string(getpid()));
  fs::create_directories(live);
  fs::create_directories(Out(".staging-4194303"));
  RemoveStaleStaging(project_.OutDir());
  EXPECT_TRUE(fs::exists(live));
  EXPECT_EQ(StagingDirs(), 1);
  RemoveStaleStaging(project_.dir / "no_such_out");  // nothing to do, no error
}

TEST_F(RunProjectTest, OptionsCheckRejectsStagesOutOfOrder) {
  RunOptions options;
  EXPECT_EQ(options.Check(), "");
  options.stages = {Stage::kMosaic, Stage::kCalibrate};
  EXPECT_THAT(options.Check(), HasSubstr("run order"));
  options.stages = {Stage::kMosaic, Stage::kMosaic};
  EXPECT_THAT(options.Check(), HasSubstr("run order"));
  options.stages = {};
  EXPECT_NE(options.Check(), "");
}

}  // namespace
}  // namespace omm
