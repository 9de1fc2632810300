// The identity of a project's inputs, for the report and for deciding whether
// a report is current.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "pipeline/core/project.h"

namespace omm {

// The files a run depends on, in a fixed order: project.yaml, table.csv and
// cmm.csv (if present), the calib/ images, the tiles, and the reused
// calibration (the .cameramodel of `calibration.from`, or out/camera.cameramodel
// of the project it names, if present).
std::vector<std::filesystem::path> ProjectInputFiles(const Project& project);

// SHA-256 over, for each input file in order: its path relative to the project
// directory (as text), a NUL byte, and the SHA-256 of its bytes. Renaming,
// editing, adding or removing any input changes it. An image's hash is the
// one LoadProject took of the bytes it decoded (Project::images), if loaded.
// Throws InputError if a file cannot be read.
std::string HashProjectInputs(const Project& project);

// SHA-256 of a file's bytes, 64 hex digits.
std::string HashFile(const std::filesystem::path& path);

}  // namespace omm
