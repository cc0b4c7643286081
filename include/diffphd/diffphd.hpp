#pragma once
/// \file diffphd.hpp
/// \brief Umbrella header: everything header-only in diffphd.
///
/// Finer headers: core/ (mesh, materials), io/ (readers, writers, generators), linalg/ (the PD
/// matrix, ordering, factorization, explicit inverse factor). The CUDA unit has its own header,
/// diffphd/cuda/device_inverse_factor.hpp, and its own target diffphd::cuda.

#include "core/errors.hpp"
#include "core/material.hpp"
#include "core/mesh.hpp"
#include "core/types.hpp"
#include "version.hpp"
