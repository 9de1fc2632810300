#include "app/child_process.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

#include <fmt/format.h>

#include "app/exit_codes.h"

extern char** environ;

namespace omm {

namespace {

std::runtime_error SystemError(const std::string& what, int error) {
  return std::runtime_error(what + ": " + std::strerror(error));
}

}  // namespace

pid_t StartChild(const std::vector<std::string>& argv, const std::filesystem::path& log_path) {
  if (argv.empty()) throw std::runtime_error("StartChild: no program");
  std::vector<char*> args;
  for (const std::string& arg : argv) args.push_back(const_cast<char*>(arg.c_str()));
  args.push_back(nullptr);

  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, log_path.c_str(),
                                   O_WRONLY | O_CREAT | O_TRUNC, 0644);
  pid_t pid = -1;
  const int error = posix_spawn(&pid, args[0], &actions, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (error != 0) throw SystemError("cannot start " + argv[0], error);
  return pid;
}

ChildEnd WaitForAnyChild() {
  int status = 0;
  pid_t pid = -1;
  do {
    pid = waitpid(-1, &status, 0);
  } while (pid < 0 && errno == EINTR);
  if (pid < 0) throw SystemError("waitpid", errno);
  ChildEnd end;
  end.pid = pid;
  if (WIFEXITED(status)) end.exit_code = WEXITSTATUS(status);
  if (WIFSIGNALED(status)) end.signal = WTERMSIG(status);
  return end;
}

std::string DescribeChildEnd(const ChildEnd& end) {
  if (end.signal != 0) {
    return fmt::format("killed by signal {} ({})", end.signal, strsignal(end.signal));
  }
  return fmt::format("exit code {}", end.exit_code);
}

ChildLog ParseChildLog(const std::string& log) {
  static const std::string kWarning = "warning: ", kError = "error: ";
  ChildLog parsed;
  bool in_error = false;
  size_t begin = 0;
  while (begin < log.size()) {
    size_t stop = log.find('\n', begin);
    if (stop == std::string::npos) stop = log.size();
    const std::string line = log.substr(begin, stop - begin);
    begin = stop + 1;
    if (line.rfind(kWarning, 0) == 0) {
      parsed.warnings.push_back(line.substr(kWarning.size()));
      in_error = false;
    } else if (line.rfind(kError, 0) == 0) {
      parsed.error = line.substr(kError.size());
      in_error = true;
    } else if (in_error) {
      parsed.error += "\n" + line;
    }
  }
  while (!parsed.error.empty() && parsed.error.back() == '\n') parsed.error.pop_back();
  return parsed;
}

ChildVerdict Verdict(const ChildEnd& end, const ChildLog& log) {
  if (end.signal == 0 && end.exit_code == kExitOk) return {};
  const bool known_code = end.exit_code == kExitFailed || end.exit_code == kExitBadInput ||
                          end.exit_code == kExitInternal;
  if (end.signal == 0 && known_code && !log.error.empty()) return {end.exit_code, log.error};
  return {kExitInternal, "internal error (a bug; please report it): omm run " +
                             DescribeChildEnd(end) + (log.error.empty() ? "" : ": " + log.error)};
}

std::filesystem::path OwnExecutable() { return std::filesystem::read_symlink("/proc/self/exe"); }

}  // namespace omm
