// Child processes and scratch directories (POSIX): starting a program with its
// output in a log file, waiting for it (with or without a timeout), saying how
// it ended, and a private temporary directory that goes when its owner does.
// Used by `omm batch` (a child `omm run` per project) and the COLMAP adapter
// (the `colmap` program).
#pragma once

#include <sys/types.h>

#include <filesystem>
#include <optional>
#include <string>
#include <system_error>
#include <vector>

namespace omm {

// How StartProcess starts a child. Its stdin is always /dev/null.
struct ProcessOptions {
  // Where the child's stderr goes: a file, created (mode 0644) if missing.
  std::filesystem::path log_path;
  // Send stdout to the log too; else stdout goes to /dev/null.
  bool stdout_to_log = false;
  // Append to the log; else it is truncated first.
  bool append_to_log = false;
  // Look argv[0] up in PATH when it has no '/' (posix_spawnp); else it is a path.
  bool search_path = false;
  // The child leads a new process group, so that a timeout kills whatever it
  // started too (KillProcess).
  bool own_process_group = false;
  // "NAME=value" each, one per name: set in the child's environment, replacing
  // this process's value; every other variable is inherited.
  std::vector<std::string> environment;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// A process that could not be started: code() holds the errno
// (std::errc::no_such_file_or_directory for a program that does not exist),
// what() reads "cannot start 'PROGRAM': REASON".
class ProcessStartError : public std::system_error {
 public:
  ProcessStartError(const std::string& program, int error);
};

// Starts `argv` (argv[0] the program) as a child of this process. Throws
// std::invalid_argument for an empty argv or invalid options (a bug in the
// caller), ProcessStartError if the program cannot be started.
pid_t StartProcess(const std::vector<std::string>& argv, const ProcessOptions& options);

// How a child ended.
struct ProcessEnd {
  pid_t pid = -1;
  int exit_code = -1;  // when it exited
  int signal = 0;      // when a signal killed it (then exit_code is -1)
  // Set when WaitForProcess killed it because this timeout passed.
  std::optional<double> timed_out_after_seconds;

  // Exited with code 0, in time.
  bool Succeeded() const;
};

// Waits until any child of this process ends. Empty if a signal whose
// handler does not restart calls (sigaction without SA_RESTART) interrupted
// the wait: the caller's cue to look at what its handler recorded. Throws
// std::system_error if there is no child.
std::optional<ProcessEnd> WaitForAnyProcess();

// Waits until child `pid` ends, at most `timeout_seconds`; then kills and
// reaps it (KillProcess) and the end says so (timed_out_after_seconds).
// Throws std::system_error if `pid` is not a child of this process.
ProcessEnd WaitForProcess(pid_t pid, double timeout_seconds);

// Kills child `pid` (SIGKILL; its whole process group when it leads one) and
// reaps it: for a child no longer wanted, also from a destructor. A pid that
// is not an unreaped child of this process is left alone.
void KillProcess(pid_t pid) noexcept;

// "exit code 3", "killed by signal 11 (Segmentation fault)", "timed out after 0.5 s".
std::string DescribeProcessEnd(const ProcessEnd& end);

// This program's own executable (for starting it again as a child).
std::filesystem::path OwnExecutable();

// A fresh private directory (mode 0700) in the system's temporary directory,
// named `prefix` followed by six random characters; removed with everything
// in it when this goes, unless Keep() was called. Throws std::system_error
// naming the parent directory and the reason if it cannot be created.
class ScratchDir {
 public:
  explicit ScratchDir(const std::string& prefix);
  ~ScratchDir();
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;

  const std::filesystem::path& path() const { return path_; }
  // Leave the directory and its contents in place when this goes.
  void Keep() { keep_ = true; }

 private:
  std::filesystem::path path_;
  bool keep_ = false;
};

}  // namespace omm
