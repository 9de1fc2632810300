// The subcommands of `omm`, each returning its exit code (exit_codes.h). They
// log through spdlog and print results to stdout.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "pipeline/core/parallel_for.h"
#include "pipeline/orchestration/stage.h"
#include "pipeline/simulate/simulation.h"

namespace omm {

// `omm run` (all stages) and `omm calibrate|mosaic|measure` (one stage);
// `calibration_study`: `omm calibrate --study`; `mosaic_features`: `--features`;
// `num_threads`: `--threads` (>= 1); `reuse_current_stages`: `omm run`
// without --force (RunOptions').
int RunCommand(const std::filesystem::path& project_dir, const std::vector<Stage>& stages,
               bool calibration_study = false,
               FeatureSource mosaic_features = FeatureSource::kHarris,
               int num_threads = HardwareThreads(), bool reuse_current_stages = false);

// `omm batch`: each argument is a project directory or a directory whose
// subdirectories are projects. Projects whose report is current are skipped
// unless `force`. Each other project runs as its own `omm run` process, up to
// `jobs` at once (child_process.h), each on num_threads / jobs threads (at
// least one). Prints a summary table
// and how the measurements agree with the CMM values over all projects; with
// `csv`, also writes every measurement to that file (report_csv.h).
// Exits kExitFailed if any project failed.
int BatchCommand(const std::vector<std::filesystem::path>& dirs, bool force,
                 const std::optional<std::filesystem::path>& csv = std::nullopt, int jobs = 1,
                 int num_threads = HardwareThreads());

// `omm simulate`.
int SimulateCommand(const std::filesystem::path& project_dir, const SimulationOptions& options,
                    const std::optional<std::filesystem::path>& truth);

// `omm report`: regenerates out/report.html and out/report.json (normalised)
// from out/ without running a stage, then prints a summary of the report, or
// its JSON. kExitBadInput if out/report.json is missing or invalid.
int ReportCommand(const std::filesystem::path& project_dir, bool json);

}  // namespace omm
