# Every dependency comes from a Debian 12 package (scripts/setup.sh installs them).
find_package(Threads REQUIRED)
find_package(Eigen3 3.4 REQUIRED NO_MODULE)
find_package(OpenCV 4 REQUIRED COMPONENTS core imgproc imgcodecs calib3d features2d stitching)
find_package(Ceres 2.1 REQUIRED)
find_package(yaml-cpp REQUIRED)
find_package(nlohmann_json 3.10 REQUIRED)
find_package(CLI11 2 REQUIRED)
find_package(fmt REQUIRED)
find_package(spdlog REQUIRED)
find_package(GTest REQUIRED)
find_package(SQLite3 REQUIRED)
find_package(OpenSSL 3 REQUIRED COMPONENTS Crypto)
find_package(apriltag REQUIRED PATHS /usr/share/apriltag/cmake)
find_package(TIFF 4.5 REQUIRED)
find_package(PkgConfig REQUIRED)
# Image files besides gray PNGs (adapters/png, tiff, jpeg): pkg-config only.
pkg_check_modules(spng REQUIRED IMPORTED_TARGET spng)
pkg_check_modules(turbojpeg REQUIRED IMPORTED_TARGET libturbojpeg)
if(OMM_BUILD_BENCHMARKS)
  find_package(benchmark REQUIRED)
endif()

# mrcal ships no CMake config: import it by hand. Its headers are C without
# extern "C" guards; include them only through adapters/mrcal/mrcal_c.h.
find_path(MRCAL_INCLUDE_DIR mrcal/mrcal.h REQUIRED)
find_library(MRCAL_LIBRARY mrcal REQUIRED)
add_library(mrcal::mrcal UNKNOWN IMPORTED)
set_target_properties(mrcal::mrcal PROPERTIES
  IMPORTED_LOCATION "${MRCAL_LIBRARY}"
  INTERFACE_INCLUDE_DIRECTORIES "${MRCAL_INCLUDE_DIR}")

# Third-party headers are SYSTEM so their warnings (OpenCV 4.6 under C++20) do
# not drown ours.
foreach(tgt Eigen3::Eigen Ceres::ceres yaml-cpp nlohmann_json::nlohmann_json
            CLI11::CLI11 fmt::fmt spdlog::spdlog apriltag::apriltag mrcal::mrcal)
  if(TARGET ${tgt})
    get_target_property(_inc ${tgt} INTERFACE_INCLUDE_DIRECTORIES)
    if(_inc)
      set_target_properties(${tgt} PROPERTIES INTERFACE_SYSTEM_INCLUDE_DIRECTORIES "${_inc}")
    endif()
  endif()
endforeach()
# libdeflate ships no CMake config either: whole-buffer zlib streams and
# CRC-32 for PNG files (adapters/png).
find_path(LIBDEFLATE_INCLUDE_DIR libdeflate.h REQUIRED)
find_library(LIBDEFLATE_LIBRARY deflate REQUIRED)
add_library(libdeflate::libdeflate UNKNOWN IMPORTED)
set_target_properties(libdeflate::libdeflate PROPERTIES
  IMPORTED_LOCATION "${LIBDEFLATE_LIBRARY}"
  INTERFACE_INCLUDE_DIRECTORIES "${LIBDEFLATE_INCLUDE_DIR}")
add_library(omm_opencv_system INTERFACE)
target_include_directories(omm_opencv_system SYSTEM INTERFACE ${OpenCV_INCLUDE_DIRS})
target_link_libraries(omm_opencv_system INTERFACE ${OpenCV_LIBS})
