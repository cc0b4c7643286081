#pragma once
/// \file diffphd.hpp
/// \brief Umbrella header: the mesh, material, I/O and linear-algebra layers.
///
/// Finer headers: core/ (mesh, materials), io/ (readers, writers, generators), linalg/ (the PD
/// matrix, ordering, factorization, explicit inverse factor), energy/ (the PD energy policies:
/// include diffphd/energy/energy.hpp, it is not pulled in here). The CUDA unit has its own header,
/// diffphd/cuda/device_inverse_factor.hpp, and its own target diffphd::cuda.

#include "core/errors.hpp"
#include "core/material.hpp"
#include "core/mesh.hpp"
#include "core/types.hpp"
#include "io/io.hpp"
#include "linalg/blas_threads.hpp"
#include "linalg/linalg.hpp"
#include "version.hpp"
