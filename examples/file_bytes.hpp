// Whole-file reads for the command-line tool (scene and task hashes, checkpoints, evaluation
// logs).
#pragma once

#include <fstream>
#include <iterator>
#include <optional>
#include <string>

namespace diffphd::cli {

/// The bytes of `path`, or nothing when it cannot be opened.
inline std::optional<std::string> read_file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return std::nullopt;
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

}  // namespace diffphd::cli
