#pragma once
/// \file material.hpp
/// \brief Per-element materials (Young's modulus, Poisson ratio, density, region) and Lame
/// parameters by eq. (1) of the paper.

#include <cmath>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "errors.hpp"
#include "mesh.hpp"
#include "types.hpp"

namespace diffphd {

/// \brief One element's material. Units: Pa, dimensionless, kg/m^3 (kg/m^2 in 2D).
struct Material {
  double youngs_modulus = 1e5;  ///< E > 0
  double poisson_ratio = 0.3;   ///< nu in (-1, 0.5)
  double density = 1000.0;      ///< rho > 0
  int region = 0;               ///< user label, carried through to output
};

/// Shear modulus mu = E / (2 (1 + nu)), eq. (1).
inline double lame_mu(double E, double nu) {
  return E / (2.0 * (1.0 + nu));
}
/// First Lame parameter lambda = E nu / ((1 + nu)(1 - 2 nu)), eq. (1).
inline double lame_lambda(double E, double nu) {
  return E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
}

/// Throws InputError naming `where` and the parameter when m is not physical.
inline void validate_material(const Material& m, const std::string& where,
                              const std::string& file = {}, long line = 0) {
  auto fail = [&](const char* name, double value, const char* rule) {
    std::ostringstream os;
    os << where << ": " << name << " = " << value << " " << rule;
    throw InputError(os.str(), file, line);
  };
  if (!(std::isfinite(m.youngs_modulus) && m.youngs_modulus > 0))
    fail("Young's modulus E", m.youngs_modulus, "must be finite and > 0");
  if (!(std::isfinite(m.poisson_ratio) && m.poisson_ratio > -1.0 && m.poisson_ratio < 0.5))
    fail("Poisson ratio nu", m.poisson_ratio, "must lie in (-1, 0.5)");
  if (!(std::isfinite(m.density) && m.density > 0))
    fail("density", m.density, "must be finite and > 0");
}

/// \brief The material of every element of a mesh, assigned by region.
///
/// Regions can be given by an element index list, an axis-aligned box or slab (by element
/// centroid), or a per-element region array with a material per region. Every assignment is
/// validated; a later assignment overrides an earlier one.
class MaterialField {
 public:
  MaterialField() = default;
  /// All #E elements get `m`.
  MaterialField(Index num_elements, const Material& m) : mat_(num_elements, m) {
    validate_material(m, "material");
  }

  Index size() const { return static_cast<Index>(mat_.size()); }
  const Material& operator[](Index e) const { return mat_[e]; }

  /// Sets one element's material (validated).
  void set(Index e, const Material& m) {
    check_element(e);
    validate_material(m, "element " + std::to_string(e));
    mat_[e] = m;
  }
  /// Assigns `m` to the listed elements. Returns how many were assigned.
  Index assign(const std::vector<Index>& elements, const Material& m) {
    validate_material(m, "region " + std::to_string(m.region));
    for (Index e : elements) check_element(e);
    for (Index e : elements) mat_[e] = m;
    return static_cast<Index>(elements.size());
  }
  /// Assigns `m` to every element whose centroid lies in `box` (closed). Returns the count.
  template <int Dim>
  Index assign_box(const SimplicialMesh<Dim>& mesh, const Eigen::AlignedBox<double, Dim>& box,
                   const Material& m) {
    check_mesh(mesh);
    std::vector<Index> sel;
    for (Index e = 0; e < mesh.num_elements(); ++e)
      if (box.contains(mesh.centroid(e))) sel.push_back(e);
    return assign(sel, m);
  }
  /// Assigns `m` to every element whose centroid has lo <= x[axis] <= hi. Returns the count.
  template <int Dim>
  Index assign_slab(const SimplicialMesh<Dim>& mesh, int axis, double lo, double hi,
                    const Material& m) {
    if (axis < 0 || axis >= Dim)
      throw InputError("assign_slab: axis " + std::to_string(axis) + " is not in [0, " +
                       std::to_string(Dim) + ")");
    check_mesh(mesh);
    std::vector<Index> sel;
    for (Index e = 0; e < mesh.num_elements(); ++e) {
      const double c = mesh.centroid(e)[axis];
      if (c >= lo && c <= hi) sel.push_back(e);
    }
    return assign(sel, m);
  }
  /// Per-element region ids with one material per region id. Every id must have a material.
  void assign_regions(const std::vector<int>& region_of_element,
                      const std::map<int, Material>& region_materials) {
    if (static_cast<Index>(region_of_element.size()) != size())
      throw InputError("assign_regions: " + std::to_string(region_of_element.size()) +
                       " region ids for " + std::to_string(size()) + " elements");
    for (const auto& kv : region_materials)
      validate_material(kv.second, "region " + std::to_string(kv.first));
    for (Index e = 0; e < size(); ++e) {
      auto it = region_materials.find(region_of_element[e]);
      if (it == region_materials.end())
        throw InputError("element " + std::to_string(e) + ": region " +
                         std::to_string(region_of_element[e]) + " has no material");
      mat_[e] = it->second;
      mat_[e].region = region_of_element[e];
    }
  }

  VectorX youngs_moduli() const {
    return collect([](const Material& m) { return m.youngs_modulus; });
  }
  VectorX poisson_ratios() const {
    return collect([](const Material& m) { return m.poisson_ratio; });
  }
  VectorX densities() const {
    return collect([](const Material& m) { return m.density; });
  }
  VectorX mu() const {
    return collect([](const Material& m) { return lame_mu(m.youngs_modulus, m.poisson_ratio); });
  }
  VectorX lambda() const {
    return collect(
        [](const Material& m) { return lame_lambda(m.youngs_modulus, m.poisson_ratio); });
  }
  std::vector<int> regions() const {
    std::vector<int> r(mat_.size());
    for (size_t e = 0; e < mat_.size(); ++e) r[e] = mat_[e].region;
    return r;
  }
  /// mu_ref = max_e mu_e (the damping normalisation of Sec. 4.5).
  double mu_ref() const { return size() ? mu().maxCoeff() : 0.0; }
  /// max_e E_e / min_e E_e.
  double stiffness_contrast() const {
    if (!size()) return 1.0;
    const VectorX E = youngs_moduli();
    return E.maxCoeff() / E.minCoeff();
  }

 private:
  template <class F>
  VectorX collect(F f) const {
    VectorX v(size());
    for (Index e = 0; e < size(); ++e) v[e] = f(mat_[e]);
    return v;
  }
  void check_element(Index e) const {
    if (e < 0 || e >= size())
      throw InputError("element index " + std::to_string(e) + " is out of range [0, " +
                       std::to_string(size()) + ")");
  }
  template <int Dim>
  void check_mesh(const SimplicialMesh<Dim>& mesh) const {
    if (mesh.num_elements() != size())
      throw InputError("material field has " + std::to_string(size()) + " elements, the mesh has " +
                       std::to_string(mesh.num_elements()));
  }
  std::vector<Material> mat_;
};

}  // namespace diffphd
