#include "app/terminal_progress.h"

#include <unistd.h>

#include <cstdio>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

namespace omm {

bool IsStderrTerminal() { return isatty(STDERR_FILENO) == 1; }

TerminalProgress::~TerminalProgress() { Finish(); }

void TerminalProgress::Report(int done, int total, const std::string& what) {
  const int percent = total > 0 ? 100 * done / total : 0;
  if (interactive_) {
    // \r and "erase line": the line is redrawn in place.
    fmt::print(stderr, "\r\033[K[{:3d}%] {}/{} {}", percent, done, total, what);
    std::fflush(stderr);
    line_open_ = true;
    if (done >= total) Finish();
    return;
  }
  // A new task (other `what` prefix) restarts the deciles.
  const std::string task = what.substr(0, what.find(' '));
  if (task != last_task_) {
    last_task_ = task;
    last_decile_ = -1;
  }
  const int decile = percent / 10;
  if (decile != last_decile_ || done >= total) {
    last_decile_ = decile;
    spdlog::info("{}% ({}/{}) {}", percent, done, total, what);
  }
}

void TerminalProgress::Finish() {
  if (line_open_) {
    fmt::print(stderr, "\r\033[K");
    std::fflush(stderr);
    line_open_ = false;
  }
}

ProgressCallback TerminalProgress::Callback() {
  return [this](int done, int total, const std::string& what) { Report(done, total, what); };
}

}  // namespace omm
