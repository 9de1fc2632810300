// Child processes: where their output goes, how they ended (exit code,
// signal, timeout), what they are started with (PATH, environment), a program
// that cannot start; scratch directories removed or kept.
#include "adapters/process/process.h"

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <thread>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

namespace omm {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::Not;
using ::testing::StartsWith;

std::string ReadFile(const fs::path& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

void WriteFile(const fs::path& path, const std::string& text) { std::ofstream(path) << text; }

ProcessEnd RunShell(const std::string& script, const ProcessOptions& options) {
  const pid_t pid = StartProcess({"/bin/sh", "-c", script}, options);
  const ProcessEnd end = WaitForAnyProcess().value();
  EXPECT_EQ(end.pid, pid);
  return end;
}

ProcessOptions LogTo(const fs::path& log) {
  ProcessOptions options;
  options.log_path = log;
  return options;
}

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

TEST(Process, ExitCodeAndStderrGoToTheTruncatedLogStdoutNowhere) {
  const ScratchDir dir("omm_process_test_");
  WriteFile(dir.path() / "a.log", "an earlier run\n");
  const ProcessEnd end =
      RunShell("echo out; echo 'error: no plate' >&2; exit 3", LogTo(dir.path() / "a.log"));
  EXPECT_EQ(end.exit_code, 3);
  EXPECT_EQ(end.signal, 0);
  EXPECT_FALSE(end.Succeeded());
  EXPECT_EQ(DescribeProcessEnd(end), "exit code 3");
  EXPECT_EQ(ReadFile(dir.path() / "a.log"), "error: no plate\n");
}

TEST(Process, StdoutTooAppendedToTheLog) {
  const ScratchDir dir("omm_process_test_");
  WriteFile(dir.path() / "b.log", "an earlier run\n");
  ProcessOptions options = LogTo(dir.path() / "b.log");
  options.stdout_to_log = true;
  options.append_to_log = true;
  const ProcessEnd end = RunShell("echo out; echo err >&2", options);
  EXPECT_TRUE(end.Succeeded());
  EXPECT_EQ(ReadFile(dir.path() / "b.log"), "an earlier run\nout\nerr\n");
}

TEST(Process, ACrashIsASignalNotAnExitCode) {
  const ScratchDir dir("omm_process_test_");
  const ProcessEnd end = RunShell("kill -SEGV $$", LogTo(dir.path() / "c.log"));
  EXPECT_EQ(end.signal, SIGSEGV);
  EXPECT_EQ(end.exit_code, -1);
  EXPECT_EQ(DescribeProcessEnd(end), "killed by signal 11 (Segmentation fault)");
}

TEST(Process, AProgramThatDoesNotExistThrowsItsErrno) {
  const ScratchDir dir("omm_process_test_");
  try {
    StartProcess({"/nonexistent/omm", "run"}, LogTo(dir.path() / "d.log"));
    FAIL() << "started";
  } catch (const ProcessStartError& e) {
    EXPECT_EQ(e.code(), std::errc::no_such_file_or_directory);
    EXPECT_STREQ(e.what(), "cannot start '/nonexistent/omm': No such file or directory");
  }
}

TEST(Process, ANameIsLookedUpInPathOnlyWhenAsked) {
  const ScratchDir dir("omm_process_test_");
  ProcessOptions options = LogTo(dir.path() / "e.log");
  EXPECT_THROW(StartProcess({"sh", "-c", "exit 0"}, options), ProcessStartError);
  options.search_path = true;
  StartProcess({"sh", "-c", "exit 4"}, options);
  EXPECT_EQ(WaitForAnyProcess().value().exit_code, 4);
}

volatile std::sig_atomic_t g_alarms = 0;
extern "C" void CountAlarm(int) { g_alarms = g_alarms + 1; }

// A signal whose handler does not restart calls ends the wait, empty; the
// child runs on.
TEST(Process, ASignalInterruptsTheWait) {
  const ScratchDir dir("omm_process_test_");
  const pid_t pid = StartProcess({"/bin/sleep", "5"}, LogTo(dir.path() / "s.log"));
  struct sigaction action {};
  struct sigaction previous {};
  action.sa_handler = CountAlarm;
  sigemptyset(&action.sa_mask);
  ASSERT_EQ(sigaction(SIGALRM, &action, &previous), 0);
  alarm(1);
  const std::optional<ProcessEnd> end = WaitForAnyProcess();
  sigaction(SIGALRM, &previous, nullptr);
  EXPECT_FALSE(end.has_value());
  EXPECT_EQ(g_alarms, 1);
  KillProcess(pid);
}

TEST(Process, TheEnvironmentIsInheritedWithTheOverridesSet) {
  const ScratchDir dir("omm_process_test_");
  ASSERT_EQ(setenv("OMM_PROCESS_TEST", "parent", 1), 0);
  ASSERT_EQ(setenv("OMM_PROCESS_TEST_KEPT", "kept", 1), 0);
  ProcessOptions options = LogTo(dir.path() / "f.log");
  options.environment = {"OMM_PROCESS_TEST=child", "OMM_PROCESS_TEST_NEW=new"};
  const ProcessEnd end = RunShell(
      "echo \"$OMM_PROCESS_TEST $OMM_PROCESS_TEST_NEW $OMM_PROCESS_TEST_KEPT\" >&2; "
      "env | grep -c '^OMM_PROCESS_TEST=' >&2",
      options);
  EXPECT_TRUE(end.Succeeded());
  EXPECT_EQ(ReadFile(dir.path() / "f.log"), "child new kept\n1\n");  // replaced, not added
  unsetenv("OMM_PROCESS_TEST");
  unsetenv("OMM_PROCESS_TEST_KEPT");
}

TEST(Process, InvalidOptionsAreSaidAndRefused) {
  ProcessOptions options;
  EXPECT_THAT(options.Check(), HasSubstr("log_path"));
  options.log_path = "/dev/null";
  EXPECT_EQ(options.Check(), "");
  options.environment = {"NO_VALUE"};
  EXPECT_THAT(options.Check(), HasSubstr("'NO_VALUE' is not NAME=value"));
  options.environment = {"=value"};
  EXPECT_THAT(options.Check(), HasSubstr("'=value' is not NAME=value"));
  EXPECT_THROW(StartProcess({"/bin/true"}, options), std::invalid_argument);
  EXPECT_THROW(StartProcess({}, LogTo("/dev/null")), std::invalid_argument);
}

TEST(Process, WaitingWithATimeoutGivesTheEndOfAProcessInTime) {
  const ScratchDir dir("omm_process_test_");
  const pid_t pid = StartProcess({"/bin/sh", "-c", "exit 5"}, LogTo(dir.path() / "g.log"));
  const ProcessEnd end = WaitForProcess(pid, 10.0);
  EXPECT_EQ(end.pid, pid);
  EXPECT_EQ(end.exit_code, 5);
  EXPECT_FALSE(end.timed_out_after_seconds);
}

TEST(Process, ATimeoutKillsTheProcessGroup) {
  const ScratchDir dir("omm_process_test_");
  ProcessOptions options = LogTo(dir.path() / "h.log");
  options.own_process_group = true;
  // A grandchild that would write to the log after 2 s unless killed with
  // its group (well after the timeout, even on a loaded machine).
  const pid_t pid = StartProcess(
      {"/bin/sh", "-c", "(sleep 2; echo survived >&2) & sleep 30 & sleep 30"}, options);
  const auto start = std::chrono::steady_clock::now();
  const ProcessEnd end = WaitForProcess(pid, 0.3);
  EXPECT_LT(SecondsSince(start), 2.0);
  EXPECT_EQ(end.pid, pid);
  EXPECT_EQ(end.timed_out_after_seconds, 0.3);
  EXPECT_EQ(end.signal, SIGKILL);
  EXPECT_FALSE(end.Succeeded());
  EXPECT_EQ(DescribeProcessEnd(end), "timed out after 0.3 s");
  std::this_thread::sleep_for(std::chrono::milliseconds(2500));
  EXPECT_THAT(ReadFile(dir.path() / "h.log"), Not(HasSubstr("survived")));
}

TEST(Process, KillProcessKillsAndReaps) {
  const ScratchDir dir("omm_process_test_");
  const pid_t pid = StartProcess({"/bin/sleep", "30"}, LogTo(dir.path() / "i.log"));
  const auto start = std::chrono::steady_clock::now();
  KillProcess(pid);
  EXPECT_LT(SecondsSince(start), 2.0);
  int status = 0;
  EXPECT_EQ(waitpid(pid, &status, WNOHANG), -1);  // reaped already
  EXPECT_EQ(errno, ECHILD);
  KillProcess(pid);  // no such child any more: nothing happens
}

TEST(Process, OwnExecutableIsThisTest) {
  EXPECT_EQ(OwnExecutable().filename(), "omm_process_test");
}

TEST(ScratchDir, IsRemovedWithItsContents) {
  fs::path path;
  {
    const ScratchDir dir("omm_process_test_");
    path = dir.path();
    EXPECT_TRUE(fs::is_directory(path));
    EXPECT_EQ(path.parent_path(), fs::temp_directory_path());
    EXPECT_THAT(path.filename().string(), StartsWith("omm_process_test_"));
    fs::create_directory(path / "sub");
    WriteFile(path / "sub" / "file", "x");
  }
  EXPECT_FALSE(fs::exists(path));
}

TEST(ScratchDir, IsKeptWhenToldTo) {
  fs::path path;
  {
    ScratchDir dir("omm_process_test_");
    path = dir.path();
    WriteFile(path / "file", "x");
    dir.Keep();
  }
  EXPECT_EQ(ReadFile(path / "file"), "x");
  fs::remove_all(path);
}

TEST(ScratchDir, AFailureSaysWhereAndWhy) {
  try {
    const ScratchDir dir("no_such_folder/omm_process_test_");
    FAIL() << "created " << dir.path();
  } catch (const std::system_error& e) {
    EXPECT_EQ(e.code(), std::errc::no_such_file_or_directory);
    EXPECT_EQ(std::string(e.what()), "cannot create a temporary directory in " +
                                         fs::temp_directory_path().string() +
                                         ": No such file or directory");
  }
}

}  // namespace
}  // namespace omm
