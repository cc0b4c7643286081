/// \file fuzz_surface.cpp
/// \brief libFuzzer harness for the surface readers, built twice: fuzz_off (the input is OFF
/// text, read by read_off) and fuzz_obj (OBJ text, read_obj), chosen by FUZZ_SURFACE_OBJ. A
/// surface read without error must have finite vertices and face indices in range.
#include <diffphd/io/surface.hpp>

#include "fuzz_common.hpp"

namespace {

void check_surface(const diffphd::io::SurfaceMesh& s) {
  if (s.V.cols() != 3 || s.F.cols() != 3) fuzz::invariant_failed("V or F is not #x3");
  if (!s.V.allFinite()) fuzz::invariant_failed("a vertex is not finite");
  for (Eigen::Index i = 0; i < s.F.size(); ++i)
    if (s.F.data()[i] < 0 || s.F.data()[i] >= s.V.rows())
      fuzz::invariant_failed("a face index is out of range");
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  fuzz::set_small_limits();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, size_t size) {
#ifdef FUZZ_SURFACE_OBJ
  const std::string path = fuzz::temp_path("in.obj");
  const auto read = [](const std::string& p) { return diffphd::io::read_obj(p); };
#else
  const std::string path = fuzz::temp_path("in.off");
  const auto read = [](const std::string& p) { return diffphd::io::read_off(p); };
#endif
  fuzz::write_file(path, data, size);
  fuzz::expect_input_error([&] { check_surface(read(path)); });
  return 0;
}
