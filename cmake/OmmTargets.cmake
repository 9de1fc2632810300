# Helpers that keep every target's flags identical.

add_library(omm_warnings INTERFACE)
target_compile_options(omm_warnings INTERFACE -Wall -Wextra -Wpedantic -Wshadow
                       -Wnon-virtual-dtor -Wno-missing-field-initializers)
if(OMM_WERROR)
  target_compile_options(omm_warnings INTERFACE -Werror)
endif()
if(OMM_SANITIZE)
  # GCC 12's -Wmaybe-uninitialized reports false positives inside libstdc++
  # (std::regex's _StateT) once ASan instruments the code; the Release build
  # keeps the warning.
  add_compile_options(-fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined
                      -Wno-maybe-uninitialized)
  add_link_options(-fsanitize=address,undefined)
  # Line tables only, compressed: sanitizer reports still name file and line,
  # and the build tree is about a fifth of full -g's (CI's disk is not large).
  add_compile_options(-g1 -gz)
  add_link_options(-gz)
  # Eigen 3.4 drops its "glibc malloc is 16-byte aligned" shortcut when
  # __SANITIZE_ADDRESS__ is defined and switches to its handmade allocator,
  # which stores the real block pointer in the 8 bytes before the data. Debian's
  # libceres.a is built without ASan and allocates Eigen matrices with plain
  # malloc, so a matrix allocated in Ceres and freed in our code (or back) reads
  # or frees a wrong pointer (ASan: heap-buffer-overflow in
  # handmade_aligned_free). Keep the uninstrumented allocation scheme: ASan's
  # malloc is 16-byte aligned on x86-64 like glibc's.
  add_compile_definitions(EIGEN_MALLOC_ALREADY_ALIGNED=1)
endif()

# omm_library(NAME SOURCES ... LINKS ...): a static library whose include root is
# the repository root (#include "pipeline/core/camera.h").
function(omm_library name)
  cmake_parse_arguments(ARG "" "" "SOURCES;LINKS" ${ARGN})
  add_library(${name} STATIC ${ARG_SOURCES})
  target_include_directories(${name} PUBLIC ${PROJECT_SOURCE_DIR})
  target_link_libraries(${name} PUBLIC ${ARG_LINKS} PRIVATE omm_warnings)
endfunction()

# omm_test(NAME SOURCES ... LINKS ... [LABELS name] [TIMEOUT s] [COST c]
#          [SLOW_TESTS filter | ONE_PROCESS suite]): one GoogleTest executable;
# each TEST becomes its own CTest name, except that ONE_PROCESS runs the tests
# of one suite as a single CTest test of that name: one process computes the
# suite's shared fixture (SetUpTestSuite) once instead of once per test. LABELS slow marks tests that scripts/test.sh leaves out of
# the sanitizer pass. SLOW_TESTS (a gtest filter, Suite.Name patterns joined
# by ':') gives the label slow, in place of LABELS, to those tests of the
# executable: its Monte-Carlo statistics, seconds in Release but minutes under
# the sanitizers, whose code its other tests take through them too. Tests get
# the environment variable OMM_SOURCE_DIR. (One label and one environment
# variable only: gtest_discover_tests splits list-valued PROPERTIES apart.)
# A label in OMM_UNBUILT_TEST_LABELS keeps the executable out of the default
# build and its tests out of CTest: the sanitizer pass does not compile what it
# does not run. The target still exists, so later target_* calls on it hold.
# COST orders a parallel ctest run, highest first (the CTest COST property;
# default 10 for slow tests, else 0): long tests started first do not end
# alone on one core of CI's two. A tree's own measured costs override it.
function(omm_test name)
  cmake_parse_arguments(ARG "" "TIMEOUT;COST;SLOW_TESTS;ONE_PROCESS" "SOURCES;LINKS;LABELS" ${ARGN})
  if(ARG_SLOW_TESTS AND ARG_ONE_PROCESS)
    message(FATAL_ERROR "omm_test(${name}): SLOW_TESTS or ONE_PROCESS, not both")
  endif()
  list(LENGTH ARG_LABELS label_count)
  if(label_count GREATER 1)
    message(FATAL_ERROR "omm_test(${name}): one label at most")
  endif()
  set(unbuilt "")
  if(ARG_LABELS AND ARG_LABELS IN_LIST OMM_UNBUILT_TEST_LABELS)
    set(unbuilt EXCLUDE_FROM_ALL)
  endif()
  add_executable(${name} ${unbuilt} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_LINKS} GTest::gtest GTest::gtest_main omm_warnings)
  if(unbuilt)
    return()
  endif()
  if(NOT ARG_TIMEOUT)
    set(ARG_TIMEOUT 600)
  endif()
  set(cost 0)
  if(ARG_COST)
    set(cost ${ARG_COST})
  elseif(ARG_LABELS STREQUAL "slow" OR ARG_SLOW_TESTS)
    set(cost 10)
  endif()
  set(props TIMEOUT ${ARG_TIMEOUT} ENVIRONMENT "OMM_SOURCE_DIR=${PROJECT_SOURCE_DIR}")
  set(own_label "")
  if(ARG_LABELS)
    set(own_label LABELS ${ARG_LABELS})
  endif()
  if(ARG_ONE_PROCESS)
    add_test(NAME ${ARG_ONE_PROCESS} COMMAND ${name} --gtest_filter=${ARG_ONE_PROCESS}.*
             WORKING_DIRECTORY ${PROJECT_SOURCE_DIR})
    set_tests_properties(${ARG_ONE_PROCESS} PROPERTIES ${props} ${own_label} COST ${cost})
    gtest_discover_tests(${name} WORKING_DIRECTORY ${PROJECT_SOURCE_DIR}
                         TEST_FILTER "-${ARG_ONE_PROCESS}.*"
                         PROPERTIES ${props} ${own_label} COST ${cost} DISCOVERY_TIMEOUT 60)
    return()
  endif()
  if(NOT ARG_SLOW_TESTS)
    gtest_discover_tests(${name} WORKING_DIRECTORY ${PROJECT_SOURCE_DIR}
                         PROPERTIES ${props} ${own_label} COST ${cost} DISCOVERY_TIMEOUT 60)
    return()
  endif()
  gtest_discover_tests(${name} WORKING_DIRECTORY ${PROJECT_SOURCE_DIR} TEST_FILTER "-${ARG_SLOW_TESTS}"
                       PROPERTIES ${props} ${own_label} DISCOVERY_TIMEOUT 60)
  if(NOT "slow" IN_LIST OMM_UNBUILT_TEST_LABELS)
    gtest_discover_tests(${name} WORKING_DIRECTORY ${PROJECT_SOURCE_DIR} TEST_FILTER "${ARG_SLOW_TESTS}"
                         PROPERTIES ${props} LABELS slow COST ${cost} DISCOVERY_TIMEOUT 60)
  endif()
endfunction()
include(GoogleTest)

# ccache, when installed, makes rebuilds (CI's second, sanitizer build of the
# same sources, later runs on the same machine) cheap; scripts/test.sh sets
# CCACHE_BASEDIR so clones in other directories share the cache.
option(OMM_CCACHE "Compile through ccache when it is installed" ON)
find_program(OMM_CCACHE_PROGRAM ccache)
if(OMM_CCACHE AND OMM_CCACHE_PROGRAM)
  set(CMAKE_C_COMPILER_LAUNCHER ${OMM_CCACHE_PROGRAM})
  set(CMAKE_CXX_COMPILER_LAUNCHER ${OMM_CCACHE_PROGRAM})
endif()
