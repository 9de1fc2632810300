#include "adapters/process/process.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <string_view>
#include <thread>

#include <fmt/format.h>

namespace omm {

namespace fs = std::filesystem;

namespace {

// posix_spawn's argv and envp: pointers into `strings`, which it does not
// modify, and a final null.
std::vector<char*> CStrings(const std::vector<std::string>& strings) {
  std::vector<char*> pointers;
  pointers.reserve(strings.size() + 1);
  for (const std::string& s : strings) pointers.push_back(const_cast<char*>(s.c_str()));
  pointers.push_back(nullptr);
  return pointers;
}

// "NAME=" of a "NAME=value" entry.
std::string_view NameOf(std::string_view entry) { return entry.substr(0, entry.find('=') + 1); }

// This process's environment with `overrides` set.
std::vector<std::string> ChildEnvironment(const std::vector<std::string>& overrides) {
  std::vector<std::string> env;
  for (char** e = environ; *e != nullptr; ++e) {
    const std::string_view name = NameOf(*e);
    if (std::none_of(overrides.begin(), overrides.end(),
                     [&](const std::string& o) { return NameOf(o) == name; })) {
      env.emplace_back(*e);
    }
  }
  env.insert(env.end(), overrides.begin(), overrides.end());
  return env;
}

pid_t WaitPid(pid_t pid, int* status, int flags) {
  pid_t done = -1;
  do {
    done = waitpid(pid, status, flags);
  } while (done < 0 && errno == EINTR);
  return done;
}

// SIGKILL to child `pid`, or to its whole process group when it leads one:
// it was started so (own_process_group), and whatever it started is there.
void SendKill(pid_t pid) { kill(getpgid(pid) == pid ? -pid : pid, SIGKILL); }

ProcessEnd EndOf(pid_t pid, int status) {
  ProcessEnd end;
  end.pid = pid;
  if (WIFEXITED(status)) end.exit_code = WEXITSTATUS(status);
  if (WIFSIGNALED(status)) end.signal = WTERMSIG(status);
  return end;
}

}  // namespace

std::string ProcessOptions::Check() const {
  if (log_path.empty()) return "log_path is empty";
  for (const std::string& entry : environment) {
    const size_t equals = entry.find('=');
    if (equals == std::string::npos || equals == 0) {
      return "environment entry '" + entry + "' is not NAME=value";
    }
  }
  return "";
}

ProcessStartError::ProcessStartError(const std::string& program, int error)
    : std::system_error(error, std::generic_category(), "cannot start '" + program + "'") {}

pid_t StartProcess(const std::vector<std::string>& argv, const ProcessOptions& options) {
  if (argv.empty()) throw std::invalid_argument("StartProcess: no program");
  if (const std::string problem = options.Check(); !problem.empty()) {
    throw std::invalid_argument("StartProcess options: " + problem);
  }
  const std::vector<std::string> env = ChildEnvironment(options.environment);
  const std::vector<char*> args = CStrings(argv), envp = CStrings(env);

  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, options.log_path.c_str(),
                                   O_WRONLY | O_CREAT | (options.append_to_log ? O_APPEND : O_TRUNC),
                                   0644);
  if (options.stdout_to_log) {
    posix_spawn_file_actions_adddup2(&actions, STDERR_FILENO, STDOUT_FILENO);
  } else {
    posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
  }
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  if (options.own_process_group) {
    posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETPGROUP);
    posix_spawnattr_setpgroup(&attr, 0);
  }
  pid_t pid = -1;
  const int error =
      options.search_path
          ? posix_spawnp(&pid, args[0], &actions, &attr, args.data(), envp.data())
          : posix_spawn(&pid, args[0], &actions, &attr, args.data(), envp.data());
  posix_spawn_file_actions_destroy(&actions);
  posix_spawnattr_destroy(&attr);
  if (error != 0) throw ProcessStartError(argv[0], error);
  return pid;
}

bool ProcessEnd::Succeeded() const {
  return exit_code == 0 && signal == 0 && !timed_out_after_seconds;
}

std::optional<ProcessEnd> WaitForAnyProcess() {
  int status = 0;
  const pid_t pid = waitpid(-1, &status, 0);
  if (pid < 0 && errno == EINTR) return std::nullopt;
  if (pid < 0) throw std::system_error(errno, std::generic_category(), "waitpid");
  return EndOf(pid, status);
}

ProcessEnd WaitForProcess(pid_t pid, double timeout_seconds) {
  // waitpid has no timeout: poll. 20 ms is nothing next to the programs run so.
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_seconds);
  int status = 0;
  while (true) {
    const pid_t done = WaitPid(pid, &status, WNOHANG);
    if (done < 0) throw std::system_error(errno, std::generic_category(), "waitpid");
    if (done == pid) return EndOf(pid, status);
    if (std::chrono::steady_clock::now() >= deadline) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  SendKill(pid);
  WaitPid(pid, &status, 0);
  ProcessEnd end = EndOf(pid, status);
  end.timed_out_after_seconds = timeout_seconds;
  return end;
}

void KillProcess(pid_t pid) noexcept {
  // Only a child not reaped yet: its pid (and group id) cannot have been reused.
  siginfo_t info{};
  if (waitid(P_PID, pid, &info, WEXITED | WNOHANG | WNOWAIT) != 0) return;
  SendKill(pid);
  int status = 0;
  WaitPid(pid, &status, 0);
}

std::string DescribeProcessEnd(const ProcessEnd& end) {
  if (end.timed_out_after_seconds) {
    return fmt::format("timed out after {:.1f} s", *end.timed_out_after_seconds);
  }
  if (end.signal != 0) {
    return fmt::format("killed by signal {} ({})", end.signal, strsignal(end.signal));
  }
  return fmt::format("exit code {}", end.exit_code);
}

fs::path OwnExecutable() { return fs::read_symlink("/proc/self/exe"); }  // Linux's /proc

ScratchDir::ScratchDir(const std::string& prefix) {
  const fs::path parent = fs::temp_directory_path();
  std::string pattern = (parent / (prefix + "XXXXXX")).string();
  if (mkdtemp(pattern.data()) == nullptr) {
    const int error = errno;  // before the message's allocations
    throw std::system_error(error, std::generic_category(),
                            "cannot create a temporary directory in " + parent.string());
  }
  path_ = pattern;
}

ScratchDir::~ScratchDir() {
  if (keep_) return;
  std::error_code ignored;
  fs::remove_all(path_, ignored);
}

}  // namespace omm
