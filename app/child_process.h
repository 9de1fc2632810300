// What `omm batch` makes of its child processes: each project runs as its own
// `omm run` (started with adapters/process), so that several run at once, and
// a crash, a leak or a memory peak in one project cannot take the batch down.
#pragma once

#include <string>
#include <vector>

#include "adapters/process/process.h"

namespace omm {

// What a child `omm` said on stderr (spdlog's "level: message" lines).
struct ChildLog {
  std::vector<std::string> warnings;  // each "warning: " line's message
  std::string error;                  // the last "error: " line's message, with any lines after it
};
ChildLog ParseChildLog(const std::string& log);

// How a child `omm` ended, as the batch reports it: exit code 0 and no
// message when it succeeded; its own exit code (1, 2 or 4) and its last error
// when it exited so and said why; kExitStopped when it stopped itself on
// SIGINT or SIGTERM (Ctrl-C; exit 130) or one of them ended it; otherwise
// kExitInternal, saying how it ended (a crash: killed by a signal).
struct ChildVerdict {
  int exit_code = 0;
  std::string message;
};
ChildVerdict Verdict(const ProcessEnd& end, const ChildLog& log);

}  // namespace omm
