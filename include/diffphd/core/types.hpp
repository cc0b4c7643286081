#pragma once
/// \file types.hpp
/// \brief Common Eigen aliases and the host/device function marker.

#include <Eigen/Core>
#include <Eigen/SparseCore>

#if defined(__CUDACC__)
#define DIFFPHD_HOST_DEVICE __host__ __device__
#else
#define DIFFPHD_HOST_DEVICE
#endif

namespace diffphd {

using Index = int;  ///< vertex and element indices (METIS and cuSPARSE use 32-bit indices)

using VectorX = Eigen::VectorXd;
using MatrixX = Eigen::MatrixXd;
/// An nv x Dim block of per-vertex vectors (positions, velocities, forces), one row a vertex.
template <int Dim>
using VertexMatrix = Eigen::Matrix<double, Eigen::Dynamic, Dim, Eigen::RowMajor>;
/// An ne x (Dim+1) list of simplices, one row an element.
template <int Dim>
using ElementMatrix = Eigen::Matrix<Index, Eigen::Dynamic, Dim + 1, Eigen::RowMajor>;
/// An nf x Dim list of boundary facets (edges in 2D, triangles in 3D), outward oriented.
template <int Dim>
using FacetMatrix = Eigen::Matrix<Index, Eigen::Dynamic, Dim, Eigen::RowMajor>;
template <int Dim>
using Vec = Eigen::Matrix<double, Dim, 1>;
template <int Dim>
using Mat = Eigen::Matrix<double, Dim, Dim>;

using SparseMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, Index>;
using SparseMatrixCSR = Eigen::SparseMatrix<double, Eigen::RowMajor, Index>;

}  // namespace diffphd
