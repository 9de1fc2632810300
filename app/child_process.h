// Child processes for `omm batch`: each project runs as its own `omm run`, so
// that several run at once, and a crash, a leak or a memory peak in one
// project cannot take the batch down.
#pragma once

#include <sys/types.h>

#include <filesystem>
#include <string>
#include <vector>

namespace omm {

// Starts `argv` (argv[0] the program's path) with stdin and stdout on
// /dev/null and stderr written to `log_path`. Throws std::runtime_error if the
// process cannot be started.
pid_t StartChild(const std::vector<std::string>& argv, const std::filesystem::path& log_path);

struct ChildEnd {
  pid_t pid = -1;
  int exit_code = -1;  // when the child exited
  int signal = 0;      // when a signal killed it (then exit_code is -1)
};

// Waits until one of this process's children ends.
ChildEnd WaitForAnyChild();

// "exit code 2", "killed by signal 11 (Segmentation fault)".
std::string DescribeChildEnd(const ChildEnd& end);

// What a child `omm` said on stderr (spdlog's "level: message" lines).
struct ChildLog {
  std::vector<std::string> warnings;  // each "warning: " line's message
  std::string error;                  // the last "error: " line's message, with any lines after it
};
ChildLog ParseChildLog(const std::string& log);

// How a child `omm` ended, as the batch reports it: exit code 0 and no
// message when it succeeded; its own exit code (1, 2 or 4) and its last error
// when it exited so and said why; otherwise kExitInternal, saying how it ended
// (a crash: killed by a signal).
struct ChildVerdict {
  int exit_code = 0;
  std::string message;
};
ChildVerdict Verdict(const ChildEnd& end, const ChildLog& log);

// This program's own executable (for starting it again as a child).
std::filesystem::path OwnExecutable();

}  // namespace omm
