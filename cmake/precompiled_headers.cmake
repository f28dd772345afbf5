# Precompiled headers shared across targets (REUSE_FROM): a clean build parses Eigen, the
# standard library, spdlog/fmt, GoogleTest/GMock and CLI11 once per kind of target instead of
# once per source (on the heavy ones 2.5 s per source for Eigen, 2.5 s for GoogleTest, 10 s for
# CLI11). Two kinds, by what a target links directly:
#   telehand_pch_test  GoogleTest: the base headers and gtest/gmock (built with gtest's defines)
#   telehand_pch_base  every other C++ target
# CLI11 stays out: its header defines validators at namespace scope, which every source that
# includes it compiles (about 6.5 s at -O2 even precompiled), so it would cost each source of a
# program what it saves in the one that parses the command line.
# The flags of a target that reuses a header must be those it was built with: the carriers link
# what their users link (the same defines) and g++ rejects a mismatch (-Winvalid-pch, with
# -Werror an error), so a target that cannot use them is listed in telehand_pch_skip. The
# sources keep including what they use; the header only makes that cheap.
option(TELEHAND_PCH "Precompile the common headers (one per kind of target)" ON)
if(NOT TELEHAND_PCH)
  return()
endif()

set(telehand_pch_base_headers
  <algorithm> <array> <atomic> <chrono> <cmath> <cstdint> <cstdio> <cstdlib> <cstring>
  <deque> <filesystem> <fstream> <functional> <iostream> <limits> <map> <memory> <mutex>
  <optional> <random> <span> <sstream> <string> <string_view> <thread> <utility> <vector>
  <Eigen/Dense> <Eigen/Geometry> <spdlog/spdlog.h> <spdlog/fmt/fmt.h>)

set(telehand_pch_source ${CMAKE_CURRENT_BINARY_DIR}/telehand_pch.cpp)
file(CONFIGURE OUTPUT ${telehand_pch_source} CONTENT "// The precompiled headers' carrier.\n")

function(telehand_pch_carrier name)
  add_library(${name} OBJECT ${telehand_pch_source})
  target_link_libraries(${name} PRIVATE ${ARGN} Eigen3::Eigen spdlog::spdlog telehand_warnings)
endfunction()
telehand_pch_carrier(telehand_pch_base)
target_precompile_headers(telehand_pch_base PRIVATE ${telehand_pch_base_headers})
if(TELEHAND_BUILD_TESTS)
  find_package(GTest REQUIRED)  # its imported targets are the tests directory's
  telehand_pch_carrier(telehand_pch_test GTest::gtest GTest::gmock)
  target_precompile_headers(telehand_pch_test PRIVATE ${telehand_pch_base_headers}
                            <gtest/gtest.h> <gmock/gmock.h>)
endif()

# Not C++ built with the common flags: the IDL's C, the DDS crypto plugin (-fPIC, hidden
# visibility).
set(telehand_pch_skip telehand_idl telehand_dds_crypto)

# Sources that compile without: g++ 12 does not keep a header's `#pragma GCC diagnostic` in a
# precompiled header, so libstdc++'s char_traits.h loses the
# -Warray-bounds/-Wstringop-overflow it turns off for its own copies, and those false
# positives on a std::string built from a literal and appended to (e.g.
# `std::string(TELEHAND_DEPLOY_DIR) + "/hand/hand24.urdf"`) become errors. A source that
# fails so with the header precompiled, and builds without it, goes here.
set(telehand_pch_skip_sources
  tests/bench/bench_capacity.cpp tests/bench/bench_hand_sim.cpp tests/teleop/test_teleop_goals.cpp
  tests/unit/server/test_web_checkpoint.cpp tests/usb/test_usb_mf2.cpp)
list(TRANSFORM telehand_pch_skip_sources PREPEND ${PROJECT_SOURCE_DIR}/)

function(telehand_pch_targets_in dir out)
  get_property(targets DIRECTORY ${dir} PROPERTY BUILDSYSTEM_TARGETS)
  get_property(subdirs DIRECTORY ${dir} PROPERTY SUBDIRECTORIES)
  foreach(sub ${subdirs})
    telehand_pch_targets_in(${sub} sub_targets)
    list(APPEND targets ${sub_targets})
  endforeach()
  set(${out} ${targets} PARENT_SCOPE)
endfunction()

telehand_pch_targets_in(${CMAKE_CURRENT_SOURCE_DIR} telehand_all_targets)
foreach(target ${telehand_all_targets})
  get_target_property(type ${target} TYPE)
  if(NOT type MATCHES "^(EXECUTABLE|STATIC_LIBRARY|OBJECT_LIBRARY)$" OR target MATCHES "^telehand_pch_"
     OR target IN_LIST telehand_pch_skip)
    continue()
  endif()
  get_target_property(links ${target} LINK_LIBRARIES)
  if(links MATCHES "GTest::" AND TARGET telehand_pch_test)
    set(kind telehand_pch_test)
  else()
    set(kind telehand_pch_base)
  endif()
  target_precompile_headers(${target} REUSE_FROM ${kind})
  # A target's C sources (the headers are C++) and the sources above compile without.
  get_target_property(sources ${target} SOURCES)
  get_target_property(source_dir ${target} SOURCE_DIR)
  foreach(source ${sources})
    cmake_path(ABSOLUTE_PATH source BASE_DIRECTORY ${source_dir} NORMALIZE)
    if(source MATCHES "\\.c$" OR source IN_LIST telehand_pch_skip_sources)
      set_source_files_properties(${source} TARGET_DIRECTORY ${target}
                                  PROPERTIES SKIP_PRECOMPILE_HEADERS ON)
    endif()
  endforeach()
endforeach()
