// Errors that are the user's: bad configuration or input files; and files
// the system would not let us write.
//
// Four kinds of failure: a broken invariant is a bug (assert); bad input is
// an InputError naming the file, the key or line, and what was expected; a
// data failure (plate not found, too few matches) is a value in a stage's
// result, never an exception; the system refusing (disk full, no
// permission, no temporary directory) is a std::system_error with its
// reason (WriteError).
#pragma once

#include <cerrno>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <system_error>

namespace omm {

class InputError : public std::runtime_error {
 public:
  // `where` is a file (and optionally ":line" or " key 'a.b'"); `what` says what
  // is wrong and what was expected.
  InputError(const std::string& where, const std::string& what)
      : std::runtime_error(where.empty() ? what : where + ": " + what),
        where_(where) {}
  const std::string& where() const { return where_; }

 private:
  std::string where_;
};

// A file that could not be written: the system's reason (errno, e.g. "No
// space left on device") after "PATH: what". Call it right after the failed
// call, before anything else may set errno.
inline std::system_error WriteError(const std::filesystem::path& path, const std::string& what) {
  const int error = errno != 0 ? errno : EIO;
  return std::system_error(error, std::generic_category(), path.string() + ": " + what);
}

}  // namespace omm
