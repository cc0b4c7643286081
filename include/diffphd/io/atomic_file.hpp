#pragma once
/// \file atomic_file.hpp
/// \brief Crash-safe file output: write a temporary file in the target's folder, then rename it
/// onto the target (std::filesystem::rename replaces it atomically on POSIX), so a reader or a
/// killed writer never leaves a half-written file under the final name.
#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>

#include "../core/errors.hpp"

namespace diffphd::io {

/// The temporary name write_file_atomically() and the writers that use replace_file() write
/// first: `path` + ".tmp" (same folder, so the rename does not cross file systems).
inline std::string temporary_path(const std::string& path) { return path + ".tmp"; }

/// Renames `tmp` onto `path` (replacing it). \throws InputError naming path on failure.
inline void replace_file(const std::string& tmp, const std::string& path) {
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) throw InputError("cannot replace the file: " + ec.message(), path);
}

/// Writes `path` atomically: `write(out)` fills a binary stream on temporary_path(path), which
/// is flushed, checked and renamed onto path. \throws InputError naming path when it cannot be
/// written.
template <class Write>
void write_file_atomically(const std::string& path, Write&& write) {
  const std::string tmp = temporary_path(path);
  {
    std::ofstream out(tmp, std::ios::out | std::ios::trunc | std::ios::binary);
    if (!out) throw InputError("cannot open file for writing", tmp);
    write(out);
    out.flush();
    if (!out) throw InputError("write failed (disk full?)", tmp);
  }
  replace_file(tmp, path);
}

}  // namespace diffphd::io
