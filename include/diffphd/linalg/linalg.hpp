#pragma once
/// \file linalg.hpp
/// \brief The linear algebra of the PD global step: the matrix of eq. (31), METIS-ordered
/// factors, the explicit inverse factor of eqs. (32)-(33) and the Dirichlet-reduced system.
/// See docs/linalg.md.

#include "inverse_factor.hpp"
#include "ordering.hpp"
#include "pd_matrix.hpp"
#include "pd_system.hpp"
#include "sparse_factor.hpp"
