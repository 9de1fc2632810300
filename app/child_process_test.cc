// What `omm batch` makes of a child `omm run`: what it said on stderr, and the
// verdict from that and how it ended.
#include "app/child_process.h"

#include <signal.h>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "app/exit_codes.h"

namespace omm {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

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
  ProcessEnd end;
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

// Ctrl-C reaches the children as well as the batch: a stop, not a bug.
TEST(ChildProcess, AChildEndedBySigintOrSigtermWasStopped) {
  for (const int signal : {SIGINT, SIGTERM}) {
    ProcessEnd end;
    end.signal = signal;
    const ChildVerdict verdict = Verdict(end, ParseChildLog("info: loaded\n"));
    EXPECT_EQ(verdict.exit_code, kExitStopped);
    EXPECT_THAT(verdict.message, HasSubstr("stopped: omm run killed by signal"));
    EXPECT_THAT(verdict.message, ::testing::Not(HasSubstr("a bug")));
  }
  // The run stopping itself on the signal, with its own message.
  ProcessEnd end;
  end.exit_code = kExitStopped;
  const ChildVerdict stopped =
      Verdict(end, ParseChildLog("error: stopped by signal 2 (Interrupt); out/ left as it was\n"));
  EXPECT_EQ(stopped.exit_code, kExitStopped);
  EXPECT_EQ(stopped.message, "stopped by signal 2 (Interrupt); out/ left as it was");
}

}  // namespace
}  // namespace omm
