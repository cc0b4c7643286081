/// \file fuzz_gmsh.cpp
/// \brief libFuzzer harness: the input is a Gmsh ASCII .msh file (2.2 or 4.1, told apart by
/// its $MeshFormat line), read as 3D and 2D and peeked at by mesh_dimension.
#include <diffphd/io/gmsh.hpp>
#include <diffphd/io/read_mesh.hpp>

#include "fuzz_common.hpp"

namespace {

template <int Dim>
void read_as(const std::string& msh) {
  fuzz::expect_input_error([&] {
    const auto m = diffphd::io::read_gmsh_with_regions<Dim>(msh);
    if (m.region.size() != static_cast<size_t>(m.mesh.num_elements()) ||
        m.vertex_id.size() != static_cast<size_t>(m.mesh.num_vertices()))
      fuzz::invariant_failed("read_gmsh: region or vertex_id has the wrong size");
  });
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  fuzz::set_small_limits();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, size_t size) {
  const std::string msh = fuzz::temp_path("in.msh");
  fuzz::write_file(msh, data, size);
  fuzz::expect_input_error([&] { diffphd::io::mesh_dimension(msh); });
  read_as<3>(msh);
  read_as<2>(msh);
  return 0;
}
