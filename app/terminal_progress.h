// Shows a ProgressCallback's reports: one updating line when stderr is a
// terminal, else a plain log line at every 10 % and at the end (so batch logs
// stay short and greppable).
#pragma once

#include <chrono>
#include <string>

#include "pipeline/core/progress.h"

namespace omm {

class TerminalProgress {
 public:
  // `interactive`: draw the updating line (pass IsStderrTerminal()).
  explicit TerminalProgress(bool interactive) : interactive_(interactive) {}
  ~TerminalProgress();

  void Report(int done, int total, const std::string& what);
  // Clears the updating line (before other output).
  void Finish();
  // A callback that forwards to Report; `this` must outlive it.
  ProgressCallback Callback();

 private:
  bool interactive_;
  bool line_open_ = false;
  int last_decile_ = -1;
  std::string last_task_;
};

bool IsStderrTerminal();

}  // namespace omm
