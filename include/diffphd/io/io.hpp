#pragma once
/// \file io.hpp
/// \brief Everything of diffphd/io: mesh readers and writers, ParaView output, generators.
/// Include the single headers instead to keep compile times small.

#include "generators.hpp"
#include "gmsh.hpp"
#include "limits.hpp"
#include "mesh_with_regions.hpp"
#include "read_mesh.hpp"
#include "surface.hpp"
#include "tetgen.hpp"
#include "vtk.hpp"
