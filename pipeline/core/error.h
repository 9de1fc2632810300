// Errors that are the user's: bad configuration or input files.
//
// Three kinds of failure (../../README.md, "Failures"): a broken invariant is a
// bug (assert); bad input is an InputError naming the file, the key or line,
// and what was expected; a data failure (plate not found, too few matches) is
// a value in a stage's result, never an exception.
#pragma once

#include <filesystem>
#include <stdexcept>
#include <string>

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

}  // namespace omm
