#pragma once
/// \file scene.hpp
/// \brief Scene files (JSON) -> a plain, validated SceneSpec, and the builders that turn a
/// SceneSpec into a mesh, a MaterialField, vertex selections, a Dirichlet mask, initial
/// velocities and the per-element muscle data (build_muscles). No dependency on the solver: a
/// SceneSpec is data; the solver (or the CLI) reads it. The schema is documented in
/// docs/scenes.md.
///
/// Contact: "mesh" may be an array of bodies, merged into one mesh by build_multibody_mesh
/// (with the body of every vertex and element); selectors may name a body ({"body": i or
/// "name"}); "initial_velocity" may be per body; "colliders" become contact::Collider<Dim>
/// (build_colliders) and "contact" a contact::ContactOptions (contact_options); has_contact()
/// says whether a scene needs the contact model.
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
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <limits>
#include <map>
#include <optional>
#include <random>
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
#include "../contact/types.hpp"
#include "../energy/volume.hpp"
#include "generators.hpp"
#include "limits.hpp"
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

/// True when the energy has the Volume term, so that solver.volume_weight applies to it.
inline bool has_volume_term(EnergyKind e) {
  return e == EnergyKind::CorotatedVolume || e == EnergyKind::CorotatedVolumeMuscle;
}

/// \brief How per-element stiffness is routed ("routing" in "solver"; paper Sec. 4.2, Fig. 4).
enum class Routing {
  StiffnessAware,  ///< "stiffness-aware": w_e from each element's material, prox with means
  PerElementProx,  ///< "per-element-prox": per-element material inside the local prox too
  Uniform          ///< "uniform": one weight for all elements (plain PD, the baseline)
};

/// \brief The convergence test of a step ("gate" in "solver").
enum class Gate {
  Gradient,     ///< "gradient" (default): ||grad Phi|| against the first iterate's force imbalance
  Paper,        ///< "paper": eq. (22) as printed (relative to ||q^k|| and ||b(q^k)||; pd only)
  StepRelative  ///< "step-relative": relative to this step's motion and the elastic part of b
};

inline const char* to_string(Gate g) {
  return g == Gate::Gradient ? "gradient" : g == Gate::Paper ? "paper" : "step-relative";
}

/// The scene-file names of the forward methods ("method" in "solver").
inline const std::vector<std::string>& method_names() {
  static const std::vector<std::string> names{"auto",          "pd",
                                              "newton-krylov", "lbfgs",
                                              "newton-direct", "newton-lagged"};
  return names;
}

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
  /// Where the mesh object is in the file: "mesh" (a single object) or "mesh[i]" (one body of
  /// an array); names the body in build errors.
  std::string json_path = "mesh";
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

/// \brief A set of mesh vertices: an index list, the vertices in a box, or in a slab, or all
/// the vertices of one body. Boxes and slabs are widened by 1e-9 of the bounding-box diagonal
/// so that vertices lying exactly on a face are selected despite rounding.
///
/// With body >= 0 a box or slab selects only that body's vertices, and "relative" fractions
/// refer to that body's bounding box (else to the whole mesh's, all bodies together).
struct VertexSelector {
  enum class Kind { Indices, Box, Slab, Body };
  Kind kind = Kind::Indices;
  std::vector<Index> indices;  ///< Indices: 0-based vertex indices (of the merged mesh)
  BoxSpec box;                 ///< Box
  SlabSpec slab;               ///< Slab
  int body = -1;               ///< Body: the body; Box/Slab: restricted to it when >= 0
  std::string body_name;       ///< the body's name when body >= 0, for messages
  int num_bodies = 1;          ///< bodies in the scene (a single-body scene needs no body map)
  std::string scene_file;      ///< for error messages
  std::string json_path;       ///< e.g. "fixed[0].vertices", for error messages
};

/// \brief A material's "youngs_modulus_spread": {"decades": D, "seed": S}. Element e that gets
/// the material has its Young's modulus (after the contrast factor) multiplied by
/// 10^(D (u_e - 1/2)), so the nominal E is the geometric centre of a log-uniform field spanning
/// D decades. u_e in [0, 1) is the top 53 bits of the (e + 1)-th draw of std::mt19937_64
/// seeded by S (e the element index in the whole mesh), so a seed gives the same field on every
/// platform and every material with that seed draws the same u_e for an element.
struct YoungsModulusSpread {
  bool enabled = false;    ///< the key was given (a region inherits the default material's)
  double decades = 0;      ///< D, finite, in [0, 12]
  std::uint64_t seed = 0;  ///< S, a non-negative integer
};

/// u_e of a spread: the top 53 bits of draw e (0-based) of mt19937_64(seed), in [0, 1), for
/// e = 0 .. n-1.
inline std::vector<double> spread_uniforms(std::uint64_t seed, Index n) {
  std::mt19937_64 g(seed);
  std::vector<double> u(static_cast<size_t>(n));
  for (auto& x : u) x = static_cast<double>(g() >> 11) * 0x1.0p-53;
  return u;
}

/// \brief One region assignment: the elements it selects get `material`. Assignments apply in
/// order; a later one overrides an earlier one. Elements are selected by index list, by their
/// centroid in a box or slab, or by the mesh's region attribute (the file's region ids, or the
/// branching generator's branch level).
struct RegionSpec {
  enum class Kind { Elements, Box, Slab, MeshRegion, Body };
  std::string name;  ///< unique; "regions[i]" when the file gives none
  Kind kind = Kind::Elements;
  std::vector<Index> elements;  ///< Elements: 0-based element indices
  BoxSpec box;                  ///< Box (element centroids)
  SlabSpec slab;                ///< Slab (element centroids)
  int mesh_region = 0;          ///< MeshRegion: the region id in the mesh
  /// Body: all elements of this body; Box/Slab/MeshRegion: restricted to it when >= 0 (relative
  /// boxes and slabs then refer to the body's bounding box)
  int body = -1;
  std::string body_name;  ///< the body's name when body >= 0, for messages
  int num_bodies = 1;     ///< bodies in the scene (a single-body scene needs no body map)
  /// Pa, -, kg/m^3; keys missing from the file are the default material's. material.region is
  /// the label given to the elements: i + 1 for regions[i] (the default material has 0).
  Material material;
  /// The material's "youngs_modulus_spread" (the default material's when the region's material
  /// does not give one; {"decades": 0} turns it off)
  YoungsModulusSpread spread;
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
  int body = -1;                ///< as RegionSpec::body
  std::string body_name;        ///< the body's name when body >= 0, for messages
  int num_bodies = 1;           ///< bodies in the scene
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
  s.body = r.body;
  s.body_name = r.body_name;
  s.num_bodies = r.num_bodies;
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

/// \brief The initial velocity v(x) = linear + angular x (x - c), c the centre of mass (of the
/// whole scene, or of `body` for a per-body entry).
struct InitialVelocitySpec {
  VectorX linear;   ///< m/s, dimension entries (zero by default)
  VectorX angular;  ///< rad/s: 3 entries in 3D, 1 in 2D (about the plane normal); zero default
  int body = -1;    ///< -1: every vertex (the object form); else only this body's vertices
  std::string json_path;  ///< "initial_velocity" or "initial_velocity[i]"
};

/// \brief One analytic collider ("colliders[i]"), dimension-agnostic (VectorX with dimension
/// entries); build_colliders<Dim>() makes contact::Collider<Dim> of it. The solid side is the
/// inside of the sphere / box and the side of the half-space opposite its normal.
struct SceneCollider {
  enum class Kind { HalfSpace, Sphere, Box };
  Kind kind = Kind::HalfSpace;
  std::string name;      ///< unique among the colliders; "colliders[i]" when not given
  VectorX point;         ///< m: half-space: a point on the plane ("point"); sphere, box: "center"
  VectorX normal;        ///< half-space: the outward (free side) normal, unit length
  double radius = 0;     ///< sphere: m, > 0
  VectorX half_extents;  ///< box: m, > 0 each (an axis-aligned box)
  VectorX velocity;  ///< m/s: scripted constant velocity while start <= t <= stop (zero default)
  double start = 0;  ///< s, >= 0
  double stop = std::numeric_limits<double>::infinity();  ///< s, > start
  double friction = 0;                                    ///< Coulomb mu >= 0
  double restitution = 0;                                 ///< in [0, 1]
  std::string json_path;                                  ///< "colliders[i]"
};

/// The scene-file name of a collider kind ("half-space", "sphere", "box").
inline const char* to_string(SceneCollider::Kind k) {
  switch (k) {
    case SceneCollider::Kind::HalfSpace:
      return "half-space";
    case SceneCollider::Kind::Sphere:
      return "sphere";
    case SceneCollider::Kind::Box:
      return "box";
  }
  return "?";
}

/// \brief The "contact" section (contact_options() turns it into contact::ContactOptions).
/// Defaults are contact::ContactOptions's, except mesh_contact (true with two or more bodies).
struct ContactSpec {
  bool given = false;  ///< the file has a "contact" section
  /// m, > 0: candidates within this distance are contacts of the step
  double distance = contact::ContactOptions{}.contact_distance;
  bool mesh_contact = false;  ///< resolved: the file's value, else (number of bodies >= 2)
  bool self_contact = contact::ContactOptions{}.self_contact;
  double friction = contact::ContactOptions{}.mesh_friction;              ///< mesh-mesh mu >= 0
  double restitution = contact::ContactOptions{}.mesh_restitution;        ///< mesh-mesh, in [0, 1]
  double ncp_tolerance = contact::ContactOptions{}.ncp_tolerance;         ///< m, > 0
  int ncp_max_iterations = contact::ContactOptions{}.ncp_max_iterations;  ///< >= 1
  double penetration_tolerance = contact::ContactOptions{}.penetration_tolerance;  ///< m, > 0
  int max_redetections = contact::ContactOptions{}.max_redetections;               ///< >= 0
  double restitution_threshold = contact::ContactOptions{}.restitution_threshold;  ///< m/s, >= 0
  contact::ContactOptions::Delassus delassus = contact::ContactOptions{}.delassus;
  contact::ContactOptions::NcpLinear ncp_linear = contact::ContactOptions{}.ncp_linear;
  int ncp_krylov_min_rows = contact::ContactOptions{}.ncp_krylov_min_rows;  ///< >= 1
  int ncp_stall_window = contact::ContactOptions{}.ncp_stall_window;        ///< >= 0
};

/// \brief Solver configuration. Defaults follow the paper (Sec. 4.3, 4.5, 5).
struct SolverSpec {
  EnergyKind energy = EnergyKind::CorotatedVolume;
  Routing routing = Routing::StiffnessAware;
  /// Volume's weight: "lame" (w = d lambda_e, default) or "lambda" (w = lambda_e, DiffPD's);
  /// only for energies with the Volume term (has_volume_term), ignored by the others
  VolumeWeight volume_weight = VolumeWeight::Lame;
  int anderson_window = -1;  ///< -1: automatic (m = 1 heterogeneous, 5 homogeneous); 0: off
  double anderson_reset = 10.0;  ///< discard the AA history when |gamma| exceeds this (> 0)
  double eps_rel = 1e-4;     ///< relative tolerance of the convergence test, > 0
  double eps_abs = 1e-8;     ///< absolute tolerance of the convergence test, >= 0
  Gate gate = Gate::Gradient;  ///< the convergence test of pd (the other methods use the gradient)
  int max_iterations = 200;  ///< outer iterations per step (PD iterations, Newton steps), >= 1
  std::string method = "auto";  ///< one of method_names()
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
  /// The first body (the whole mesh of a single-body scene). Builders read body 0 from here.
  MeshSpec mesh;
  /// Every body in file order, body 0 first (bodies[0] is a copy of `mesh`; size 1 for a single
  /// "mesh" object). The bodies are merged into one mesh: build_multibody_mesh().
  std::vector<MeshSpec> bodies;
  /// One per body: the mesh object's "name", else "mesh" (a single object) or "mesh[i]".
  std::vector<std::string> body_names;
  Material default_material;        ///< region label 0
  YoungsModulusSpread default_spread;  ///< the default material's "youngs_modulus_spread"
  std::vector<RegionSpec> regions;  ///< applied in order over the default material
  ContrastSpec contrast;
  std::vector<FixSpec> fixed;
  std::vector<DriverSpec> drivers;
  VectorX gravity;  ///< m/s^2, dimension entries (zero by default)
  std::vector<ForceSpec> forces;
  /// The object form of "initial_velocity" (every vertex, about the centre of mass of the whole
  /// scene); zero when the file gives the per-body (array) form.
  InitialVelocitySpec initial_velocity;
  /// The per-body form: at most one entry per body, each about that body's centre of mass.
  std::vector<InitialVelocitySpec> body_velocities;
  double h = 1.0 / 60.0;  ///< s, the time step of one solver step, > 0
  SolverSpec solver;
  OutputSpec output;
  MuscleSpec muscles;  ///< empty when the file has no "muscles" section
  std::vector<SceneCollider> colliders;  ///< "colliders", in file order (empty: none)
  ContactSpec contact;                   ///< "contact" (defaults when not given)
};

/// \brief The number of bodies of a scene (>= 1; a hand-made SceneSpec with `bodies` empty has
/// one, `mesh`).
inline int num_bodies(const SceneSpec& scene) {
  return std::max<int>(1, static_cast<int>(scene.bodies.size()));
}

/// \brief The mesh of body b: `mesh` for body 0, `bodies[b]` for the others.
inline const MeshSpec& body_mesh(const SceneSpec& scene, int b) {
  return b == 0 ? scene.mesh : scene.bodies.at(static_cast<size_t>(b));
}

/// \brief The name of body b ("mesh" when the SceneSpec has no names).
inline std::string body_name(const SceneSpec& scene, int b) {
  return static_cast<size_t>(b) < scene.body_names.size() ? scene.body_names[b]
         : b == 0                                         ? std::string("mesh")
                                                          : "mesh[" + std::to_string(b) + "]";
}

/// \brief True when the scene needs the contact model: it has colliders, or two or more bodies
/// with mesh_contact, or self_contact.
inline bool has_contact(const SceneSpec& scene) {
  return !scene.colliders.empty() || (num_bodies(scene) >= 2 && scene.contact.mesh_contact) ||
         scene.contact.self_contact;
}

/// \brief The contact options of the scene's "contact" section (defaults where not given).
inline contact::ContactOptions contact_options(const SceneSpec& scene) {
  const ContactSpec& c = scene.contact;
  contact::ContactOptions o;
  o.contact_distance = c.distance;
  o.mesh_contact = c.mesh_contact;
  o.self_contact = c.self_contact;
  o.mesh_friction = c.friction;
  o.mesh_restitution = c.restitution;
  o.ncp_tolerance = c.ncp_tolerance;
  o.ncp_max_iterations = c.ncp_max_iterations;
  o.penetration_tolerance = c.penetration_tolerance;
  o.max_redetections = c.max_redetections;
  o.restitution_threshold = c.restitution_threshold;
  o.delassus = c.delassus;
  o.ncp_linear = c.ncp_linear;
  o.ncp_krylov_min_rows = c.ncp_krylov_min_rows;
  o.ncp_stall_window = c.ncp_stall_window;
  return o;
}

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
    expect_keys(j, path, std::vector<const char*>(allowed));
  }
  /// expect_object with a list built at run time.
  void expect_keys(const json& j, const std::string& path,
                   const std::vector<const char*>& allowed) const {
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

/// A material's "youngs_modulus_spread" object (YoungsModulusSpread) at path.
inline YoungsModulusSpread parse_youngs_spread(const Parser& p, const json& j,
                                               const std::string& path) {
  p.expect_object(j, path, {"decades", "seed"});
  YoungsModulusSpread sp;
  sp.enabled = true;
  sp.decades = p.number(j, path, "decades");
  if (!(sp.decades >= 0 && sp.decades <= 12))
    p.fail(child(path, "decades"), "must lie in [0, 12], found " + format_number(sp.decades));
  const long seed = p.integer(j, path, "seed");
  if (seed < 0)
    p.fail(child(path, "seed"), "must be a non-negative integer, found " + std::to_string(seed));
  sp.seed = static_cast<std::uint64_t>(seed);
  return sp;
}

/// A "material" object into m; with `spread`, the key "youngs_modulus_spread" is allowed and
/// read into *spread (left as it is when the key is missing).
inline void parse_material(const Parser& p, const json& j, const std::string& path, Material& m,
                           bool require_youngs_modulus, YoungsModulusSpread* spread = nullptr) {
  if (spread)
    p.expect_object(j, path,
                    {"youngs_modulus", "poisson_ratio", "density", "youngs_modulus_spread"});
  else
    p.expect_object(j, path, {"youngs_modulus", "poisson_ratio", "density"});
  if (spread && j.contains("youngs_modulus_spread"))
    *spread = parse_youngs_spread(p, j.at("youngs_modulus_spread"),
                                  child(path, "youngs_modulus_spread"));
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

/// The one key among `keys` that obj holds; fails when several are given, and when none is
/// given unless `optional` (then "" is returned). `list` names the keys in the "give one of"
/// message (default: `keys`).
inline std::string one_of_keys(const Parser& p, const json& obj, const std::string& path,
                               const std::vector<const char*>& keys, bool optional = false,
                               const std::vector<const char*>& list = {}) {
  std::string found, names;
  for (const char* k : list.empty() ? keys : list)
    names += std::string(names.empty() ? "" : ", ") + "\"" + k + "\"";
  for (const char* k : keys) {
    if (obj.contains(k)) {
      if (!found.empty())
        p.fail(path, "give only one of " + std::string("\"") + found + "\" and \"" + k + "\"");
      found = k;
    }
  }
  if (found.empty() && !optional) p.fail(path, "give one of " + names);
  return found;
}

/// The one key among `keys` that obj holds; fails when none or several are given.
inline std::string one_of(const Parser& p, const json& obj, const std::string& path,
                          std::initializer_list<const char*> keys) {
  return one_of_keys(p, obj, path, std::vector<const char*>(keys));
}

/// The bodies of a scene as selectors see them: their names in order (body i is names[i]).
/// Empty where bodies are unknown (task files): there "body" is not an allowed key.
using BodyList = std::vector<std::string>;

/// The body that j (at path) names: an index in [0, #bodies) or a body's name.
inline int parse_body(const Parser& p, const json& j, const std::string& path,
                      const BodyList& bodies) {
  const int n = static_cast<int>(bodies.size());
  auto known = [&] {
    std::string k;
    for (int b = 0; b < n; ++b) k += (b ? ", " : "") + std::to_string(b) + " \"" + bodies[b] + "\"";
    return k;
  };
  if (j.is_string()) {
    const std::string name = j.get<std::string>();
    for (int b = 0; b < n; ++b)
      if (bodies[b] == name) return b;
    std::string msg = "no body is named \"" + name + "\"";
    std::string best;
    size_t best_d = std::numeric_limits<size_t>::max();
    for (const std::string& b : bodies) {
      const size_t d = edit_distance(name, b);
      if (d < best_d) best_d = d, best = b;
    }
    if (!best.empty() && best_d <= std::max<size_t>(2, name.size() / 3))
      msg += " (did you mean \"" + best + "\"?)";
    p.fail(path, msg + "; the scene's bodies are " + known());
  }
  if (!j.is_number()) p.fail(path, "expected a body index or name, found " + type_of(j));
  const long b = p.integer(j, path);
  if (b < 0 || b >= n)
    p.fail(path, "body " + std::to_string(b) + " does not exist: the scene has " +
                     std::to_string(n) + (n == 1 ? " body (" : " bodies (") + known() + ")");
  return static_cast<int>(b);
}

/// obj["vertices"] (at parent.vertices): exactly one of "indices", "box", "slab", or "body"
/// alone or with one of "box", "slab" (the box or slab restricted to the body). `bodies`: the
/// scene's bodies (empty: "body" is not allowed).
inline VertexSelector parse_selector(const Parser& p, const json& obj, const std::string& parent,
                                     int dim, const BodyList& bodies = {}) {
  const std::string path = child(parent, "vertices");
  const json& j = p.required(obj, parent, "vertices");
  std::vector<const char*> keys = {"indices", "box", "slab"};
  if (!bodies.empty()) keys.push_back("body");
  p.expect_keys(j, path, keys);
  VertexSelector s;
  s.scene_file = p.file();
  s.json_path = path;
  s.num_bodies = std::max<int>(1, static_cast<int>(bodies.size()));
  std::string k;
  if (!bodies.empty() && j.contains("body")) {
    s.body = parse_body(p, j.at("body"), child(path, "body"), bodies);
    s.body_name = bodies[s.body];
    if (j.contains("indices"))
      p.fail(path,
             "\"indices\" (vertex numbers of the whole mesh) do not combine with \"body\"; "
             "give \"body\" alone, with \"box\" or with \"slab\"");
    k = one_of_keys(p, j, path, {"box", "slab"}, /*optional=*/true);
    if (k.empty()) {
      s.kind = VertexSelector::Kind::Body;
      return s;
    }
  } else {
    k = one_of_keys(p, j, path, {"indices", "box", "slab"}, false, keys);
  }
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
/// "elements", "box", "slab", "mesh_region", or "body" alone or with one of "box", "slab",
/// "mesh_region" (restricted to the body). `bodies`: the scene's bodies (empty: no "body").
inline ElementSelector parse_element_selector(const Parser& p, const json& obj,
                                              const std::string& path, int dim,
                                              const BodyList& bodies = {}) {
  ElementSelector sel;
  sel.json_path = path;
  sel.num_bodies = std::max<int>(1, static_cast<int>(bodies.size()));
  std::vector<const char*> keys = {"elements", "box", "slab", "mesh_region"};
  if (!bodies.empty()) keys.push_back("body");
  std::string k;
  if (!bodies.empty() && obj.contains("body")) {
    sel.body = parse_body(p, obj.at("body"), child(path, "body"), bodies);
    sel.body_name = bodies[sel.body];
    if (obj.contains("elements"))
      p.fail(path,
             "\"elements\" (element numbers of the whole mesh) do not combine with "
             "\"body\"; give \"body\" alone, with \"box\", \"slab\" or \"mesh_region\"");
    k = one_of_keys(p, obj, path, {"box", "slab", "mesh_region"}, /*optional=*/true);
    if (k.empty()) {
      sel.kind = ElementSelector::Kind::Body;
      return sel;
    }
  } else {
    k = one_of_keys(p, obj, path, {"elements", "box", "slab", "mesh_region"}, false, keys);
  }
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
    const long id = p.integer(obj.at(k), child(path, k));
    if (id < std::numeric_limits<int>::min() || id > std::numeric_limits<int>::max())
      p.fail(child(path, k), "a region id must fit in an int, found " + std::to_string(id));
    sel.mesh_region = static_cast<int>(id);
  }
  return sel;
}

/// The "muscles" section (see MuscleSpec); per_axis names the fibre's expected length.
inline MuscleSpec parse_muscles(const Parser& p, const json& j, int dim, const char* per_axis,
                                const BodyList& bodies = {}) {
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
    std::vector<const char*> keys = {"name",        "elements", "box",       "slab",
                                     "mesh_region", "fibre",    "stiffness", "activation"};
    if (!bodies.empty()) keys.push_back("body");
    p.expect_keys(g, gp, keys);
    MuscleGroupSpec grp;
    grp.json_path = gp;
    grp.name = g.contains("name") ? p.string(g.at("name"), child(gp, "name")) : gp;
    if (grp.name.empty()) p.fail(child(gp, "name"), "must not be empty");
    const auto [it, inserted] = names.emplace(grp.name, gp);
    if (!inserted)
      p.fail(child(gp, "name"),
             "muscle group name \"" + grp.name + "\" is used twice (also " + it->second + ")");
    grp.elements = parse_element_selector(p, g, gp, dim, bodies);
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

/// One mesh object (the single "mesh" object, or one body "mesh[i]" of an array) at `path`.
inline MeshSpec parse_mesh_object(const Parser& p, const json& j, const std::string& path) {
  if (!j.is_object()) p.fail(path, "expected an object, found " + type_of(j));
  MeshSpec m;
  m.json_path = path;
  const std::string k = one_of(p, j, path, {"file", "generator"});
  auto common = [&](std::initializer_list<const char*> keys) {
    std::vector<const char*> all(keys);
    all.push_back("name");
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
      std::string msg = "unknown key \"" + it.key() + "\" in " + path;
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
  // A cell count above the element limit cannot give a mesh within io::limits() (and would
  // not fit in an int); the builders check the whole mesh.
  const long max_count = static_cast<long>(
      std::min<std::int64_t>(limits().max_elements, std::numeric_limits<int>::max()));
  auto bounded = [&](long v, long minimum, const std::string& at) {
    p.at_least(v, minimum, at);
    if (v > max_count)
      p.fail(at, "must be <= " + std::to_string(max_count) + " (io::limits().max_elements), found " +
                     std::to_string(v));
    return static_cast<int>(v);
  };
  auto count = [&](const char* key, long minimum, std::optional<long> def = {}) {
    return bounded(p.integer(j, path, key, def), minimum, child(path, key));
  };
  auto length = [&](const char* key) {
    const double v = p.number(j, path, key);
    p.positive(v, child(path, key));
    return v;
  };
  if (k == "file") {
    common({});
    const std::string given = p.string(j.at("file"), child(path, "file"));
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
      p.fail(child(path, "file"), "mesh file not found: " + probe + " (resolved from \"" + given +
                                      "\" relative to the scene file's folder)");
    if (ext == ".node" || ext == ".ele") {
      const std::string ele = detail::strip_extension(m.file) + ".ele";
      if (!fs::is_regular_file(ele, ec)) p.fail(child(path, "file"), "mesh file not found: " + ele);
    } else if (ext != ".msh") {
      p.fail(child(path, "file"),
             "unknown mesh file extension \"" + ext + "\" (expected .node, .ele or .msh)");
    }
    try {
      m.dimension = mesh_dimension(m.file);
    } catch (const InputError& e) {
      p.fail(child(path, "file"), e.what());
    }
  } else {
    const std::string g = p.string(j.at("generator"), child(path, "generator"));
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
        p.fail(child(path, "major_radius"),
               "must be > minor_radius = " + format_number(m.minor_radius) + ", found " +
                   format_number(m.major_radius));
      m.ring_segments = count("ring_segments", 3);
      m.tube_resolution = count("tube_resolution", 1);
    } else if (g == "branching") {
      common({"trunk_length", "trunk_radius", "levels", "branches", "length_ratio", "radius_ratio",
              "branch_angle", "cell_size"});
      m.kind = MeshSpec::Kind::Branching;
      PlantParams& q = m.plant;
      const PlantParams d;
      q.trunk_length = p.number(j, path, "trunk_length", d.trunk_length);
      p.positive(q.trunk_length, child(path, "trunk_length"));
      q.trunk_radius = p.number(j, path, "trunk_radius", d.trunk_radius);
      p.positive(q.trunk_radius, child(path, "trunk_radius"));
      const long levels = p.integer(j, path, "levels", d.levels);
      if (levels < 1 || levels > 3)
        p.fail(child(path, "levels"), "must be 1, 2 or 3, found " + std::to_string(levels));
      q.levels = static_cast<int>(levels);
      const long branches = p.integer(j, path, "branches", d.branches);
      if (branches != 2 && branches != 3)
        p.fail(child(path, "branches"), "must be 2 or 3, found " + std::to_string(branches));
      q.branches = static_cast<int>(branches);
      q.length_ratio = p.number(j, path, "length_ratio", d.length_ratio);
      if (!(q.length_ratio > 0 && q.length_ratio <= 1))
        p.fail(child(path, "length_ratio"),
               "must lie in (0, 1], found " + format_number(q.length_ratio));
      q.radius_ratio = p.number(j, path, "radius_ratio", d.radius_ratio);
      if (!(q.radius_ratio > 0 && q.radius_ratio <= 1))
        p.fail(child(path, "radius_ratio"),
               "must lie in (0, 1], found " + format_number(q.radius_ratio));
      q.branch_angle = p.number(j, path, "branch_angle", d.branch_angle);
      if (!(q.branch_angle > 0 && q.branch_angle <= 90))
        p.fail(child(path, "branch_angle"),
               "must lie in (0, 90] degrees, found " + format_number(q.branch_angle));
      q.cell_size = p.number(j, path, "cell_size", d.cell_size);
      p.positive(q.cell_size, child(path, "cell_size"));
      try {
        plant_branches(q);  // radius >= cell_size for every level
      } catch (const InputError& e) {
        p.fail(path, e.what());
      }
    } else {
      p.fail(child(path, "generator"),
             "unknown generator \"" + g +
                 "\" (expected \"box\", \"bar\", \"rectangle\", \"sheet\", "
                 "\"sphere\", \"torus\" or \"branching\")");
    }
    if (m.kind == MeshSpec::Kind::Box || m.kind == MeshSpec::Kind::Rectangle) {
      const int d = m.dimension;
      const char* why = d == 3 ? "a box is 3D" : "a rectangle is 2D";
      m.lo = p.vector(p.required(j, path, "lo"), child(path, "lo"), d, why);
      m.hi = p.vector(p.required(j, path, "hi"), child(path, "hi"), d, why);
      for (int a = 0; a < d; ++a)
        if (!(m.hi[a] > m.lo[a]))
          p.fail(item(child(path, "hi"), a), "must be > lo[" + std::to_string(a) +
                                                 "] = " + format_number(m.lo[a]) + ", found " +
                                                 format_number(m.hi[a]));
    }
    if (m.kind == MeshSpec::Kind::Box || m.kind == MeshSpec::Kind::Rectangle ||
        m.kind == MeshSpec::Kind::Sheet) {
      const int n = m.kind == MeshSpec::Kind::Box ? 3 : 2;
      const json& c = p.array(p.required(j, path, "cells"), child(path, "cells"));
      if (static_cast<int>(c.size()) != n)
        p.fail(child(path, "cells"),
               "expected " + std::to_string(n) + " cell counts, found " + std::to_string(c.size()));
      m.cells.resize(n);
      for (int a = 0; a < n; ++a) {
        const std::string at = item(child(path, "cells"), a);
        m.cells[a] = bounded(p.integer(c[a], at), 1, at);
      }
    }
  }
  m.scale = p.number(j, path, "scale", 1.0);
  p.positive(m.scale, child(path, "scale"));
  m.translate = j.contains("translate")
                    ? p.vector(j.at("translate"), child(path, "translate"), m.dimension,
                               m.dimension == 3 ? "the mesh is 3D" : "the mesh is 2D")
                    : VectorX::Zero(m.dimension);
  return m;
}

/// The single "mesh" object of a scene (parse_bodies reads the array form too).
inline MeshSpec parse_mesh(const Parser& p, const json& root) {
  return parse_mesh_object(p, p.required(root, "", "mesh"), "mesh");
}

/// "mesh": one object (one body) or an array of mesh objects (the bodies, in order), all of
/// one dimension. Fills s.mesh (body 0), s.bodies and s.body_names (unique, non-empty).
inline void parse_bodies(const Parser& p, const json& root, SceneSpec& s) {
  const json& j = p.required(root, "", "mesh");
  std::vector<std::pair<const json*, std::string>> objects;
  if (j.is_array()) {
    if (j.empty()) p.fail("mesh", "the list of bodies is empty");
    for (size_t i = 0; i < j.size(); ++i) objects.emplace_back(&j[i], item("mesh", i));
  } else if (j.is_object()) {
    objects.emplace_back(&j, "mesh");
  } else {
    p.fail("mesh",
           "expected an object (one body) or an array of objects (several bodies), "
           "found " +
               type_of(j));
  }
  std::map<std::string, std::string> names;  // name -> JSON path
  for (const auto& [obj, path] : objects) {
    MeshSpec m = parse_mesh_object(p, *obj, path);
    if (!s.bodies.empty() && m.dimension != s.bodies[0].dimension)
      p.fail(path, "is a " + std::to_string(m.dimension) + "D mesh but mesh[0] is " +
                       std::to_string(s.bodies[0].dimension) +
                       "D: all bodies must have the same dimension");
    std::string name = path;
    if (obj->contains("name")) {
      name = p.string(obj->at("name"), child(path, "name"));
      if (name.empty()) p.fail(child(path, "name"), "must not be empty");
    }
    const auto [it, inserted] = names.emplace(name, path);
    if (!inserted)
      p.fail(obj->contains("name") ? child(path, "name") : path,
             "body name \"" + name + "\" is used twice (also " + it->second + ")");
    s.bodies.push_back(std::move(m));
    s.body_names.push_back(std::move(name));
  }
  s.mesh = s.bodies[0];
}

/// The "colliders" array (see SceneCollider).
inline std::vector<SceneCollider> parse_colliders(const Parser& p, const json& j, int dim) {
  const char* per_axis = dim == 3 ? "one per axis of a 3D scene" : "one per axis of a 2D scene";
  const json& cs = p.array(j, "colliders");
  std::vector<SceneCollider> out;
  std::map<std::string, std::string> names;  // name -> JSON path
  for (size_t i = 0; i < cs.size(); ++i) {
    const std::string path = item("colliders", i);
    const json& c = cs[i];
    if (!c.is_object()) p.fail(path, "expected an object, found " + type_of(c));
    const std::string type = p.string(p.required(c, path, "type"), child(path, "type"));
    SceneCollider col;
    col.json_path = path;
    std::vector<const char*> keys = {"type",     "name",  "friction", "restitution",
                                     "velocity", "start", "stop"};
    if (type == "half-space") {
      col.kind = SceneCollider::Kind::HalfSpace;
      keys.insert(keys.end(), {"point", "normal"});
    } else if (type == "sphere") {
      col.kind = SceneCollider::Kind::Sphere;
      keys.insert(keys.end(), {"center", "radius"});
    } else if (type == "box") {
      col.kind = SceneCollider::Kind::Box;
      keys.insert(keys.end(), {"center", "half_extents"});
    } else {
      p.fail(child(path, "type"), "unknown collider type \"" + type +
                                      "\" (expected \"half-space\", \"sphere\" or \"box\")");
    }
    p.expect_keys(c, path, keys);
    col.name = c.contains("name") ? p.string(c.at("name"), child(path, "name")) : path;
    if (col.name.empty()) p.fail(child(path, "name"), "must not be empty");
    const auto [it, inserted] = names.emplace(col.name, path);
    if (!inserted)
      p.fail(child(path, "name"),
             "collider name \"" + col.name + "\" is used twice (also " + it->second + ")");
    auto vec = [&](const char* key) {
      return p.vector(p.required(c, path, key), child(path, key), dim, per_axis);
    };
    col.normal = VectorX::Zero(dim);
    col.half_extents = VectorX::Zero(dim);
    if (col.kind == SceneCollider::Kind::HalfSpace) {
      col.point = vec("point");
      col.normal = vec("normal");
      const double n = col.normal.norm();
      if (!(n > 0)) p.fail(child(path, "normal"), "must not be the zero vector");
      col.normal /= n;
    } else {
      col.point = vec("center");
      if (col.kind == SceneCollider::Kind::Sphere) {
        col.radius = p.number(c, path, "radius");
        p.positive(col.radius, child(path, "radius"));
      } else {
        col.half_extents = vec("half_extents");
        for (int d = 0; d < dim; ++d)
          p.positive(col.half_extents[d], item(child(path, "half_extents"), d));
      }
    }
    col.friction = p.number(c, path, "friction", 0.0);
    p.non_negative(col.friction, child(path, "friction"));
    col.restitution = p.number(c, path, "restitution", 0.0);
    if (!(col.restitution >= 0 && col.restitution <= 1))
      p.fail(child(path, "restitution"),
             "must lie in [0, 1], found " + format_number(col.restitution));
    col.velocity = c.contains("velocity") ? vec("velocity") : VectorX::Zero(dim);
    parse_window(p, c, path, col.start, col.stop);
    out.push_back(std::move(col));
  }
  return out;
}

/// The "contact" section (see ContactSpec); bodies: the number of bodies (mesh_contact's
/// default is bodies >= 2).
inline ContactSpec parse_contact(const Parser& p, const json& root, int bodies) {
  ContactSpec c;
  c.mesh_contact = bodies >= 2;
  if (!root.contains("contact")) return c;
  const std::string path = "contact";
  const json& j = root.at("contact");
  p.expect_object(j, path,
                  {"distance", "mesh_contact", "self_contact", "friction", "restitution",
                   "ncp_tolerance", "ncp_max_iterations", "penetration_tolerance",
                   "max_redetections", "restitution_threshold", "delassus", "ncp_linear",
                   "ncp_krylov_min_rows", "ncp_stall_window"});
  c.given = true;
  c.distance = p.number(j, path, "distance", c.distance);
  p.positive(c.distance, "contact.distance");
  c.mesh_contact = p.boolean(j, path, "mesh_contact", c.mesh_contact);
  c.self_contact = p.boolean(j, path, "self_contact", c.self_contact);
  c.friction = p.number(j, path, "friction", c.friction);
  p.non_negative(c.friction, "contact.friction");
  c.restitution = p.number(j, path, "restitution", c.restitution);
  if (!(c.restitution >= 0 && c.restitution <= 1))
    p.fail("contact.restitution", "must lie in [0, 1], found " + format_number(c.restitution));
  c.ncp_tolerance = p.number(j, path, "ncp_tolerance", c.ncp_tolerance);
  p.positive(c.ncp_tolerance, "contact.ncp_tolerance");
  const long it = p.integer(j, path, "ncp_max_iterations", c.ncp_max_iterations);
  p.at_least(it, 1, "contact.ncp_max_iterations");
  c.ncp_max_iterations = static_cast<int>(std::min<long>(it, 1'000'000'000));
  c.penetration_tolerance = p.number(j, path, "penetration_tolerance", c.penetration_tolerance);
  p.positive(c.penetration_tolerance, "contact.penetration_tolerance");
  const long r = p.integer(j, path, "max_redetections", c.max_redetections);
  p.at_least(r, 0, "contact.max_redetections");
  c.max_redetections = static_cast<int>(std::min<long>(r, 1'000'000));
  c.restitution_threshold = p.number(j, path, "restitution_threshold", c.restitution_threshold);
  p.non_negative(c.restitution_threshold, "contact.restitution_threshold");
  if (j.contains("delassus")) {
    using D = contact::ContactOptions::Delassus;
    const std::string d = p.string(j.at("delassus"), "contact.delassus");
    if (d == "auto")
      c.delassus = D::Auto;
    else if (d == "solves")
      c.delassus = D::Solves;
    else if (d == "inverse-factor")
      c.delassus = D::InverseFactor;
    else
      p.fail("contact.delassus", "unknown Delassus method \"" + d +
                                     "\" (expected \"auto\", \"solves\" or \"inverse-factor\")");
  }
  if (j.contains("ncp_linear")) {
    using L = contact::ContactOptions::NcpLinear;
    const std::string d = p.string(j.at("ncp_linear"), "contact.ncp_linear");
    if (d == "auto")
      c.ncp_linear = L::Auto;
    else if (d == "dense")
      c.ncp_linear = L::Dense;
    else if (d == "krylov")
      c.ncp_linear = L::Krylov;
    else
      p.fail("contact.ncp_linear", "unknown NCP linear solver \"" + d +
                                       "\" (expected \"auto\", \"dense\" or \"krylov\")");
  }
  const long kr = p.integer(j, path, "ncp_krylov_min_rows", c.ncp_krylov_min_rows);
  p.at_least(kr, 1, "contact.ncp_krylov_min_rows");
  c.ncp_krylov_min_rows = static_cast<int>(std::min<long>(kr, 1'000'000'000));
  const long sw = p.integer(j, path, "ncp_stall_window", c.ncp_stall_window);
  p.at_least(sw, 0, "contact.ncp_stall_window");
  c.ncp_stall_window = static_cast<int>(std::min<long>(sw, 1'000'000'000));
  return c;
}

inline SceneSpec parse(const Parser& p, const json& root, std::optional<double> contrast) {
  p.expect_object(root, "",
                  {"name", "description", "mesh", "material", "regions", "contrast", "fixed",
                   "drivers", "gravity", "forces", "initial_velocity", "time", "solver", "muscles",
                   "colliders", "contact"});
  SceneSpec s;
  s.file = p.file();
  s.output.name = root.contains("name") ? p.string(root.at("name"), "name")
                                        : std::filesystem::path(p.file()).stem().string();
  if (root.contains("description")) s.description = p.string(root.at("description"), "description");

  parse_bodies(p, root, s);
  const int dim = s.mesh.dimension;
  const BodyList& bodies = s.body_names;
  const char* per_axis = dim == 3 ? "one per axis of a 3D scene" : "one per axis of a 2D scene";

  // Materials and regions.
  parse_material(p, p.required(root, "", "material"), "material", s.default_material, true,
                 &s.default_spread);
  s.default_material.region = 0;
  std::set<std::string> names;
  if (root.contains("regions")) {
    const json& rs = p.array(root.at("regions"), "regions");
    for (size_t i = 0; i < rs.size(); ++i) {
      const std::string path = item("regions", i);
      const json& r = rs[i];
      p.expect_object(r, path,
                      {"name", "elements", "box", "slab", "mesh_region", "body", "material"});
      RegionSpec reg;
      reg.json_path = path;
      reg.name = r.contains("name") ? p.string(r.at("name"), child(path, "name")) : path;
      if (reg.name.empty()) p.fail(child(path, "name"), "must not be empty");
      if (reg.name == "default")
        p.fail(child(path, "name"), "\"default\" names the default material; choose another");
      if (!names.insert(reg.name).second)
        p.fail(child(path, "name"), "region name \"" + reg.name + "\" is used twice");
      const ElementSelector sel = parse_element_selector(p, r, path, dim, bodies);
      reg.kind = sel.kind;
      reg.elements = sel.elements;
      reg.box = sel.box;
      reg.slab = sel.slab;
      reg.mesh_region = sel.mesh_region;
      reg.body = sel.body;
      reg.body_name = sel.body_name;
      reg.num_bodies = sel.num_bodies;
      reg.material = s.default_material;
      reg.spread = s.default_spread;
      parse_material(p, p.required(r, path, "material"), child(path, "material"), reg.material,
                     false, &reg.spread);
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
      f.vertices = parse_selector(p, fs[i], path, dim, bodies);
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
          if (p.integer(d, path, "axis", 2L) != 2)
            p.fail(child(path, "axis"), "a 2D twist turns about the plane normal: axis must be 2");
          dr.axis = 2;
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
      dr.vertices = parse_selector(p, d, path, dim, bodies);
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
      f.vertices = parse_selector(p, fs[i], path, dim, bodies);
      const std::string k = one_of(p, fs[i], path, {"force", "total_force"});
      f.total = k == "total_force";
      f.force = p.vector(fs[i].at(k), child(path, k), dim, per_axis);
      parse_window(p, fs[i], path, f.start, f.stop);
      s.forces.push_back(std::move(f));
    }
  }
  s.initial_velocity.linear = VectorX::Zero(dim);
  s.initial_velocity.angular = VectorX::Zero(dim == 3 ? 3 : 1);
  s.initial_velocity.json_path = "initial_velocity";
  if (root.contains("initial_velocity")) {
    // One object for every vertex ({"linear", "angular"}), or an array of per-body entries
    // ({"body", "linear", "angular"}); a single object with "body" is a one-entry array.
    const json& v = root.at("initial_velocity");
    auto read = [&](const json& o, const std::string& path, bool per_body) {
      InitialVelocitySpec iv;
      iv.json_path = path;
      iv.linear = VectorX::Zero(dim);
      iv.angular = VectorX::Zero(dim == 3 ? 3 : 1);
      if (per_body) {
        p.expect_object(o, path, {"body", "linear", "angular"});
        iv.body = parse_body(p, p.required(o, path, "body"), child(path, "body"), bodies);
      } else {
        p.expect_object(o, path, {"linear", "angular", "body"});
      }
      if (o.contains("linear"))
        iv.linear = p.vector(o.at("linear"), child(path, "linear"), dim, per_axis);
      if (o.contains("angular")) {
        if (dim == 3)
          iv.angular =
              p.vector(o.at("angular"), child(path, "angular"), 3, "a 3D angular velocity");
        else
          iv.angular[0] = p.number(o.at("angular"), child(path, "angular"));
      }
      return iv;
    };
    if (v.is_array()) {
      std::map<int, std::string> seen;  // body -> JSON path
      for (size_t i = 0; i < v.size(); ++i) {
        const std::string path = item("initial_velocity", i);
        InitialVelocitySpec iv = read(v[i], path, true);
        const auto [it, inserted] = seen.emplace(iv.body, path);
        if (!inserted)
          p.fail(child(path, "body"), "body \"" + bodies[iv.body] +
                                          "\" already has an initial velocity (" + it->second +
                                          ")");
        s.body_velocities.push_back(std::move(iv));
      }
    } else if (v.is_object() && v.contains("body")) {
      s.body_velocities.push_back(read(v, "initial_velocity", true));
    } else {
      InitialVelocitySpec iv = read(v, "initial_velocity", false);
      s.initial_velocity.linear = iv.linear;
      s.initial_velocity.angular = iv.angular;
    }
  }

  // Time.
  {
    const json& t = p.required(root, "", "time");
    p.expect_object(t, "time", {"h", "frames", "substeps", "allow_long_run"});
    s.h = p.number(t, "time", "h");
    p.positive(s.h, "time.h");
    const long frames = p.integer(t, "time", "frames");
    if (frames <= 0) p.fail("time.frames", "must be > 0, found " + std::to_string(frames));
    const long substeps = p.integer(t, "time", "substeps", 1L);
    if (substeps <= 0) p.fail("time.substeps", "must be > 0, found " + std::to_string(substeps));
    if (frames > 100'000'000 || substeps > 100'000)
      p.fail("time", "frames or substeps is implausibly large");
    const bool long_run = p.boolean(t, "time", "allow_long_run", false);
    const std::int64_t max_steps = limits().max_steps;
    if (frames * substeps > max_steps && !long_run)
      p.fail(t.contains("substeps") ? "time.substeps" : "time.frames",
             "frames x substeps = " + std::to_string(frames) + " x " + std::to_string(substeps) +
                 " = " + std::to_string(frames * substeps) + " solver steps, more than " +
                 std::to_string(max_steps) +
                 " (io::limits().max_steps): set \"allow_long_run\": true in \"time\" if the "
                 "run is meant to be that long");
    s.output.frames = static_cast<int>(frames);
    s.output.substeps = static_cast<int>(substeps);
  }

  // Solver.
  if (root.contains("solver")) {
    const json& j = root.at("solver");
    const std::string path = "solver";
    p.expect_object(j, path,
                    {"energy", "routing", "volume_weight", "anderson_window", "anderson_reset",
                     "eps_rel", "eps_abs", "gate", "max_iterations", "damping", "method"});
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
    if (j.contains("volume_weight")) {
      const std::string v = p.string(j.at("volume_weight"), "solver.volume_weight");
      if (!parse_volume_weight(v, sv.volume_weight))
        p.fail("solver.volume_weight", "unknown volume weight \"" + v +
                                           "\" (expected \"lambda\" or \"lame\")");
      if (!has_volume_term(sv.energy))
        p.fail("solver.volume_weight",
               std::string("solver.energy \"") + to_string(sv.energy) +
                   "\" has no Volume term (use \"" + to_string(EnergyKind::CorotatedVolume) +
                   "\" or \"" + to_string(EnergyKind::CorotatedVolumeMuscle) + "\")");
    }
    if (j.contains("gate")) {
      const std::string g = p.string(j.at("gate"), "solver.gate");
      if (g == "gradient")
        sv.gate = Gate::Gradient;
      else if (g == "paper")
        sv.gate = Gate::Paper;
      else if (g == "step-relative")
        sv.gate = Gate::StepRelative;
      else
        p.fail("solver.gate", "unknown gate \"" + g +
                                  "\" (expected \"gradient\", \"paper\" or \"step-relative\")");
    }
    if (j.contains("method")) {
      const std::string m = p.string(j.at("method"), "solver.method");
      const auto& names = method_names();
      if (std::find(names.begin(), names.end(), m) == names.end())
        p.fail("solver.method", "unknown method \"" + m +
                                    "\" (expected \"auto\", \"pd\", \"newton-krylov\", "
                                    "\"lbfgs\", \"newton-direct\" or \"newton-lagged\")");
      sv.method = m;
    }
    const long m = p.integer(j, path, "anderson_window", -1L);
    if (m < -1 || m > 64)
      p.fail("solver.anderson_window",
             "must be -1 (automatic), 0 (off) or a window of 1..64, found " + std::to_string(m));
    sv.anderson_window = static_cast<int>(m);
    sv.anderson_reset = p.number(j, path, "anderson_reset", sv.anderson_reset);
    p.positive(sv.anderson_reset, "solver.anderson_reset");
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
    s.muscles = parse_muscles(p, root.at("muscles"), dim, per_axis, bodies);
    if (!has_muscle_term(s.solver.energy))
      p.fail("muscles", std::string("solver.energy \"") + to_string(s.solver.energy) +
                            "\" has no muscle term (use \"" +
                            to_string(EnergyKind::CorotatedVolumeMuscle) + "\")");
  } else if (has_muscle_term(s.solver.energy)) {
    p.fail("solver.energy", std::string("\"") + to_string(s.solver.energy) +
                                "\" needs a \"muscles\" section (the muscle groups with their "
                                "fibres and stiffness)");
  }

  if (root.contains("colliders")) s.colliders = parse_colliders(p, root.at("colliders"), dim);
  s.contact = parse_contact(p, root, num_bodies(s));
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
  const Limits& lim = limits();
  in.seekg(0, std::ios::end);
  const std::int64_t bytes = std::max<std::int64_t>(0, static_cast<std::int64_t>(in.tellg()));
  in.seekg(0, std::ios::beg);
  if (bytes > lim.max_scene_bytes)
    throw InputError("the scene file has " + std::to_string(bytes) + " bytes, more than the limit " +
                         std::to_string(lim.max_scene_bytes) + " (io::limits().max_scene_bytes)",
                     path);
  nlohmann::json root;
  // Duplicate keys are errors (JSON parsers keep the last one in silence).
  struct Frame {
    std::set<std::string> keys;
    std::string name, last_key;
  };
  std::vector<Frame> stack;
  // Open objects and arrays (entries counted for arrays), to bound array sizes and nesting.
  struct Container {
    bool array;
    std::int64_t entries;
    std::string name;
  };
  std::vector<Container> open;
  auto callback = [&](int, nlohmann::json::parse_event_t event, nlohmann::json& parsed) {
    using E = nlohmann::json::parse_event_t;
    if (event == E::value || event == E::object_start || event == E::array_start) {
      if (!open.empty() && open.back().array && ++open.back().entries > lim.max_json_array)
        throw InputError("the array" +
                             (open.back().name.empty() ? std::string()
                                                       : " under \"" + open.back().name + "\"") +
                             " has more than " + std::to_string(lim.max_json_array) +
                             " entries (io::limits().max_json_array)",
                         path);
    }
    if (event == E::object_start || event == E::array_start) {
      if (static_cast<int>(open.size()) >= lim.max_json_depth)
        throw InputError("objects and arrays nested deeper than " +
                             std::to_string(lim.max_json_depth) +
                             " levels (io::limits().max_json_depth)",
                         path);
      const std::string name = stack.empty() ? std::string() : stack.back().last_key;
      open.push_back({event == E::array_start, 0, open.empty() || !open.back().array
                                                      ? name
                                                      : open.back().name});
    } else if ((event == E::object_end || event == E::array_end) && !open.empty()) {
      open.pop_back();
    }
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
  } catch (const nlohmann::json::exception& e) {
    // Not a syntax error, e.g. out_of_range 406 "number overflow parsing '1e999'" (found by
    // fuzz_scene; it used to escape as a nlohmann exception).
    std::string msg = e.what();
    const auto pos = msg.find("] ");
    if (pos != std::string::npos) msg = msg.substr(pos + 2);
    throw InputError("invalid JSON: " + msg, path);
  }
  return scene_detail::parse(scene_detail::Parser(path), root, contrast);
}

/// \brief 2 or 3: the dimension of the scene's mesh (known from load_scene).
inline int scene_dimension(const SceneSpec& scene) {
  return scene.mesh.dimension;
}

/// \brief Builds body b of the scene (body_mesh(scene, b)) with its region ids: read from the
/// file (region = the file's region attribute) or generated (region = the branch level for
/// "branching", 0 otherwise), then scaled and translated.
/// \tparam Dim must equal scene_dimension(scene)
/// \return #V by Dim positions, #E elements, #E region ids
/// \throws InputError naming the scene file and the body ("mesh: ..." or "mesh[i]: ...", and
///   the mesh file for reader errors)
template <int Dim>
MeshWithRegions<Dim> build_body_mesh(const SceneSpec& scene, int b) {
  scene_detail::check_dimension<Dim>(scene, "build_mesh");
  const MeshSpec& m = body_mesh(scene, b);
  if (m.dimension != Dim)
    throw InputError(m.json_path + ": the body is " + std::to_string(m.dimension) + "D in a " +
                         std::to_string(Dim) + "D scene",
                     scene.file);
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
    throw InputError(m.json_path + ": " + std::string(e.what()), scene.file);
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

/// \brief The scene's bodies merged into one mesh (vertices and elements concatenated in
/// order, body 0 first), with the body of every vertex and element. The base MeshWithRegions
/// holds the merged mesh, the concatenated region ids and file vertex numbers (each body's own
/// numbering), and the union of the Gmsh region names (the first body's name wins on a clash).
template <int Dim>
struct MultiBodyMesh : MeshWithRegions<Dim> {
  std::vector<int> vertex_body;         ///< #V: the body of each vertex
  std::vector<int> element_body;        ///< #E: the body of each element
  std::vector<Index> vertex_begin;      ///< #B + 1: body b's vertices are [begin[b], begin[b+1])
  std::vector<Index> element_begin;     ///< #B + 1: body b's elements are [begin[b], begin[b+1])
  std::vector<std::string> body_names;  ///< #B

  int num_bodies() const { return static_cast<int>(body_names.size()); }
  Index num_body_vertices(int b) const { return vertex_begin[b + 1] - vertex_begin[b]; }
  Index num_body_elements(int b) const { return element_begin[b + 1] - element_begin[b]; }
};

/// \brief Builds every body (build_body_mesh) and merges them into one mesh; the multi-body
/// counterpart of build_mesh_with_regions (for one body the mesh, region ids and vertex
/// numbers are the same as build_mesh_with_regions's).
/// \tparam Dim must equal scene_dimension(scene)
/// \throws InputError naming the scene file and the body ("mesh[i]: ...")
template <int Dim>
MultiBodyMesh<Dim> build_multibody_mesh(const SceneSpec& scene) {
  scene_detail::check_dimension<Dim>(scene, "build_multibody_mesh");
  const int nb = num_bodies(scene);
  std::vector<MeshWithRegions<Dim>> parts;
  parts.reserve(nb);
  for (int b = 0; b < nb; ++b) parts.push_back(build_body_mesh<Dim>(scene, b));
  MultiBodyMesh<Dim> out;
  out.vertex_begin.assign(1, 0);
  out.element_begin.assign(1, 0);
  for (int b = 0; b < nb; ++b) {
    out.vertex_begin.push_back(out.vertex_begin.back() + parts[b].mesh.num_vertices());
    out.element_begin.push_back(out.element_begin.back() + parts[b].mesh.num_elements());
    out.body_names.push_back(body_name(scene, b));
  }
  const Index nv = out.vertex_begin.back(), ne = out.element_begin.back();
  out.vertex_body.resize(nv);
  out.element_body.resize(ne);
  if (nb == 1) {
    static_cast<MeshWithRegions<Dim>&>(out) = std::move(parts[0]);
  } else {
    VertexMatrix<Dim> X(nv, Dim);
    ElementMatrix<Dim> T(ne, Dim + 1);
    for (int b = 0; b < nb; ++b) {
      const SimplicialMesh<Dim>& m = parts[b].mesh;
      X.middleRows(out.vertex_begin[b], m.num_vertices()) = m.rest_positions();
      T.middleRows(out.element_begin[b], m.num_elements()) =
          (m.elements().array() + out.vertex_begin[b]).matrix();
      out.region.insert(out.region.end(), parts[b].region.begin(), parts[b].region.end());
      out.vertex_id.insert(out.vertex_id.end(), parts[b].vertex_id.begin(),
                           parts[b].vertex_id.end());
      out.region_names.insert(parts[b].region_names.begin(), parts[b].region_names.end());
    }
    try {
      out.mesh = SimplicialMesh<Dim>(std::move(X), std::move(T));
    } catch (const InputError& e) {
      throw InputError("mesh: merging the bodies: " + std::string(e.what()), scene.file);
    }
  }
  for (int b = 0; b < nb; ++b) {
    std::fill(out.vertex_body.begin() + out.vertex_begin[b],
              out.vertex_body.begin() + out.vertex_begin[b + 1], b);
    std::fill(out.element_body.begin() + out.element_begin[b],
              out.element_body.begin() + out.element_begin[b + 1], b);
  }
  return out;
}

/// \brief Builds the scene's mesh with its region ids: read from the file (region = the file's
/// region attribute) or generated (region = the branch level for "branching", 0 otherwise),
/// then scaled and translated. A scene with several bodies gives the merged mesh (the
/// MeshWithRegions part of build_multibody_mesh; use that for the body of each vertex).
/// \tparam Dim must equal scene_dimension(scene)
/// \return #V by Dim positions, #E elements, #E region ids
/// \throws InputError naming the scene file (and the mesh file for reader errors)
template <int Dim>
MeshWithRegions<Dim> build_mesh_with_regions(const SceneSpec& scene) {
  scene_detail::check_dimension<Dim>(scene, "build_mesh");
  if (num_bodies(scene) == 1) return build_body_mesh<Dim>(scene, 0);
  MultiBodyMesh<Dim> merged = build_multibody_mesh<Dim>(scene);
  return std::move(static_cast<MeshWithRegions<Dim>&>(merged));
}

/// \brief The scene's mesh (see build_mesh_with_regions).
template <int Dim>
SimplicialMesh<Dim> build_mesh(const SceneSpec& scene) {
  return build_mesh_with_regions<Dim>(scene).mesh;
}

namespace scene_detail {

/// The members of body `body` among `n` items (vertices or elements) with per-item bodies
/// `item_body` (an empty map is a single-body scene: every item is in body 0). For body < 0
/// every item. fail() is called (it throws) when the map is missing or has the wrong size.
template <typename Fail>
std::vector<char> body_members(int body, int num_bodies, const std::vector<int>& item_body, Index n,
                               const char* what, Fail&& fail) {
  std::vector<char> in(static_cast<size_t>(n), 1);
  if (body < 0) return in;
  if (item_body.empty()) {
    if (num_bodies <= 1 && body == 0) return in;
    fail(std::string("body: the body of every ") + what + " is not known (the scene has " +
         std::to_string(num_bodies) +
         " bodies: build the mesh with build_multibody_mesh<Dim>() and pass its " +
         (what[0] == 'v' ? "vertex_body" : "element_body") + ")");
  }
  if (static_cast<Index>(item_body.size()) != n)
    fail(std::string("body: ") + std::to_string(item_body.size()) + " body ids for " +
         std::to_string(n) + (what[0] == 'v' ? " vertices" : " elements"));
  for (Index i = 0; i < n; ++i) in[i] = item_body[i] == body;
  return in;
}

/// The bounding box (and closing tolerance) of the vertices flagged in `in`; all vertices when
/// `in` flags them all.
template <int Dim>
std::pair<Eigen::AlignedBox<double, Dim>, double> bounds(const VertexMatrix<Dim>& X,
                                                         const std::vector<char>& in) {
  Eigen::AlignedBox<double, Dim> box;
  for (Index v = 0; v < X.rows(); ++v)
    if (in[v]) box.extend(Vec<Dim>(X.row(v).transpose()));
  if (box.isEmpty()) box.extend(Vec<Dim>::Zero());
  return {box, 1e-9 * box.diagonal().norm()};
}

inline std::string body_label(int body, const std::string& name) {
  return "body " + std::to_string(body) + (name.empty() ? "" : " \"" + name + "\"");
}

}  // namespace scene_detail

/// \brief The vertices a selector picks, sorted and unique.
/// \param[in] mesh  #V by Dim rest positions are tested
/// \param[in] vertex_body  #V: the body of every vertex (MultiBodyMesh::vertex_body); needed
///   only by selectors with a "body" in a scene of several bodies (empty: unknown)
/// \return vertex indices in [0, #V)
/// \throws InputError "SCENE: JSON.PATH: ..." when an index is out of range, nothing matches,
///   or the selector names a body and the bodies of the vertices are not given
template <int Dim>
std::vector<Index> select_vertices(const VertexSelector& sel, const SimplicialMesh<Dim>& mesh,
                                   const std::vector<int>& vertex_body = {}) {
  auto fail = [&](const std::string& msg) {
    throw InputError(sel.json_path.empty() ? msg : sel.json_path + ": " + msg, sel.scene_file);
  };
  std::vector<Index> out;
  const auto& X = mesh.rest_positions();
  const Index nv = mesh.num_vertices();
  const std::vector<char> in =
      scene_detail::body_members(sel.body, sel.num_bodies, vertex_body, nv, "vertex", fail);
  const auto [bb, tol] =
      sel.body >= 0 ? scene_detail::bounds<Dim>(X, in) : scene_detail::bounds(mesh);
  switch (sel.kind) {
    case VertexSelector::Kind::Indices:
      for (size_t i = 0; i < sel.indices.size(); ++i) {
        const Index v = sel.indices[i];
        if (v < 0 || v >= nv)
          fail("indices[" + std::to_string(i) + "] = " + std::to_string(v) +
               " is out of range: the mesh has " + std::to_string(nv) + " vertices");
        out.push_back(v);
      }
      break;
    case VertexSelector::Kind::Box: {
      if (sel.box.lo.size() != Dim || sel.box.hi.size() != Dim)
        fail("box: lo and hi need " + std::to_string(Dim) + " entries");
      const auto [lo, hi] = scene_detail::absolute_box<Dim>(sel.box, bb, tol);
      for (Index v = 0; v < nv; ++v)
        if (in[v] && (X.row(v).transpose().array() >= lo.array()).all() &&
            (X.row(v).transpose().array() <= hi.array()).all())
          out.push_back(v);
      break;
    }
    case VertexSelector::Kind::Slab: {
      if (sel.slab.axis < 0 || sel.slab.axis >= Dim)
        fail("slab: axis " + std::to_string(sel.slab.axis) + " does not exist in " +
             std::to_string(Dim) + "D");
      const auto [lo, hi] = scene_detail::absolute_slab<Dim>(sel.slab, bb, tol);
      for (Index v = 0; v < nv; ++v)
        if (in[v] && X(v, sel.slab.axis) >= lo && X(v, sel.slab.axis) <= hi) out.push_back(v);
      break;
    }
    case VertexSelector::Kind::Body:
      for (Index v = 0; v < nv; ++v)
        if (in[v]) out.push_back(v);
      break;
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  if (out.empty()) {
    std::ostringstream os;
    if (sel.body >= 0 && sel.kind == VertexSelector::Kind::Body)
      os << "selects no vertex (" << scene_detail::body_label(sel.body, sel.body_name)
         << " has none)";
    else if (sel.body >= 0)
      os << "selects no vertex of " << scene_detail::body_label(sel.body, sel.body_name)
         << " (its bounding box is [" << bb.min().transpose() << "] .. [" << bb.max().transpose()
         << "])";
    else
      os << "selects no vertex (the mesh's bounding box is [" << bb.min().transpose() << "] .. ["
         << bb.max().transpose() << "])";
    fail(os.str());
  }
  return out;
}

/// \brief The elements a selector picks (by index, centroid in a box or slab, mesh region id,
/// or body), sorted.
/// \param[in] mesh_regions  #E region ids of the mesh (needed for Kind::MeshRegion)
/// \param[in] element_body  #E: the body of every element (MultiBodyMesh::element_body);
///   needed only by selectors with a "body" in a scene of several bodies (empty: unknown)
/// \throws InputError "SCENE: JSON.PATH: ..." for out-of-range indices or an empty selection
template <int Dim>
std::vector<Index> select_elements(const ElementSelector& r, const SimplicialMesh<Dim>& mesh,
                                   const std::vector<int>& mesh_regions,
                                   const std::string& scene_file = {},
                                   const std::vector<int>& element_body = {}) {
  auto fail = [&](const std::string& msg) {
    throw InputError(r.json_path.empty() ? msg : r.json_path + ": " + msg, scene_file);
  };
  std::vector<Index> out;
  const Index ne = mesh.num_elements();
  const std::vector<char> in =
      scene_detail::body_members(r.body, r.num_bodies, element_body, ne, "element", fail);
  // The bounding box of the body: of the vertices of its elements.
  std::vector<char> body_vertices;
  if (r.body >= 0) {
    body_vertices.assign(static_cast<size_t>(mesh.num_vertices()), 0);
    for (Index e = 0; e < ne; ++e)
      if (in[e])
        for (int a = 0; a <= Dim; ++a) body_vertices[mesh.elements()(e, a)] = 1;
  }
  const auto [bb, tol] = r.body >= 0
                             ? scene_detail::bounds<Dim>(mesh.rest_positions(), body_vertices)
                             : scene_detail::bounds(mesh);
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
        if (!in[e]) continue;
        const Vec<Dim> c = mesh.centroid(e);
        if ((c.array() >= lo.array()).all() && (c.array() <= hi.array()).all()) out.push_back(e);
      }
      break;
    }
    case ElementSelector::Kind::Slab: {
      if (r.slab.axis >= Dim) fail("slab: axis out of range");
      const auto [lo, hi] = scene_detail::absolute_slab<Dim>(r.slab, bb, tol);
      for (Index e = 0; e < ne; ++e) {
        if (!in[e]) continue;
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
      std::set<int> ids;
      for (Index e = 0; e < ne; ++e)
        if (in[e]) ids.insert(mesh_regions[e]);
      for (Index e = 0; e < ne; ++e)
        if (in[e] && mesh_regions[e] == r.mesh_region) out.push_back(e);
      if (out.empty()) {
        std::string known;
        for (int id : ids) known += (known.empty() ? "" : ", ") + std::to_string(id);
        fail("mesh_region: no element has region id " + std::to_string(r.mesh_region) + " (" +
             (r.body >= 0 ? scene_detail::body_label(r.body, r.body_name)
                          : std::string("the mesh")) +
             " has " + known + ")");
      }
      break;
    }
    case ElementSelector::Kind::Body:
      for (Index e = 0; e < ne; ++e)
        if (in[e]) out.push_back(e);
      break;
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  if (out.empty()) {
    if (r.body >= 0 && r.kind == ElementSelector::Kind::Body)
      fail("selects no element (" + scene_detail::body_label(r.body, r.body_name) + " has none)");
    if (r.body >= 0)
      fail("selects no element of " + scene_detail::body_label(r.body, r.body_name) +
           " (by element centroid)");
    fail("selects no element (by element centroid)");
  }
  return out;
}

/// \brief The elements a region assignment picks (see the ElementSelector overload).
/// \throws InputError "SCENE: regions[i]: ..." for out-of-range indices or an empty selection
template <int Dim>
std::vector<Index> select_elements(const RegionSpec& r, const SimplicialMesh<Dim>& mesh,
                                   const std::vector<int>& mesh_regions,
                                   const std::string& scene_file = {},
                                   const std::vector<int>& element_body = {}) {
  return select_elements(element_selector(r), mesh, mesh_regions, scene_file, element_body);
}

/// \brief The vertices a selector picks on a multi-body mesh (body selectors use its bodies).
template <int Dim>
std::vector<Index> select_vertices(const VertexSelector& sel, const MultiBodyMesh<Dim>& m) {
  return select_vertices(sel, m.mesh, m.vertex_body);
}

/// \brief The elements a selector picks on a multi-body mesh (its region ids and bodies).
template <int Dim>
std::vector<Index> select_elements(const ElementSelector& r, const MultiBodyMesh<Dim>& m,
                                   const std::string& scene_file = {}) {
  return select_elements(r, m.mesh, m.region, scene_file, m.element_body);
}

/// \brief The material of every element: the default material, then each region assignment
/// in order, with the named regions' Young's modulus multiplied by scene.contrast.factor.
/// Region labels (Material::region): 0 default, i + 1 for regions[i].
/// \param[in] mesh  the mesh from build_mesh<Dim>(scene)
/// \param[in] file_regions  #E region ids (MeshWithRegions::region); needed only by
///   "mesh_region" assignments
/// \param[in] element_body  #E bodies (MultiBodyMesh::element_body); needed only by "body"
///   assignments in a scene of several bodies
/// \throws InputError naming the scene file and the region's JSON path
template <int Dim>
MaterialField build_materials(const SceneSpec& scene, const SimplicialMesh<Dim>& mesh,
                              const std::vector<int>& file_regions = {},
                              const std::vector<int>& element_body = {}) {
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
  // The spread each element's material carries (nullptr: none) and where it was given.
  std::vector<const YoungsModulusSpread*> spread(static_cast<size_t>(mesh.num_elements()),
                                                 &scene.default_spread);
  std::vector<const std::string*> where(spread.size());
  const std::string default_path = "material";
  std::fill(where.begin(), where.end(), &default_path);
  for (const RegionSpec& r : scene.regions) {
    const std::vector<Index> sel = select_elements(r, mesh, file_regions, scene.file, element_body);
    try {
      field.assign(sel, scaled(r.material, r.name));
    } catch (const InputError& e) {
      throw InputError(r.json_path + ".material (with contrast factor): " + e.message(),
                       scene.file);
    }
    for (Index e : sel) {
      spread[e] = &r.spread;
      where[e] = &r.json_path;
    }
  }
  // Per-element Young's modulus spreads (YoungsModulusSpread), one draw sequence per seed.
  std::map<std::uint64_t, std::vector<double>> uniforms;
  for (Index e = 0; e < mesh.num_elements(); ++e) {
    const YoungsModulusSpread& sp = *spread[e];
    if (!sp.enabled || sp.decades == 0) continue;
    auto it = uniforms.find(sp.seed);
    if (it == uniforms.end())
      it = uniforms.emplace(sp.seed, spread_uniforms(sp.seed, mesh.num_elements())).first;
    Material m = field[e];
    m.youngs_modulus *= std::pow(10.0, sp.decades * (it->second[e] - 0.5));
    try {
      field.set(e, m);
    } catch (const InputError& err) {
      throw InputError(*where[e] + (where[e] == &default_path ? "" : ".material") +
                           " (with youngs_modulus_spread): " + err.message(),
                       scene.file);
    }
  }
  return field;
}

/// \brief build_materials on a multi-body mesh (its region ids and element bodies).
template <int Dim>
MaterialField build_materials(const SceneSpec& scene, const MultiBodyMesh<Dim>& m) {
  return build_materials<Dim>(scene, m.mesh, m.region, m.element_body);
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
                          const std::vector<int>& mesh_regions = {},
                          const std::vector<int>& element_body = {}) {
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
    const std::vector<Index> sel =
        select_elements(grp.elements, mesh, mesh_regions, scene.file, element_body);
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

/// \brief build_muscles on a multi-body mesh (its region ids and element bodies).
template <int Dim>
MuscleField build_muscles(const SceneSpec& scene, const MultiBodyMesh<Dim>& m) {
  return build_muscles<Dim>(scene, m.mesh, m.region, m.element_body);
}

/// \brief The Dirichlet mask of the scene's "fixed" entries (drivers are not included).
/// \param[in] vertex_body  #V bodies (MultiBodyMesh::vertex_body); needed only by "body"
///   selectors in a scene of several bodies
/// \return #V by Dim flags, true where the coordinate is fixed (PDSystem::set_dirichlet)
template <int Dim>
Eigen::Matrix<bool, Eigen::Dynamic, Dim> fixed_mask(const SceneSpec& scene,
                                                    const SimplicialMesh<Dim>& mesh,
                                                    const std::vector<int>& vertex_body = {}) {
  scene_detail::check_dimension<Dim>(scene, "fixed_mask");
  Eigen::Matrix<bool, Eigen::Dynamic, Dim> mask =
      Eigen::Matrix<bool, Eigen::Dynamic, Dim>::Constant(mesh.num_vertices(), Dim, false);
  for (const FixSpec& f : scene.fixed)
    for (Index v : select_vertices(f.vertices, mesh, vertex_body))
      for (int d = 0; d < Dim; ++d) mask(v, d) = mask(v, d) || f.axes[d];
  return mask;
}

/// \brief fixed_mask on a multi-body mesh.
template <int Dim>
Eigen::Matrix<bool, Eigen::Dynamic, Dim> fixed_mask(const SceneSpec& scene,
                                                    const MultiBodyMesh<Dim>& m) {
  return fixed_mask<Dim>(scene, m.mesh, m.vertex_body);
}

namespace scene_detail {

/// Adds v = linear + angular x (x - c) to the rows of V flagged in `in` (every row when `in`
/// is null), c the centre of mass (lumped masses `mass`) of those vertices.
template <int Dim>
void add_rigid_velocity(VertexMatrix<Dim>& V, const VertexMatrix<Dim>& X, const VectorX& mass,
                        const std::vector<char>* in, const InitialVelocitySpec& iv) {
  Vec<Dim> c = Vec<Dim>::Zero();
  if (!in) {
    c = (X.transpose() * mass) / mass.sum();
  } else {
    double m = 0;
    for (Index v = 0; v < X.rows(); ++v)
      if ((*in)[v]) c += mass[v] * X.row(v).transpose(), m += mass[v];
    if (m > 0) c /= m;
  }
  const Vec<Dim> lin = iv.linear.head<Dim>();
  for (Index v = 0; v < X.rows(); ++v) {
    if (in && !(*in)[v]) continue;
    const Vec<Dim> r = X.row(v).transpose() - c;
    Vec<Dim> w;
    if constexpr (Dim == 3)
      w = Vec<3>(iv.angular.head<3>()).cross(r);
    else
      w = iv.angular[0] * Vec<2>(-r[1], r[0]);
    V.row(v) += (lin + w).transpose();
  }
}

}  // namespace scene_detail

/// \brief The initial velocity of every vertex: the object form, linear + angular x (x - c)
/// with c the centre of mass of the lumped masses of all vertices, plus each per-body entry
/// (scene.body_velocities) on its body's vertices, about that body's centre of mass.
/// \param[in] vertex_body  #V bodies (MultiBodyMesh::vertex_body); needed only by per-body
///   entries in a scene of several bodies
/// \return #V by Dim velocities, m/s
/// \throws InputError when per-body entries need vertex_body and it is not given
template <int Dim>
VertexMatrix<Dim> initial_velocities(const SceneSpec& scene, const SimplicialMesh<Dim>& mesh,
                                     const MaterialField& materials,
                                     const std::vector<int>& vertex_body = {}) {
  scene_detail::check_dimension<Dim>(scene, "initial_velocities");
  const VectorX mass = mesh.lumped_mass(materials.densities());
  const auto& X = mesh.rest_positions();
  const Index nv = mesh.num_vertices();
  VertexMatrix<Dim> V = VertexMatrix<Dim>::Zero(nv, Dim);
  scene_detail::add_rigid_velocity<Dim>(V, X, mass, nullptr, scene.initial_velocity);
  for (const InitialVelocitySpec& iv : scene.body_velocities) {
    auto fail = [&](const std::string& msg) {
      throw InputError(iv.json_path + ": " + msg, scene.file);
    };
    const std::vector<char> in =
        scene_detail::body_members(iv.body, num_bodies(scene), vertex_body, nv, "vertex", fail);
    scene_detail::add_rigid_velocity<Dim>(V, X, mass, &in, iv);
  }
  return V;
}

/// \brief initial_velocities on a multi-body mesh.
template <int Dim>
VertexMatrix<Dim> initial_velocities(const SceneSpec& scene, const MultiBodyMesh<Dim>& m,
                                     const MaterialField& materials) {
  return initial_velocities<Dim>(scene, m.mesh, materials, m.vertex_body);
}

/// \brief The scene's colliders as contact::Collider<Dim> (in file order; an unbounded stop
/// becomes Collider's default stop_time).
/// \tparam Dim must equal scene_dimension(scene)
template <int Dim>
std::vector<contact::Collider<Dim>> build_colliders(const SceneSpec& scene) {
  scene_detail::check_dimension<Dim>(scene, "build_colliders");
  std::vector<contact::Collider<Dim>> out;
  for (const SceneCollider& c : scene.colliders) {
    using K = typename contact::Collider<Dim>::Kind;
    contact::Collider<Dim> k;
    k.kind = c.kind == SceneCollider::Kind::HalfSpace ? K::HalfSpace
             : c.kind == SceneCollider::Kind::Sphere  ? K::Sphere
                                                      : K::Box;
    k.name = c.name;
    k.point = c.point.head<Dim>();
    if (c.kind == SceneCollider::Kind::HalfSpace) k.normal = c.normal.head<Dim>();
    if (c.kind == SceneCollider::Kind::Sphere) k.radius = c.radius;
    if (c.kind == SceneCollider::Kind::Box) k.half_extents = c.half_extents.head<Dim>();
    k.velocity = c.velocity.size() == Dim ? Vec<Dim>(c.velocity.head<Dim>()) : Vec<Dim>::Zero();
    k.start_time = c.start;
    if (std::isfinite(c.stop)) k.stop_time = c.stop;
    k.friction = c.friction;
    k.restitution = c.restitution;
    out.push_back(std::move(k));
  }
  return out;
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
