# FindCHOLMOD
# -----------
# Finds SuiteSparse's CHOLMOD (Debian: libsuitesparse-dev) and the BLAS/LAPACK it needs
# (Debian: libopenblas-dev provides both).
#
# Imported target: CHOLMOD::CHOLMOD
# Result variables: CHOLMOD_FOUND
include(FindPackageHandleStandardArgs)
include(CMakeFindDependencyMacro)
find_path(CHOLMOD_INCLUDE_DIR NAMES cholmod.h PATH_SUFFIXES suitesparse)
find_library(CHOLMOD_LIBRARY NAMES cholmod)
find_library(CHOLMOD_SUITESPARSECONFIG_LIBRARY NAMES suitesparseconfig)
foreach(_lib amd camd colamd ccolamd)
  string(TOUPPER ${_lib} _LIB)
  find_library(CHOLMOD_${_LIB}_LIBRARY NAMES ${_lib})
endforeach()
find_package_handle_standard_args(CHOLMOD
  REQUIRED_VARS CHOLMOD_LIBRARY CHOLMOD_INCLUDE_DIR CHOLMOD_SUITESPARSECONFIG_LIBRARY)
if(CHOLMOD_FOUND AND NOT TARGET CHOLMOD::CHOLMOD)
  find_package(BLAS QUIET)
  find_package(LAPACK QUIET)
  add_library(CHOLMOD::CHOLMOD UNKNOWN IMPORTED)
  set(_deps ${CHOLMOD_SUITESPARSECONFIG_LIBRARY})
  foreach(_lib AMD CAMD COLAMD CCOLAMD)
    if(CHOLMOD_${_lib}_LIBRARY)
      list(APPEND _deps ${CHOLMOD_${_lib}_LIBRARY})
    endif()
  endforeach()
  if(LAPACK_FOUND)
    list(APPEND _deps ${LAPACK_LIBRARIES})
  endif()
  if(BLAS_FOUND)
    list(APPEND _deps ${BLAS_LIBRARIES})
  endif()
  set_target_properties(CHOLMOD::CHOLMOD PROPERTIES
    IMPORTED_LOCATION "${CHOLMOD_LIBRARY}"
    INTERFACE_INCLUDE_DIRECTORIES "${CHOLMOD_INCLUDE_DIR}"
    INTERFACE_LINK_LIBRARIES "${_deps}")
endif()
mark_as_advanced(CHOLMOD_INCLUDE_DIR CHOLMOD_LIBRARY CHOLMOD_SUITESPARSECONFIG_LIBRARY)
