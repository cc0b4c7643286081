#pragma once
/// \file text_reader.hpp
/// \brief Internal: a line-by-line tokenizer that knows the file and 1-based line it reads, so
/// that every parse error becomes an InputError naming both. Not part of the public API.

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <limits>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "../../core/errors.hpp"
#include "../limits.hpp"

namespace diffphd::io::detail {

/// Lower-case extension of path including the dot (".node"), or "" when there is none.
inline std::string extension_of(const std::string& path) {
  const auto slash = path.find_last_of("/\\");
  const auto dot = path.find_last_of('.');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return {};
  std::string ext = path.substr(dot);
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext;
}

/// path without its extension (the part before the last dot of the file name).
inline std::string strip_extension(const std::string& path) {
  const std::string ext = extension_of(path);
  return path.substr(0, path.size() - ext.size());
}

/// Reads a text file line by line, splits lines into whitespace-separated tokens and parses
/// numbers; every failure throws InputError("file:line: ...").
class TextReader {
 public:
  /// Counts check_count() does not compare with the file size.
  static constexpr long kSmallCount = 1024;

  /// \param[in] path  file to read; throws InputError when it cannot be opened
  /// \param[in] comment  character that starts a comment running to the end of the line, or '\0'
  explicit TextReader(std::string path, char comment = '#')
      : path_(std::move(path)), comment_(comment) {
    in_.open(path_, std::ios::in | std::ios::binary);
    if (!in_) throw InputError("cannot open file for reading", path_);
    in_.seekg(0, std::ios::end);
    const auto end = in_.tellg();
    size_ = end > 0 ? static_cast<long long>(end) : 0;
    in_.seekg(0, std::ios::beg);
  }

  /// Advances to the next line holding at least one token (comments and blank lines are
  /// skipped). Returns false at the end of the file.
  bool next() {
    tokens_.clear();
    while (std::getline(in_, buffer_)) {
      ++line_;
      split();
      if (!tokens_.empty()) return true;
    }
    return false;
  }

  /// Like next(), but throws "unexpected end of file" with `what` was expected.
  void require_next(const std::string& what) {
    if (!next()) throw InputError("unexpected end of file: expected " + what, path_, line_ + 1);
  }

  const std::string& path() const { return path_; }
  /// 1-based number of the current line (0 before the first call to next()).
  long line() const { return line_; }
  size_t size() const { return tokens_.size(); }
  std::string_view token(size_t i) const { return tokens_[i]; }
  /// The current line's first token equals s.
  bool starts_with(std::string_view s) const { return !tokens_.empty() && tokens_[0] == s; }

  [[noreturn]] void fail(const std::string& message) const {
    throw InputError(message, path_, line_);
  }

  /// Requires that the current line holds exactly n tokens (at least n when at_least).
  void expect_size(size_t n, const std::string& what, bool at_least = false) const {
    if (tokens_.size() == n || (at_least && tokens_.size() > n)) return;
    fail("expected " + std::string(at_least ? "at least " : "") + std::to_string(n) +
         (n == 1 ? " field (" : " fields (") + what + "), found " + std::to_string(tokens_.size()));
  }

  /// Token i as a finite double; `what` names the value in the error message.
  double real(size_t i, const std::string& what) const {
    const double v = parse_real(i, what);
    if (!std::isfinite(v)) fail(what + " is not finite: '" + std::string(tokens_[i]) + "'");
    return v;
  }

  /// Token i as a double that may be NaN or Inf (checked by the caller).
  double parse_real(size_t i, const std::string& what) const {
    if (i >= tokens_.size()) fail("missing " + what);
    std::string_view t = tokens_[i];
    if (!t.empty() && t[0] == '+') t.remove_prefix(1);
    double v = 0;
    const auto r = std::from_chars(t.data(), t.data() + t.size(), v);
    if (r.ec != std::errc() || r.ptr != t.data() + t.size())
      fail("expected a number for " + what + ", found '" + std::string(tokens_[i]) + "'");
    return v;
  }

  /// Token i as an integer; `what` names the value in the error message.
  long integer(size_t i, const std::string& what) const {
    if (i >= tokens_.size()) fail("missing " + what);
    std::string_view t = tokens_[i];
    if (!t.empty() && t[0] == '+') t.remove_prefix(1);
    long v = 0;
    const auto r = std::from_chars(t.data(), t.data() + t.size(), v);
    if (r.ec != std::errc() || r.ptr != t.data() + t.size())
      fail("expected an integer for " + what + ", found '" + std::string(tokens_[i]) + "'");
    return v;
  }

  /// Token i as an integer that fits in an int (region ids, physical tags).
  int int_integer(size_t i, const std::string& what) const {
    const long v = integer(i, what);
    if (v < std::numeric_limits<int>::min() || v > std::numeric_limits<int>::max())
      fail(what + " does not fit in an int: '" + std::string(tokens_[i]) + "'");
    return static_cast<int>(v);
  }

  /// Bytes of the file after the current line (0 at the end of the file).
  long long bytes_left() const {
    const auto pos = in_.rdbuf()->pubseekoff(0, std::ios::cur, std::ios::in);
    return pos < 0 ? 0 : std::max<long long>(0, size_ - static_cast<long long>(pos));
  }

  /// Checks a count n >= 0 that the current line declares, before anything is allocated for
  /// it: n must not exceed `limit` (the io::Limits member named `limit_name`; none when that is
  /// null), and n entries of at least `bytes_each` bytes (two per number: a digit and a
  /// separator; the last entry may lack its newline) must fit in what is left of the file.
  /// Counts up to kSmallCount pass the size test (allocating for them is harmless) so that a
  /// mildly truncated file gets the reader's own message saying where the data ends. `what`
  /// names the entries ("points").
  void check_count(long n, const std::string& what, long bytes_each, std::int64_t limit = 0,
                   const char* limit_name = nullptr) const {
    if (limit_name && n > limit)
      fail(std::to_string(n) + " " + what + " declared here exceed the limit " +
           std::to_string(limit) + " (io::limits()." + limit_name + ")");
    const long long left = bytes_left();
    if (n > kSmallCount && n > (left + 1) / bytes_each)
      fail(std::to_string(n) + " " + what + " declared here cannot fit in the " +
           std::to_string(left) + " bytes that follow (at least " + std::to_string(bytes_each) +
           " each): truncated or corrupt file");
  }

  /// Token i as an integer written as an integer or an integral real ("3", "3.0", "-1e0").
  long integral_real(size_t i, const std::string& what) const {
    const double v = real(i, what);
    if (v != std::round(v) || std::abs(v) > 2e9)
      fail(what + " must be an integer, found '" + std::string(tokens_[i]) + "'");
    return static_cast<long>(std::lround(v));
  }

 private:
  void split() {
    if (!buffer_.empty() && buffer_.back() == '\r') buffer_.pop_back();
    size_t end = buffer_.size();
    if (comment_ != '\0') {
      const auto c = buffer_.find(comment_);
      if (c != std::string::npos) end = c;
    }
    size_t i = 0;
    while (i < end) {
      while (i < end && std::isspace(static_cast<unsigned char>(buffer_[i]))) ++i;
      const size_t start = i;
      while (i < end && !std::isspace(static_cast<unsigned char>(buffer_[i]))) ++i;
      if (i > start) tokens_.emplace_back(buffer_.data() + start, i - start);
    }
  }

  std::string path_;
  char comment_;
  std::ifstream in_;
  long long size_ = 0;
  std::string buffer_;
  std::vector<std::string_view> tokens_;
  long line_ = 0;
};

/// Opens path for writing; throws InputError naming path when that fails.
inline std::ofstream open_for_writing(const std::string& path) {
  std::ofstream out(path, std::ios::out | std::ios::trunc);
  if (!out) throw InputError("cannot open file for writing", path);
  out.precision(17);
  return out;
}

/// Throws InputError naming path when the stream went bad while writing.
inline void finish_writing(std::ofstream& out, const std::string& path) {
  out.flush();
  if (!out) throw InputError("write failed (disk full?)", path);
}

}  // namespace diffphd::io::detail
