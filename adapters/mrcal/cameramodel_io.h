// mrcal .cameramodel files (mrcal 2.2's mrcal_write_cameramodel_file /
// mrcal_read_cameramodel_file): lens model, intrinsics, imager size. The
// camera is written at the reference (rt_cam_ref = 0); optimization_inputs are
// not written (the C API does not carry them; our solve record does).
// `valid_intrinsics_region`, a key of the format that the C API skips, is
// written and read here beside it (CameraModel::valid_region_px): a list of
// [x, y] vertices, closed (the last repeats the first) as mrcal writes it.
#pragma once

#include <filesystem>

#include "pipeline/core/camera.h"

namespace omm {

// Throws InputError naming the file if the model is invalid or mrcal cannot
// write it.
void WriteCameraModel(const std::filesystem::path& path, const CameraModel& camera);

// Throws InputError naming the file if it cannot be read or parsed.
CameraModel ReadCameraModel(const std::filesystem::path& path);

}  // namespace omm
