// `omm batch`'s child processes: how a child ended (exit code or signal),
// what it said on stderr, and a program that cannot start.
#include "app/child_process.h"

#include <signal.h>

#include <stdexcept>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "app/exit_codes.h"
#include "tests/test_util.h"

namespace omm {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

ChildEnd RunShell(const std::string& script, const std::filesystem::path& log) {
  const pid_t pid = StartChild({"/bin/sh", "-c", script}, log);
  const ChildEnd end = WaitForAnyChild();
  EXPECT_EQ(end.pid, pid);
  return end;
}

TEST(ChildProcess, ExitCodeAndStderrGoToTheLogStdoutNowhere) {
  testing::TempDir dir;
  const ChildEnd end =
      RunShell("echo out; echo 'error: no plate' >&2; exit 3", dir.path() / "a.log");
  EXPECT_EQ(end.exit_code, 3);
  EXPECT_EQ(end.signal, 0);
  EXPECT_EQ(DescribeChildEnd(end), "exit code 3");
  EXPECT_EQ(testing::ReadTextFile(dir.path() / "a.log"), "error: no plate\n");
}

TEST(ChildProcess, ACrashIsASignalNotAnExitCode) {
  testing::TempDir dir;
  const ChildEnd end = RunShell("kill -SEGV $$", dir.path() / "b.log");
  EXPECT_EQ(end.signal, SIGSEGV);
  EXPECT_EQ(end.exit_code, -1);
  EXPECT_THAT(DescribeChildEnd(end), HasSubstr("killed by signal 11"));
}

TEST(ChildProcess, AProgramThatDoesNotExistThrows) {
  testing::TempDir dir;
  EXPECT_THROW(StartChild({"/nonexistent/omm", "run"}, dir.path() / "c.log"), std::runtime_error);
}

TEST(ChildProcess, TheLogsWarningsAndLastErrorWithItsFollowingLines) {
  const ChildLog log = ParseChildLog(
      "info: loaded\n"
      "warning: tile 3 held\n"
      "error: first\n"
      "warning: exposure\n"
      "error: stage 'mosaic' failed:\n"
      "  pair r0c0-r0c1 has no matches\n");
  EXPECT_THAT(log.warnings, ElementsAre("tile 3 held", "exposure"));
  EXPECT_EQ(log.error, "stage 'mosaic' failed:\n  pair r0c0-r0c1 has no matches");
  EXPECT_EQ(ParseChildLog("info: done\n").error, "");
}

TEST(ChildProcess, TheVerdictKeepsTheChildsReasonAndCallsACrashABug) {
  ChildEnd end;
  end.exit_code = 0;
  EXPECT_EQ(Verdict(end, {}).exit_code, kExitOk);
  end.exit_code = kExitFailed;
  const ChildVerdict failed = Verdict(end, ParseChildLog("error: stage 'calibrate' failed\n"));
  EXPECT_EQ(failed.exit_code, kExitFailed);
  EXPECT_EQ(failed.message, "stage 'calibrate' failed");
  end.exit_code = 3;  // not one of omm's codes
  EXPECT_EQ(Verdict(end, {}).exit_code, kExitInternal);
  EXPECT_THAT(Verdict(end, {}).message, HasSubstr("omm run exit code 3"));
  end.exit_code = -1;
  end.signal = SIGSEGV;
  const ChildVerdict crashed = Verdict(end, ParseChildLog("info: loaded\n"));
  EXPECT_EQ(crashed.exit_code, kExitInternal);
  EXPECT_THAT(crashed.message, HasSubstr("a bug"));
  EXPECT_THAT(crashed.message, HasSubstr("killed by signal 11"));
}

TEST(ChildProcess, OwnExecutableIsThisTest) {
  EXPECT_EQ(OwnExecutable().filename(), "omm_child_process_test");
}

}  // namespace
}  // namespace omm
