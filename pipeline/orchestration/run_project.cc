#include "pipeline/orchestration/run_project.h"

#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <iterator>
#include <optional>
#include <system_error>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "adapters/project_io/report_csv.h"
#include "adapters/project_io/report_json.h"
#include "adapters/report_html/report_html.h"
#include "pipeline/core/error.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/orchestration/input_hash.h"
#include "pipeline/orchestration/version.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

constexpr const char* kStagingPrefix = ".staging-";
constexpr const char* kReportName = "report.json";
constexpr const char* kReportHtmlName = "report.html";

// Whether `report` has `stage`'s section.
bool HasSection(const Report& report, Stage stage) {
  switch (stage) {
    case Stage::kCalibrate: return report.calibration.has_value();
    case Stage::kMosaic: return report.mosaic.has_value();
    case Stage::kMeasure: return report.measurements.has_value();
  }
  return false;
}

// The first of the files of `stage`'s results that later stages read
// which out/ lacks; "" if none.
std::string MissingOutput(Stage stage, const Report& report, const fs::path& out_dir) {
  for (const std::string& file : StageOutputFiles(stage, report)) {
    std::error_code ec;
    if (!fs::is_regular_file(out_dir / file, ec)) return (out_dir / file).string();
  }
  return "";
}

// The leading stages of `stages` (run order) whose sections `report` has
// (StartingReport kept them: current) and whose files are in out/: those
// `omm run` keeps instead of running them again.
std::vector<Stage> StagesToKeep(const Report& report, const std::vector<Stage>& stages,
                                const fs::path& out_dir, bool log_missing) {
  std::vector<Stage> kept;
  for (const Stage stage : stages) {
    if (!HasSection(report, stage)) break;
    if (const std::string missing = MissingOutput(stage, report, out_dir); !missing.empty()) {
      if (log_missing) spdlog::info("{}: {} is missing: rerun", StageName(stage), missing);
      break;
    }
    kept.push_back(stage);
  }
  return kept;
}

// A rerun stage invalidates its own section and those of later stages.
void DropSectionsFrom(Stage first, Report& report) {
  const std::vector<Stage> all = AllStages();
  for (auto stage = std::find(all.begin(), all.end(), first); stage != all.end(); ++stage) {
    report.stage_inputs_sha256.erase(StageName(*stage));
  }
  switch (first) {
    case Stage::kCalibrate: report.calibration.reset(); [[fallthrough]];
    case Stage::kMosaic: report.mosaic.reset(); [[fallthrough]];
    case Stage::kMeasure:
      report.features.reset();
      report.measurements.reset();
      report.extra.erase(
          std::remove_if(report.extra.begin(), report.extra.end(),
                         [](const auto& member) { return member.first == "measure"; }),
          report.extra.end());
  }
}

// out/report.json if there is one (ReadReportJson's InputError if it is
// unreadable), whichever omm version wrote it.
std::optional<Report> EarlierReport(const Project& project) {
  const fs::path path = project.OutDir() / kReportName;
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return std::nullopt;
  return ReadReportJson(path);
}

// How many of the stages, in run order, have a section in `report` that
// ran on the inputs `stages` hashes.
size_t NumCurrentSections(const Report& report, const StageInputHashes& stages) {
  const std::vector<Stage> all = AllStages();
  size_t n = 0;
  for (; n < all.size(); ++n) {
    const auto ran_on = report.stage_inputs_sha256.find(StageName(all[n]));
    if (!HasSection(report, all[n]) || ran_on == report.stage_inputs_sha256.end() ||
        ran_on->second != stages.Of(all[n]))
      break;
  }
  return n;
}

// The report to start from: the earlier one's sections of the stages whose
// inputs it ran on are this run's (`stages`), in run order up to the first
// whose are not. *stale: the stages of the sections dropped so (their
// results in out/ are from other inputs).
Report StartingReport(const Project& project, const std::string& inputs_sha256,
                      const StageInputHashes& stages, std::vector<Stage>* stale) {
  Report report;
  try {
    if (std::optional<Report> earlier = EarlierReport(project)) {
      if (earlier->software_version == SoftwareVersion()) {
        report = std::move(*earlier);
      } else {
        spdlog::info("{} is from another omm version ({}); starting afresh",
                     (project.OutDir() / kReportName).string(), earlier->software_version);
      }
    }
  } catch (const InputError& e) {
    spdlog::warn("ignoring unreadable earlier report: {}", e.what());
  }
  const std::vector<Stage> all = AllStages();
  const size_t current = NumCurrentSections(report, stages);
  if (current < all.size()) {
    if (HasSection(report, all[current])) {
      spdlog::info("{}: its inputs changed since out/report.json was written",
                   StageName(all[current]));
    }
    std::copy_if(all.begin() + static_cast<std::ptrdiff_t>(current), all.end(),
                 std::back_inserter(*stale),
                 [&report](Stage later) { return HasSection(report, later); });
    DropSectionsFrom(all[current], report);
  }
  report.format = kReportFormat;
  report.project = project.name;
  report.software_version = SoftwareVersion();
  report.inputs_sha256 = inputs_sha256;
  return report;
}

// report.json, its tables (measurements.csv, features.csv) and report.html
// into the staging directory; the page draws on this run's mosaic in memory
// and files, else on those earlier runs left in out/.
void WriteReports(const Project& project, const StageContext& context) {
  WriteReportJson(context.staging_dir / kReportName, context.report);
  WriteReportTables(context.staging_dir, context.report);
  WriteReportHtml(context.staging_dir / kReportHtmlName, context.report,
                  {context.staging_dir, context.out_dir}, project.measurements, {},
                  context.mosaic.get());
}

// Moves the staged outputs into out/, report.json last.
void Commit(const fs::path& staging_dir, const fs::path& out_dir) {
  try {
    for (const auto& entry : fs::directory_iterator(staging_dir)) {
      const fs::path& from = entry.path();
      if (from.filename() == kReportName) continue;
      const fs::path to = out_dir / from.filename();
      // rename() replaces a file atomically but not a directory.
      if (fs::is_directory(from) || fs::is_directory(to)) fs::remove_all(to);
      fs::rename(from, to);
    }
    fs::rename(staging_dir / kReportName, out_dir / kReportName);
  } catch (const fs::filesystem_error& e) {
    throw InputError(out_dir.string(),
                     std::string("cannot move the results into place: ") + e.code().message());
  }
}

}  // namespace

void RemoveStaleStaging(const fs::path& out_dir) {
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(out_dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind(kStagingPrefix, 0) != 0) continue;
    const pid_t pid = static_cast<pid_t>(std::atol(name.c_str() + std::strlen(kStagingPrefix)));
    if (pid > 0 && kill(pid, 0) != 0 && errno == ESRCH) {
      spdlog::debug("removing {} left by an interrupted run", entry.path().string());
      fs::remove_all(entry.path(), ec);
    }
  }
  if (fs::is_empty(out_dir, ec) && !ec) fs::remove(out_dir, ec);  // the stale run had made it
}

// Hands the calib images LoadProject decoded to the calibration, if it
// runs (StageContext::calib_decoded), which frees each once searched; else
// drops them.
void HandOverDecodedCalibImages(bool calibrating, Project& project, StageContext& context) {
  if (!project.images) return;
  if (calibrating) {
    for (const LoadedImage& image : project.images->calib)
      context.calib_decoded.push_back(image.image);
  }
  project.images =
      std::make_shared<const LoadedImages>(WithoutDecodedImages(*project.images, true, false));
}

// Drops the decoded images no later stage of the run reads: the calib images
// after any stage (the calibration runs first), the tiles once the mosaic
// stage has made their gray images (StageContext::tiles). A mosaic_tiles
// still running reads project.images: it is waited for first.
void DropDecodedImagesNoLongerRead(StageContext& context, Project& project) {
  context.calib_decoded.clear();
  if (!project.images || context.tiles == nullptr) return;
  if (context.mosaic_tiles.valid()) context.mosaic_tiles.wait();
  project.images =
      std::make_shared<const LoadedImages>(WithoutDecodedImages(*project.images, false, true));
}

void RunStage(Stage stage, StageContext& context) {
  switch (stage) {
    case Stage::kCalibrate: return RunCalibrateStage(context);
    case Stage::kMosaic: return RunMosaicStage(context);
    case Stage::kMeasure: return RunMeasureStage(context);
  }
}

std::string RunOptions::Check() const {
  if (stages.empty()) return "no stage to run";
  if (!runner) return "no stage runner";
  if (num_threads < 0) return "num_threads must be >= 0 (0: HardwareThreads())";
  const std::vector<Stage> all = AllStages();
  auto at = all.begin();
  for (const Stage stage : stages) {
    at = std::find(at, all.end(), stage);
    if (at == all.end())
      return "stages must be distinct and in run order (calibrate, mosaic, measure)";
    ++at;
  }
  return "";
}

std::string RunSummary::Brief() const {
  const std::string kept =
      stages_kept.empty() ? "" : fmt::format(" ({} current, kept)", StageNames(stages_kept));
  if (stages_run.empty()) {
    return fmt::format("nothing to run: {} current (`--force` reruns): {}", StageNames(stages_kept),
                       report_path.string());
  }
  return fmt::format("{} done in {:.1f} s{}: {}", StageNames(stages_run), seconds, kept,
                     report_path.string());
}

RunSummary RunProject(Project project, const RunOptions& options) {
  if (const std::string problem = options.Check(); !problem.empty()) {
    throw std::invalid_argument("RunOptions: " + problem);
  }
  const auto start = std::chrono::steady_clock::now();
  const fs::path out_dir = project.OutDir();
  RemoveStaleStaging(out_dir);
  std::error_code ec;
  const bool out_existed = fs::is_directory(out_dir, ec);
  fs::create_directories(out_dir, ec);
  if (ec) throw InputError(out_dir.string(), "cannot create the output directory: " + ec.message());

  const fs::path staging_dir = out_dir / (kStagingPrefix + std::to_string(getpid()));
  fs::remove_all(staging_dir, ec);
  fs::create_directory(staging_dir, ec);
  if (ec) throw InputError(staging_dir.string(), "cannot create directory: " + ec.message());

  RunSummary summary;
  try {
    spdlog::info("hashing the inputs of {}", project.dir.string());
    if (project.sample_bits < 16) {
      spdlog::info("images: 16-bit files {}: read as {}-bit samples (full scale {})",
                   project.camera.sample_bits
                       ? std::string("of project.yaml's camera.sample_bits")
                       : fmt::format("whose samples stay below 2^{}", project.sample_bits),
                   project.sample_bits, (1 << project.sample_bits) - 1);
    }
    const StageInputHashes stage_inputs = HashStageInputs(project, options.mosaic_features);
    std::vector<Stage> stale;
    Report report = StartingReport(project, HashProjectInputs(project), stage_inputs, &stale);
    std::vector<Stage> to_run = options.stages;
    if (options.reuse_current_stages) {
      summary.stages_kept = StagesToKeep(report, options.stages, out_dir, true);
      for (const Stage stage : summary.stages_kept) {
        spdlog::info("{}: current (its inputs unchanged since out/ was written), kept",
                     StageName(stage));
      }
      to_run.erase(to_run.begin(),
                   to_run.begin() + static_cast<std::ptrdiff_t>(summary.stages_kept.size()));
    }
    if (!to_run.empty()) DropSectionsFrom(to_run.front(), report);
    StageContext context{project,
                         staging_dir,
                         out_dir,
                         report,
                         options.progress,
                         options.calibration_study,
                         options.mosaic_features,
                         options.num_threads > 0 ? options.num_threads : HardwareThreads()};
    context.mosaic_follows =
        std::find(to_run.begin(), to_run.end(), Stage::kMosaic) != to_run.end();
    context.stale_in_out = stale;
    HandOverDecodedCalibImages(
        std::find(to_run.begin(), to_run.end(), Stage::kCalibrate) != to_run.end(), project,
        context);
    for (const Stage stage : to_run) {
      spdlog::info("{}: starting", StageName(stage));
      options.runner(stage, context);
      DropDecodedImagesNoLongerRead(context, project);
      report.stage_inputs_sha256[StageName(stage)] = stage_inputs.Of(stage);
      spdlog::info("{}: done", StageName(stage));
      summary.stages_run.push_back(stage);
    }
    WriteReports(project, context);
    for (std::future<void>& write : context.pending_writes) write.get();
    // The last report, and the last chance for a stop (RunCommand's) to
    // leave out/ as it was.
    if (options.progress) options.progress(1, 1, "move the results into out/");
    Commit(staging_dir, out_dir);
    summary.report = std::move(report);
  } catch (...) {
    fs::remove_all(staging_dir, ec);
    if (!out_existed) fs::remove(out_dir, ec);  // only if still empty
    throw;
  }
  fs::remove_all(staging_dir, ec);
  summary.report_path = out_dir / kReportName;
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

bool ReportIsCurrent(const Project& project) {
  const fs::path path = project.OutDir() / kReportName;
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return false;
  try {
    const Report report = ReadReportJson(path);
    const std::vector<Stage> all = AllStages();
    return report.software_version == SoftwareVersion() && report.calibration && report.mosaic &&
           report.measurements && report.inputs_sha256 == HashProjectInputs(project) &&
           std::all_of(all.begin(), all.end(), [&](Stage stage) {
             return MissingOutput(stage, report, project.OutDir()).empty();
           });
  } catch (const InputError&) {
    return false;
  }
}

std::vector<Stage> StagesRunWouldKeep(const Project& project, FeatureSource mosaic_features) {
  try {
    const std::optional<Report> earlier = EarlierReport(project);
    if (!earlier || earlier->software_version != SoftwareVersion()) return {};
    const std::vector<Stage> all = AllStages();
    const size_t current = NumCurrentSections(*earlier, HashStageInputs(project, mosaic_features));
    return StagesToKeep(*earlier, {all.begin(), all.begin() + static_cast<std::ptrdiff_t>(current)},
                        project.OutDir(), false);
  } catch (const InputError&) {
    return {};
  }
}

}  // namespace omm
