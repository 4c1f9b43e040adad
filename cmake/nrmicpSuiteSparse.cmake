# Finds CHOLMOD and UMFPACK (SuiteSparse) and defines the imported targets
# SuiteSparse::CHOLMOD and SuiteSparse::UMFPACK when they are found.
# SuiteSparse >= 7 ships CMake configs (tried first); Debian bookworm's 5.12 does not, so
# the headers and libraries are then found by hand.
include_guard(GLOBAL)

foreach(_comp CHOLMOD UMFPACK)
  if(NOT TARGET SuiteSparse::${_comp})
    find_package(${_comp} CONFIG QUIET)
  endif()
endforeach()

find_path(NRMICP_SUITESPARSE_INCLUDE_DIR NAMES cholmod.h PATH_SUFFIXES suitesparse)
find_library(NRMICP_SUITESPARSECONFIG_LIBRARY NAMES suitesparseconfig)

function(_nrmicp_suitesparse_component comp header lib)
  if(TARGET SuiteSparse::${comp})
    return()
  endif()
  find_path(NRMICP_${comp}_INCLUDE_DIR NAMES ${header} PATH_SUFFIXES suitesparse)
  find_library(NRMICP_${comp}_LIBRARY NAMES ${lib})
  if(NRMICP_${comp}_INCLUDE_DIR AND NRMICP_${comp}_LIBRARY)
    add_library(SuiteSparse::${comp} UNKNOWN IMPORTED)
    set_target_properties(SuiteSparse::${comp} PROPERTIES
      IMPORTED_LOCATION "${NRMICP_${comp}_LIBRARY}"
      INTERFACE_INCLUDE_DIRECTORIES "${NRMICP_${comp}_INCLUDE_DIR}")
    if(NRMICP_SUITESPARSECONFIG_LIBRARY)
      set_property(TARGET SuiteSparse::${comp} APPEND PROPERTY
        INTERFACE_LINK_LIBRARIES "${NRMICP_SUITESPARSECONFIG_LIBRARY}")
    endif()
  endif()
endfunction()

_nrmicp_suitesparse_component(CHOLMOD cholmod.h cholmod)
_nrmicp_suitesparse_component(UMFPACK umfpack.h umfpack)

# Adds the found components to an INTERFACE target, with NRMICP_HAVE_<COMP> defined.
function(nrmicp_link_suitesparse target)
  foreach(_comp CHOLMOD UMFPACK)
    if(TARGET SuiteSparse::${_comp})
      target_link_libraries(${target} INTERFACE SuiteSparse::${_comp})
      target_compile_definitions(${target} INTERFACE NRMICP_HAVE_${_comp})
    endif()
  endforeach()
endfunction()
