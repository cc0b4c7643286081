/// \file fuzz_tetgen_node.cpp
/// \brief libFuzzer harness: the input is a TetGen/Triangle .node file, read with a fixed small
/// .ele (tests/data/two.ele: two tetrahedra over points 0..4) as 3D and as 2D, and peeked at by
/// mesh_dimension.
#include <diffphd/io/read_mesh.hpp>
#include <diffphd/io/tetgen.hpp>

#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  fuzz::set_small_limits();
  fuzz::copy_data_file("two.ele", "in.ele");
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, size_t size) {
  const std::string node = fuzz::temp_path("in.node");
  fuzz::write_file(node, data, size);
  fuzz::expect_input_error([&] { diffphd::io::mesh_dimension(node); });
  fuzz::expect_input_error([&] { diffphd::io::read_tetgen_with_regions<3>(node); });
  fuzz::expect_input_error([&] { diffphd::io::read_tetgen_with_regions<2>(node); });
  return 0;
}
