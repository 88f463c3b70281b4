# CMake package of libbassclient, installed by `make install` into <prefix>/lib/cmake/bassclient.
#
#   find_package(bassclient REQUIRED)           # CMAKE_PREFIX_PATH=<prefix> if not a system prefix
#   target_link_libraries(app PRIVATE bassclient::bassclient)   # shared library
#   target_link_libraries(app PRIVATE bassclient::static)       # static library
#
# Both targets carry the include directory of bass.h (and the C++ wrapper bass.hpp).
# Sets bassclient_FOUND, bassclient_VERSION, bassclient_INCLUDE_DIRS, bassclient_LIBRARIES.
# The package is relocatable: paths are computed from this file's location.

get_filename_component(_bassclient_prefix "${CMAKE_CURRENT_LIST_DIR}/../../.." ABSOLUTE)
set(_bassclient_libdir "${_bassclient_prefix}/lib")
set(bassclient_INCLUDE_DIRS "${_bassclient_prefix}/include")

if(NOT EXISTS "${bassclient_INCLUDE_DIRS}/bass.h" OR NOT EXISTS "${_bassclient_libdir}/libbassclient.so")
  set(bassclient_FOUND FALSE)
  set(bassclient_NOT_FOUND_MESSAGE "bass.h or libbassclient.so missing under ${_bassclient_prefix}")
  return()
endif()

if(NOT TARGET bassclient::bassclient)
  add_library(bassclient::bassclient SHARED IMPORTED)
  set_target_properties(bassclient::bassclient PROPERTIES
    IMPORTED_LOCATION "${_bassclient_libdir}/libbassclient.so"
    # The library's SONAME (set in libbassclient/build.rs): an executable records
    # "libbassclient.so.0", found through the rpath CMake adds, or the loader's path.
    IMPORTED_SONAME "libbassclient.so.0"
    INTERFACE_INCLUDE_DIRECTORIES "${bassclient_INCLUDE_DIRS}")
endif()

if(NOT TARGET bassclient::static AND EXISTS "${_bassclient_libdir}/libbassclient.a")
  find_package(Threads REQUIRED)
  add_library(bassclient::static STATIC IMPORTED)
  set_target_properties(bassclient::static PROPERTIES
    IMPORTED_LOCATION "${_bassclient_libdir}/libbassclient.a"
    INTERFACE_INCLUDE_DIRECTORIES "${bassclient_INCLUDE_DIRS}"
    INTERFACE_LINK_LIBRARIES "Threads::Threads;${CMAKE_DL_LIBS};m;rt;util;gcc_s")
endif()

set(bassclient_LIBRARIES bassclient::bassclient)
set(bassclient_FOUND TRUE)
unset(_bassclient_libdir)
unset(_bassclient_prefix)
