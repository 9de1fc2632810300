// `omm`: on-machine vision metrology from the command line. See README.md.
#include <malloc.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <CLI/CLI.hpp>

#include "app/commands.h"
#include "app/exit_codes.h"
#include "pipeline/core/board.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/orchestration/version.h"
#include "pipeline/simulate/simulate_project.h"

namespace fs = std::filesystem;

namespace {

constexpr const char* kExitCodes = R"(Exit codes:
  0  done
  1  a stage failed on the data (e.g. no plate found), or the system refused
     (a file not written: disk full, no permission); batch: some project failed
  2  bad input: command line, project files (the message names file and key or line)
  4  internal error (a bug; please report it)
  130  stopped by Ctrl-C (SIGINT) or SIGTERM: out/ left as it was (a second
       Ctrl-C ends a run at once); batch: its children killed, the rest not
       started, the summary printed

Every project is a directory in format omm-project/1 (project.yaml, calib/,
tiles/, table.csv, optional cmm.csv); results go to its out/ (report.json, ...),
written only when every stage succeeded.)";

void SetUpLogging(int verbose, bool quiet) {
  auto logger = spdlog::stderr_color_mt("omm");
  logger->set_pattern("%^%l%$: %v");
  spdlog::set_default_logger(logger);
  spdlog::set_level(quiet          ? spdlog::level::warn
                    : verbose >= 2 ? spdlog::level::trace
                    : verbose == 1 ? spdlog::level::debug
                                   : spdlog::level::info);
}

// `omm calibrate|mosaic|measure PROJECT`.
CLI::App* AddStageCommand(CLI::App& app, omm::Stage stage, const std::string& help,
                          std::string& project, std::optional<omm::Stage>& chosen) {
  CLI::App* command = app.add_subcommand(omm::StageName(stage), help);
  command->add_option("PROJECT", project, "project directory")->required();
  command->callback([stage, &chosen] { chosen = stage; });
  return command;
}

std::string PresetList() {
  std::string list;
  for (const std::string& preset : omm::SimulationPresets())
    list += (list.empty() ? "" : ", ") + preset;
  return list;
}

// glibc's allocator, tuned for a process that fills and frees images of
// tens of MB on a few threads:
// - Freed buffers stay with the allocator for the next image. By default
//   glibc gives blocks of 128 kB .. 32 MB back to the kernel as soon as
//   they are freed (munmap, or trimming the heap's top), and the kernel
//   zero-fills every page of the next such allocation again on first touch
//   (`omm run` on the demo: 180 k page faults, 0.7 GB of zeroed pages, for
//   a peak of 0.36 GB; 32 MB is glibc's largest mmap threshold).
// - One arena: a thread's own arena keeps what it freed from the others.
// Not transparent huge pages (glibc.malloc.hugetlb=1, which glibc takes
// from GLIBC_TUNABLES only, so omm restarted itself with it until
// 2026-12-03): on a virtual machine whose free memory goes back to the host
// (virtio-balloon's free page reporting, in 2 MB blocks), a huge page's
// first touch costs the host's faults too. Their kernel time varied from
// 0.05 to 1.2 s a run with the machine's history; without them it stayed at
// 0.23-0.40 s. Four interleaved rounds there, mean wall time without / with:
// sparse-texture seed 1001 2.31 / 2.83 s, demo 1001 3.29 / 3.61 s,
// lens-mismatch 1007 6.04 / 6.30 s.
void TuneAllocator() {
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, std::numeric_limits<int>::max());
  mallopt(M_ARENA_MAX, 1);
}

// `omm batch DIR...`.
struct BatchArgs {
  std::vector<fs::path> dirs;
  bool force = false;
  // A run keeps about 1.7 cores busy (`omm_run_benchmark`: CPU / wall time).
  int jobs = std::max(1, omm::HardwareThreads() / 2);
  std::optional<fs::path> csv;
};

CLI::App* AddBatchCommand(CLI::App& app, BatchArgs& args) {
  CLI::App* batch = app.add_subcommand(
      "batch",
      "Run many projects, each as its own `omm run`, several at once, and print a summary table.\n"
      "Each DIR is a project directory or a directory of project directories.\n"
      "Projects whose out/report.json is current (same inputs, same omm) are skipped, and\n"
      "of the others only the stages whose inputs changed are rerun.\n"
      "Writes each project's out/ as `omm run` does; a failing project does not stop the batch;\n"
      "with --csv, one table of every measurement of every project.");
  batch->add_option("DIR", args.dirs, "project directories or folders of projects")->required();
  batch->add_flag("--force", args.force,
                  "rerun projects whose report is current, every stage (`omm run --force`)");
  batch
      ->add_option("-j,--jobs", args.jobs,
                   "projects run at once (default: half the CPUs this process may use)")
      ->check(CLI::Range(1, 256))
      ->capture_default_str();
  batch->add_option("--csv", args.csv,
                    "also write every project's measurements (value, sigma, CMM deviation) to "
                    "this CSV file");
  return batch;
}

// `omm simulate OUT`.
struct SimulateArgs {
  fs::path out;
  omm::SimulationOptions simulation;
  std::optional<fs::path> truth;
};

CLI::App* AddSimulateCommand(CLI::App& app, SimulateArgs& args) {
  CLI::App* simulate = app.add_subcommand(
      "simulate",
      "Render a synthetic project with known truth (for the demo, tests, planning a capture).\n"
      "Writes the project directory OUT (must not exist or be empty) and its truth as JSON\n"
      "(default OUT.truth.json beside it, outside the project).");
  simulate->add_option("OUT", args.out, "project directory to create")->required();
  simulate
      ->add_option("--seed", args.simulation.seed,
                   "random seed; the same seed gives the same project")
      ->capture_default_str();
  simulate->add_option("--preset", args.simulation.preset, "scene preset: " + PresetList())
      ->capture_default_str();
  simulate->add_flag("--plate-on-part", args.simulation.plate_on_part,
                     "also lay the calibration plate on the part (a scale reference; the demo "
                     "preset always has it)");
  simulate
      ->add_option_function<std::string>(
          "--board",
          [&args](const std::string& board) {
            const std::optional<omm::BoardType> type = omm::BoardTypeFromName(board);
            if (!type) {
              throw CLI::ValidationError(
                  "--board", "expected caltab, circles or chessboard, got '" + board + "'");
            }
            args.simulation.board = *type;
          },
          "the calibration plate: caltab (default: 7 x 7 dots in a frame), circles (the same "
          "dots alone) or chessboard (7 x 9 inner corners, 11 mm squares)")
      ->type_name("TYPE");
  simulate
      ->add_option("--calib-images", args.simulation.num_calib_images,
                   "calibration images (3..100: one partly outside the image, one without "
                   "the plate, the rest full)")
      ->capture_default_str();
  simulate
      ->add_option_function<std::string>(
          "--grid",
          [&args](const std::string& grid) {
            int cols = 0, rows = 0;
            char x = 0, rest = 0;
            if (std::sscanf(grid.c_str(), "%d%c%d%c", &cols, &x, &rows, &rest) != 3 || x != 'x') {
              throw CLI::ValidationError("--grid",
                                         "expected COLSxROWS, e.g. 3x3, got '" + grid + "'");
            }
            args.simulation.grid_cols = cols;
            args.simulation.grid_rows = rows;
          },
          "tiles per row x rows, COLSxROWS (default 3x3; 4x1 is a strip along the machine's X)")
      ->type_name("COLSxROWS");
  simulate
      ->add_option("--table-sigma", args.simulation.table_sigma_mm,
                   "1-sigma error of each table position, mm per axis (also table.sigma_mm)")
      ->capture_default_str();
  simulate->add_option("--truth", args.truth, "where to write the truth JSON");
  return simulate;
}

// `omm report PROJECT`.
CLI::App* AddReportCommand(CLI::App& app, std::string& project, bool& json) {
  CLI::App* report = app.add_subcommand(
      "report",
      "Regenerate the reports from the saved results (no stage is rerun) and print a summary\n"
      "(calibration, mosaic, measurements vs CMM).\n"
      "Reads PROJECT/out/ (report.json, the mosaic, the plots) and project.yaml.\n"
      "Writes PROJECT/out/report.html, out/report.json (normalised) and its tables\n"
      "(out/measurements.csv, out/features.csv).");
  report->add_option("PROJECT", project, "project directory")->required();
  report->add_flag("--json", json, "print the report's JSON instead of the summary");
  return report;
}

}  // namespace

int main(int argc, char** argv) {
  TuneAllocator();
  CLI::App app{
      "omm: on-machine vision metrology. Calibrates the camera over an NC machine "
      "table, registers the tiles of a flat workpiece into an orthorectified mosaic, "
      "and measures holes with their uncertainty.",
      "omm"};
  app.footer(kExitCodes);
  app.set_version_flag("--version", std::string("omm ") + omm::SoftwareVersion());
  app.require_subcommand(1);
  app.fallthrough();
  int verbose = 0;
  bool quiet = false;
  app.add_flag("-v,--verbose", verbose, "more log detail (-vv: everything)");
  app.add_flag("-q,--quiet", quiet, "warnings and errors only");
  int threads = omm::HardwareThreads();
  app.add_option("--threads", threads,
                 "threads for one project's work (default: the CPUs this process may use;\n"
                 "batch: shared among the projects running at once); the results do not depend\n"
                 "on it")
      ->check(CLI::Range(1, 1024).description(""))
      ->type_name("N");

  std::string project;
  std::optional<omm::Stage> stage;

  CLI::App* run = app.add_subcommand(
      "run",
      "Run every stage on a project: calibrate, mosaic, measure.\n"
      "Reads PROJECT/project.yaml, calib/, tiles/, table.csv, cmm.csv.\n"
      "Writes PROJECT/out/: report.json, camera.cameramodel, the mosaic, ... (all or nothing).\n"
      "Keeps the stages whose inputs are unchanged since out/ was written (--force reruns them).");
  run->add_option("PROJECT", project, "project directory")->required();
  bool force = false;
  run->add_flag("--force", force,
                "rerun every stage (by default the stages whose inputs are unchanged since out/\n"
                "was written are kept: a new cmm.csv reruns only measure)");

  bool study = false;
  CLI::App* calibrate = AddStageCommand(
      app, omm::Stage::kCalibrate,
      "Calibrate the camera from the plate images.\n"
      "Reads PROJECT/project.yaml (camera, board) and calib/ (or calibration.from).\n"
      "Writes PROJECT/out/camera.cameramodel, out/calibration/ (solve record, plots) and the\n"
      "report's calibration section.",
      project, stage);
  calibrate->add_flag(
      "--study", study,
      "also run the image-count study: calibrate on random subsets of 3..N images,\n"
      "report the spread of the intrinsics against the count and how many suffice\n"
      "(slow: ~150 solves; writes out/calibration/study.svg)");
  CLI::App* mosaic =
      AddStageCommand(app, omm::Stage::kMosaic,
                      "Register the tiles and write the orthorectified mosaic.\n"
                      "Reads PROJECT/project.yaml, tiles/, table.csv and out/camera.cameramodel.\n"
                      "Writes PROJECT/out/mosaic.* and the report's mosaic section.",
                      project, stage);
  std::string features = "harris";
  const std::map<std::string, omm::FeatureSource> feature_sources{
      {"harris", omm::FeatureSource::kHarris},
      {"sift", omm::FeatureSource::kSift},
      {"both", omm::FeatureSource::kHarrisAndSift}};
  for (CLI::App* command : {run, mosaic}) {
    command
        ->add_option("--features", features,
                     "the mosaic's features: harris (default), sift (COLMAP's: runs the installed\n"
                     "colmap on the tiles, a minute or two) or both")
        ->check(CLI::IsMember({"harris", "sift", "both"}).description(""))
        ->type_name("harris|sift|both");
  }
  AddStageCommand(app, omm::Stage::kMeasure,
                  "Measure the features and measurements listed in project.yaml.\n"
                  "Reads PROJECT/project.yaml, cmm.csv and the mosaic stage's results in out/.\n"
                  "Writes the report's measurements section (values, 1-sigma, CMM deviations).",
                  project, stage);

  BatchArgs batch_args;
  CLI::App* batch = AddBatchCommand(app, batch_args);
  SimulateArgs simulate_args;
  CLI::App* simulate = AddSimulateCommand(app, simulate_args);
  bool json = false;
  CLI::App* report = AddReportCommand(app, project, json);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);  // prints help, version or the error
    return code == 0 ? omm::kExitOk : omm::kExitBadInput;
  }
  SetUpLogging(verbose, quiet);

  const omm::FeatureSource mosaic_features = feature_sources.at(features);
  if (run->parsed())
    return omm::RunCommand(project, omm::AllStages(), false, mosaic_features, threads, !force);
  if (stage) return omm::RunCommand(project, {*stage}, study, mosaic_features, threads);
  if (batch->parsed()) {
    return omm::BatchCommand(batch_args.dirs, batch_args.force, batch_args.csv, batch_args.jobs,
                             threads);
  }
  if (simulate->parsed()) {
    simulate_args.simulation.num_threads = threads;
    return omm::SimulateCommand(simulate_args.out, simulate_args.simulation, simulate_args.truth);
  }
  if (report->parsed()) return omm::ReportCommand(project, json);
  return omm::kExitBadInput;
}
