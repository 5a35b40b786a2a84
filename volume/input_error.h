#pragma once
// Bad input from the user (a file, a scene key, a flag). The command line turns it into
// one line on stderr and exit status 2; everything else is an internal error (exit 1).
#include <stdexcept>
#include <string>

namespace iso {

class InputError : public std::runtime_error {
 public:
  // `where` names the place inside `file`: a JSON path, a header line, a byte offset.
  InputError(const std::string& file, const std::string& where, const std::string& what)
      : std::runtime_error(file + (where.empty() ? "" : ": " + where) + ": " + what) {}
  // A message already in that form (passed on from a child process).
  explicit InputError(const std::string& message) : std::runtime_error(message) {}
};

}  // namespace iso
