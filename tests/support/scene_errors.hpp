#pragma once
// The check the scene tests share: an action on a scene file must throw an InputError that
// names the file first ("PATH: ...") and contains every expected phrase. Header only (Catch2
// macros); include as "support/scene_errors.hpp".
#include <functional>
#include <string>
#include <vector>

#include <catch2/catch.hpp>

#include <diffphd/core/errors.hpp>
#include <diffphd/io/scene.hpp>

namespace diffphd::test {

/// fn() must throw an InputError whose file() is `path`, whose message starts with "path: "
/// and contains every string of `expect`.
inline void check_file_error(const std::string& path, const std::function<void()>& fn,
                             const std::vector<std::string>& expect) {
  try {
    fn();
    FAIL("no InputError for " << path);
  } catch (const InputError& e) {
    const std::string what = e.what();
    INFO(what);
    CHECK(e.file() == path);
    CHECK(what.rfind(path + ": ", 0) == 0);
    for (const std::string& x : expect) CHECK_THAT(what, Catch::Contains(x));
  }
}

/// io::load_scene(path) must fail that way.
inline void check_load_error(const std::string& path, const std::vector<std::string>& expect) {
  check_file_error(path, [&] { io::load_scene(path); }, expect);
}

}  // namespace diffphd::test
