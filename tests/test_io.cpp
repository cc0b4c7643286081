// Tests of diffphd/io: TetGen, Gmsh, OFF, OBJ readers and writers, VTU/PVD output.
#include <catch2/catch.hpp>

#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <diffphd/io/generators.hpp>
#include <diffphd/io/read_mesh.hpp>
#include <diffphd/io/surface.hpp>
#include <diffphd/io/vtk.hpp>

namespace fs = std::filesystem;
using Catch::Contains;
using namespace diffphd;

namespace {

const std::string kData = DIFFPHD_SOURCE_DIR "/tests/data/";
const std::string kBad = DIFFPHD_SOURCE_DIR "/tests/data/bad/";

/// A fresh directory under the system temp dir, removed with everything in it at scope exit.
struct TempDir {
  fs::path path;
  TempDir() {
    std::random_device rd;
    path = fs::temp_directory_path() / ("diffphd_test_io_" + std::to_string(rd()));
    fs::create_directories(path);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
  std::string operator/(const std::string& name) const { return (path / name).string(); }
};

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

size_t count_of(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) ++n;
  return n;
}

/// A bad input file, where its error must point ("file:line:") and what it must say.
struct BadCase {
  std::string file;
  std::string where;
  std::string message;
  std::function<void(const std::string&)> read;
};

void check_bad_cases(const std::vector<BadCase>& cases) {
  for (const BadCase& c : cases) {
    INFO("file " << c.file);
    CHECK_THROWS_AS(c.read(kBad + c.file), InputError);
    CHECK_THROWS_WITH(c.read(kBad + c.file), Contains(c.where) && Contains(c.message));
  }
}

template <int Dim>
void require_same_mesh(const SimplicialMesh<Dim>& a, const SimplicialMesh<Dim>& b, double tol = 0) {
  REQUIRE(a.num_vertices() == b.num_vertices());
  REQUIRE(a.num_elements() == b.num_elements());
  CHECK((a.rest_positions() - b.rest_positions()).cwiseAbs().maxCoeff() <= tol);
  CHECK(a.elements() == b.elements());
}

/// Every undirected edge of a triangle surface is used exactly twice, once in each direction.
bool closed_and_consistent(const Eigen::MatrixXi& F) {
  std::map<std::pair<int, int>, int> directed;
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    for (int k = 0; k < 3; ++k) ++directed[{F(f, k), F(f, (k + 1) % 3)}];
  for (const auto& [edge, n] : directed) {
    if (n != 1) return false;
    const auto reverse = directed.find({edge.second, edge.first});
    if (reverse == directed.end() || reverse->second != 1) return false;
  }
  return true;
}

/// Volume enclosed by a closed outward triangle surface (divergence theorem).
double enclosed_volume(const Eigen::MatrixXd& V, const Eigen::MatrixXi& F) {
  double vol = 0;
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const Eigen::Vector3d a = V.row(F(f, 0)), b = V.row(F(f, 1)), c = V.row(F(f, 2));
    vol += a.dot(b.cross(c)) / 6.0;
  }
  return vol;
}

}  // namespace

// ---- TetGen ------------------------------------------------------------------------------

TEST_CASE("TetGen: 0- and 1-based output of the same cube give the same mesh", "[io][tetgen]") {
  const auto m0 = io::read_tetgen_with_regions<3>(kData + "tetgen_cube0");
  const auto m1 = io::read_tetgen_with_regions<3>(kData + "tetgen_cube1.node");
  require_same_mesh(m0.mesh, m1.mesh);
  CHECK(m0.mesh.num_vertices() == 66);
  CHECK(m0.mesh.num_elements() == 133);
  CHECK(m0.mesh.total_volume() == Approx(1.0).epsilon(1e-12));
  CHECK(m0.mesh.rest_volumes().minCoeff() > 0);
  CHECK(m0.region == std::vector<int>(133, 0));
  CHECK(m1.region == std::vector<int>(133, 7));  // tetgen -A with region attribute 7
  CHECK(m0.vertex_id.front() == 0);
  CHECK(m1.vertex_id.front() == 1);
  CHECK(m1.vertex_id.back() == 66);
  CHECK(m0.mesh.source().file == kData + "tetgen_cube0.ele");
  // The boundary of the cube: closed, outward, enclosing the volume.
  const Eigen::MatrixXi F = m0.mesh.boundary_facets();
  CHECK(closed_and_consistent(F));
  CHECK(enclosed_volume(m0.mesh.rest_positions(), F) == Approx(1.0).epsilon(1e-12));
}

TEST_CASE("TetGen: comments, attributes, markers, blank lines and the three path forms",
          "[io][tetgen]") {
  for (const std::string p : {"two", "two.node", "two.ele"}) {
    const auto m = io::read_tetgen_with_regions<3>(kData + p);
    REQUIRE(m.mesh.num_vertices() == 5);
    REQUIRE(m.mesh.num_elements() == 2);
    CHECK(m.region == std::vector<int>{1, 2});
    CHECK(m.mesh.rest_positions().row(4) == Eigen::RowVector3d(1, 1, 1));
    CHECK(m.mesh.source().element_line == std::vector<long>{2, 3});
  }
  const auto one = io::read_tetgen(kData + "two1");
  require_same_mesh(io::read_tetgen(kData + "two"), one);
}

TEST_CASE("TetGen: 2D Triangle files", "[io][tetgen]") {
  const auto m = io::read_tetgen_with_regions<2>(kData + "square2d");
  CHECK(m.mesh.num_elements() == 2);
  CHECK(m.mesh.total_volume() == Approx(1.0));
  CHECK(m.region == std::vector<int>{1, 2});
  require_same_mesh(io::read_tetgen2d(kData + "square2d.ele"), m.mesh);
  CHECK_THROWS_WITH(io::read_tetgen<3>(kData + "square2d"),
                    Contains("square2d.node:2:") && Contains("is 2D but a 3D mesh"));
  CHECK_THROWS_WITH(io::read_tetgen<2>(kData + "two"),
                    Contains("two.node:2:") && Contains("is 3D but a 2D mesh"));
}

TEST_CASE("TetGen: bad input names the file and line", "[io][tetgen][errors]") {
  const auto rd = [](const std::string& p) { io::read_tetgen<3>(p); };
  check_bad_cases({
      {"missing", "missing.node:", "cannot open file", rd},
      {"trunc", "trunc.node:1:", "declares 5 points but the file ends after 3", rd},
      {"nonnumeric", "nonnumeric.node:4:", "expected a number for coordinate 1 of point 2", rd},
      {"nan", "nan.node:3:", "coordinate 0 of point 1 is not finite: 'nan'", rd},
      {"inf", "inf.node:5:", "coordinate 2 of point 3 is not finite: 'inf'", rd},
      {"repeated_point", "repeated_point.node:4:", "point number 1 is repeated", rd},
      {"fields", "fields.node:3:", "expected 4 fields", rd},
      {"extra", "extra.node:7:", "extra data after the 5 points", rd},
      {"range", "range.ele:3:", "element 1: vertex index 5 is out of range [0, 5)", rd},
      {"repeat", "repeat.ele:2:", "element 0: vertex index 1 is repeated", rd},
      {"inverted", "inverted.ele:3:", "element 1: inverted rest element", rd},
      {"degenerate", "degenerate.ele:3:", "element 1: degenerate rest element", rd},
      {"trunc_ele", "trunc_ele.ele:1:", "declares 3 elements but the file ends after 2", rd},
      {"element_seq", "element_seq.ele:3:", "element number 0 is repeated or out of sequence", rd},
      {"region_nonint", "region_nonint.ele:2:", "region attribute of element 0 must be an integer",
       rd},
      {"ele_nonnumeric", "ele_nonnumeric.ele:3:", "found 'three'", rd},
      {"quadratic", "quadratic.ele:1:", "second-order elements are not supported", rd},
      {"onebased_zero", "onebased_zero.ele:2:", "vertex index 0 is out of range [1, 6)", rd},
  });
  InputError e("x");
  try {
    io::read_tetgen(kBad + "inverted");
  } catch (const InputError& err) {
    e = err;
  }
  CHECK(e.file() == kBad + "inverted.ele");
  CHECK(e.line() == 3);
}

TEST_CASE("TetGen: write_tetgen round trip, 0- and 1-based, with regions", "[io][tetgen]") {
  TempDir tmp;
  const auto box = make_box(Vec<3>(0, 0, 0), Vec<3>(1, 0.5, 0.25), Eigen::Vector3i(4, 2, 1));
  std::vector<int> region(box.num_elements());
  for (size_t e = 0; e < region.size(); ++e) region[e] = static_cast<int>(e % 3);
  for (int base : {0, 1}) {
    io::write_tetgen(tmp / "box", box, region, base);
    const auto back = io::read_tetgen_with_regions<3>(tmp / "box.ele");
    require_same_mesh(box, back.mesh);
    CHECK(back.region == region);
    CHECK(back.vertex_id.front() == base);
  }
  const auto rect = make_rectangle(Vec<2>(0, 0), Vec<2>(2, 1), Eigen::Vector2i(3, 2));
  io::write_tetgen(tmp / "rect", rect);
  require_same_mesh(rect, io::read_tetgen<2>(tmp / "rect"));
  CHECK_THROWS_WITH(io::write_tetgen(tmp / "no/such/dir/box", box),
                    Contains("no/such/dir/box.node") && Contains("cannot open file for writing"));
}

// ---- Gmsh --------------------------------------------------------------------------------

TEST_CASE("Gmsh: 2.2, 4.1 and parametric 4.1 files of the same box give the same mesh",
          "[io][gmsh]") {
  const auto m22 = io::read_gmsh_with_regions<3>(kData + "gmsh_box22.msh");
  const auto m41 = io::read_gmsh_with_regions<3>(kData + "gmsh_box41.msh");
  const auto m41p = io::read_gmsh_with_regions<3>(kData + "gmsh_box41_param.msh");
  require_same_mesh(m22.mesh, m41.mesh);
  require_same_mesh(m22.mesh, m41p.mesh);
  CHECK(m22.vertex_id == m41.vertex_id);
  CHECK(m22.mesh.num_elements() == 100);
  CHECK(m22.mesh.total_volume() == Approx(1.0).epsilon(1e-12));
  CHECK(m22.mesh.rest_volumes().minCoeff() > 0);  // Gmsh tets are positive as written
  CHECK(m22.region == std::vector<int>(100, 7));  // Physical Volume("solid", 7)
  CHECK(m41.region == m22.region);
  CHECK(m41p.region == m22.region);
  CHECK(m22.region_names == std::map<int, std::string>{{7, "solid"}});
  CHECK(m41.region_names == m22.region_names);
  CHECK(closed_and_consistent(m22.mesh.boundary_facets()));
  CHECK(io::read_gmsh<3>(kData + "gmsh_box41.msh").num_vertices() == m41.mesh.num_vertices());
}

TEST_CASE("Gmsh: 2D files, a clockwise surface is flipped as a whole", "[io][gmsh]") {
  // gmsh_square.geo: surface 1 is counterclockwise, surface 2 clockwise (Gmsh meshes it CW).
  const auto m22 = io::read_gmsh_with_regions<2>(kData + "gmsh_square22.msh");
  const auto m41 = io::read_gmsh_with_regions<2>(kData + "gmsh_square41.msh");
  require_same_mesh(m22.mesh, m41.mesh);
  CHECK(m22.region == m41.region);
  CHECK(m22.mesh.total_volume() == Approx(2.0).epsilon(1e-12));
  CHECK(m22.mesh.rest_volumes().minCoeff() > 0);
  const std::set<int> regions(m22.region.begin(), m22.region.end());
  CHECK(regions == std::set<int>{1, 2});
  CHECK(m22.region_names == std::map<int, std::string>{{1, "a"}, {2, "b"}});
  CHECK_THROWS_WITH(io::read_gmsh<3>(kData + "gmsh_square22.msh"),
                    Contains("gmsh_square22.msh: no tetrahedra (type 4)"));
  CHECK_THROWS_WITH(io::read_gmsh<2>(kData + "gmsh_box22.msh"),
                    Contains("gmsh_box22.msh:") && Contains("read it as a 3D mesh"));
}

TEST_CASE("Gmsh: physical names with spaces, point elements ignored", "[io][gmsh]") {
  const auto m = io::read_gmsh_with_regions<3>(kData + "two22.msh");
  CHECK(m.mesh.num_elements() == 2);
  CHECK(m.region == std::vector<int>{1, 2});
  CHECK(m.region_names.at(1) == "soft part");
  CHECK(m.mesh.source().element_line == std::vector<long>{20, 21});
  CHECK(m.mesh.source().vertex_line == std::vector<long>{11, 12, 13, 14, 15});
}

TEST_CASE("Gmsh: bad input names the file and line", "[io][gmsh][errors]") {
  const auto rd = [](const std::string& p) { io::read_gmsh<3>(p); };
  check_bad_cases({
      {"missing.msh", "missing.msh:", "cannot open file", rd},
      {"binary.msh", "binary.msh:2:", "binary .msh is not supported", rd},
      {"version3.msh", "version3.msh:2:", "version 3.0 is not supported", rd},
      {"trunc_nodes.msh", "trunc_nodes.msh:5:", "declares 5 nodes, found 3", rd},
      {"nodes_count_small.msh", "nodes_count_small.msh:10:", "expected $EndNodes", rd},
      {"nonnumeric.msh", "nonnumeric.msh:8:", "expected a number for coordinate 1 of node 3", rd},
      {"nan.msh", "nan.msh:9:", "coordinate 2 of node 4 is not finite", rd},
      {"undefined_node.msh", "undefined_node.msh:16:", "node tag 9 is not defined", rd},
      {"repeated_node.msh", "repeated_node.msh:8:", "node tag 2 is repeated", rd},
      {"inverted.msh", "inverted.msh:16:", "element 1: inverted rest element", rd},
      {"trunc_elements.msh", "trunc_elements.msh:13:", "declares 3 elements, found 2", rd},
      {"short_element.msh", "short_element.msh:15:", "expected 9 fields", rd},
      {"trunc41.msh", "trunc41.msh:9:", "expected 1 field (node tag), found 3", rd},
      {"inverted2d.msh", "inverted2d.msh:14:", "element 1: inverted rest element",
       [](const std::string& p) { io::read_gmsh<2>(p); }},
      {"nonplanar2d.msh", "nonplanar2d.msh:9:", "node tag 4 has z = 0.5",
       [](const std::string& p) { io::read_gmsh<2>(p); }},
  });
}

TEST_CASE("Gmsh: write_gmsh22 round trip in 2D and 3D", "[io][gmsh]") {
  TempDir tmp;
  const auto box = make_box(Vec<3>(-1, 0, 0), Vec<3>(1, 1, 3), Eigen::Vector3i(2, 1, 3));
  std::vector<int> region(box.num_elements(), 4);
  region[0] = 9;
  io::write_gmsh22(tmp / "box.msh", box, region);
  const auto back = io::read_gmsh_with_regions<3>(tmp / "box.msh");
  require_same_mesh(box, back.mesh);
  CHECK(back.region == region);
  const auto rect = make_rectangle(Vec<2>(0, 0), Vec<2>(1, 1), Eigen::Vector2i(2, 2));
  io::write_gmsh22(tmp / "rect.msh", rect);
  require_same_mesh(rect, io::read_gmsh<2>(tmp / "rect.msh"));
}

// ---- dispatch ----------------------------------------------------------------------------

TEST_CASE("read_mesh dispatches by extension, mesh_dimension peeks", "[io]") {
  CHECK(io::mesh_dimension(kData + "two.node") == 3);
  CHECK(io::mesh_dimension(kData + "two.ele") == 3);
  CHECK(io::mesh_dimension(kData + "square2d.node") == 2);
  CHECK(io::mesh_dimension(kData + "gmsh_box41.msh") == 3);
  CHECK(io::mesh_dimension(kData + "gmsh_box22.msh") == 3);
  CHECK(io::mesh_dimension(kData + "gmsh_square22.msh") == 2);
  CHECK(io::mesh_dimension(kData + "gmsh_square41.msh") == 2);
  require_same_mesh(io::read_mesh<3>(kData + "two.node"), io::read_tetgen(kData + "two"));
  require_same_mesh(io::read_mesh<3>(kData + "gmsh_box41.msh"),
                    io::read_gmsh<3>(kData + "gmsh_box22.msh"));
  CHECK(io::read_mesh_with_regions<2>(kData + "gmsh_square41.msh").region.size() > 0);
  CHECK_THROWS_WITH(io::read_mesh<3>(kData + "tetra.off"),
                    Contains("tetra.off: unknown mesh file extension '.off'"));
  CHECK_THROWS_WITH(io::mesh_dimension(kData + "nothing.vtk"), Contains("nothing.vtk"));
  CHECK_THROWS_WITH(io::mesh_dimension(kBad + "binary.msh"), Contains("binary.msh:2:"));
}

// ---- OFF / OBJ -----------------------------------------------------------------------------

TEST_CASE("OFF: read, fan triangulation and round trip", "[io][off]") {
  const auto tet = io::read_off(kData + "tetra.off");
  CHECK(tet.V.rows() == 4);
  CHECK(tet.F.rows() == 4);
  CHECK(closed_and_consistent(tet.F));
  CHECK(enclosed_volume(tet.V, tet.F) == Approx(1.0 / 6.0));
  const auto cube = io::read_off(kData + "tetgen_cube.off");  // 6 quads, outward
  CHECK(cube.F.rows() == 12);
  CHECK(closed_and_consistent(cube.F));
  CHECK(enclosed_volume(cube.V, cube.F) == Approx(1.0));
  TempDir tmp;
  io::write_off(tmp / "cube.off", cube.V, cube.F);
  const auto back = io::read_off(tmp / "cube.off");
  CHECK(back.V == cube.V);
  CHECK(back.F == cube.F);
}

TEST_CASE("OBJ: v/vt/vn forms, negative indices, polygons, round trip", "[io][obj]") {
  const auto s = io::read_obj(kData + "square_mixed.obj");
  REQUIRE(s.V.rows() == 6);
  REQUIRE(s.F.rows() == 4);
  Eigen::MatrixXi expected(4, 3);
  expected << 0, 1, 2, 0, 2, 3, 1, 4, 5, 1, 5, 2;
  CHECK(s.F == expected);
  double area = 0;
  for (int f = 0; f < 4; ++f) {
    const Eigen::Vector3d a = s.V.row(s.F(f, 0)), b = s.V.row(s.F(f, 1)), c = s.V.row(s.F(f, 2));
    const Eigen::Vector3d n = (b - a).cross(c - a);
    CHECK(n.z() > 0);
    area += n.norm() / 2;
  }
  CHECK(area == Approx(2.0));
  TempDir tmp;
  io::write_obj(tmp / "s.obj", s.V, s.F);
  const auto back = io::read_obj(tmp / "s.obj");
  CHECK(back.V == s.V);
  CHECK(back.F == s.F);
  CHECK_THROWS_WITH(io::write_obj(tmp / "no/dir/s.obj", s.V, s.F),
                    Contains("no/dir/s.obj") && Contains("cannot open file for writing"));
}

TEST_CASE("OFF and OBJ: bad input names the file and line", "[io][off][obj][errors]") {
  const auto off = [](const std::string& p) { io::read_off(p); };
  const auto obj = [](const std::string& p) { io::read_obj(p); };
  check_bad_cases({
      {"missing.off", "missing.off:", "cannot open file", off},
      {"off_trunc.off", "off_trunc.off:2:", "declares 4 faces but the file ends after 3", off},
      {"off_range.off", "off_range.off:9:", "face 2: vertex index 4 is out of range [0, 4)", off},
      {"off_nonnumeric.off", "off_nonnumeric.off:5:", "found 'x'", off},
      {"off_badheader.off", "off_badheader.off:1:", "not an OFF file", off},
      {"missing.obj", "missing.obj:", "cannot open file", obj},
      {"obj_zero.obj", "obj_zero.obj:4:", "vertex index 0 is invalid", obj},
      {"obj_range.obj", "obj_range.obj:6:", "vertex index 9 is out of range [1, 3]", obj},
      {"obj_nan.obj", "obj_nan.obj:2:", "coordinate 1 of vertex 2 is not finite", obj},
      {"obj_negative.obj", "obj_negative.obj:4:", "relative vertex index -4", obj},
      {"obj_nonnumeric.obj", "obj_nonnumeric.obj:4:", "expected a vertex index in 'c'", obj},
  });
}

// ---- Bounded resources (io::limits(), docs/reliability.md) ------------------------------

TEST_CASE("Readers: counts beyond the limits or the file size are rejected before allocating",
          "[io][errors][limits]") {
  const auto tet3 = [](const std::string& p) { io::read_tetgen<3>(p); };
  const auto msh3 = [](const std::string& p) { io::read_gmsh<3>(p); };
  const auto off = [](const std::string& p) { io::read_off(p); };
  const auto obj = [](const std::string& p) { io::read_obj(p); };
  check_bad_cases({
      // A 35-byte file claiming 10^11 points.
      {"huge_points.node", "huge_points.node:1:",
       "100000000000 points declared here exceed the limit 100000000 "
       "(io::limits().max_vertices)",
       tet3},
      {"size_points.node", "size_points.node:1:",
       "5000000 points declared here cannot fit in the 24 bytes that follow", tet3},
      {"huge_attr.node", "huge_attr.node:1:",
       "9223372036854775807 point attributes declared here cannot fit", tet3},
      {"huge_elements.ele", "huge_elements.ele:1:",
       "100000000000 elements declared here exceed the limit 100000000 "
       "(io::limits().max_elements)",
       tet3},
      {"huge_eattr.ele", "huge_eattr.ele:1:",
       "9223372036854775807 element attributes declared here cannot fit", tet3},
      {"huge_nodes22.msh", "huge_nodes22.msh:5:",
       "100000000000 nodes declared here exceed the limit 100000000", msh3},
      {"size_block41.msh", "size_block41.msh:6:",
       "50000000 nodes in the block declared here cannot fit", msh3},
      {"size_elements22.msh", "size_elements22.msh:5:",
       "3000000 elements declared here cannot fit", msh3},
      {"huge_entities41.msh", "huge_entities41.msh:5:",
       "9223372036854775807 entities of dimension 0 declared here cannot fit", msh3},
      // Tags that do not fit in an int used to wrap silently (4294967298 became region 2).
      {"physical_int.msh", "physical_int.msh:21:",
       "the physical tag does not fit in an int: '4294967298'", msh3},
      {"huge_faces.off", "huge_faces.off:2:",
       "100000000000 faces declared here exceed the limit 100000000", off},
      {"size_vertices.off", "size_vertices.off:2:",
       "50000000 vertices declared here cannot fit in the 6 bytes that follow", off},
      // Found while reviewing read_obj for its harness: index 4294967297 wrapped to 0 when
      // stored as an int (a silently wrong face), and -LONG_MIN overflowed.
      {"obj_huge_index.obj", "obj_huge_index.obj:4:",
       "vertex index 4294967297 is above the limit of 100000000 vertices", obj},
      {"obj_min_index.obj", "obj_min_index.obj:4:",
       "relative vertex index -9223372036854775808 reaches before the first vertex", obj},
  });
  // mesh_dimension peeks at the same files without reading the counts.
  CHECK(io::mesh_dimension(kBad + "huge_points.node") == 3);
}

TEST_CASE("Readers: io::limits() can be lowered and raised", "[io][limits]") {
  io::Limits& lim = io::limits();
  const io::Limits saved = lim;
  lim.max_vertices = 3;
  CHECK_THROWS_WITH(io::read_tetgen<3>(kData + "two"),
                    Contains("two.node:2:") &&
                        Contains("5 points declared here exceed the limit 3 "
                                 "(io::limits().max_vertices)"));
  CHECK_THROWS_WITH(io::read_off(kData + "tetra.off"),
                    Contains("tetra.off:3:") && Contains("4 vertices declared here exceed the limit 3"));
  CHECK_THROWS_WITH(io::read_obj(kData + "square_mixed.obj"),
                    Contains("more than 3 vertices (io::limits().max_vertices)"));
  lim.max_vertices = saved.max_vertices;
  lim.max_elements = 1;
  CHECK_THROWS_WITH(io::read_gmsh<3>(kData + "two22.msh"),
                    Contains("declared here exceed the limit 1 (io::limits().max_elements)"));
  CHECK_THROWS_WITH(make_box(Vec<3>(0, 0, 0), Vec<3>(1, 1, 1), Eigen::Vector3i(1, 1, 1)),
                    Contains("make_box: the mesh would have 8 vertices and 6 elements") &&
                        Contains("(io::limits().max_vertices and max_elements)"));
  lim = saved;
  CHECK(io::read_tetgen<3>(kData + "two").num_vertices() == 5);
  // Generators check their size before an int overflows.
  CHECK_THROWS_WITH(make_box(Vec<3>(0, 0, 0), Vec<3>(1, 1, 1), Eigen::Vector3i(100000, 100000, 1)),
                    Contains("make_box: the mesh would have 2e+10 vertices"));
  CHECK_THROWS_WITH(make_sphere(1.0, 1 << 30), Contains("make_sphere: the mesh would have"));
  CHECK_THROWS_WITH(make_bar(1e12, 1, 1, 1'000'000'000), Contains("make_bar: the mesh would have"));
}

TEST_CASE("write_surface_obj: deformed boundary in 3D, flat triangles in 2D", "[io][obj]") {
  TempDir tmp;
  const auto box = make_box(Vec<3>(0, 0, 0), Vec<3>(1, 1, 1), Eigen::Vector3i(2, 2, 2));
  const VertexMatrix<3> x = 2.0 * box.rest_positions();
  io::write_surface_obj(tmp / "box.obj", box, x);
  const auto s = io::read_obj(tmp / "box.obj");
  CHECK(s.F.rows() == box.boundary_facets().rows());
  CHECK(s.V.rows() == 26);  // 27 grid vertices minus the interior one
  CHECK(closed_and_consistent(s.F));
  CHECK(enclosed_volume(s.V, s.F) == Approx(8.0));

  const auto rect = make_rectangle(Vec<2>(0, 0), Vec<2>(3, 1), Eigen::Vector2i(3, 1));
  io::write_surface_obj(tmp / "rect.obj", rect, rect.rest_positions());
  const auto r = io::read_obj(tmp / "rect.obj");
  CHECK(r.F.rows() == rect.num_elements());
  CHECK(r.V.col(2).cwiseAbs().maxCoeff() == 0);
  CHECK_THROWS_AS(io::write_surface_obj(tmp / "bad.obj", rect, x), InputError);
}

// ---- VTU / PVD -----------------------------------------------------------------------------

TEST_CASE("write_vtu: points, cells, types and data arrays", "[io][vtk]") {
  TempDir tmp;
  const auto box = make_box(Vec<3>(0, 0, 0), Vec<3>(1, 1, 1), Eigen::Vector3i(1, 1, 2));
  io::PointData pd{{"velocity", Eigen::MatrixXd::Ones(box.num_vertices(), 3)},
                   {"mass", box.lumped_mass(Eigen::VectorXd::Ones(box.num_elements()))}};
  io::CellData cd{{"region", Eigen::VectorXd::LinSpaced(box.num_elements(), 0, 11)}};
  io::write_vtu(tmp / "box.vtu", box, box.rest_positions(), pd, cd);
  const std::string text = slurp(tmp / "box.vtu");
  CHECK_THAT(text, Contains("NumberOfPoints=\"12\" NumberOfCells=\"12\""));
  CHECK_THAT(text, Contains("Name=\"velocity\" NumberOfComponents=\"3\""));
  CHECK_THAT(text, Contains("Name=\"mass\" NumberOfComponents=\"1\""));
  CHECK_THAT(text, Contains("<CellData>") && Contains("Name=\"region\""));
  std::string tetra_types;
  for (int e = 0; e < 12; ++e) tetra_types += "10 ";  // VTK_TETRA
  CHECK_THAT(text, Contains("Name=\"types\" format=\"ascii\">\n" + tetra_types + "\n"));

  const auto rect = make_rectangle(Vec<2>(0, 0), Vec<2>(1, 1), Eigen::Vector2i(1, 1));
  io::write_vtu(tmp / "rect.vtu", rect, rect.rest_positions(),
                {{"u", Eigen::MatrixXd::Zero(4, 2)}});
  const std::string t2 = slurp(tmp / "rect.vtu");
  CHECK_THAT(t2, Contains("NumberOfPoints=\"4\" NumberOfCells=\"2\""));
  CHECK_THAT(t2, Contains("Name=\"u\" NumberOfComponents=\"3\""));  // 2D vectors padded
  CHECK_THAT(t2, Contains("Name=\"types\" format=\"ascii\">\n5 5"));
  CHECK_THAT(t2, Contains("Name=\"offsets\" format=\"ascii\">\n3 6"));

  CHECK_THROWS_WITH(io::write_vtu(tmp / "x.vtu", rect, rect.rest_positions(),
                                  {{"bad", Eigen::MatrixXd::Zero(3, 1)}}),
                    Contains("point data 'bad' has 3 rows, expected 4"));
  CHECK_THROWS_WITH(io::write_vtu(tmp / "x.vtu", rect, rect.rest_positions(), {},
                                  {{"c", Eigen::VectorXd::Zero(5)}}),
                    Contains("cell data 'c' has 5 entries, expected 2"));
  CHECK_THROWS_WITH(io::write_vtu(tmp / "no/dir/x.vtu", rect, rect.rest_positions()),
                    Contains("no/dir/x.vtu: cannot open file for writing"));
}

TEST_CASE("PvdWriter: numbered frames and a collection rewritten after each", "[io][vtk]") {
  TempDir tmp;
  const auto rect = make_rectangle(Vec<2>(0, 0), Vec<2>(1, 1), Eigen::Vector2i(2, 2));
  io::PvdWriter pvd(tmp / "run", "sheet");
  for (int i = 0; i < 3; ++i) {
    VertexMatrix<2> x = rect.rest_positions();
    x.col(1).array() -= 0.1 * i;
    pvd.add_frame(0.01 * i, rect, x, {}, {{"id", Eigen::VectorXd::Zero(rect.num_elements())}});
    const std::string collection = slurp(pvd.pvd_path());
    CHECK(count_of(collection, "<DataSet") == static_cast<size_t>(i + 1));
  }
  CHECK(pvd.num_frames() == 3);
  CHECK(pvd.pvd_path() == tmp / "run/sheet.pvd");
  CHECK(pvd.frame_path(2) == tmp / "run/sheet_000002.vtu");
  CHECK(fs::exists(pvd.frame_path(0)));
  CHECK(fs::exists(pvd.frame_path(2)));
  const std::string collection = slurp(pvd.pvd_path());
  CHECK_THAT(collection, Contains("timestep=\"0.02\"") && Contains("file=\"sheet_000002.vtu\""));
  CHECK_FALSE(fs::exists(pvd.pvd_path() + ".tmp"));
}

// ---- committed real meshes -----------------------------------------------------------------

TEST_CASE("Real meshes: bunny and armadillo read with positive volumes", "[io][data]") {
  for (const std::string name : {"bunny", "armadillo"}) {
    const std::string base = std::string(DIFFPHD_DATA_DIR) + "/meshes/" + name;
    if (!fs::exists(base + ".node") || !fs::exists(base + ".ele")) {
      WARN("skipped: " << base << ".node/.ele not found");
      continue;
    }
    INFO(name);
    CHECK(io::mesh_dimension(base + ".node") == 3);
    const auto mesh = io::read_mesh<3>(base + ".ele");
    CHECK(mesh.num_elements() > 1000);
    CHECK(mesh.rest_volumes().minCoeff() > 0);
    const Eigen::MatrixXi F = mesh.boundary_facets();
    CHECK(closed_and_consistent(F));
    CHECK(enclosed_volume(mesh.rest_positions(), F) == Approx(mesh.total_volume()).epsilon(1e-9));
    if (fs::exists(base + "_surface.off")) {
      const auto surface = io::read_off(base + "_surface.off");
      CHECK(enclosed_volume(surface.V, surface.F) == Approx(mesh.total_volume()).epsilon(1e-6));
    }
  }
}
