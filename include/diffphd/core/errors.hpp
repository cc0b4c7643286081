#pragma once
/// \file errors.hpp
/// \brief Exceptions for bad user input. Numerical trouble is reported by status, not by these.

#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace diffphd {

/// \brief Bad input from a user: a file, a parameter, an element. The message names where.
///
/// what() reads "FILE:LINE: message" when a file and line are known, "FILE: message" with only a
/// file, and "message" otherwise.
class InputError : public std::runtime_error {
 public:
  explicit InputError(const std::string& message, std::string file = {}, long line = 0)
      : std::runtime_error(format(message, file, line)),
        file_(std::move(file)),
        line_(line),
        message_(message) {}

  /// The file the bad input came from, or empty.
  const std::string& file() const { return file_; }
  /// The 1-based line in file(), or 0 when unknown.
  long line() const { return line_; }
  /// The message without the location prefix.
  const std::string& message() const { return message_; }

 private:
  static std::string format(const std::string& message, const std::string& file, long line) {
    std::ostringstream os;
    if (!file.empty()) {
      os << file;
      if (line > 0) os << ':' << line;
      os << ": ";
    }
    os << message;
    return os.str();
  }
  std::string file_;
  long line_;
  std::string message_;
};

/// \brief Where a mesh came from, so that errors found after reading can name the file and line.
struct MeshSource {
  std::string file;                ///< file name, empty for meshes built in memory
  std::vector<long> element_line;  ///< 1-based line of each element in file, or empty
  std::vector<long> vertex_line;   ///< 1-based line of each vertex in file, or empty

  long line_of_element(long e) const {
    return (e >= 0 && e < static_cast<long>(element_line.size())) ? element_line[e] : 0;
  }
  long line_of_vertex(long v) const {
    return (v >= 0 && v < static_cast<long>(vertex_line.size())) ? vertex_line[v] : 0;
  }
};

}  // namespace diffphd
