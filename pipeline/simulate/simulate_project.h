// `omm simulate`: renders a complete project directory with known truth.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "pipeline/core/progress.h"

namespace omm {

struct SimulationOptions {
  std::uint64_t seed = 1;     // everything random is drawn from this seed
  std::string preset = "demo";  // one of SimulationPresets()

  // Empty if valid, else what is wrong (unknown preset, ...).
  std::string Check() const;
};

// Names of the presets, e.g. "demo", "markers", "low-texture", "exposure".
std::vector<std::string> SimulationPresets();

// Renders the project into `project_dir` (created; must not exist or be
// empty) and writes its truth to `truth_path` (JSON). Throws InputError for
// bad options or an unwritable destination.
void SimulateProjectDirectory(const SimulationOptions& options,
                              const std::filesystem::path& project_dir,
                              const std::filesystem::path& truth_path,
                              const ProgressCallback& progress);

// Where `omm simulate OUT` puts the truth by default: OUT.truth.json beside
// the project directory (outside it, so the project stays as a user's would).
std::filesystem::path DefaultTruthPath(const std::filesystem::path& project_dir);

}  // namespace omm
