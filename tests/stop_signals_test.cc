// `omm run` and `omm batch` stopped by SIGINT (Ctrl-C) or SIGTERM (slow:
// a render). A run stops at its next progress report and leaves out/ as it
// was: none if it had none, an earlier run's byte for byte. A batch kills
// the children running, starts no other, says which in its summary, and
// leaves nothing behind (no scratch logs, no out/ of a stopped project).
// The project is MeasureRun's render of demo seed 101 (14 calib/ images).
#include <cstdlib>
#include <filesystem>
#include <map>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "tests/sim_cache.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

using ::testing::HasSubstr;

// The shell starts a background job with SIGINT ignored, and omm keeps a
// signal it was started ignoring; Ctrl-C reaches a foreground one.
const std::string kForeground = "env --default-signal=INT ";

// `omm batch -j 1` on two copies of a demo project, given `signal` 0.3 s
// after its scratch folder appears: the first child (a run of 1.5 s or
// more) is running then.
void ExpectStopped(const std::string& signal) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 101, 14);
  testing::TempDir dir, scratch;
  testing::CopyProject(sim.project_dir, dir.path() / "a");
  testing::CopyProject(sim.project_dir, dir.path() / "b");
  const testing::CommandResult result = testing::RunCommand(
      "TMPDIR=" + scratch.path().string() + " " + kForeground + testing::OmmProgram().string() +
      " batch -j 1 " + dir.path().string() + " & pid=$!; while kill -0 $pid && [ -z \"$(ls " +
      scratch.path().string() + ")\" ]; do sleep 0.05; done; sleep 0.3; kill -" + signal +
      " $pid; wait $pid");
  EXPECT_EQ(result.exit_code, 130) << result.output;
  EXPECT_THAT(result.output, HasSubstr("STOPPED: killed: the batch got signal"));
  EXPECT_THAT(result.output, HasSubstr("STOPPED: not run: the batch got signal"));
  EXPECT_THAT(result.output, HasSubstr("2 projects, 0 failed, 2 stopped"));
  EXPECT_TRUE(fs::is_empty(scratch.path())) << "scratch logs left";
  EXPECT_FALSE(fs::exists(dir.path() / "a" / "out")) << "a stopped run's out/ left";
  EXPECT_FALSE(fs::exists(dir.path() / "b" / "out"));
}

TEST(BatchStop, SigintStopsTheBatch) { ExpectStopped("INT"); }

TEST(BatchStop, SigtermStopsTheBatch) { ExpectStopped("TERM"); }

// `omm run --force` (every stage, even where out/ is current) on `project`
// on one thread (3 s for the demo), given `signal` `delay_s` after its
// staging directory appears.
testing::CommandResult RunAndSignal(const fs::path& project, const std::string& signal,
                                    double delay_s) {
  return testing::RunCommand(
      kForeground + testing::OmmProgram().string() + " --threads 1 run --force " +
      project.string() + " 2>&1 & pid=$!; while kill -0 $pid && [ -z \"$(ls -a " +
      (project / "out").string() + " 2>/dev/null | grep staging)\" ]; do sleep 0.02; done; sleep " +
      std::to_string(delay_s) + "; kill -" + signal + " $pid; wait $pid");
}

// The files under `dir` with their contents, by relative path.
std::map<std::string, std::string> Contents(const fs::path& dir) {
  std::map<std::string, std::string> contents;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    if (entry.is_regular_file())
      contents[fs::relative(entry.path(), dir).string()] = testing::ReadTextFile(entry.path());
  }
  return contents;
}

TEST(RunStop, SigintLeavesNoOutWhereThereWasNone) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 101, 14);
  testing::TempDir dir;
  testing::CopyProject(sim.project_dir, dir.path());
  const testing::CommandResult result = RunAndSignal(dir.path(), "INT", 0.3);
  EXPECT_EQ(result.exit_code, 130) << result.output;
  EXPECT_THAT(result.output, HasSubstr("stopped by signal 2"));
  EXPECT_FALSE(fs::exists(dir.path() / "out")) << "a stopped run's out/ left";
}

TEST(RunStop, SigtermKeepsAnEarlierOutByteForByte) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 101, 14);
  testing::TempDir dir;
  testing::CopyProject(sim.project_dir, dir.path());
  ASSERT_EQ(testing::RunOmm("-q run " + dir.path().string()).exit_code, 0);
  const std::map<std::string, std::string> before = Contents(dir.path() / "out");
  // Later than the first case: the mosaic stage runs then.
  const testing::CommandResult result = RunAndSignal(dir.path(), "TERM", 1.0);
  EXPECT_EQ(result.exit_code, 130) << result.output;
  EXPECT_THAT(result.output, HasSubstr("stopped by signal 15"));
  EXPECT_TRUE(Contents(dir.path() / "out") == before) << "out/ changed";
}

// Started with SIGINT ignored (a script's background job, nohup), a run
// keeps ignoring it and completes.
TEST(RunStop, ASigintIgnoredAtStartStaysIgnored) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 101, 14);
  testing::TempDir dir;
  testing::CopyProject(sim.project_dir, dir.path());
  const testing::CommandResult result = testing::RunCommand(
      testing::OmmProgram().string() + " -q run " + dir.path().string() +
      " 2>&1 & pid=$!; while kill -0 $pid && [ -z \"$(ls -a " + (dir.path() / "out").string() +
      " 2>/dev/null | grep staging)\" ]; do sleep 0.02; done; kill -INT $pid; wait $pid");
  EXPECT_EQ(result.exit_code, 0) << result.output;
  EXPECT_TRUE(fs::exists(dir.path() / "out" / "report.json"));
}

}  // namespace
}  // namespace omm
