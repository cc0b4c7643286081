#pragma once
/// \file scene.hpp
/// \brief Scene files (JSON) -> a plain, validated SceneSpec, and the builders that turn a
/// SceneSpec into a mesh, a MaterialField, vertex selections, a Dirichlet mask, initial
/// velocities and the per-element muscle data (build_muscles). No dependency on the solver: a
/// SceneSpec is data; the solver (or the CLI) reads it. The schema is documented in
/// docs/scenes.md.
///
/// Every error in a scene file is an InputError whose what() reads
/// "SCENE_FILE: JSON.PATH: message", e.g.
/// "scenes/armadillo_twist.json: regions[2].material.youngs_modulus: must be > 0, found -1";
/// unknown keys are errors with a suggestion ("unknown key \"youngs_modulis\" in
/// regions[2].material (did you mean \"youngs_modulus\"?)"). Errors found while building
/// (a selector that matches no vertex, an element index out of range, a region that matches no
/// element) name the scene file and the JSON path too.
///
/// \code
/// diffphd::io::SceneSpec scene = diffphd::io::load_scene("scenes/armadillo_twist.json", 100.0);
/// if (diffphd::io::scene_dimension(scene) == 3) {
///   auto m = diffphd::io::build_mesh_with_regions<3>(scene);
///   diffphd::MaterialField mats = diffphd::io::build_materials<3>(scene, m.mesh, m.region);
///   auto fixed = diffphd::io::fixed_mask<3>(scene, m.mesh);     // #V by 3, for PDSystem
///   std::vector<diffphd::Index> top = diffphd::io::select_vertices<3>(scene.drivers[0].vertices,
///                                                                     m.mesh);
/// }
/// \endcode

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "../core/errors.hpp"
#include "../core/material.hpp"
#include "../core/mesh.hpp"
#include "../core/types.hpp"
#include "generators.hpp"
#include "mesh_with_regions.hpp"
#include "plant.hpp"
#include "read_mesh.hpp"

namespace diffphd::io {

// ---------------------------------------------------------------------------------------------
// The plain data
// ---------------------------------------------------------------------------------------------

/// \brief The PD energy of a scene ("energy" in "solver").
enum class EnergyKind {
  CorotatedVolume,      ///< "corotated+volume": Corotated (w = 2 mu) plus Volume (w = lambda)
  NeoHookean,           ///< "neo-hookean": the Neo-Hookean prox term (Sec. 4.2)
  NeoHookeanLogVolume,  ///< "neo-hookean+logvolume": Neo-Hookean prox plus the log-volume barrier
  Corotated,            ///< "corotated": Corotated only
  /// "corotated+volume+muscle": Corotated plus Volume plus the Muscle fibre term (needs a
  /// "muscles" section)
  CorotatedVolumeMuscle
};

/// True when the energy has a muscle (fibre) term, so that a scene with it needs "muscles".
inline bool has_muscle_term(EnergyKind e) {
  return e == EnergyKind::CorotatedVolumeMuscle;
}

/// \brief How per-element stiffness is routed ("routing" in "solver"; paper Sec. 4.2, Fig. 4).
enum class Routing {
  StiffnessAware,  ///< "stiffness-aware": w_e from each element's material, prox with means
  PerElementProx,  ///< "per-element-prox": per-element material inside the local prox too
  Uniform          ///< "uniform": one weight for all elements (plain PD, the baseline)
};

/// \brief What the dual gate's tolerances are relative to ("gate" in "solver").
enum class Gate {
  Paper,        ///< "paper": eq. (22) as printed (relative to ||q^k|| and ||b(q^k)||)
  StepRelative  ///< "step-relative": relative to this step's motion and the elastic part of b
};

inline const char* to_string(Gate g) { return g == Gate::Paper ? "paper" : "step-relative"; }

/// The scene-file name of an energy ("corotated+volume", ...).
inline const char* to_string(EnergyKind e) {
  switch (e) {
    case EnergyKind::CorotatedVolume:
      return "corotated+volume";
    case EnergyKind::NeoHookean:
      return "neo-hookean";
    case EnergyKind::NeoHookeanLogVolume:
      return "neo-hookean+logvolume";
    case EnergyKind::Corotated:
      return "corotated";
    case EnergyKind::CorotatedVolumeMuscle:
      return "corotated+volume+muscle";
  }
  return "?";
}
/// The scene-file name of a routing ("stiffness-aware", ...).
inline const char* to_string(Routing r) {
  switch (r) {
    case Routing::StiffnessAware:
      return "stiffness-aware";
    case Routing::PerElementProx:
      return "per-element-prox";
    case Routing::Uniform:
      return "uniform";
  }
  return "?";
}

/// \brief The mesh of a scene: a file or a generator, then an optional scale and translation
/// (x -> scale x + translate). Lengths in metres. Only the fields of `kind` are meaningful.
struct MeshSpec {
  enum class Kind { File, Box, Bar, Rectangle, Sheet, Sphere, Torus, Branching };
  Kind kind = Kind::Box;
  int dimension = 3;  ///< 2 (triangles) or 3 (tetrahedra); from the file or the generator

  std::string file;  ///< File: resolved path (relative to the scene file's folder)

  VectorX lo, hi;         ///< Box, Rectangle: opposite corners, m (dimension entries)
  Eigen::VectorXi cells;  ///< Box: 3 cells per axis; Rectangle: 2; Sheet: cells along x and z

  double length = 0, width = 0, height = 0;    ///< Bar: m (Sheet uses width)
  int cells_along_length = 0;                  ///< Bar
  double depth = 0, thickness = 0;             ///< Sheet: m
  double radius = 0;                           ///< Sphere: m
  int resolution = 0;                          ///< Sphere: cells along the radius
  double major_radius = 0, minor_radius = 0;   ///< Torus: m
  int ring_segments = 0, tube_resolution = 0;  ///< Torus
  PlantParams plant;                           ///< Branching

  double scale = 1.0;  ///< uniform scale factor, > 0
  VectorX translate;   ///< m, dimension entries (zero by default)
};

/// \brief An axis-aligned box [lo, hi] (closed). With relative = true, lo and hi are fractions
/// of the mesh's bounding box (0 = its low corner, 1 = its high corner along each axis).
struct BoxSpec {
  VectorX lo, hi;  ///< m (or fractions), dimension entries, lo <= hi
  bool relative = false;
};

/// \brief The slab lo <= x[axis] <= hi (closed). relative as in BoxSpec.
struct SlabSpec {
  int axis = 0;                                          ///< 0, 1 or 2 (< dimension)
  double lo = -std::numeric_limits<double>::infinity();  ///< m (or fraction)
  double hi = std::numeric_limits<double>::infinity();   ///< m (or fraction)
  bool relative = false;
};

/// \brief A set of mesh vertices: an index list, the vertices in a box, or in a slab.
/// Boxes and slabs are widened by 1e-9 of the bounding-box diagonal so that vertices lying
/// exactly on a face are selected despite rounding.
struct VertexSelector {
  enum class Kind { Indices, Box, Slab };
  Kind kind = Kind::Indices;
  std::vector<Index> indices;  ///< Indices: 0-based vertex indices
  BoxSpec box;                 ///< Box
  SlabSpec slab;               ///< Slab
  std::string scene_file;      ///< for error messages
  std::string json_path;       ///< e.g. "fixed[0].vertices", for error messages
};

/// \brief One region assignment: the elements it selects get `material`. Assignments apply in
/// order; a later one overrides an earlier one. Elements are selected by index list, by their
/// centroid in a box or slab, or by the mesh's region attribute (the file's region ids, or the
/// branching generator's branch level).
struct RegionSpec {
  enum class Kind { Elements, Box, Slab, MeshRegion };
  std::string name;  ///< unique; "regions[i]" when the file gives none
  Kind kind = Kind::Elements;
  std::vector<Index> elements;  ///< Elements: 0-based element indices
  BoxSpec box;                  ///< Box (element centroids)
  SlabSpec slab;                ///< Slab (element centroids)
  int mesh_region = 0;          ///< MeshRegion: the region id in the mesh
  /// Pa, -, kg/m^3; keys missing from the file are the default material's. material.region is
  /// the label given to the elements: i + 1 for regions[i] (the default material has 0).
  Material material;
  std::string json_path;  ///< "regions[i]"
};

/// \brief A set of mesh elements, chosen the way a region assignment chooses them (by index
/// list, by centroid in a box or slab, or by the mesh's region id). Used by muscle groups;
/// select_elements() takes it (and RegionSpec).
struct ElementSelector {
  using Kind = RegionSpec::Kind;
  Kind kind = Kind::Elements;
  std::vector<Index> elements;  ///< Elements: 0-based element indices
  BoxSpec box;                  ///< Box (element centroids)
  SlabSpec slab;                ///< Slab (element centroids)
  int mesh_region = 0;          ///< MeshRegion: the region id in the mesh
  std::string json_path;        ///< e.g. "muscles.groups[3]", for error messages
};

/// The element selection of a region assignment.
inline ElementSelector element_selector(const RegionSpec& r) {
  ElementSelector s;
  s.kind = r.kind;
  s.elements = r.elements;
  s.box = r.box;
  s.slab = r.slab;
  s.mesh_region = r.mesh_region;
  s.json_path = r.json_path;
  return s;
}

/// \brief One muscle group ("muscles.groups[i]"): the elements it selects get the Muscle term
/// k/2 (|F m| - a)^2 with the group's stiffness k, fibre m and activation a (energies/muscle.hpp).
/// Groups must not overlap (checked when built, build_muscles()).
struct MuscleGroupSpec {
  std::string name;          ///< unique among the groups; "muscles.groups[i]" when not given
  ElementSelector elements;  ///< which elements
  VectorX fibre;             ///< rest-space fibre direction, dimension entries, unit length
  double stiffness = 0;      ///< k, Pa, > 0 (the group's "stiffness", else muscles.stiffness)
  double activation = 1.0;   ///< a, target fibre stretch (1 = rest length), finite, > 0
  std::string json_path;     ///< "muscles.groups[i]"
};

/// \brief The "muscles" section: fibre actuation of element groups. Needs an energy with a
/// muscle term ("corotated+volume+muscle"); such an energy needs this section. `groups` is
/// empty when the scene has no "muscles" section. The contrast factor does not scale muscle
/// stiffness.
struct MuscleSpec {
  double stiffness = 0;                 ///< the file's default k, Pa (0 when not given)
  std::vector<MuscleGroupSpec> groups;  ///< in file order; the group index is the position here
  bool empty() const { return groups.empty(); }
};

/// \brief A Dirichlet condition: the selected vertices stay at their rest position along the
/// flagged axes.
struct FixSpec {
  VertexSelector vertices;
  std::array<bool, 3> axes{{true, true, true}};  ///< per axis; only the first dimension used
};

/// \brief A scripted driver on a vertex set (Dirichlet while active). Between start and stop
/// the selected vertices follow a prescribed motion from their positions at `start`: twist
/// rotates them about the line through `center` along `axis` with angular_velocity; pull moves
/// them with constant `velocity`. After stop they are released (free) when release_at_stop,
/// else held where the motion ended. Before start they are free.
struct DriverSpec {
  enum class Kind { Twist, Pull };
  Kind kind = Kind::Twist;
  VertexSelector vertices;
  int axis = 2;                   ///< Twist: 0, 1 or 2 (in 2D always 2, the plane normal)
  std::optional<VectorX> center;  ///< Twist: m; absent = centroid of the selected vertices
  double angular_velocity = 0;    ///< Twist: rad/s, right-handed about +axis
  VectorX velocity;               ///< Pull: m/s, dimension entries
  double start = 0;               ///< s, >= 0
  double stop = std::numeric_limits<double>::infinity();  ///< s, > start
  bool release_at_stop = false;
  std::string json_path;  ///< "drivers[i]"
};

/// \brief A constant force on a vertex set while start <= t < stop.
struct ForceSpec {
  VertexSelector vertices;
  /// N, dimension entries: on each selected vertex, or (total = true) the total shared equally
  /// by the selected vertices (see per_vertex_force).
  VectorX force;
  bool total = false;
  double start = 0;                                       ///< s
  double stop = std::numeric_limits<double>::infinity();  ///< s
  std::string json_path;                                  ///< "forces[i]"
};

/// \brief The initial velocity v(x) = linear + angular x (x - c), c the centre of mass.
struct InitialVelocitySpec {
  VectorX linear;   ///< m/s, dimension entries (zero by default)
  VectorX angular;  ///< rad/s: 3 entries in 3D, 1 in 2D (about the plane normal); zero default
};

/// \brief Solver configuration. Defaults follow the paper (Sec. 4.3, 4.5, 5).
struct SolverSpec {
  EnergyKind energy = EnergyKind::CorotatedVolume;
  Routing routing = Routing::StiffnessAware;
  int anderson_window = -1;  ///< -1: automatic (m = 1 heterogeneous, 5 homogeneous); 0: off
  double eps_rel = 1e-4;     ///< dual-gate relative tolerance, eq. (22), > 0
  double eps_abs = 1e-8;     ///< dual-gate absolute tolerance, eq. (22), >= 0
  Gate gate = Gate::Paper;   ///< what eps_rel is relative to
  int max_iterations = 200;  ///< PD iterations per step, >= 1
  double alpha = 0;          ///< mass damping alpha, 1/s, >= 0 (eq. 31)
  double beta0 = 0;          ///< stiffness damping beta_0, s, >= 0 (Sec. 4.5)
};

/// \brief The contrast hook: the Young's modulus of regions[i] is multiplied by
/// factor^exponents[i] (exponents default to 1; 0.5 puts a region halfway between 1x and the
/// full contrast on a log scale, as the paper's Armadillo slabs).
struct ContrastSpec {
  std::vector<std::string> regions;  ///< region names; "default" names the default material
  std::vector<double> exponents;     ///< one per region, finite (1 when the file gives none)
  double default_factor = 1;         ///< the file's "default", > 0
  double factor = 1;                 ///< applied: the command line's --contrast, else default
};

/// \brief Frames, steps per frame and the output name. Duration = frames substeps h.
struct OutputSpec {
  int frames = 1;    ///< >= 1
  int substeps = 1;  ///< solver steps per frame, >= 1
  std::string name;  ///< the scene's name (the file's stem when not given)
};

/// \brief A whole scene, validated. SI units throughout.
struct SceneSpec {
  std::string file;  ///< the scene file as given to load_scene
  std::string description;
  MeshSpec mesh;
  Material default_material;        ///< region label 0
  std::vector<RegionSpec> regions;  ///< applied in order over the default material
  ContrastSpec contrast;
  std::vector<FixSpec> fixed;
  std::vector<DriverSpec> drivers;
  VectorX gravity;  ///< m/s^2, dimension entries (zero by default)
  std::vector<ForceSpec> forces;
  InitialVelocitySpec initial_velocity;
  double h = 1.0 / 60.0;  ///< s, the time step of one solver step, > 0
  SolverSpec solver;
  OutputSpec output;
  MuscleSpec muscles;  ///< empty when the file has no "muscles" section
};

// ---------------------------------------------------------------------------------------------
// Parsing
// ---------------------------------------------------------------------------------------------

namespace scene_detail {

using json = nlohmann::json;
constexpr double kInf = std::numeric_limits<double>::infinity();

inline std::string child(const std::string& path, const std::string& key) {
  return path.empty() ? key : path + "." + key;
}
inline std::string item(const std::string& path, size_t i) {
  return path + "[" + std::to_string(i) + "]";
}
inline std::string where(const std::string& path) {
  return path.empty() ? std::string("the top level") : path;
}

inline size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<size_t> prev(b.size() + 1), cur(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) prev[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    cur[0] = i;
    for (size_t j = 1; j <= b.size(); ++j)
      cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (a[i - 1] != b[j - 1])});
    std::swap(prev, cur);
  }
  return prev[b.size()];
}

inline std::string type_of(const json& j) {
  if (j.is_number()) return "a number";
  if (j.is_string()) return "a string";
  if (j.is_boolean()) return "a boolean";
  if (j.is_array()) return "an array";
  if (j.is_object()) return "an object";
  if (j.is_null()) return "null";
  return j.type_name();
}

inline std::string format_number(double v) {
  std::ostringstream os;
  os.precision(12);
  os << v;
  return os.str();
}

/// Reads one scene file; knows the file name so that every error names it.
class Parser {
 public:
  explicit Parser(std::string file) : file_(std::move(file)) {}

  [[noreturn]] void fail(const std::string& path, const std::string& message) const {
    throw InputError(path.empty() ? message : path + ": " + message, file_);
  }
  const std::string& file() const { return file_; }

  /// Checks that j is an object whose keys are all in `allowed` (plus "comment").
  void expect_object(const json& j, const std::string& path,
                     std::initializer_list<const char*> allowed) const {
    if (!j.is_object()) fail(path, "expected an object, found " + type_of(j));
    for (auto it = j.begin(); it != j.end(); ++it) {
      const std::string& key = it.key();
      if (key == "comment") continue;
      bool ok = false;
      for (const char* a : allowed) ok = ok || key == a;
      if (ok) continue;
      std::string best;
      size_t best_d = std::numeric_limits<size_t>::max();
      for (const char* a : allowed) {
        const size_t d = edit_distance(key, a);
        if (d < best_d) best_d = d, best = a;
      }
      std::string msg = "unknown key \"" + key + "\" in " + where(path);
      if (!best.empty() && best_d <= std::max<size_t>(2, key.size() / 3))
        msg += " (did you mean \"" + best + "\"?)";
      else {
        msg += " (allowed:";
        for (const char* a : allowed) msg += std::string(" \"") + a + "\"";
        msg += ")";
      }
      throw InputError(msg, file_);
    }
  }

  static bool has(const json& obj, const char* key) { return obj.contains(key); }

  const json& required(const json& obj, const std::string& path, const char* key) const {
    if (!obj.contains(key)) fail(path, std::string("missing required key \"") + key + "\"");
    return obj.at(key);
  }

  double number(const json& j, const std::string& path) const {
    if (!j.is_number()) fail(path, "expected a number, found " + type_of(j));
    const double v = j.get<double>();
    if (!std::isfinite(v)) fail(path, "must be finite");
    return v;
  }
  long integer(const json& j, const std::string& path) const {
    if (!j.is_number()) fail(path, "expected an integer, found " + type_of(j));
    if (j.is_number_integer()) return j.get<long>();
    const double v = j.get<double>();
    if (!(std::isfinite(v) && v == std::floor(v) && std::abs(v) < 1e15))
      fail(path, "expected an integer, found " + format_number(v));
    return static_cast<long>(v);
  }
  bool boolean(const json& j, const std::string& path) const {
    if (!j.is_boolean()) fail(path, "expected true or false, found " + type_of(j));
    return j.get<bool>();
  }
  std::string string(const json& j, const std::string& path) const {
    if (!j.is_string()) fail(path, "expected a string, found " + type_of(j));
    return j.get<std::string>();
  }
  const json& array(const json& j, const std::string& path) const {
    if (!j.is_array()) fail(path, "expected an array, found " + type_of(j));
    return j;
  }
  /// An array of exactly n numbers.
  VectorX vector(const json& j, const std::string& path, int n, const char* why) const {
    array(j, path);
    if (static_cast<int>(j.size()) != n)
      fail(path, "expected " + std::to_string(n) + " numbers (" + why + "), found " +
                     std::to_string(j.size()));
    VectorX v(n);
    for (int i = 0; i < n; ++i) v[i] = number(j[i], item(path, i));
    return v;
  }

  // Keyed variants: obj[key] at path.key, with a default when missing.
  double number(const json& obj, const std::string& path, const char* key,
                std::optional<double> def = {}) const {
    if (!obj.contains(key)) {
      if (def) return *def;
      fail(path, std::string("missing required key \"") + key + "\"");
    }
    return number(obj.at(key), child(path, key));
  }
  long integer(const json& obj, const std::string& path, const char* key,
               std::optional<long> def = {}) const {
    if (!obj.contains(key)) {
      if (def) return *def;
      fail(path, std::string("missing required key \"") + key + "\"");
    }
    return integer(obj.at(key), child(path, key));
  }
  bool boolean(const json& obj, const std::string& path, const char* key, bool def) const {
    return obj.contains(key) ? boolean(obj.at(key), child(path, key)) : def;
  }

  // Range checks that name the value.
  void positive(double v, const std::string& path) const {
    if (!(v > 0)) fail(path, "must be > 0, found " + format_number(v));
  }
  void non_negative(double v, const std::string& path) const {
    if (!(v >= 0)) fail(path, "must be >= 0, found " + format_number(v));
  }
  void at_least(long v, long lo, const std::string& path) const {
    if (v < lo) fail(path, "must be >= " + std::to_string(lo) + ", found " + std::to_string(v));
  }
  int axis(const json& obj, const std::string& path, const char* key, int dim) const {
    const long a = integer(obj, path, key);
    if (a < 0 || a > 2)
      fail(child(path, key), "axis must be 0, 1 or 2, found " + std::to_string(a));
    if (a >= dim)
      fail(child(path, key),
           "axis " + std::to_string(a) + " does not exist in a " + std::to_string(dim) + "D scene");
    return static_cast<int>(a);
  }

 private:
  std::string file_;
};

inline void parse_material(const Parser& p, const json& j, const std::string& path, Material& m,
                           bool require_youngs_modulus) {
  p.expect_object(j, path, {"youngs_modulus", "poisson_ratio", "density"});
  if (require_youngs_modulus || j.contains("youngs_modulus"))
    m.youngs_modulus = p.number(j, path, "youngs_modulus");
  if (j.contains("poisson_ratio")) m.poisson_ratio = p.number(j, path, "poisson_ratio");
  if (j.contains("density")) m.density = p.number(j, path, "density");
  if (!(m.youngs_modulus > 0))
    p.fail(child(path, "youngs_modulus"), "must be > 0, found " + format_number(m.youngs_modulus));
  if (!(m.poisson_ratio > -1 && m.poisson_ratio < 0.5))
    p.fail(child(path, "poisson_ratio"),
           "must lie in (-1, 0.5), found " + format_number(m.poisson_ratio));
  if (!(m.density > 0))
    p.fail(child(path, "density"), "must be > 0, found " + format_number(m.density));
}

inline BoxSpec parse_box(const Parser& p, const json& j, const std::string& path, int dim) {
  p.expect_object(j, path, {"lo", "hi", "relative"});
  const char* why = dim == 3 ? "one per axis of a 3D scene" : "one per axis of a 2D scene";
  BoxSpec b;
  b.lo = p.vector(p.required(j, path, "lo"), child(path, "lo"), dim, why);
  b.hi = p.vector(p.required(j, path, "hi"), child(path, "hi"), dim, why);
  b.relative = p.boolean(j, path, "relative", false);
  for (int d = 0; d < dim; ++d)
    if (b.lo[d] > b.hi[d])
      p.fail(item(child(path, "hi"), d), "must be >= lo[" + std::to_string(d) +
                                             "] = " + format_number(b.lo[d]) + ", found " +
                                             format_number(b.hi[d]));
  return b;
}

inline SlabSpec parse_slab(const Parser& p, const json& j, const std::string& path, int dim) {
  p.expect_object(j, path, {"axis", "lo", "hi", "relative"});
  SlabSpec s;
  s.axis = p.axis(j, path, "axis", dim);
  s.lo = p.number(j, path, "lo", -kInf);
  s.hi = p.number(j, path, "hi", kInf);
  s.relative = p.boolean(j, path, "relative", false);
  if (!j.contains("lo") && !j.contains("hi")) p.fail(path, "give \"lo\", \"hi\" or both");
  if (s.lo > s.hi)
    p.fail(child(path, "hi"),
           "must be >= lo = " + format_number(s.lo) + ", found " + format_number(s.hi));
  return s;
}

inline std::vector<Index> parse_indices(const Parser& p, const json& j, const std::string& path) {
  p.array(j, path);
  if (j.empty()) p.fail(path, "the index list is empty");
  std::vector<Index> out;
  for (size_t i = 0; i < j.size(); ++i) {
    const long v = p.integer(j[i], item(path, i));
    if (v < 0 || v > std::numeric_limits<Index>::max())
      p.fail(item(path, i), "index must be >= 0, found " + std::to_string(v));
    out.push_back(static_cast<Index>(v));
  }
  return out;
}

/// The one key among `keys` that obj holds; fails when none or several are given.
inline std::string one_of(const Parser& p, const json& obj, const std::string& path,
                          std::initializer_list<const char*> keys) {
  std::string found, list;
  for (const char* k : keys) {
    list += std::string(list.empty() ? "" : ", ") + "\"" + k + "\"";
    if (obj.contains(k)) {
      if (!found.empty())
        p.fail(path, "give only one of " + std::string("\"") + found + "\" and \"" + k + "\"");
      found = k;
    }
  }
  if (found.empty()) p.fail(path, "give one of " + list);
  return found;
}

inline VertexSelector parse_selector(const Parser& p, const json& obj, const std::string& parent,
                                     int dim) {
  const std::string path = child(parent, "vertices");
  const json& j = p.required(obj, parent, "vertices");
  p.expect_object(j, path, {"indices", "box", "slab"});
  VertexSelector s;
  s.scene_file = p.file();
  s.json_path = path;
  const std::string k = one_of(p, j, path, {"indices", "box", "slab"});
  if (k == "indices") {
    s.kind = VertexSelector::Kind::Indices;
    s.indices = parse_indices(p, j.at(k), child(path, k));
  } else if (k == "box") {
    s.kind = VertexSelector::Kind::Box;
    s.box = parse_box(p, j.at(k), child(path, k), dim);
  } else {
    s.kind = VertexSelector::Kind::Slab;
    s.slab = parse_slab(p, j.at(k), child(path, k), dim);
  }
  return s;
}

/// The element selection of obj (a region or a muscle group at `path`): exactly one of
/// "elements", "box", "slab", "mesh_region".
inline ElementSelector parse_element_selector(const Parser& p, const json& obj,
                                              const std::string& path, int dim) {
  ElementSelector sel;
  sel.json_path = path;
  const std::string k = one_of(p, obj, path, {"elements", "box", "slab", "mesh_region"});
  if (k == "elements") {
    sel.kind = ElementSelector::Kind::Elements;
    sel.elements = parse_indices(p, obj.at(k), child(path, k));
  } else if (k == "box") {
    sel.kind = ElementSelector::Kind::Box;
    sel.box = parse_box(p, obj.at(k), child(path, k), dim);
  } else if (k == "slab") {
    sel.kind = ElementSelector::Kind::Slab;
    sel.slab = parse_slab(p, obj.at(k), child(path, k), dim);
  } else {
    sel.kind = ElementSelector::Kind::MeshRegion;
    sel.mesh_region = static_cast<int>(p.integer(obj.at(k), child(path, k)));
  }
  return sel;
}

/// The "muscles" section (see MuscleSpec); per_axis names the fibre's expected length.
inline MuscleSpec parse_muscles(const Parser& p, const json& j, int dim, const char* per_axis) {
  const std::string path = "muscles";
  p.expect_object(j, path, {"stiffness", "groups"});
  MuscleSpec m;
  if (j.contains("stiffness")) {
    m.stiffness = p.number(j, path, "stiffness");
    p.positive(m.stiffness, "muscles.stiffness");
  }
  const json& gs = p.array(p.required(j, path, "groups"), "muscles.groups");
  if (gs.empty()) p.fail("muscles.groups", "the list is empty");
  std::map<std::string, std::string> names;  // name -> JSON path
  for (size_t i = 0; i < gs.size(); ++i) {
    const std::string gp = item("muscles.groups", i);
    const json& g = gs[i];
    p.expect_object(
        g, gp,
        {"name", "elements", "box", "slab", "mesh_region", "fibre", "stiffness", "activation"});
    MuscleGroupSpec grp;
    grp.json_path = gp;
    grp.name = g.contains("name") ? p.string(g.at("name"), child(gp, "name")) : gp;
    if (grp.name.empty()) p.fail(child(gp, "name"), "must not be empty");
    const auto [it, inserted] = names.emplace(grp.name, gp);
    if (!inserted)
      p.fail(child(gp, "name"),
             "muscle group name \"" + grp.name + "\" is used twice (also " + it->second + ")");
    grp.elements = parse_element_selector(p, g, gp, dim);
    grp.fibre = p.vector(p.required(g, gp, "fibre"), child(gp, "fibre"), dim, per_axis);
    const double n = grp.fibre.norm();
    if (!(n > 0)) p.fail(child(gp, "fibre"), "must not be the zero vector");
    grp.fibre /= n;
    if (g.contains("stiffness")) {
      grp.stiffness = p.number(g, gp, "stiffness");
      p.positive(grp.stiffness, child(gp, "stiffness"));
    } else if (m.stiffness > 0) {
      grp.stiffness = m.stiffness;
    } else {
      p.fail(gp, "missing \"stiffness\" (give it here or as muscles.stiffness)");
    }
    grp.activation = p.number(g, gp, "activation", 1.0);
    p.positive(grp.activation, child(gp, "activation"));
    m.groups.push_back(std::move(grp));
  }
  return m;
}

inline void parse_window(const Parser& p, const json& j, const std::string& path, double& start,
                         double& stop) {
  start = p.number(j, path, "start", 0.0);
  p.non_negative(start, child(path, "start"));
  stop = j.contains("stop") ? p.number(j, path, "stop") : kInf;
  if (!(stop > start))
    p.fail(child(path, "stop"),
           "must be > start = " + format_number(start) + ", found " + format_number(stop));
}

inline MeshSpec parse_mesh(const Parser& p, const json& root) {
  const std::string path = "mesh";
  const json& j = p.required(root, "", "mesh");
  if (!j.is_object()) p.fail(path, "expected an object, found " + type_of(j));
  MeshSpec m;
  const std::string k = one_of(p, j, path, {"file", "generator"});
  auto common = [&](std::initializer_list<const char*> keys) {
    std::vector<const char*> all(keys);
    all.push_back("scale");
    all.push_back("translate");
    all.push_back(k == "file" ? "file" : "generator");
    // expect_object takes an initializer_list; check by hand with the same message.
    if (!j.is_object()) p.fail(path, "expected an object");
    for (auto it = j.begin(); it != j.end(); ++it) {
      if (it.key() == "comment") continue;
      if (std::find_if(all.begin(), all.end(), [&](const char* a) { return it.key() == a; }) !=
          all.end())
        continue;
      std::string best;
      size_t best_d = std::numeric_limits<size_t>::max();
      for (const char* a : all) {
        const size_t d = edit_distance(it.key(), a);
        if (d < best_d) best_d = d, best = a;
      }
      std::string msg = "unknown key \"" + it.key() + "\" in mesh";
      if (best_d <= std::max<size_t>(2, it.key().size() / 3))
        msg += " (did you mean \"" + best + "\"?)";
      else {
        msg += " (allowed here:";
        for (const char* a : all) msg += std::string(" \"") + a + "\"";
        msg += ")";
      }
      throw InputError(msg, p.file());
    }
  };
  auto count = [&](const char* key, long minimum, std::optional<long> def = {}) {
    const long v = p.integer(j, path, key, def);
    p.at_least(v, minimum, child(path, key));
    return static_cast<int>(v);
  };
  auto length = [&](const char* key) {
    const double v = p.number(j, path, key);
    p.positive(v, child(path, key));
    return v;
  };
  if (k == "file") {
    common({});
    const std::string given = p.string(j.at("file"), "mesh.file");
    namespace fs = std::filesystem;
    fs::path resolved = fs::path(given);
    if (resolved.is_relative()) resolved = fs::path(p.file()).parent_path() / resolved;
    m.kind = MeshSpec::Kind::File;
    m.file = resolved.lexically_normal().string();
    std::error_code ec;
    const std::string ext = detail::extension_of(m.file);
    std::string probe = m.file;
    if (ext == ".node" || ext == ".ele") probe = detail::strip_extension(m.file) + ".node";
    if (!fs::is_regular_file(probe, ec))
      p.fail("mesh.file", "mesh file not found: " + probe + " (resolved from \"" + given +
                              "\" relative to the scene file's folder)");
    if (ext == ".node" || ext == ".ele") {
      const std::string ele = detail::strip_extension(m.file) + ".ele";
      if (!fs::is_regular_file(ele, ec)) p.fail("mesh.file", "mesh file not found: " + ele);
    } else if (ext != ".msh") {
      p.fail("mesh.file",
             "unknown mesh file extension \"" + ext + "\" (expected .node, .ele or .msh)");
    }
    try {
      m.dimension = mesh_dimension(m.file);
    } catch (const InputError& e) {
      p.fail("mesh.file", e.what());
    }
  } else {
    const std::string g = p.string(j.at("generator"), "mesh.generator");
    if (g == "box") {
      common({"lo", "hi", "cells"});
      m.kind = MeshSpec::Kind::Box;
      m.dimension = 3;
    } else if (g == "rectangle") {
      common({"lo", "hi", "cells"});
      m.kind = MeshSpec::Kind::Rectangle;
      m.dimension = 2;
    } else if (g == "bar") {
      common({"length", "width", "height", "cells_along_length"});
      m.kind = MeshSpec::Kind::Bar;
      m.length = length("length");
      m.width = length("width");
      m.height = length("height");
      m.cells_along_length = count("cells_along_length", 1);
    } else if (g == "sheet") {
      common({"width", "depth", "thickness", "cells"});
      m.kind = MeshSpec::Kind::Sheet;
      m.width = length("width");
      m.depth = length("depth");
      m.thickness = length("thickness");
    } else if (g == "sphere") {
      common({"radius", "resolution"});
      m.kind = MeshSpec::Kind::Sphere;
      m.radius = length("radius");
      m.resolution = count("resolution", 1);
    } else if (g == "torus") {
      common({"major_radius", "minor_radius", "ring_segments", "tube_resolution"});
      m.kind = MeshSpec::Kind::Torus;
      m.major_radius = length("major_radius");
      m.minor_radius = length("minor_radius");
      if (!(m.major_radius > m.minor_radius))
        p.fail("mesh.major_radius", "must be > minor_radius = " + format_number(m.minor_radius) +
                                        ", found " + format_number(m.major_radius));
      m.ring_segments = count("ring_segments", 3);
      m.tube_resolution = count("tube_resolution", 1);
    } else if (g == "branching") {
      common({"trunk_length", "trunk_radius", "levels", "branches", "length_ratio", "radius_ratio",
              "branch_angle", "cell_size"});
      m.kind = MeshSpec::Kind::Branching;
      PlantParams& q = m.plant;
      const PlantParams d;
      q.trunk_length = p.number(j, path, "trunk_length", d.trunk_length);
      p.positive(q.trunk_length, "mesh.trunk_length");
      q.trunk_radius = p.number(j, path, "trunk_radius", d.trunk_radius);
      p.positive(q.trunk_radius, "mesh.trunk_radius");
      q.levels = static_cast<int>(p.integer(j, path, "levels", d.levels));
      if (q.levels < 1 || q.levels > 3)
        p.fail("mesh.levels", "must be 1, 2 or 3, found " + std::to_string(q.levels));
      q.branches = static_cast<int>(p.integer(j, path, "branches", d.branches));
      if (q.branches != 2 && q.branches != 3)
        p.fail("mesh.branches", "must be 2 or 3, found " + std::to_string(q.branches));
      q.length_ratio = p.number(j, path, "length_ratio", d.length_ratio);
      if (!(q.length_ratio > 0 && q.length_ratio <= 1))
        p.fail("mesh.length_ratio", "must lie in (0, 1], found " + format_number(q.length_ratio));
      q.radius_ratio = p.number(j, path, "radius_ratio", d.radius_ratio);
      if (!(q.radius_ratio > 0 && q.radius_ratio <= 1))
        p.fail("mesh.radius_ratio", "must lie in (0, 1], found " + format_number(q.radius_ratio));
      q.branch_angle = p.number(j, path, "branch_angle", d.branch_angle);
      if (!(q.branch_angle > 0 && q.branch_angle <= 90))
        p.fail("mesh.branch_angle",
               "must lie in (0, 90] degrees, found " + format_number(q.branch_angle));
      q.cell_size = p.number(j, path, "cell_size", d.cell_size);
      p.positive(q.cell_size, "mesh.cell_size");
      try {
        plant_branches(q);  // radius >= cell_size for every level
      } catch (const InputError& e) {
        p.fail("mesh", e.what());
      }
    } else {
      p.fail("mesh.generator", "unknown generator \"" + g +
                                   "\" (expected \"box\", \"bar\", \"rectangle\", \"sheet\", "
                                   "\"sphere\", \"torus\" or \"branching\")");
    }
    if (m.kind == MeshSpec::Kind::Box || m.kind == MeshSpec::Kind::Rectangle) {
      const int d = m.dimension;
      const char* why = d == 3 ? "a box is 3D" : "a rectangle is 2D";
      m.lo = p.vector(p.required(j, path, "lo"), "mesh.lo", d, why);
      m.hi = p.vector(p.required(j, path, "hi"), "mesh.hi", d, why);
      for (int a = 0; a < d; ++a)
        if (!(m.hi[a] > m.lo[a]))
          p.fail(item("mesh.hi", a), "must be > lo[" + std::to_string(a) +
                                         "] = " + format_number(m.lo[a]) + ", found " +
                                         format_number(m.hi[a]));
    }
    if (m.kind == MeshSpec::Kind::Box || m.kind == MeshSpec::Kind::Rectangle ||
        m.kind == MeshSpec::Kind::Sheet) {
      const int n = m.kind == MeshSpec::Kind::Box ? 3 : 2;
      const json& c = p.array(p.required(j, path, "cells"), "mesh.cells");
      if (static_cast<int>(c.size()) != n)
        p.fail("mesh.cells",
               "expected " + std::to_string(n) + " cell counts, found " + std::to_string(c.size()));
      m.cells.resize(n);
      for (int a = 0; a < n; ++a) {
        const long v = p.integer(c[a], item("mesh.cells", a));
        p.at_least(v, 1, item("mesh.cells", a));
        m.cells[a] = static_cast<int>(v);
      }
    }
  }
  m.scale = p.number(j, path, "scale", 1.0);
  p.positive(m.scale, "mesh.scale");
  m.translate = j.contains("translate")
                    ? p.vector(j.at("translate"), "mesh.translate", m.dimension,
                               m.dimension == 3 ? "the mesh is 3D" : "the mesh is 2D")
                    : VectorX::Zero(m.dimension);
  return m;
}

inline SceneSpec parse(const Parser& p, const json& root, std::optional<double> contrast) {
  p.expect_object(
      root, "",
      {"name", "description", "mesh", "material", "regions", "contrast", "fixed", "drivers",
       "gravity", "forces", "initial_velocity", "time", "solver", "muscles"});
  SceneSpec s;
  s.file = p.file();
  s.output.name = root.contains("name") ? p.string(root.at("name"), "name")
                                        : std::filesystem::path(p.file()).stem().string();
  if (root.contains("description")) s.description = p.string(root.at("description"), "description");

  s.mesh = parse_mesh(p, root);
  const int dim = s.mesh.dimension;
  const char* per_axis = dim == 3 ? "one per axis of a 3D scene" : "one per axis of a 2D scene";

  // Materials and regions.
  parse_material(p, p.required(root, "", "material"), "material", s.default_material, true);
  s.default_material.region = 0;
  std::set<std::string> names;
  if (root.contains("regions")) {
    const json& rs = p.array(root.at("regions"), "regions");
    for (size_t i = 0; i < rs.size(); ++i) {
      const std::string path = item("regions", i);
      const json& r = rs[i];
      p.expect_object(r, path, {"name", "elements", "box", "slab", "mesh_region", "material"});
      RegionSpec reg;
      reg.json_path = path;
      reg.name = r.contains("name") ? p.string(r.at("name"), child(path, "name")) : path;
      if (reg.name.empty()) p.fail(child(path, "name"), "must not be empty");
      if (reg.name == "default")
        p.fail(child(path, "name"), "\"default\" names the default material; choose another");
      if (!names.insert(reg.name).second)
        p.fail(child(path, "name"), "region name \"" + reg.name + "\" is used twice");
      const ElementSelector sel = parse_element_selector(p, r, path, dim);
      reg.kind = sel.kind;
      reg.elements = sel.elements;
      reg.box = sel.box;
      reg.slab = sel.slab;
      reg.mesh_region = sel.mesh_region;
      reg.material = s.default_material;
      parse_material(p, p.required(r, path, "material"), child(path, "material"), reg.material,
                     false);
      reg.material.region = static_cast<int>(i) + 1;
      s.regions.push_back(std::move(reg));
    }
  }

  // Contrast hook.
  if (root.contains("contrast")) {
    const json& c = root.at("contrast");
    p.expect_object(c, "contrast", {"regions", "exponents", "default"});
    const json& list = p.array(p.required(c, "contrast", "regions"), "contrast.regions");
    if (list.empty()) p.fail("contrast.regions", "the list is empty");
    for (size_t i = 0; i < list.size(); ++i) {
      const std::string n = p.string(list[i], item("contrast.regions", i));
      if (n != "default" && !names.count(n)) {
        std::string known = "\"default\"";
        for (const auto& r : s.regions) known += ", \"" + r.name + "\"";
        p.fail(item("contrast.regions", i),
               "no region is named \"" + n + "\" (known: " + known + ")");
      }
      s.contrast.regions.push_back(n);
    }
    s.contrast.exponents.assign(list.size(), 1.0);
    if (c.contains("exponents")) {
      const json& ex = p.array(c.at("exponents"), "contrast.exponents");
      if (ex.size() != list.size())
        p.fail("contrast.exponents", "has " + std::to_string(ex.size()) +
                                         " entries, contrast.regions has " +
                                         std::to_string(list.size()));
      for (size_t i = 0; i < ex.size(); ++i) {
        const std::string path = item("contrast.exponents", i);
        if (!ex[i].is_number()) p.fail(path, "must be a number");
        const double e = ex[i].get<double>();
        if (!std::isfinite(e)) p.fail(path, "must be finite");
        s.contrast.exponents[i] = e;
      }
    }
    s.contrast.default_factor = p.number(c, "contrast", "default", 1.0);
    p.positive(s.contrast.default_factor, "contrast.default");
    s.contrast.factor = s.contrast.default_factor;
  }
  if (contrast) {
    if (!(std::isfinite(*contrast) && *contrast > 0))
      throw InputError("--contrast " + format_number(*contrast) + ": must be finite and > 0",
                       p.file());
    if (s.contrast.regions.empty())
      throw InputError(
          "--contrast was given but the scene has no \"contrast\" entry naming the "
          "regions it scales",
          p.file());
    s.contrast.factor = *contrast;
  }

  // Boundary conditions.
  if (root.contains("fixed")) {
    const json& fs = p.array(root.at("fixed"), "fixed");
    for (size_t i = 0; i < fs.size(); ++i) {
      const std::string path = item("fixed", i);
      p.expect_object(fs[i], path, {"vertices", "axes"});
      FixSpec f;
      f.vertices = parse_selector(p, fs[i], path, dim);
      if (fs[i].contains("axes")) {
        const std::string ap = child(path, "axes");
        const json& a = p.array(fs[i].at("axes"), ap);
        if (static_cast<int>(a.size()) != dim)
          p.fail(ap, "expected " + std::to_string(dim) + " booleans (" + per_axis + "), found " +
                         std::to_string(a.size()));
        for (int d = 0; d < dim; ++d) f.axes[d] = p.boolean(a[d], item(ap, d));
        if (!(f.axes[0] || f.axes[1] || (dim == 3 && f.axes[2]))) p.fail(ap, "no axis is fixed");
      }
      s.fixed.push_back(std::move(f));
    }
  }

  // Drivers.
  if (root.contains("drivers")) {
    const json& ds = p.array(root.at("drivers"), "drivers");
    for (size_t i = 0; i < ds.size(); ++i) {
      const std::string path = item("drivers", i);
      const json& d = ds[i];
      if (!d.is_object()) p.fail(path, "expected an object, found " + type_of(d));
      const std::string type = p.string(p.required(d, path, "type"), child(path, "type"));
      DriverSpec dr;
      dr.json_path = path;
      if (type == "twist") {
        p.expect_object(d, path,
                        {"type", "vertices", "axis", "center", "angular_velocity", "start", "stop",
                         "release_at_stop"});
        dr.kind = DriverSpec::Kind::Twist;
        if (dim == 3) {
          dr.axis = p.axis(d, path, "axis", 3);
        } else {
          dr.axis = static_cast<int>(p.integer(d, path, "axis", 2L));
          if (dr.axis != 2)
            p.fail(child(path, "axis"), "a 2D twist turns about the plane normal: axis must be 2");
        }
        if (d.contains("center"))
          dr.center = p.vector(d.at("center"), child(path, "center"), dim, per_axis);
        dr.angular_velocity = p.number(d, path, "angular_velocity");
      } else if (type == "pull") {
        p.expect_object(d, path,
                        {"type", "vertices", "velocity", "start", "stop", "release_at_stop"});
        dr.kind = DriverSpec::Kind::Pull;
        dr.velocity =
            p.vector(p.required(d, path, "velocity"), child(path, "velocity"), dim, per_axis);
      } else {
        p.fail(child(path, "type"),
               "unknown driver type \"" + type + "\" (expected \"twist\" or \"pull\")");
      }
      dr.vertices = parse_selector(p, d, path, dim);
      parse_window(p, d, path, dr.start, dr.stop);
      dr.release_at_stop = p.boolean(d, path, "release_at_stop", false);
      s.drivers.push_back(std::move(dr));
    }
  }

  // Forces.
  s.gravity = root.contains("gravity") ? p.vector(root.at("gravity"), "gravity", dim, per_axis)
                                       : VectorX::Zero(dim);
  if (root.contains("forces")) {
    const json& fs = p.array(root.at("forces"), "forces");
    for (size_t i = 0; i < fs.size(); ++i) {
      const std::string path = item("forces", i);
      p.expect_object(fs[i], path, {"vertices", "force", "total_force", "start", "stop"});
      ForceSpec f;
      f.json_path = path;
      f.vertices = parse_selector(p, fs[i], path, dim);
      const std::string k = one_of(p, fs[i], path, {"force", "total_force"});
      f.total = k == "total_force";
      f.force = p.vector(fs[i].at(k), child(path, k), dim, per_axis);
      parse_window(p, fs[i], path, f.start, f.stop);
      s.forces.push_back(std::move(f));
    }
  }
  s.initial_velocity.linear = VectorX::Zero(dim);
  s.initial_velocity.angular = VectorX::Zero(dim == 3 ? 3 : 1);
  if (root.contains("initial_velocity")) {
    const json& v = root.at("initial_velocity");
    p.expect_object(v, "initial_velocity", {"linear", "angular"});
    if (v.contains("linear"))
      s.initial_velocity.linear =
          p.vector(v.at("linear"), "initial_velocity.linear", dim, per_axis);
    if (v.contains("angular")) {
      if (dim == 3)
        s.initial_velocity.angular =
            p.vector(v.at("angular"), "initial_velocity.angular", 3, "a 3D angular velocity");
      else
        s.initial_velocity.angular[0] = p.number(v.at("angular"), "initial_velocity.angular");
    }
  }

  // Time.
  {
    const json& t = p.required(root, "", "time");
    p.expect_object(t, "time", {"h", "frames", "substeps"});
    s.h = p.number(t, "time", "h");
    p.positive(s.h, "time.h");
    const long frames = p.integer(t, "time", "frames");
    if (frames <= 0) p.fail("time.frames", "must be > 0, found " + std::to_string(frames));
    const long substeps = p.integer(t, "time", "substeps", 1L);
    if (substeps <= 0) p.fail("time.substeps", "must be > 0, found " + std::to_string(substeps));
    if (frames > 100'000'000 || substeps > 100'000)
      p.fail("time", "frames or substeps is implausibly large");
    s.output.frames = static_cast<int>(frames);
    s.output.substeps = static_cast<int>(substeps);
  }

  // Solver.
  if (root.contains("solver")) {
    const json& j = root.at("solver");
    const std::string path = "solver";
    p.expect_object(j, path,
                    {"energy", "routing", "anderson_window", "eps_rel", "eps_abs", "gate",
                     "max_iterations", "damping"});
    SolverSpec& sv = s.solver;
    if (j.contains("energy")) {
      const std::string e = p.string(j.at("energy"), "solver.energy");
      bool ok = false;
      for (EnergyKind k :
           {EnergyKind::CorotatedVolume, EnergyKind::NeoHookean, EnergyKind::NeoHookeanLogVolume,
            EnergyKind::Corotated, EnergyKind::CorotatedVolumeMuscle})
        if (e == to_string(k)) sv.energy = k, ok = true;
      if (!ok)
        p.fail("solver.energy", "unknown energy \"" + e +
                                    "\" (expected \"corotated+volume\", \"neo-hookean\", "
                                    "\"neo-hookean+logvolume\", \"corotated\" or "
                                    "\"corotated+volume+muscle\")");
    }
    if (j.contains("routing")) {
      const std::string r = p.string(j.at("routing"), "solver.routing");
      bool ok = false;
      for (Routing k : {Routing::StiffnessAware, Routing::PerElementProx, Routing::Uniform})
        if (r == to_string(k)) sv.routing = k, ok = true;
      if (!ok)
        p.fail("solver.routing", "unknown routing \"" + r +
                                     "\" (expected \"stiffness-aware\", \"per-element-prox\" or "
                                     "\"uniform\")");
    }
    if (j.contains("gate")) {
      const std::string g = p.string(j.at("gate"), "solver.gate");
      if (g == "paper")
        sv.gate = Gate::Paper;
      else if (g == "step-relative")
        sv.gate = Gate::StepRelative;
      else
        p.fail("solver.gate", "unknown gate \"" + g + "\" (expected \"paper\" or \"step-relative\")");
    }
    const long m = p.integer(j, path, "anderson_window", -1L);
    if (m < -1 || m > 64)
      p.fail("solver.anderson_window",
             "must be -1 (automatic), 0 (off) or a window of 1..64, found " + std::to_string(m));
    sv.anderson_window = static_cast<int>(m);
    sv.eps_rel = p.number(j, path, "eps_rel", sv.eps_rel);
    p.positive(sv.eps_rel, "solver.eps_rel");
    sv.eps_abs = p.number(j, path, "eps_abs", sv.eps_abs);
    p.non_negative(sv.eps_abs, "solver.eps_abs");
    const long it = p.integer(j, path, "max_iterations", sv.max_iterations);
    p.at_least(it, 1, "solver.max_iterations");
    sv.max_iterations = static_cast<int>(std::min<long>(it, 1'000'000'000));
    if (j.contains("damping")) {
      const json& d = j.at("damping");
      p.expect_object(d, "solver.damping", {"alpha", "beta0"});
      sv.alpha = p.number(d, "solver.damping", "alpha", 0.0);
      p.non_negative(sv.alpha, "solver.damping.alpha");
      sv.beta0 = p.number(d, "solver.damping", "beta0", 0.0);
      p.non_negative(sv.beta0, "solver.damping.beta0");
    }
  }

  // Muscles (after the solver: the energy must have a muscle term, and the other way round).
  if (root.contains("muscles")) {
    s.muscles = parse_muscles(p, root.at("muscles"), dim, per_axis);
    if (!has_muscle_term(s.solver.energy))
      p.fail("muscles", std::string("solver.energy \"") + to_string(s.solver.energy) +
                            "\" has no muscle term (use \"" +
                            to_string(EnergyKind::CorotatedVolumeMuscle) + "\")");
  } else if (has_muscle_term(s.solver.energy)) {
    p.fail("solver.energy", std::string("\"") + to_string(s.solver.energy) +
                                "\" needs a \"muscles\" section (the muscle groups with their "
                                "fibres and stiffness)");
  }
  return s;
}

/// The bounding box of the mesh and the tolerance used to close boxes and slabs.
template <int Dim>
std::pair<Eigen::AlignedBox<double, Dim>, double> bounds(const SimplicialMesh<Dim>& mesh) {
  const auto box = mesh.bounding_box();
  return {box, 1e-9 * box.diagonal().norm()};
}

/// Absolute [lo, hi] of a box spec (relative fractions mapped to the bounding box), widened.
template <int Dim>
std::pair<Vec<Dim>, Vec<Dim>> absolute_box(const BoxSpec& b,
                                           const Eigen::AlignedBox<double, Dim>& bb, double tol) {
  Vec<Dim> lo = b.lo.template head<Dim>(), hi = b.hi.template head<Dim>();
  if (b.relative) {
    lo = bb.min() + lo.cwiseProduct(bb.sizes());
    hi = bb.min() + hi.cwiseProduct(bb.sizes());
  }
  return {(lo.array() - tol).matrix(), (hi.array() + tol).matrix()};
}

template <int Dim>
std::pair<double, double> absolute_slab(const SlabSpec& s, const Eigen::AlignedBox<double, Dim>& bb,
                                        double tol) {
  double lo = s.lo, hi = s.hi;
  if (s.relative) {
    const double a = bb.min()[s.axis], w = bb.sizes()[s.axis];
    lo = std::isfinite(lo) ? a + lo * w : lo;
    hi = std::isfinite(hi) ? a + hi * w : hi;
  }
  return {lo - tol, hi + tol};
}

template <int Dim>
void check_dimension(const SceneSpec& s, const char* fn) {
  if (s.mesh.dimension != Dim)
    throw InputError(std::string(fn) + "<" + std::to_string(Dim) + ">: the scene is " +
                         std::to_string(s.mesh.dimension) + "D (use scene_dimension())",
                     s.file);
}

}  // namespace scene_detail

/// \brief Parses a scene file (JSON) into a validated SceneSpec.
/// \param[in] path  the scene file; paths inside it are relative to its folder
/// \param[in] contrast  the command line's --contrast factor: overrides the file's
///   contrast.default (an error when the scene has no "contrast" entry)
/// \throws InputError "PATH: JSON.PATH: message" for every problem (see the file comment)
inline SceneSpec load_scene(const std::string& path, std::optional<double> contrast = {}) {
  std::ifstream in(path, std::ios::in | std::ios::binary);
  if (!in) throw InputError("cannot open scene file for reading", path);
  nlohmann::json root;
  // Duplicate keys are errors (JSON parsers keep the last one in silence).
  struct Frame {
    std::set<std::string> keys;
    std::string name, last_key;
  };
  std::vector<Frame> stack;
  auto callback = [&](int, nlohmann::json::parse_event_t event, nlohmann::json& parsed) {
    using E = nlohmann::json::parse_event_t;
    if (event == E::object_start) {
      stack.push_back({{}, stack.empty() ? std::string() : stack.back().last_key, {}});
    } else if (event == E::object_end) {
      if (!stack.empty()) stack.pop_back();
    } else if (event == E::key && !stack.empty()) {
      const std::string key = parsed.get<std::string>();
      if (!stack.back().keys.insert(key).second)
        throw InputError("duplicate key \"" + key + "\"" +
                             (stack.back().name.empty()
                                  ? std::string(stack.size() == 1 ? " at the top level" : "")
                                  : " in an object under \"" + stack.back().name + "\""),
                         path);
      stack.back().last_key = key;
    }
    return true;
  };
  try {
    root = nlohmann::json::parse(in, callback, true, /*ignore_comments=*/false);
  } catch (const nlohmann::json::parse_error& e) {
    std::string msg = e.what();
    const auto pos = msg.find("parse error");
    if (pos != std::string::npos) msg = msg.substr(pos);
    throw InputError("invalid JSON: " + msg, path);
  }
  return scene_detail::parse(scene_detail::Parser(path), root, contrast);
}

/// \brief 2 or 3: the dimension of the scene's mesh (known from load_scene).
inline int scene_dimension(const SceneSpec& scene) {
  return scene.mesh.dimension;
}

/// \brief Builds the scene's mesh with its region ids: read from the file (region = the file's
/// region attribute) or generated (region = the branch level for "branching", 0 otherwise),
/// then scaled and translated.
/// \tparam Dim must equal scene_dimension(scene)
/// \return #V by Dim positions, #E elements, #E region ids
/// \throws InputError naming the scene file (and the mesh file for reader errors)
template <int Dim>
MeshWithRegions<Dim> build_mesh_with_regions(const SceneSpec& scene) {
  scene_detail::check_dimension<Dim>(scene, "build_mesh");
  const MeshSpec& m = scene.mesh;
  MeshWithRegions<Dim> out;
  auto set = [&](SimplicialMesh<Dim> mesh, std::vector<int> region = {}) {
    if (region.empty()) region.assign(mesh.num_elements(), 0);
    out.mesh = std::move(mesh);
    out.region = std::move(region);
  };
  try {
    if (m.kind == MeshSpec::Kind::File) {
      out = read_mesh_with_regions<Dim>(m.file);
    } else if constexpr (Dim == 2) {
      set(make_rectangle(m.lo.head<2>(), m.hi.head<2>(), m.cells.head<2>()));
    } else {
      switch (m.kind) {
        case MeshSpec::Kind::Box:
          set(make_box(Vec<3>(m.lo.head<3>()), Vec<3>(m.hi.head<3>()),
                       Eigen::Vector3i(m.cells.head<3>())));
          break;
        case MeshSpec::Kind::Bar:
          set(make_bar(m.length, m.width, m.height, m.cells_along_length));
          break;
        case MeshSpec::Kind::Sheet:
          set(make_sheet(m.width, m.depth, m.thickness, Eigen::Vector2i(m.cells.head<2>())));
          break;
        case MeshSpec::Kind::Sphere:
          set(make_sphere(m.radius, m.resolution));
          break;
        case MeshSpec::Kind::Torus:
          set(make_torus(m.major_radius, m.minor_radius, m.ring_segments, m.tube_resolution));
          break;
        case MeshSpec::Kind::Branching: {
          PlantMesh plant = make_branching_plant(m.plant);
          set(std::move(plant.mesh), std::move(plant.level));
          break;
        }
        default:
          throw InputError("build_mesh: a rectangle is 2D", scene.file);
      }
    }
  } catch (const InputError& e) {
    // Reader errors already name the mesh file and line; add the scene file.
    throw InputError("mesh: " + std::string(e.what()), scene.file);
  }
  if (m.scale != 1.0 || !m.translate.isZero(0)) {
    VertexMatrix<Dim> X = out.mesh.rest_positions() * m.scale;
    X.rowwise() += m.translate.head<Dim>().transpose();
    ElementMatrix<Dim> T = out.mesh.elements();
    MeshSource src = out.mesh.source();
    out.mesh = SimplicialMesh<Dim>(std::move(X), std::move(T), std::move(src));
  }
  if (out.vertex_id.empty()) {
    out.vertex_id.resize(out.mesh.num_vertices());
    for (Index v = 0; v < out.mesh.num_vertices(); ++v) out.vertex_id[v] = v;
  }
  return out;
}

/// \brief The scene's mesh (see build_mesh_with_regions).
template <int Dim>
SimplicialMesh<Dim> build_mesh(const SceneSpec& scene) {
  return build_mesh_with_regions<Dim>(scene).mesh;
}

/// \brief The vertices a selector picks, sorted and unique.
/// \param[in] mesh  #V by Dim rest positions are tested
/// \return vertex indices in [0, #V)
/// \throws InputError "SCENE: JSON.PATH: ..." when an index is out of range or nothing matches
template <int Dim>
std::vector<Index> select_vertices(const VertexSelector& sel, const SimplicialMesh<Dim>& mesh) {
  auto fail = [&](const std::string& msg) {
    throw InputError(sel.json_path.empty() ? msg : sel.json_path + ": " + msg, sel.scene_file);
  };
  std::vector<Index> out;
  const auto& X = mesh.rest_positions();
  const auto [bb, tol] = scene_detail::bounds(mesh);
  switch (sel.kind) {
    case VertexSelector::Kind::Indices:
      for (size_t i = 0; i < sel.indices.size(); ++i) {
        const Index v = sel.indices[i];
        if (v < 0 || v >= mesh.num_vertices())
          fail("indices[" + std::to_string(i) + "] = " + std::to_string(v) +
               " is out of range: the mesh has " + std::to_string(mesh.num_vertices()) +
               " vertices");
        out.push_back(v);
      }
      break;
    case VertexSelector::Kind::Box: {
      if (sel.box.lo.size() != Dim || sel.box.hi.size() != Dim)
        fail("box: lo and hi need " + std::to_string(Dim) + " entries");
      const auto [lo, hi] = scene_detail::absolute_box<Dim>(sel.box, bb, tol);
      for (Index v = 0; v < mesh.num_vertices(); ++v)
        if ((X.row(v).transpose().array() >= lo.array()).all() &&
            (X.row(v).transpose().array() <= hi.array()).all())
          out.push_back(v);
      break;
    }
    case VertexSelector::Kind::Slab: {
      if (sel.slab.axis < 0 || sel.slab.axis >= Dim)
        fail("slab: axis " + std::to_string(sel.slab.axis) + " does not exist in " +
             std::to_string(Dim) + "D");
      const auto [lo, hi] = scene_detail::absolute_slab<Dim>(sel.slab, bb, tol);
      for (Index v = 0; v < mesh.num_vertices(); ++v)
        if (X(v, sel.slab.axis) >= lo && X(v, sel.slab.axis) <= hi) out.push_back(v);
      break;
    }
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  if (out.empty()) {
    std::ostringstream os;
    os << "selects no vertex (the mesh's bounding box is [" << bb.min().transpose() << "] .. ["
       << bb.max().transpose() << "])";
    fail(os.str());
  }
  return out;
}

/// \brief The elements a selector picks (by index, centroid in a box or slab, or mesh region
/// id), sorted.
/// \param[in] mesh_regions  #E region ids of the mesh (needed for Kind::MeshRegion)
/// \throws InputError "SCENE: JSON.PATH: ..." for out-of-range indices or an empty selection
template <int Dim>
std::vector<Index> select_elements(const ElementSelector& r, const SimplicialMesh<Dim>& mesh,
                                   const std::vector<int>& mesh_regions,
                                   const std::string& scene_file = {}) {
  auto fail = [&](const std::string& msg) {
    throw InputError(r.json_path.empty() ? msg : r.json_path + ": " + msg, scene_file);
  };
  std::vector<Index> out;
  const auto [bb, tol] = scene_detail::bounds(mesh);
  const Index ne = mesh.num_elements();
  switch (r.kind) {
    case ElementSelector::Kind::Elements:
      for (size_t i = 0; i < r.elements.size(); ++i) {
        if (r.elements[i] < 0 || r.elements[i] >= ne)
          fail("elements[" + std::to_string(i) + "] = " + std::to_string(r.elements[i]) +
               " is out of range: the mesh has " + std::to_string(ne) + " elements");
        out.push_back(r.elements[i]);
      }
      break;
    case ElementSelector::Kind::Box: {
      const auto [lo, hi] = scene_detail::absolute_box<Dim>(r.box, bb, tol);
      for (Index e = 0; e < ne; ++e) {
        const Vec<Dim> c = mesh.centroid(e);
        if ((c.array() >= lo.array()).all() && (c.array() <= hi.array()).all()) out.push_back(e);
      }
      break;
    }
    case ElementSelector::Kind::Slab: {
      if (r.slab.axis >= Dim) fail("slab: axis out of range");
      const auto [lo, hi] = scene_detail::absolute_slab<Dim>(r.slab, bb, tol);
      for (Index e = 0; e < ne; ++e) {
        const double c = mesh.centroid(e)[r.slab.axis];
        if (c >= lo && c <= hi) out.push_back(e);
      }
      break;
    }
    case ElementSelector::Kind::MeshRegion: {
      if (static_cast<Index>(mesh_regions.size()) != ne)
        fail("mesh_region: the mesh's region ids are not available (" +
             std::to_string(mesh_regions.size()) + " ids for " + std::to_string(ne) +
             " elements; pass them to build_materials / build_muscles)");
      std::set<int> ids(mesh_regions.begin(), mesh_regions.end());
      for (Index e = 0; e < ne; ++e)
        if (mesh_regions[e] == r.mesh_region) out.push_back(e);
      if (out.empty()) {
        std::string known;
        for (int id : ids) known += (known.empty() ? "" : ", ") + std::to_string(id);
        fail("mesh_region: no element has region id " + std::to_string(r.mesh_region) +
             " (the mesh has " + known + ")");
      }
      break;
    }
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  if (out.empty()) fail("selects no element (by element centroid)");
  return out;
}

/// \brief The elements a region assignment picks (see the ElementSelector overload).
/// \throws InputError "SCENE: regions[i]: ..." for out-of-range indices or an empty selection
template <int Dim>
std::vector<Index> select_elements(const RegionSpec& r, const SimplicialMesh<Dim>& mesh,
                                   const std::vector<int>& mesh_regions,
                                   const std::string& scene_file = {}) {
  return select_elements(element_selector(r), mesh, mesh_regions, scene_file);
}

/// \brief The material of every element: the default material, then each region assignment
/// in order, with the named regions' Young's modulus multiplied by scene.contrast.factor.
/// Region labels (Material::region): 0 default, i + 1 for regions[i].
/// \param[in] mesh  the mesh from build_mesh<Dim>(scene)
/// \param[in] file_regions  #E region ids (MeshWithRegions::region); needed only by
///   "mesh_region" assignments
/// \throws InputError naming the scene file and the region's JSON path
template <int Dim>
MaterialField build_materials(const SceneSpec& scene, const SimplicialMesh<Dim>& mesh,
                              const std::vector<int>& file_regions = {}) {
  scene_detail::check_dimension<Dim>(scene, "build_materials");
  auto scaled = [&](Material m, const std::string& name) {
    for (size_t i = 0; i < scene.contrast.regions.size(); ++i)
      if (scene.contrast.regions[i] == name)
        m.youngs_modulus *= std::pow(scene.contrast.factor, i < scene.contrast.exponents.size()
                                                                ? scene.contrast.exponents[i]
                                                                : 1.0);
    return m;
  };
  MaterialField field;
  try {
    field = MaterialField(mesh.num_elements(), scaled(scene.default_material, "default"));
  } catch (const InputError& e) {
    throw InputError("material (with contrast factor): " + e.message(), scene.file);
  }
  for (const RegionSpec& r : scene.regions) {
    const std::vector<Index> sel = select_elements(r, mesh, file_regions, scene.file);
    try {
      field.assign(sel, scaled(r.material, r.name));
    } catch (const InputError& e) {
      throw InputError(r.json_path + ".material (with contrast factor): " + e.message(),
                       scene.file);
    }
  }
  return field;
}

/// \brief The per-element muscle data of a scene on its mesh (build_muscles()): what
/// Solver::set_muscle and Solver::set_activation take.
struct MuscleField {
  std::vector<int> group;  ///< #E: the muscle group of each element, -1 outside every group
  VectorX stiffness;       ///< #E: k_e, Pa (the group's stiffness; 0 outside groups)
  /// #E by 3: the group's unit fibre direction (first Dim entries; the rest 0); (1, 0, 0)
  /// outside groups (unused there: k_e = 0)
  MatrixX fibres;
  VectorX activations;             ///< #G: the groups' activations from the file
  std::vector<std::string> names;  ///< #G: the groups' names

  int num_groups() const { return static_cast<int>(names.size()); }
  /// Per-group activations -> #E per-element activations (1, the rest length, outside groups).
  /// \throws InputError when a.size() != num_groups() or an entry is not finite
  VectorX element_activations(const VectorX& a) const {
    if (a.size() != num_groups())
      throw InputError("element_activations: " + std::to_string(a.size()) + " activations for " +
                       std::to_string(num_groups()) + " muscle groups");
    if (!a.allFinite()) throw InputError("element_activations: non-finite activation");
    VectorX out = VectorX::Ones(static_cast<Index>(group.size()));
    for (size_t e = 0; e < group.size(); ++e)
      if (group[e] >= 0) out[static_cast<Index>(e)] = a[group[e]];
    return out;
  }
};

/// \brief The scene's muscle groups on its mesh: per-element group index, stiffness and fibre,
/// and the per-group activations. A scene without "muscles" gives no group (every element -1,
/// stiffness 0).
/// \param[in] mesh  the mesh from build_mesh<Dim>(scene)
/// \param[in] mesh_regions  #E region ids (MeshWithRegions::region); needed only by groups
///   that select by "mesh_region"
/// \throws InputError naming the scene file and the group's JSON path when a group selects no
///   element or an index out of range, and naming both groups when an element is in two
template <int Dim>
MuscleField build_muscles(const SceneSpec& scene, const SimplicialMesh<Dim>& mesh,
                          const std::vector<int>& mesh_regions = {}) {
  scene_detail::check_dimension<Dim>(scene, "build_muscles");
  const Index ne = mesh.num_elements();
  const auto& groups = scene.muscles.groups;
  MuscleField out;
  out.group.assign(ne, -1);
  out.stiffness = VectorX::Zero(ne);
  out.fibres = MatrixX::Zero(ne, 3);
  out.fibres.col(0).setOnes();
  out.activations.resize(static_cast<Index>(groups.size()));
  for (size_t g = 0; g < groups.size(); ++g) {
    const MuscleGroupSpec& grp = groups[g];
    out.names.push_back(grp.name);
    out.activations[static_cast<Index>(g)] = grp.activation;
    const std::vector<Index> sel = select_elements(grp.elements, mesh, mesh_regions, scene.file);
    Index overlaps = 0, first = -1;
    for (Index e : sel)
      if (out.group[e] >= 0 && overlaps++ == 0) first = e;
    if (overlaps > 0) {
      const MuscleGroupSpec& other = groups[out.group[first]];
      throw InputError(grp.json_path + ": muscle group \"" + grp.name + "\" overlaps group \"" +
                           other.name + "\" (" + other.json_path + ") in " +
                           std::to_string(overlaps) + " element(s), the first element " +
                           std::to_string(first) +
                           "; an element belongs to at most one muscle group",
                       scene.file);
    }
    for (Index e : sel) {
      out.group[e] = static_cast<int>(g);
      out.stiffness[e] = grp.stiffness;
      out.fibres.row(e).setZero();
      for (int k = 0; k < Dim; ++k) out.fibres(e, k) = grp.fibre[k];
    }
  }
  return out;
}

/// \brief The Dirichlet mask of the scene's "fixed" entries (drivers are not included).
/// \return #V by Dim flags, true where the coordinate is fixed (PDSystem::set_dirichlet)
template <int Dim>
Eigen::Matrix<bool, Eigen::Dynamic, Dim> fixed_mask(const SceneSpec& scene,
                                                    const SimplicialMesh<Dim>& mesh) {
  scene_detail::check_dimension<Dim>(scene, "fixed_mask");
  Eigen::Matrix<bool, Eigen::Dynamic, Dim> mask =
      Eigen::Matrix<bool, Eigen::Dynamic, Dim>::Constant(mesh.num_vertices(), Dim, false);
  for (const FixSpec& f : scene.fixed)
    for (Index v : select_vertices(f.vertices, mesh))
      for (int d = 0; d < Dim; ++d) mask(v, d) = mask(v, d) || f.axes[d];
  return mask;
}

/// \brief The initial velocity of every vertex: linear + angular x (x - c), c the centre of
/// mass of the lumped masses.
/// \return #V by Dim velocities, m/s
template <int Dim>
VertexMatrix<Dim> initial_velocities(const SceneSpec& scene, const SimplicialMesh<Dim>& mesh,
                                     const MaterialField& materials) {
  scene_detail::check_dimension<Dim>(scene, "initial_velocities");
  const VectorX mass = mesh.lumped_mass(materials.densities());
  const auto& X = mesh.rest_positions();
  const Vec<Dim> c = (X.transpose() * mass) / mass.sum();
  VertexMatrix<Dim> V(mesh.num_vertices(), Dim);
  const Vec<Dim> lin = scene.initial_velocity.linear.head<Dim>();
  for (Index v = 0; v < mesh.num_vertices(); ++v) {
    const Vec<Dim> r = X.row(v).transpose() - c;
    Vec<Dim> w;
    if constexpr (Dim == 3)
      w = Vec<3>(scene.initial_velocity.angular.head<3>()).cross(r);
    else
      w = scene.initial_velocity.angular[0] * Vec<2>(-r[1], r[0]);
    V.row(v) = (lin + w).transpose();
  }
  return V;
}

/// \brief The force on each of `count` selected vertices: f.force, or f.force / count when
/// f.total. N, dimension entries.
inline VectorX per_vertex_force(const ForceSpec& f, Index count) {
  return f.total ? VectorX(f.force / static_cast<double>(std::max<Index>(count, 1))) : f.force;
}

/// \brief Where a driver puts its vertices at time t.
/// \param[in] d  the driver
/// \param[in] X0  #S by Dim positions of the selected vertices at time d.start
/// \param[in] center  the twist centre (d.center, or the centroid of X0 when absent)
/// \param[in] t  time in s; the motion is frozen at d.stop (whether it is still applied after
///   stop is d.release_at_stop's business) and is the identity before d.start
/// \return #S by Dim prescribed positions
template <int Dim>
VertexMatrix<Dim> driver_positions(const DriverSpec& d, const VertexMatrix<Dim>& X0, double t) {
  const double tau = std::clamp(t, d.start, d.stop) - d.start;
  VertexMatrix<Dim> X = X0;
  if (d.kind == DriverSpec::Kind::Pull) {
    X.rowwise() += (tau * d.velocity.head<Dim>()).transpose();
    return X;
  }
  const Vec<Dim> c =
      d.center ? Vec<Dim>(d.center->head<Dim>()) : Vec<Dim>(X0.colwise().mean().transpose());
  const double angle = d.angular_velocity * tau;
  Mat<Dim> R;
  if constexpr (Dim == 3)
    R = Eigen::AngleAxisd(angle, Vec<3>::Unit(d.axis)).toRotationMatrix();
  else
    R << std::cos(angle), -std::sin(angle), std::sin(angle), std::cos(angle);
  for (Index v = 0; v < X.rows(); ++v) X.row(v) = (c + R * (X0.row(v).transpose() - c)).transpose();
  return X;
}

}  // namespace diffphd::io
