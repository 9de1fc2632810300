// The `omm` program as a user meets it: help, exit codes, error messages and
// what is (not) left in out/.
#include <algorithm>
#include <cmath>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "adapters/project_io/report_json.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using ::testing::Not;

namespace omm {
namespace {

std::string Quoted(const fs::path& path) { return "'" + path.string() + "'"; }

class CliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    project_ = testing::TinyProject(dir_.path() / "job");
    testing::WriteTinyProject(project_);
  }
  testing::TempDir dir_;
  Project project_;
};

TEST(Cli, EverySubcommandHasHelpSayingWhatItReadsAndWrites) {
  for (const std::string command :
       {"run", "calibrate", "mosaic", "measure", "batch", "simulate", "report"}) {
    const auto result = testing::RunOmm(command + " --help");
    EXPECT_EQ(result.exit_code, 0) << command;
    EXPECT_THAT(result.output, HasSubstr("Usage: omm " + command)) << command;
    EXPECT_THAT(result.output, HasSubstr("Writes")) << command;
  }
  const auto top = testing::RunOmm("--help");
  EXPECT_EQ(top.exit_code, 0);
  EXPECT_THAT(top.output, HasSubstr("Exit codes:"));
}

TEST(Cli, VersionAndUsageErrors) {
  const auto version = testing::RunOmm("--version");
  EXPECT_EQ(version.exit_code, 0);
  // The CMake version and the source revision it was built from.
  EXPECT_THAT(version.output, ContainsRegex("omm 0\\.[0-9]+\\.[0-9]+\\+[0-9a-z-]+"));
  EXPECT_EQ(testing::RunOmm("").exit_code, 2);
  EXPECT_EQ(testing::RunOmm("frobnicate").exit_code, 2);
  EXPECT_EQ(testing::RunOmm("run").exit_code, 2);  // PROJECT missing
  const auto no_threads = testing::RunOmm("--threads 0 run /nonexistent");
  EXPECT_EQ(no_threads.exit_code, 2);
  EXPECT_THAT(no_threads.output, HasSubstr("--threads"));
}

// The arguments arrive as given and the exit code comes back: 1 (a stage
// failed on the data) and 2 (a path with spaces that is not there, named in
// the message); `--version` says 0.
TEST_F(CliTest, ArgumentsAndExitCodesPassThrough) {
  const fs::path spaced = dir_.path() / "a job with  spaces";
  const auto version = testing::RunOmm("--version");
  EXPECT_EQ(version.exit_code, 0);
  EXPECT_THAT(version.output, HasSubstr("omm 0."));
  const auto failed = testing::RunOmm("run " + Quoted(project_.dir));
  EXPECT_EQ(failed.exit_code, 1) << failed.output;
  EXPECT_THAT(failed.output, HasSubstr("stage 'calibrate' failed"));
  const auto missing = testing::RunOmm("run " + Quoted(spaced));
  EXPECT_EQ(missing.exit_code, 2) << missing.output;
  EXPECT_THAT(missing.output, HasSubstr(spaced.string()));
}

TEST_F(CliTest, BadProjectExitsTwoAndNamesFileAndKey) {
  testing::ReplaceInFile(project_.dir / "project.yaml", "pitch_mm: 12.5", "pitch_mm: -12.5");
  const auto result = testing::RunOmm("run " + Quoted(project_.dir));
  EXPECT_EQ(result.exit_code, 2) << result.output;
  EXPECT_THAT(result.output, HasSubstr("project.yaml:"));
  EXPECT_THAT(result.output, HasSubstr("board.pitch_mm"));
  EXPECT_FALSE(fs::exists(project_.OutDir()));
}

TEST_F(CliTest, SimulateRefusesTooFewCalibImagesBeforeWriting) {
  const auto result =
      testing::RunOmm("simulate " + Quoted(dir_.path() / "sim") + " --calib-images 2");
  EXPECT_EQ(result.exit_code, 2) << result.output;
  EXPECT_THAT(result.output, HasSubstr("num_calib_images must be in 3..100"));
  EXPECT_FALSE(fs::exists(dir_.path() / "sim"));
}

TEST_F(CliTest, SimulateRefusesABadGridBeforeWriting) {
  for (const char* grid : {"3y3", "1x1", "7x2", "3x"}) {
    const auto result =
        testing::RunOmm("simulate " + Quoted(dir_.path() / "sim") + " --grid " + grid);
    EXPECT_EQ(result.exit_code, 2) << grid << ": " << result.output;
    EXPECT_THAT(result.output, HasSubstr("grid")) << grid;
    EXPECT_FALSE(fs::exists(dir_.path() / "sim")) << grid;
  }
}

TEST_F(CliTest, SimulateRefusesAnUnknownBoardBeforeWriting) {
  const auto result =
      testing::RunOmm("simulate " + Quoted(dir_.path() / "sim") + " --board checkerboard");
  EXPECT_EQ(result.exit_code, 2) << result.output;
  EXPECT_THAT(result.output, HasSubstr("expected caltab, circles or chessboard"));
  EXPECT_FALSE(fs::exists(dir_.path() / "sim"));
}

TEST_F(CliTest, MissingProjectExitsTwo) {
  const auto result = testing::RunOmm("run " + Quoted(dir_.path() / "nowhere"));
  EXPECT_EQ(result.exit_code, 2);
  EXPECT_THAT(result.output, HasSubstr("nowhere"));
}

TEST_F(CliTest, CorruptTileIsNamedAndLeavesNoReport) {
  testing::WriteTextFile(project_.TilePath("Part_03.png"), "\x89PNG\r\n\x1a\n cut short");
  const auto result = testing::RunOmm("run " + Quoted(project_.dir));
  EXPECT_NE(result.exit_code, 0);
  EXPECT_THAT(result.output, HasSubstr("Part_03.png"));
  EXPECT_FALSE(fs::exists(project_.OutDir() / "report.json"));
}

TEST_F(CliTest, FailedRunKeepsAnEarlierReportByteForByte) {
  Report earlier;
  earlier.project = "tiny";
  fs::create_directories(project_.OutDir());
  WriteReportJson(project_.OutDir() / "report.json", earlier);
  const std::string before = testing::ReadTextFile(project_.OutDir() / "report.json");
  const auto result = testing::RunOmm("run " + Quoted(project_.dir));
  EXPECT_NE(result.exit_code, 0);
  EXPECT_EQ(testing::ReadTextFile(project_.OutDir() / "report.json"), before);
  std::vector<std::string> left;
  for (const auto& entry : fs::directory_iterator(project_.OutDir())) {
    left.push_back(entry.path().filename().string());
  }
  EXPECT_EQ(left, std::vector<std::string>{"report.json"});  // no staging left behind
}

TEST_F(CliTest, PlainImagesFailCalibrationWithTheirReasons) {
  const auto result = testing::RunOmm("run " + Quoted(project_.dir));
  EXPECT_EQ(result.exit_code, 1) << result.output;
  EXPECT_THAT(result.output, HasSubstr("stage 'calibrate' failed"));
  // One line per reason, not per image.
  EXPECT_THAT(result.output, HasSubstr("; plate not found: calib_01.png, calib_02.png"));
  EXPECT_THAT(result.output, HasSubstr("is project.yaml's board (caltab of 7 x 7 marks, pitch"));
  EXPECT_FALSE(fs::exists(project_.OutDir()));
  // No calibrated camera: the mosaic stage says which stage must run first.
  const auto mosaic = testing::RunOmm("mosaic " + Quoted(project_.dir));
  EXPECT_EQ(mosaic.exit_code, 2);
  EXPECT_THAT(mosaic.output, HasSubstr("no calibrated camera: run `omm calibrate`"));
}

TEST_F(CliTest, BatchReportsEveryProjectAndDoesNotStop) {
  Project bad = testing::TinyProject(dir_.path() / "bad");
  testing::WriteTinyProject(bad);
  testing::ReplaceInFile(bad.dir / "table.csv", "image,x_mm,y_mm", "image,x,y");
  const fs::path csv = dir_.path() / "summary.csv";
  // Both projects at once, each its own `omm run`.
  const auto result = testing::RunOmm("batch --jobs 2 " + Quoted(dir_.path()) +  // a folder
                                      " --csv " + Quoted(csv));
  EXPECT_EQ(result.exit_code, 1) << result.output;
  EXPECT_THAT(result.output, HasSubstr("2 projects, 2 failed"));
  EXPECT_THAT(result.output, HasSubstr("FAILED (2)"));  // bad: table.csv header
  EXPECT_THAT(result.output, HasSubstr("table.csv:1"));
  EXPECT_THAT(result.output, HasSubstr("FAILED (1)"));  // job: no plate in its gray images
  EXPECT_THAT(result.output, HasSubstr("no measurement has a CMM value"));
  // The CSV: its header, then each failed project as one row saying why.
  const std::string table = testing::ReadTextFile(csv);
  EXPECT_EQ(table.rfind("project,measurement,type,value_mm,sigma_mm,cmm_mm,cmm_sigma_mm,"
                        "deviation_mm,deviation_sigma,deviation_combined_sigma,error\n",
                        0),
            0u);
  EXPECT_EQ(std::count(table.begin(), table.end(), '\n'), 3) << table;
  EXPECT_THAT(table, HasSubstr((bad.dir.string() + ",,,,,,,,,,")));
  EXPECT_THAT(table, HasSubstr("table.csv:1"));
}

TEST_F(CliTest, BatchRunsProjectsAsTheirOwnRunsAndRefusesZeroJobs) {
  // The child's failure message reaches the batch whole, as `omm run` gives
  // it (PlainImagesFailCalibrationWithTheirReasons).
  const auto batch = testing::RunOmm("batch -j 1 " + Quoted(project_.dir));
  EXPECT_EQ(batch.exit_code, 1) << batch.output;
  EXPECT_THAT(batch.output, HasSubstr("1 project, 1 failed"));
  EXPECT_THAT(batch.output, HasSubstr("FAILED (1): stage 'calibrate' failed"));
  EXPECT_THAT(batch.output, HasSubstr("; plate not found: calib_01.png, calib_02.png"));
  EXPECT_FALSE(fs::exists(project_.OutDir()));

  // The threads shared among the projects running at once.
  const auto shared = testing::RunOmm("--threads 5 batch -j 2 " + Quoted(project_.dir));
  EXPECT_THAT(shared.output, HasSubstr("on 2 threads")) << shared.output;
  const auto one = testing::RunOmm("--threads 3 batch -j 3 " + Quoted(project_.dir));
  EXPECT_THAT(one.output, HasSubstr("on 1 thread\n")) << one.output;

  const auto zero = testing::RunOmm("batch --jobs 0 " + Quoted(project_.dir));
  EXPECT_EQ(zero.exit_code, 2);
  EXPECT_THAT(zero.output, HasSubstr("--jobs"));
}

// The system refusing (here: no temporary directory for the children's
// logs) is said as such, exit 1, not taken for a bug.
TEST_F(CliTest, BatchWithoutATemporaryDirectorySaysSo) {
  const auto batch =
      testing::RunCommand("TMPDIR=/nonexistent/omm " + testing::OmmProgram().string() +
                          " batch -j 1 " + Quoted(project_.dir));
  EXPECT_EQ(batch.exit_code, 1) << batch.output;
  EXPECT_THAT(batch.output, HasSubstr("temp_directory_path: No such file or directory"));
  EXPECT_THAT(batch.output, Not(HasSubstr("a bug")));
}

TEST_F(CliTest, ReportPrintsTheMeasurements) {
  EXPECT_EQ(testing::RunOmm("report " + Quoted(project_.dir)).exit_code, 2);  // no report yet
  Report report;
  report.project = "tiny";
  MeasurementReport m;
  m.name = "A_to_B";
  m.value_mm = 202.6021;
  m.sigma_mm = 0.0031;
  report.measurements = std::vector<MeasurementReport>{m};
  fs::create_directories(project_.OutDir());
  WriteReportJson(project_.OutDir() / "report.json", report);
  const auto text = testing::RunOmm("report " + Quoted(project_.dir));
  EXPECT_EQ(text.exit_code, 0);
  EXPECT_THAT(text.output, HasSubstr("A_to_B"));
  EXPECT_THAT(text.output, HasSubstr("202.6021"));
  EXPECT_THAT(text.output, Not(HasSubstr("dev/both")));
  // It writes the report's tables too.
  EXPECT_THAT(testing::ReadTextFile(project_.OutDir() / "measurements.csv"),
              HasSubstr("\ntiny,A_to_B,distance,202.6021,0.0031,"));
  EXPECT_TRUE(fs::exists(project_.OutDir() / "features.csv"));
  // Where cmm.csv stated the CMM's sigma: its column and the deviation
  // against both sigmas.
  m.cmm_mm = 202.6033;
  m.cmm_sigma_mm = 0.0012;
  m.deviation_mm = 202.6021 - 202.6033;
  m.deviation_sigma = *m.deviation_mm / 0.0031;
  m.deviation_combined_sigma = *m.deviation_mm / std::hypot(0.0031, 0.0012);
  report.measurements = std::vector<MeasurementReport>{m};
  WriteReportJson(project_.OutDir() / "report.json", report);
  const auto with_cmm = testing::RunOmm("report " + Quoted(project_.dir));
  EXPECT_EQ(with_cmm.exit_code, 0);
  EXPECT_THAT(with_cmm.output, HasSubstr("dev/sigma cmm_sigma  dev/both"));
  EXPECT_THAT(with_cmm.output, HasSubstr("   -0.39    0.0012     -0.36"));
  const auto json = testing::RunOmm("report --json " + Quoted(project_.dir));
  EXPECT_THAT(json.output, HasSubstr("\"format\": \"omm-report/1\""));
}

}  // namespace
}  // namespace omm
