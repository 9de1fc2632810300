// Running stages on a loaded project, with transactional output.
//
// Output protocol: a run writes everything into out/.staging-<pid>/ and moves
// it into out/ only when every requested stage succeeded, report.json last
// (each move is an atomic rename on one file system). A failed or interrupted
// run therefore leaves out/report.json as the earlier complete report, or
// absent; never half-written. Stale staging directories of processes that no
// longer run are removed at the next run.
//
// A run starts from out/report.json when the same software version wrote
// it, keeping the sections of the stages whose inputs are unchanged
// (HashStageInputs: a new cmm.csv leaves the calibration and the mosaic
// current), and drops the sections of the stages it reruns and of those
// after them (their results would be stale). A single-stage run (`omm
// measure`) thus builds on the earlier stages' results in out/ while they
// are current, and refuses those the report names stale
// (StageContext::stale_in_out); `omm run` also keeps, without rerunning
// them, the stages in front that are current
// (RunOptions::reuse_current_stages).
#pragma once

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "pipeline/core/progress.h"
#include "pipeline/core/project.h"
#include "pipeline/core/report.h"
#include "pipeline/orchestration/stage.h"

namespace omm {

// Removes out/.staging-<pid> directories whose process is gone (a run
// killed or interrupted), and out/ itself if that leaves it empty. A run
// does so first; `omm batch` after the children it stopped.
void RemoveStaleStaging(const std::filesystem::path& out_dir);

// Runs one stage: RunStage dispatches to the runners of stage.h; tests pass
// their own to exercise the output protocol.
using StageRunner = std::function<void(Stage, StageContext&)>;
void RunStage(Stage stage, StageContext& context);

struct RunOptions {
  // The stages to run, in run order (a subsequence of AllStages()).
  std::vector<Stage> stages = AllStages();
  // Progress of long work inside stages, and once just before out/ is
  // replaced; may be empty. What it throws stops the run, out/ untouched.
  ProgressCallback progress;
  // Run the calibration's image-count study (`omm calibrate --study`).
  bool calibration_study = false;
  // The mosaic's feature source (`omm mosaic|run --features`): SIFT runs the
  // installed colmap on the tiles.
  FeatureSource mosaic_features = FeatureSource::kHarris;
  // What runs a stage.
  StageRunner runner = RunStage;
  // Threads for the stages' parallel work; 0: HardwareThreads(). The results
  // do not depend on it.
  int num_threads = 0;
  // Keep the results in out/ of the first stages of `stages` whose inputs
  // are unchanged instead of running them again (`omm run` without
  // --force): a stage's results depend on its inputs and the software
  // version alone.
  bool reuse_current_stages = false;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct RunSummary {
  std::filesystem::path report_path;  // out/report.json
  Report report;                      // as written
  std::vector<Stage> stages_run;
  std::vector<Stage> stages_kept;  // current in out/, not run (reuse_current_stages)
  double seconds = 0.0;  // wall time of the run

  // One line, e.g. "calibrate, mosaic, measure done in 42.1 s: out/report.json"
  // or "measure done in 0.4 s (calibrate, mosaic current, kept): ...".
  std::string Brief() const;
};

// Runs `options.stages` on `project` and commits their outputs to out/.
// Throws InputError (bad input, including an unwritable out/) or
// StageFailedError; out/ is untouched then. The images LoadProject decoded
// are dropped as soon as no later stage reads them (the calib images after
// the calibration, the tiles once converted for the mosaic): freed if the
// caller moved `project` in.
RunSummary RunProject(Project project, const RunOptions& options);

// True if out/report.json exists, was written by this software version from
// the project's current inputs, and has every stage's section, and out/
// holds the files later stages read (StageOutputFiles).
bool ReportIsCurrent(const Project& project);

// The stages, in run order, that `omm run` (RunOptions::reuse_current_stages,
// the mosaic from `mosaic_features`) would keep from out/ rather than run:
// those in front whose inputs are unchanged since this omm version wrote
// out/report.json, while their files are there. `omm batch` tells so.
std::vector<Stage> StagesRunWouldKeep(const Project& project, FeatureSource mosaic_features);

}  // namespace omm
