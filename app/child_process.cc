#include "app/child_process.h"

#include <csignal>

#include "app/exit_codes.h"

namespace omm {

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

ChildVerdict Verdict(const ProcessEnd& end, const ChildLog& log) {
  if (end.signal == 0 && end.exit_code == kExitOk) return {};
  const bool known_code = end.exit_code == kExitFailed || end.exit_code == kExitBadInput ||
                          end.exit_code == kExitInternal;
  if (end.signal == 0 && known_code && !log.error.empty()) return {end.exit_code, log.error};
  // Ctrl-C reaches the children too; a stop, not a crash: the run stops
  // itself (exit 130), or the signal ends it.
  if (end.signal == 0 && end.exit_code == kExitStopped) {
    return {kExitStopped, log.error.empty() ? "stopped: omm run exited with 130" : log.error};
  }
  if (end.signal == SIGINT || end.signal == SIGTERM) {
    return {kExitStopped, "stopped: omm run " + DescribeProcessEnd(end)};
  }
  return {kExitInternal, "internal error (a bug; please report it): omm run " +
                             DescribeProcessEnd(end) + (log.error.empty() ? "" : ": " + log.error)};
}

}  // namespace omm
