// `omm simulate`: renders a complete project directory with known truth.
//
// The scene and images come from simulation.h (pure, no files); this writes
// them as a project directory (project-format.md) plus the truth as JSON
// (adapters/project_io/truth_json.h).
#pragma once

#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

#include "pipeline/core/progress.h"
#include "pipeline/simulate/simulation.h"

namespace omm {

struct SimulationSummary {
  int num_calib_images = 0;
  int num_tiles = 0;
  std::size_t num_rays = 0;          // supersample rays in the camera's ray table
  double max_ray_residual_px = 0.0;  // RayTableSummary::max_residual_px
  double seconds = 0.0;              // wall time of the whole run
  std::string brief;                 // one line for the log
};

// Renders the project into `project_dir` (created; must not exist or be
// empty) and writes its truth to `truth_path` (JSON). Reports progress once
// per image. Throws InputError for bad options or an unwritable destination.
SimulationSummary SimulateProjectDirectory(const SimulationOptions& options,
                                           const std::filesystem::path& project_dir,
                                           const std::filesystem::path& truth_path,
                                           const ProgressCallback& progress);

// Where `omm simulate OUT` puts the truth by default: OUT.truth.json beside
// the project directory (outside it, so the project stays as a user's would).
std::filesystem::path DefaultTruthPath(const std::filesystem::path& project_dir);

}  // namespace omm
