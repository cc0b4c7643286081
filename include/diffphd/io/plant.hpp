#pragma once
/// \file plant.hpp
/// \brief make_branching_plant: a procedural plant-like branching body (trunk and two or three
/// levels of branches) as one connected, conforming tetrahedral mesh.
///
/// Construction: the plant is a union of capsules (segment plus radius), one per branch. The
/// union is voxelised on a regular grid of cubic cells (a cell is occupied when its centre lies
/// in some capsule, and in the half-space y >= 0 so the trunk stands on a flat base at y = 0);
/// the largest face-connected set of occupied cells is kept, and every kept cell is split into
/// the same 6 Kuhn tetrahedra as make_box. Neighbouring cells then share their split faces, so
/// the mesh is conforming by construction, and it is one connected component. If a branch's tip
/// does not fall into a kept cell (the branch is too thin for the grid, or cut off) the
/// generator throws instead of returning a plant with a branch missing.
///
/// The surface is a staircase of cell faces (resolution = cell_size); every tetrahedron has the
/// quality of a Kuhn tet of a cube (0.657), and volumes are exact for the voxelised shape.

#include <algorithm>
#include <array>
#include <cmath>
#include <queue>
#include <string>
#include <vector>

#include "../core/errors.hpp"
#include "../core/mesh.hpp"
#include "../core/types.hpp"
#include "generators.hpp"

namespace diffphd {

/// \brief Parameters of make_branching_plant. Lengths in metres, angles in degrees.
struct PlantParams {
  double trunk_length = 0.5;   ///< m, along +y from the base at the origin
  double trunk_radius = 0.04;  ///< m
  int levels = 2;              ///< levels of branches above the trunk, 1..3
  int branches = 2;            ///< children per branch tip, 2 or 3
  double length_ratio = 0.65;  ///< child length / parent length, in (0, 1]
  double radius_ratio = 0.7;   ///< child radius / parent radius, in (0, 1]
  double branch_angle = 35.0;  ///< degrees between a child and its parent, in (0, 90]
  double cell_size = 0.02;     ///< m, voxel edge; every branch radius must be >= cell_size
};

/// \brief One capsule of the plant: the segment start -> tip with a radius.
struct PlantBranch {
  Vec<3> start;   ///< m
  Vec<3> tip;     ///< m
  double radius;  ///< m
  int level;      ///< 0 for the trunk, 1.. for branches
  int parent;     ///< index of the parent branch, -1 for the trunk
};

/// \brief What make_branching_plant returns: the mesh, a per-element level and the capsules.
struct PlantMesh {
  SimplicialMesh<3> mesh;
  /// #E level of each element: the lowest level among the capsules that contain the centre of
  /// the element's cell (0 = trunk). Usable as region ids.
  std::vector<int> level;
  std::vector<PlantBranch> branches;  ///< the capsules, trunk first
};

namespace plant_detail {

inline double segment_distance(const Vec<3>& p, const Vec<3>& a, const Vec<3>& b) {
  const Vec<3> ab = b - a;
  const double t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
  return (p - (a + t * ab)).norm();
}

inline void check(bool ok, const std::string& message) {
  if (!ok) throw InputError("make_branching_plant: " + message);
}

}  // namespace plant_detail

/// \brief The capsules of the plant described by p (no meshing). Children of a branch start
/// at its tip and leave at branch_angle from its direction, spread evenly around it (rotated by
/// the golden angle from one level to the next so the levels do not line up).
inline std::vector<PlantBranch> plant_branches(const PlantParams& p) {
  using plant_detail::check;
  check(std::isfinite(p.trunk_length) && p.trunk_length > 0, "trunk_length must be > 0");
  check(std::isfinite(p.trunk_radius) && p.trunk_radius > 0, "trunk_radius must be > 0");
  check(p.levels >= 1 && p.levels <= 3, "levels must be 1, 2 or 3");
  check(p.branches == 2 || p.branches == 3, "branches must be 2 or 3");
  check(p.length_ratio > 0 && p.length_ratio <= 1, "length_ratio must lie in (0, 1]");
  check(p.radius_ratio > 0 && p.radius_ratio <= 1, "radius_ratio must lie in (0, 1]");
  check(p.branch_angle > 0 && p.branch_angle <= 90, "branch_angle must lie in (0, 90] degrees");
  check(std::isfinite(p.cell_size) && p.cell_size > 0, "cell_size must be > 0");
  const double pi = 3.14159265358979323846;
  const double golden = pi * (3.0 - std::sqrt(5.0));
  const double theta = p.branch_angle * pi / 180.0;
  std::vector<PlantBranch> out;
  out.push_back({Vec<3>(0, 0, 0), Vec<3>(0, p.trunk_length, 0), p.trunk_radius, 0, -1});
  for (size_t i = 0; i < out.size(); ++i) {
    const PlantBranch parent = out[i];
    if (parent.level >= p.levels) continue;
    const Vec<3> d = (parent.tip - parent.start).normalized();
    const Vec<3> helper = std::abs(d.x()) < 0.9 ? Vec<3>(1, 0, 0) : Vec<3>(0, 0, 1);
    const Vec<3> u = d.cross(helper).normalized(), w = d.cross(u);
    const double len = (parent.tip - parent.start).norm() * p.length_ratio;
    const double r = parent.radius * p.radius_ratio;
    for (int k = 0; k < p.branches; ++k) {
      const double phi = 2 * pi * k / p.branches + golden * parent.level;
      const Vec<3> dc =
          std::cos(theta) * d + std::sin(theta) * (std::cos(phi) * u + std::sin(phi) * w);
      out.push_back({parent.tip, parent.tip + len * dc, r, parent.level + 1, static_cast<int>(i)});
    }
  }
  for (const auto& b : out)
    check(b.radius >= p.cell_size,
          "a level-" + std::to_string(b.level) + " branch has radius " + std::to_string(b.radius) +
              " m, below cell_size = " + std::to_string(p.cell_size) +
              " m: decrease cell_size or increase trunk_radius / radius_ratio");
  return out;
}

/// \brief A plant-like branching body (see the file comment).
/// \return a conforming, connected tetrahedral mesh standing on y = 0 (6 tets per kept cell),
///   the per-element branch level and the capsules
/// \throws InputError naming the parameter for bad parameters, or when a branch is lost
inline PlantMesh make_branching_plant(const PlantParams& p = {}) {
  const std::vector<PlantBranch> caps = plant_branches(p);
  const double c = p.cell_size;
  Vec<3> lo = Vec<3>::Constant(1e300), hi = Vec<3>::Constant(-1e300);
  for (const auto& b : caps) {
    lo = lo.cwiseMin(b.start.cwiseMin(b.tip) - Vec<3>::Constant(b.radius));
    hi = hi.cwiseMax(b.start.cwiseMax(b.tip) + Vec<3>::Constant(b.radius));
  }
  lo.y() = 0;  // the flat base
  Eigen::Vector3i n;
  const Vec<3> cells = ((hi - lo) / c).array().ceil().max(1.0);
  plant_detail::check(cells.prod() <= 20'000'000,
                      "the grid has more than 20000000 cells: increase cell_size");
  generators_detail::check_grid_size<3>("make_branching_plant", {cells[0], cells[1], cells[2]});
  for (int d = 0; d < 3; ++d) {
    n[d] = static_cast<int>(cells[d]);
    if (d != 1) lo[d] = 0.5 * (lo[d] + hi[d]) - 0.5 * n[d] * c;  // centre the grid in x, z
  }
  const long ncells = static_cast<long>(n[0]) * n[1] * n[2];
  auto cell_id = [&](int i, int j, int k) { return i + static_cast<long>(n[0]) * (j + n[1] * k); };
  std::vector<int> label(ncells, -1);  // lowest capsule level containing the centre, -1 if none
  for (const auto& b : caps) {
    Eigen::Vector3i a0, a1;
    for (int d = 0; d < 3; ++d) {
      const double blo = std::min(b.start[d], b.tip[d]) - b.radius;
      const double bhi = std::max(b.start[d], b.tip[d]) + b.radius;
      a0[d] = std::max(0, static_cast<int>(std::floor((blo - lo[d]) / c)));
      a1[d] = std::min(n[d] - 1, static_cast<int>(std::floor((bhi - lo[d]) / c)));
    }
    for (int k = a0[2]; k <= a1[2]; ++k)
      for (int j = a0[1]; j <= a1[1]; ++j)
        for (int i = a0[0]; i <= a1[0]; ++i) {
          const Vec<3> centre = lo + c * Vec<3>(i + 0.5, j + 0.5, k + 0.5);
          if (plant_detail::segment_distance(centre, b.start, b.tip) <= b.radius) {
            int& l = label[cell_id(i, j, k)];
            if (l < 0 || b.level < l) l = b.level;
          }
        }
  }
  // Largest face-connected component of occupied cells.
  std::vector<int> comp(ncells, -1);
  int best = -1;
  long best_size = 0;
  int ncomp = 0;
  for (long s = 0; s < ncells; ++s) {
    if (label[s] < 0 || comp[s] >= 0) continue;
    long size = 0;
    std::queue<long> queue;
    queue.push(s);
    comp[s] = ncomp;
    while (!queue.empty()) {
      const long q = queue.front();
      queue.pop();
      ++size;
      const int i = static_cast<int>(q % n[0]), j = static_cast<int>((q / n[0]) % n[1]),
                k = static_cast<int>(q / (static_cast<long>(n[0]) * n[1]));
      const int nb[6][3] = {{i - 1, j, k}, {i + 1, j, k}, {i, j - 1, k},
                            {i, j + 1, k}, {i, j, k - 1}, {i, j, k + 1}};
      for (const auto& m : nb) {
        if (m[0] < 0 || m[1] < 0 || m[2] < 0 || m[0] >= n[0] || m[1] >= n[1] || m[2] >= n[2])
          continue;
        const long r = cell_id(m[0], m[1], m[2]);
        if (label[r] >= 0 && comp[r] < 0) {
          comp[r] = ncomp;
          queue.push(r);
        }
      }
    }
    if (size > best_size) best_size = size, best = ncomp;
    ++ncomp;
  }
  plant_detail::check(best >= 0, "no grid cell is occupied: decrease cell_size");
  for (size_t b = 0; b < caps.size(); ++b) {
    // The cell of a point slightly inside the tip along the branch must be kept.
    const Vec<3> dir = (caps[b].tip - caps[b].start).normalized();
    const Vec<3> q = caps[b].tip - 0.5 * c * dir;
    Eigen::Vector3i ijk;
    for (int d = 0; d < 3; ++d)
      ijk[d] = std::clamp(static_cast<int>(std::floor((q[d] - lo[d]) / c)), 0, n[d] - 1);
    plant_detail::check(comp[cell_id(ijk[0], ijk[1], ijk[2])] == best,
                        "branch " + std::to_string(b) + " (level " + std::to_string(caps[b].level) +
                            ") is not connected to the trunk on this grid: decrease cell_size");
  }
  // Vertices of the kept cells, compacted; 6 Kuhn tets per cell (same split as make_box).
  const long nvx = static_cast<long>(n[0] + 1) * (n[1] + 1) * (n[2] + 1);
  auto vertex_id = [&](int i, int j, int k) {
    return i + static_cast<long>(n[0] + 1) * (j + static_cast<long>(n[1] + 1) * k);
  };
  std::vector<Index> compact(nvx, -1);
  std::vector<Vec<3>> xs;
  std::vector<std::array<Index, 4>> tets;
  std::vector<int> level;
  static constexpr int kPerm[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2},
                                      {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  for (int k = 0; k < n[2]; ++k)
    for (int j = 0; j < n[1]; ++j)
      for (int i = 0; i < n[0]; ++i) {
        const long cid = cell_id(i, j, k);
        if (comp[cid] != best) continue;
        auto corner = [&](int bits) {
          const int ci = i + (bits & 1), cj = j + ((bits >> 1) & 1), ck = k + ((bits >> 2) & 1);
          Index& v = compact[vertex_id(ci, cj, ck)];
          if (v < 0) {
            v = static_cast<Index>(xs.size());
            xs.push_back(lo + c * Vec<3>(ci, cj, ck));
          }
          return v;
        };
        for (const auto& perm : kPerm) {
          std::array<Index, 4> t;
          int bits = 0;
          t[0] = corner(0);
          for (int a = 0; a < 3; ++a) {
            bits |= 1 << perm[a];
            t[a + 1] = corner(bits);
          }
          tets.push_back(t);
          level.push_back(label[cid]);
        }
      }
  VertexMatrix<3> X(static_cast<Index>(xs.size()), 3);
  for (size_t v = 0; v < xs.size(); ++v) X.row(static_cast<Index>(v)) = xs[v].transpose();
  ElementMatrix<3> T(static_cast<Index>(tets.size()), 4);
  for (size_t e = 0; e < tets.size(); ++e)
    for (int a = 0; a < 4; ++a) T(static_cast<Index>(e), a) = tets[e][a];
  return PlantMesh{generators_detail::oriented_mesh<3>(std::move(X), std::move(T)),
                   std::move(level), caps};
}

}  // namespace diffphd
