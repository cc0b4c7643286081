# FindMETIS
# ---------
# Finds the METIS graph partitioning library (Debian: libmetis-dev, 32-bit indices).
#
# Imported target: METIS::METIS
# Result variables: METIS_FOUND, METIS_INCLUDE_DIRS, METIS_LIBRARIES
include(FindPackageHandleStandardArgs)
find_path(METIS_INCLUDE_DIR NAMES metis.h PATH_SUFFIXES metis)
find_library(METIS_LIBRARY NAMES metis)
find_package_handle_standard_args(METIS REQUIRED_VARS METIS_LIBRARY METIS_INCLUDE_DIR)
if(METIS_FOUND AND NOT TARGET METIS::METIS)
  add_library(METIS::METIS UNKNOWN IMPORTED)
  set_target_properties(METIS::METIS PROPERTIES
    IMPORTED_LOCATION "${METIS_LIBRARY}"
    INTERFACE_INCLUDE_DIRECTORIES "${METIS_INCLUDE_DIR}")
endif()
set(METIS_INCLUDE_DIRS ${METIS_INCLUDE_DIR})
set(METIS_LIBRARIES ${METIS_LIBRARY})
mark_as_advanced(METIS_INCLUDE_DIR METIS_LIBRARY)
