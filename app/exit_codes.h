// Exit codes of the `omm` program (documented in `omm --help` and README.md).
#pragma once

namespace omm {

inline constexpr int kExitOk = 0;        // everything asked for was done
inline constexpr int kExitFailed = 1;    // a stage failed on the data; batch: some project failed
inline constexpr int kExitBadInput = 2;  // bad command line, project files or options
// 3 was "a stage not built yet" while the pipeline was being written; unused.
inline constexpr int kExitInternal = 4;  // a bug: an unexpected error (please report it)
inline constexpr int kExitStopped = 130;  // stopped by SIGINT (Ctrl-C) or SIGTERM

}  // namespace omm
