#pragma once
/// \file fuzz_common.hpp
/// \brief Shared by the libFuzzer harnesses (see docs/reliability.md): the readers take paths,
/// so every input is written to a file in a per-process temporary folder; InputError is the
/// only exception a reader may throw on bad input, anything else (another exception, a crash, a
/// sanitizer report, a broken invariant) is a finding.

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <string>

#include <unistd.h>

#include <diffphd/core/errors.hpp>
#include <diffphd/io/limits.hpp>

namespace fuzz {

/// The per-process temporary folder under $TMPDIR (else /tmp), created on first use and
/// removed at a normal exit (scripts/fuzz.sh points TMPDIR into its build folder, where the
/// folders of crashed runs stay).
inline const std::string& temp_dir() {
  static const std::string dir = [] {
    const char* tmp = std::getenv("TMPDIR");
    std::string pattern = std::string(tmp && *tmp ? tmp : "/tmp") + "/diffphd-fuzz-XXXXXX";
    char* name = pattern.data();
    if (!mkdtemp(name)) {
      std::perror("mkdtemp");
      std::abort();
    }
    std::string d = name;
    static std::string to_remove = d;
    std::atexit([] { std::system(("rm -rf '" + to_remove + "'").c_str()); });
    return d;
  }();
  return dir;
}

/// temp_dir()/name.
inline std::string temp_path(const std::string& name) { return temp_dir() + "/" + name; }

/// Writes size bytes to path (overwriting it).
inline void write_file(const std::string& path, const std::uint8_t* data, size_t size) {
  std::ofstream out(path, std::ios::out | std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  if (!out) std::abort();
}

/// Copies DIFFPHD_DATA_DIR/name (a fixed file of tests/data) to temp_dir()/as.
inline void copy_data_file(const std::string& name, const std::string& as) {
  std::ifstream in(std::string(DIFFPHD_DATA_DIR) + "/" + name, std::ios::binary);
  if (!in) {
    std::fprintf(stderr, "fuzz: cannot read %s/%s\n", DIFFPHD_DATA_DIR, name.c_str());
    std::abort();
  }
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  write_file(temp_path(as), reinterpret_cast<const std::uint8_t*>(text.data()), text.size());
}

/// The mesh files a fuzzed scene may name, copied beside it: two.node/two.ele (3D, two tets),
/// square2d.node/square2d.ele (2D), box.msh (3D Gmsh 2.2) and square.msh (2D Gmsh 2.2).
inline void copy_scene_meshes() {
  copy_data_file("two.node", "two.node");
  copy_data_file("two.ele", "two.ele");
  copy_data_file("square2d.node", "square2d.node");
  copy_data_file("square2d.ele", "square2d.ele");
  copy_data_file("gmsh_box22.msh", "box.msh");
  copy_data_file("gmsh_square22.msh", "square.msh");
}

/// Runs f; an InputError is the expected outcome of bad input and is swallowed (printed when
/// the environment sets DIFFPHD_FUZZ_VERBOSE, to check what a seed reaches).
template <class F>
void expect_input_error(F&& f) {
  static const bool verbose = std::getenv("DIFFPHD_FUZZ_VERBOSE") != nullptr;
  try {
    f();
    if (verbose) std::fprintf(stderr, "fuzz: read without error\n");
  } catch (const diffphd::InputError& e) {
    if (verbose) std::fprintf(stderr, "fuzz: InputError: %s\n", e.what());
  }
}

/// A broken invariant of a successfully read result: report and abort (a finding).
[[noreturn]] inline void invariant_failed(const char* what) {
  std::fprintf(stderr, "fuzz: invariant broken: %s\n", what);
  std::abort();
}

/// Small limits so that an input that passes the checks still runs fast under the sanitizers.
inline void set_small_limits() {
  diffphd::io::Limits& l = diffphd::io::limits();
  l.max_vertices = 20'000;
  l.max_elements = 20'000;
}

}  // namespace fuzz
