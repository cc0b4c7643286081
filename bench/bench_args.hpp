// Command-line values for the bench programs: the whole argument is read as a number in a stated
// range, or the program stops with exit code 2 and a message that names the option and the value.
// (std::atoi read "12x" as 12 and "x" as 0 without a word, so a typo became a silent 0-step soak
// or a clamped repetition count.)
#pragma once

#include <charconv>
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <sstream>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

namespace diffphd::bench_args {

[[noreturn]] inline void fail(std::string_view program, std::string_view option,
                              const std::string& message) {
  std::cerr << program << ": error: " << option << ": " << message << "\n";
  std::exit(2);
}

/// argv[i + 1], the value of option argv[i]; advances i. Stops when the option is the last word.
inline std::string_view value(std::string_view program, int argc, char** argv, int& i) {
  if (i + 1 >= argc) fail(program, argv[i], "needs a value");
  return argv[++i];
}

/// The whole of `text` as an integer in [lo, hi].
inline long long integer(std::string_view program, std::string_view option, std::string_view text,
                         long long lo, long long hi) {
  long long v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (text.empty() || ec == std::errc::invalid_argument || end != text.data() + text.size())
    fail(program, option, "\"" + std::string(text) + "\" is not an integer");
  if (ec == std::errc::result_out_of_range || v < lo || v > hi)
    fail(program, option,
         "\"" + std::string(text) + "\" is out of range [" + std::to_string(lo) + ", " +
             std::to_string(hi) + "]");
  return v;
}

/// The whole of `text` as a finite number in [lo, hi].
inline double number(std::string_view program, std::string_view option, std::string_view text,
                     double lo, double hi) {
  double v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (text.empty() || ec == std::errc::invalid_argument || end != text.data() + text.size())
    fail(program, option, "\"" + std::string(text) + "\" is not a number");
  if (ec == std::errc::result_out_of_range || !std::isfinite(v) || v < lo || v > hi) {
    std::ostringstream range;
    range << "\"" << text << "\" is out of range [" << lo << ", " << hi << "]";
    fail(program, option, range.str());
  }
  return v;
}

/// A comma-separated list of integers in [lo, hi] ("8,12,16"); empty items are errors.
inline std::vector<int> integer_list(std::string_view program, std::string_view option,
                                     std::string_view text, int lo, int hi) {
  std::vector<int> out;
  for (std::size_t start = 0;;) {
    const std::size_t comma = text.find(',', start);
    const std::string_view item = text.substr(
        start, comma == std::string_view::npos ? std::string_view::npos : comma - start);
    out.push_back(static_cast<int>(integer(program, option, item, lo, hi)));
    if (comma == std::string_view::npos) return out;
    start = comma + 1;
  }
}

}  // namespace diffphd::bench_args
