#pragma once
/// \file ordering.hpp
/// \brief METIS nested-dissection fill-reducing ordering of a symmetric sparse matrix.

#include <algorithm>
#include <stdexcept>
#include <string>
#include <vector>

#include <metis.h>

#include "../core/errors.hpp"
#include "../core/types.hpp"

namespace diffphd {

static_assert(sizeof(idx_t) == sizeof(Index),
              "diffphd expects METIS built with 32-bit idx_t (IDXTYPEWIDTH 32)");

/// \brief A fill-reducing permutation: perm[new] = old and its inverse iperm[old] = new.
struct Ordering {
  Eigen::VectorXi perm;
  Eigen::VectorXi iperm;
};

/// \brief METIS_NodeND on the adjacency graph of A (the pattern of A + A^T without the
/// diagonal).
///
/// \param[in] A  n by n sparse matrix; its pattern is symmetrised, values are ignored
/// \return perm (perm[new] = old) and iperm (iperm[old] = new), both of size n
/// Throws InputError when A is not square and std::runtime_error naming the METIS return code
/// when METIS fails.
inline Ordering metis_nested_dissection_ordering(const SparseMatrix& A) {
  if (A.rows() != A.cols())
    throw InputError("metis_nested_dissection: matrix is " + std::to_string(A.rows()) + " x " +
                     std::to_string(A.cols()) + ", expected square");
  const Index n = static_cast<Index>(A.rows());
  Ordering out;
  out.perm.resize(n);
  out.iperm.resize(n);
  if (n == 0) return out;
  // Symmetrised adjacency without the diagonal, in CSR (xadj, adjncy).
  std::vector<std::vector<Index>> adj(n);
  for (Index j = 0; j < A.outerSize(); ++j)
    for (SparseMatrix::InnerIterator it(A, j); it; ++it) {
      const Index i = static_cast<Index>(it.row());
      if (i == j) continue;
      adj[i].push_back(j);
      adj[j].push_back(i);
    }
  std::vector<idx_t> xadj(n + 1, 0), adjncy;
  for (Index i = 0; i < n; ++i) {
    auto& a = adj[i];
    std::sort(a.begin(), a.end());
    a.erase(std::unique(a.begin(), a.end()), a.end());
    xadj[i + 1] = xadj[i] + static_cast<idx_t>(a.size());
  }
  adjncy.reserve(xadj[n]);
  for (auto& a : adj) adjncy.insert(adjncy.end(), a.begin(), a.end());
  if (adjncy.empty()) {  // no edges: any order is optimal (METIS rejects an empty graph)
    for (Index i = 0; i < n; ++i) out.perm[i] = out.iperm[i] = i;
    return out;
  }
  idx_t nvtxs = n;
  idx_t options[METIS_NOPTIONS];
  METIS_SetDefaultOptions(options);
  options[METIS_OPTION_NUMBERING] = 0;
  std::vector<idx_t> metis_perm(n), metis_iperm(n);
  const int rc = METIS_NodeND(&nvtxs, xadj.data(), adjncy.data(), nullptr, options,
                              metis_perm.data(), metis_iperm.data());
  if (rc != METIS_OK)
    throw std::runtime_error("metis_nested_dissection: METIS_NodeND failed with return code " +
                             std::to_string(rc) +
                             (rc == METIS_ERROR_MEMORY  ? " (METIS_ERROR_MEMORY)"
                              : rc == METIS_ERROR_INPUT ? " (METIS_ERROR_INPUT)"
                                                        : " (METIS_ERROR)"));
  // METIS 5 manual, METIS_NodeND: "row (column) i of A' is the perm[i] row (column) of A, and
  // row (column) i of A is the iperm[i] row (column) of A'", i.e. perm[new] = old. The test
  // suite checks this against the fill of the factor; here only the consistency is checked.
  for (Index i = 0; i < n; ++i) {
    out.perm[i] = metis_perm[i];
    out.iperm[i] = metis_iperm[i];
  }
  for (Index i = 0; i < n; ++i)
    if (out.perm[i] < 0 || out.perm[i] >= n || out.iperm[out.perm[i]] != i)
      throw std::runtime_error("metis_nested_dissection: METIS returned an invalid permutation");
  return out;
}

/// \brief The METIS nested-dissection permutation of A with perm[new] = old (see
/// metis_nested_dissection_ordering() for the inverse as well).
inline Eigen::VectorXi metis_nested_dissection(const SparseMatrix& A) {
  return metis_nested_dissection_ordering(A).perm;
}

}  // namespace diffphd
