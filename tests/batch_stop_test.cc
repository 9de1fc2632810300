// `omm batch` stopped by SIGINT (Ctrl-C) or SIGTERM: the children running
// are killed, the others not started, the summary says which, and nothing
// is left behind (no scratch logs, no out/ of a stopped project). Run on
// copies of a rendered project, the batch signalled while its first child
// runs (slow: a render).
#include <cstdlib>
#include <filesystem>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "tests/sim_cache.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

using ::testing::HasSubstr;

// `omm batch -j 1` on two copies of a demo project, given `signal` 0.3 s
// after its scratch folder appears: the first child (a run of 1.5 s or
// more) is running then.
void ExpectStopped(const std::string& signal) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 101);
  testing::TempDir dir, scratch;
  testing::CopyProject(sim.project_dir, dir.path() / "a");
  testing::CopyProject(sim.project_dir, dir.path() / "b");
  const testing::CommandResult result = testing::RunCommand(
      "TMPDIR=" + scratch.path().string() + " " + testing::OmmProgram().string() + " batch -j 1 " +
      dir.path().string() + " & pid=$!; while kill -0 $pid && [ -z \"$(ls " +
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

}  // namespace
}  // namespace omm
