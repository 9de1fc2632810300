// Reads a project directory (format omm-project/1) into a Project.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "pipeline/core/parallel_for.h"
#include "pipeline/core/project.h"

namespace omm {

// Parses project.yaml, table.csv, cmm.csv and the image lists of `dir`, and
// checks them against each other (every feature, measurement, tile and CMM
// name resolves; every image decodes and all have one size). Each image file
// is read once (num_threads at a time), hashed (SHA-256) and decoded; the
// result keeps them in Project::images for the stages. Throws InputError
// naming the file, the line or key, and what was expected.
Project LoadProject(const std::filesystem::path& dir, int num_threads = HardwareThreads());

// The top-level keys project.yaml may have.
const std::vector<std::string>& ProjectYamlKeys();

}  // namespace omm
