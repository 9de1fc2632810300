# Writes ${OUT}: the source revision the build was made from, for
# SoftwareVersion() (pipeline/orchestration/version.cc). Run at every build
# (omm_source_revision in pipeline/orchestration/CMakeLists.txt); the file is
# rewritten only when the revision changes, so an unchanged tree rebuilds
# nothing. `git describe --always --dirty`: a commit id, "-dirty" when the
# tree has uncommitted changes; "unknown" outside a git checkout.
execute_process(
  COMMAND git describe --always --dirty --abbrev=12
  WORKING_DIRECTORY "${SOURCE_DIR}"
  OUTPUT_VARIABLE revision
  OUTPUT_STRIP_TRAILING_WHITESPACE
  ERROR_QUIET
  RESULT_VARIABLE status)
if(NOT status EQUAL 0 OR revision STREQUAL "")
  set(revision "unknown")
endif()
set(content "#define OMM_SOURCE_REVISION \"${revision}\"\n")
if(EXISTS "${OUT}")
  file(READ "${OUT}" old)
endif()
if(NOT old STREQUAL content)
  file(WRITE "${OUT}" "${content}")
endif()
