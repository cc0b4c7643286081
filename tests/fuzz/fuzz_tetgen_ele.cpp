/// \file fuzz_tetgen_ele.cpp
/// \brief libFuzzer harness: the input is a TetGen/Triangle .ele file, read against a fixed 3D
/// .node (tests/data/two.node, 5 points numbered from 0) and a fixed 2D .node
/// (tests/data/square2d.node).
#include <diffphd/io/tetgen.hpp>

#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  fuzz::set_small_limits();
  fuzz::copy_data_file("two.node", "in3.node");
  fuzz::copy_data_file("square2d.node", "in2.node");
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, size_t size) {
  const std::string ele3 = fuzz::temp_path("in3.ele"), ele2 = fuzz::temp_path("in2.ele");
  fuzz::write_file(ele3, data, size);
  fuzz::write_file(ele2, data, size);
  fuzz::expect_input_error([&] { diffphd::io::read_tetgen_with_regions<3>(ele3); });
  fuzz::expect_input_error([&] { diffphd::io::read_tetgen_with_regions<2>(ele2); });
  return 0;
}
