#include "app/commands.h"

#include <signal.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <functional>
#include <map>
#include <stdexcept>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "adapters/process/process.h"
#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/report_csv.h"
#include "adapters/project_io/report_json.h"
#include "adapters/project_io/text_file.h"
#include "adapters/report_html/report_html.h"
#include "app/batch_summary.h"
#include "app/child_process.h"
#include "app/exit_codes.h"
#include "app/terminal_progress.h"
#include "pipeline/core/error.h"
#include "pipeline/orchestration/run_project.h"
#include "pipeline/simulate/simulate_project.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

struct Outcome {
  int exit_code = kExitOk;
  std::string message;  // empty when ok
};

// Thrown through a run's stages when SIGINT or SIGTERM asked it to stop.
// Not a std::exception, so that no stage takes it for a failure of its own:
// only RunProject's clean-up (catch (...): the staging directory and an
// out/ the run made removed) and Guarded see it.
struct StopRequested {
  int signal = 0;
};

// Runs `body`, turning the three kinds of failure into exit codes.
Outcome Guarded(const std::function<void()>& body) {
  try {
    body();
    return {};
  } catch (const StopRequested& stop) {
    return {kExitStopped, fmt::format("stopped by signal {} ({}); out/ left as it was", stop.signal,
                                      strsignal(stop.signal))};
  } catch (const InputError& e) {
    return {kExitBadInput, e.what()};
  } catch (const StageFailedError& e) {
    return {kExitFailed, e.what()};
  } catch (const std::system_error& e) {
    // The system refused: disk full, no permission, no temporary directory.
    return {kExitFailed, e.what()};
  } catch (const std::exception& e) {
    return {kExitInternal, std::string("internal error (a bug; please report it): ") + e.what()};
  }
}

int Finish(const Outcome& outcome) {
  if (outcome.exit_code != kExitOk) spdlog::error("{}", outcome.message);
  return outcome.exit_code;
}

std::string Optional(const std::optional<double>& value, const char* format_spec = "{:.4f}") {
  return value ? fmt::format(fmt::runtime(format_spec), *value) : "-";
}

// Project directories named by `dirs` (a project, or a folder of projects).
std::vector<fs::path> FindProjects(const std::vector<fs::path>& dirs) {
  std::vector<fs::path> projects;
  std::error_code ec;
  for (const fs::path& dir : dirs) {
    if (fs::is_regular_file(dir / "project.yaml", ec)) {
      projects.push_back(dir);
      continue;
    }
    if (!fs::is_directory(dir, ec)) throw InputError(dir.string(), "directory not found");
    std::vector<fs::path> found;
    for (const auto& entry : fs::directory_iterator(dir, ec)) {
      if (fs::is_regular_file(entry.path() / "project.yaml", ec)) found.push_back(entry.path());
    }
    if (found.empty()) {
      throw InputError(dir.string(),
                       "neither a project (no project.yaml) nor a folder of projects");
    }
    std::sort(found.begin(), found.end());
    projects.insert(projects.end(), found.begin(), found.end());
  }
  return projects;
}

// One line of `omm batch`'s summary table.
struct BatchRow {
  std::string project, result = "ok", measurements = "-";
  double seconds = 0.0;
  std::vector<Stage> kept;  // the stages its `omm run` keeps from out/ (current)
};

// The signal that asked `omm run` or `omm batch` to stop (SIGINT, SIGTERM);
// 0 while none. Lock-free, so the handler may set it, and the threads that
// report progress read it.
std::atomic<int> g_stop_signal{0};
static_assert(std::atomic<int>::is_always_lock_free);
extern "C" void RecordStopSignal(int signal) { g_stop_signal = signal; }

// While it lives, SIGINT and SIGTERM are recorded in g_stop_signal, with
// sigaction's `flags`: 0 for the batch, whose wait for its children they
// must interrupt (no SA_RESTART); the earlier handlers after. A signal the
// program was started ignoring (nohup, a script's background job) stays
// ignored.
class StopSignals {
 public:
  explicit StopSignals(int flags = 0) {
    g_stop_signal = 0;
    struct sigaction action {};
    action.sa_handler = RecordStopSignal;
    action.sa_flags = flags;
    sigemptyset(&action.sa_mask);
    for (const auto& [signal, previous] :
         {std::pair{SIGINT, &previous_int_}, std::pair{SIGTERM, &previous_term_}}) {
      sigaction(signal, nullptr, previous);
      if (previous->sa_handler != SIG_IGN) sigaction(signal, &action, nullptr);
    }
  }
  ~StopSignals() {
    sigaction(SIGINT, &previous_int_, nullptr);
    sigaction(SIGTERM, &previous_term_, nullptr);
  }
  StopSignals(const StopSignals&) = delete;
  StopSignals& operator=(const StopSignals&) = delete;

 private:
  struct sigaction previous_int_ {};
  struct sigaction previous_term_ {};
};

// The outcome of a child `omm run`; its warnings are relayed, naming the
// project.
Outcome ChildOutcome(const ProcessEnd& end, const std::string& log, const std::string& project) {
  const ChildLog said = ParseChildLog(log);
  for (const std::string& warning : said.warnings) spdlog::warn("{}: {}", project, warning);
  const ChildVerdict verdict = Verdict(end, said);
  return {verdict.exit_code, verdict.message};
}

// One `omm batch`: a row and the measurements per project, filled in as
// each one ends or is skipped.
class Batch {
 public:
  explicit Batch(std::vector<fs::path> projects)
      : projects_(std::move(projects)), rows_(projects_.size()), measurements_(projects_.size()) {
    for (size_t i = 0; i < projects_.size(); ++i) {
      rows_[i].project = projects_[i].string();
      measurements_[i].project = projects_[i].string();
    }
  }

  // Those to run: the others are skipped (report current) or refused
  // (project files unreadable) here, without a child.
  std::vector<size_t> ProjectsToRun(bool force, int num_threads) {
    std::vector<size_t> to_run;
    for (size_t i = 0; i < projects_.size(); ++i) {
      bool current = false;
      const Outcome loaded = Guarded([&] {
        const Project project = LoadProject(projects_[i], num_threads);
        current = !force && ReportIsCurrent(project);
        if (!force && !current) rows_[i].kept = StagesRunWouldKeep(project, FeatureSource::kHarris);
      });
      if (loaded.exit_code != kExitOk || current) {
        rows_[i].result = current ? "current (skipped)" : "";
        Conclude(i, loaded);
      } else {
        to_run.push_back(i);
      }
    }
    return to_run;
  }

  // Each project of `to_run` as its own `omm run -q` on `child_threads`
  // (with --force if `force`), up to `jobs` at a time; their logs go to a scratch folder, and their
  // warnings and errors are relayed. SIGINT or SIGTERM stops the batch: the
  // children running are killed, the others not started, and the rows say
  // which. True if stopped.
  bool Run(const std::vector<size_t>& to_run, int jobs, int child_threads, bool force) {
    if (to_run.empty()) return false;
    const fs::path program = OwnExecutable();
    ScratchDir logs("omm-batch-");
    struct Running {
      size_t index;
      fs::path log;
      std::chrono::steady_clock::time_point start;
    };
    std::map<pid_t, Running> running;
    // If anything below throws, the children still running are killed and
    // reaped before `logs` (declared earlier) is removed under them.
    struct KillRunning {
      const std::map<pid_t, Running>& children;
      ~KillRunning() {
        for (const auto& entry : children) KillProcess(entry.first);
      }
    } const kill_running{running};
    const StopSignals stop_signals;
    size_t next = 0;
    while ((next < to_run.size() || !running.empty()) && g_stop_signal == 0) {
      while (next < to_run.size() && running.size() < static_cast<size_t>(jobs) &&
             g_stop_signal == 0) {
        const size_t i = to_run[next++];
        ProcessOptions options;
        options.log_path = logs.path() / fmt::format("{}.log", i);
        try {
          std::vector<std::string> arguments = {program.string(), "-q", "--threads",
                                                std::to_string(child_threads), "run"};
          if (force) arguments.push_back("--force");
          arguments.push_back(projects_[i].string());
          const pid_t pid = StartProcess(arguments, options);
          running.emplace(pid, Running{i, options.log_path, std::chrono::steady_clock::now()});
          spdlog::info("started {} on {} thread{}", rows_[i].project, child_threads,
                       child_threads == 1 ? "" : "s");
        } catch (const ProcessStartError& e) {
          // That project's failure; the others still run.
          Conclude(i, {kExitFailed, "cannot start omm: " + e.code().message()});
        }
      }
      if (running.empty() || g_stop_signal != 0) continue;
      const std::optional<ProcessEnd> ended = WaitForAnyProcess();
      if (!ended) continue;  // a signal: g_stop_signal says whether to stop
      const ProcessEnd& end = *ended;
      const auto it = running.find(end.pid);
      if (it == running.end()) continue;
      const Running child = it->second;
      running.erase(it);
      rows_[child.index].seconds =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - child.start).count();
      Conclude(child.index, ChildOutcome(end, ReadTextFile(child.log, "log not found"),
                                         rows_[child.index].project));
    }
    if (g_stop_signal == 0) return false;
    const std::string why = fmt::format("the batch got signal {} ({})",
                                        static_cast<int>(g_stop_signal), strsignal(g_stop_signal));
    for (const auto& [pid, child] : running) {
      KillProcess(pid);
      Conclude(child.index, {kExitStopped, "killed: " + why});
    }
    running.clear();
    // What the stopped runs left (Ctrl-C stops the children too).
    for (size_t i = 0; i < projects_.size(); ++i) {
      if (IsStopped(rows_[i])) RemoveStaleStaging(projects_[i] / "out");
    }
    for (; next < to_run.size(); ++next) Conclude(to_run[next], {kExitStopped, "not run: " + why});
    return true;
  }

  // After project i has ended (or was skipped), with the outcome of `omm
  // run`: its row, its measurements and a log line.
  void Conclude(size_t i, const Outcome& run) {
    BatchRow& row = rows_[i];
    ProjectMeasurements& made = measurements_[i];
    Outcome outcome = run;
    if (outcome.exit_code == kExitOk && !row.kept.empty()) {
      std::vector<Stage> rerun = AllStages();
      rerun.erase(rerun.begin(), rerun.begin() + static_cast<std::ptrdiff_t>(row.kept.size()));
      row.result = rerun.empty() ? "ok (all stages current, none rerun)"
                                 : fmt::format("ok (reran {}; {} current)", StageNames(rerun),
                                               StageNames(row.kept));
    }
    if (outcome.exit_code == kExitOk) {
      outcome = Guarded([&] {
        const Report report = ReadReportJson(projects_[i] / "out" / "report.json");
        row.measurements = MeasurementBrief(report);
        if (report.measurements) made.measurements = *report.measurements;
      });
    }
    if (outcome.exit_code == kExitStopped) {
      row.result = "STOPPED: " + outcome.message;
      row.measurements = "-";
      made = {projects_[i].string(), {}, outcome.message};
    } else if (outcome.exit_code != kExitOk) {
      row.result = fmt::format("FAILED ({}): {}", outcome.exit_code, outcome.message);
      row.measurements = "-";
      made = {projects_[i].string(), {}, outcome.message};  // out/ is an earlier run's, if any
    }
    ++done_;
    const size_t total = projects_.size();
    if (outcome.exit_code != kExitOk) {
      spdlog::error("[{}/{}] {}: {}", done_, total, row.project, outcome.message);
    } else if (row.seconds == 0.0) {
      spdlog::info("[{}/{}] {}: {}", done_, total, row.project, row.result);
    } else {
      spdlog::info("[{}/{}] {}: {} in {:.1f} s", done_, total, row.project, row.result,
                   row.seconds);
    }
  }

  // The summary table and the agreement with the CMM, on stdout.
  void PrintSummary() const {
    size_t width = 7;
    for (const BatchRow& row : rows_) width = std::max(width, row.project.size());
    fmt::print("{:<{}}  {:>8}  {:<34}  {}\n", "project", width, "time_s", "measurements", "result");
    for (const BatchRow& row : rows_) {
      fmt::print("{:<{}}  {:>8.1f}  {:<34}  {}\n", row.project, width, row.seconds,
                 row.measurements, row.result);
    }
    fmt::print("{} project{}, {} failed{}\n", rows_.size(), rows_.size() == 1 ? "" : "s",
               NumFailed(), NumStopped() > 0 ? fmt::format(", {} stopped", NumStopped()) : "");
    fmt::print("{}\n", CmmAgreement(measurements_));
  }

  const std::vector<ProjectMeasurements>& Measurements() const { return measurements_; }
  long NumFailed() const {
    return std::count_if(rows_.begin(), rows_.end(),
                         [](const BatchRow& r) { return r.result.rfind("FAILED", 0) == 0; });
  }
  long NumStopped() const { return std::count_if(rows_.begin(), rows_.end(), IsStopped); }

 private:
  static bool IsStopped(const BatchRow& row) { return row.result.rfind("STOPPED", 0) == 0; }

  std::vector<fs::path> projects_;
  std::vector<BatchRow> rows_;
  std::vector<ProjectMeasurements> measurements_;
  size_t done_ = 0;
};

}  // namespace

int RunCommand(const fs::path& project_dir, const std::vector<Stage>& stages,
               bool calibration_study, FeatureSource mosaic_features, int num_threads,
               bool reuse_current_stages) {
  return Finish(Guarded([&] {
    // Ctrl-C or SIGTERM: the run stops at its next progress report (within
    // a second or so: the longest stretch without one is a calibration's
    // solves; longer while COLMAP or the calibration study runs), the last
    // just before out/ is replaced, and leaves out/ as it was. Reads and
    // writes are restarted, not failed; the same signal again ends the
    // program at once (SA_RESETHAND; the next run removes what it left).
    const StopSignals stop_signals(SA_RESTART | SA_RESETHAND);
    Project project = LoadProject(project_dir, num_threads);
    spdlog::info("loaded {}: {} calibration images, {} tiles, {} measurements", project.name,
                 project.calib_images.size(), project.tiles.size(), project.measurements.size());
    TerminalProgress progress(IsStderrTerminal());
    RunOptions options;
    options.stages = stages;
    options.calibration_study = calibration_study;
    options.mosaic_features = mosaic_features;
    options.num_threads = num_threads;
    options.reuse_current_stages = reuse_current_stages;
    options.progress = [report = progress.Callback()](int done, int total,
                                                      const std::string& what) {
      if (g_stop_signal != 0) throw StopRequested{g_stop_signal};
      report(done, total, what);
    };
    const RunSummary summary = RunProject(std::move(project), options);
    progress.Finish();
    spdlog::info("{}", summary.Brief());
    fmt::print("{}\n", summary.report_path.string());
  }));
}

int BatchCommand(const std::vector<fs::path>& dirs, bool force, const std::optional<fs::path>& csv,
                 int jobs, int num_threads) {
  // The machine shared among the projects running at once.
  const int child_threads = std::max(1, num_threads / std::max(1, jobs));
  std::vector<fs::path> projects;
  if (const Outcome found = Guarded([&] { projects = FindProjects(dirs); });
      found.exit_code != kExitOk) {
    return Finish(found);
  }
  Batch batch(std::move(projects));
  const std::vector<size_t> to_run = batch.ProjectsToRun(force, num_threads);
  bool stopped = false;
  if (const Outcome ran = Guarded([&] { stopped = batch.Run(to_run, jobs, child_threads, force); });
      ran.exit_code != kExitOk) {
    return Finish(ran);
  }
  batch.PrintSummary();
  if (csv) {
    const Outcome written =
        Guarded([&] { WriteTextFileAtomically(*csv, MeasurementsCsv(batch.Measurements())); });
    if (written.exit_code != kExitOk) return Finish(written);
    fmt::print("{}\n", csv->string());
  }
  if (stopped) return kExitStopped;
  // A child stopped from outside counts as failed.
  return batch.NumFailed() > 0 || batch.NumStopped() > 0 ? kExitFailed : kExitOk;
}

int SimulateCommand(const fs::path& project_dir, const SimulationOptions& options,
                    const std::optional<fs::path>& truth) {
  return Finish(Guarded([&] {
    if (const std::string problem = options.Check(); !problem.empty()) {
      throw InputError("omm simulate", problem);
    }
    const fs::path truth_path = truth ? *truth : DefaultTruthPath(project_dir);
    TerminalProgress progress(IsStderrTerminal());
    const SimulationSummary summary =
        SimulateProjectDirectory(options, project_dir, truth_path, progress.Callback());
    progress.Finish();
    spdlog::info("{}", summary.brief);
    spdlog::info("simulated project '{}' (preset {}{}, seed {}); truth in {}", project_dir.string(),
                 options.preset, options.plate_on_part ? " with the plate on the part" : "",
                 options.seed, truth_path.string());
    fmt::print("{}\n", project_dir.string());
  }));
}

int ReportCommand(const fs::path& project_dir, bool json) {
  return Finish(Guarded([&] {
    const fs::path path = project_dir / "out" / "report.json";
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) {
      throw InputError(path.string(), "no report yet (run 'omm run " + project_dir.string() + "')");
    }
    const Report report = ReadReportJson(path);
    // The distances' lines need project.yaml's measurements; an archived out/
    // whose project no longer loads still gets its page, without them.
    std::vector<MeasurementSpec> measurements;
    try {
      measurements = LoadProject(project_dir).measurements;
    } catch (const InputError& e) {
      spdlog::warn("report.html without distance lines: {}", e.what());
    }
    WriteReportJson(path, report);
    WriteReportTables(project_dir / "out", report);
    const fs::path html_path = project_dir / "out" / "report.html";
    WriteReportHtml(html_path, report, {project_dir / "out"}, measurements);
    spdlog::info("wrote {}, its tables (measurements.csv, features.csv) and {}", path.string(),
                 html_path.string());
    if (json) {
      fmt::print("{}", ReportToJson(report));
      return;
    }
    fmt::print("project {}  (omm {}, inputs {})\n", report.project, report.software_version,
               report.inputs_sha256.substr(0, 12));
    if (report.calibration) {
      const CalibrationReport& c = *report.calibration;
      fmt::print("calibration: {}, rms {:.3f} px, {} images used, {} rejected\n", c.lens_model,
                 c.rms_px, c.images_used, c.images_rejected.size());
      for (const RejectedImage& r : c.images_rejected)
        fmt::print("  rejected {}: {}\n", r.image, r.why);
    }
    if (report.mosaic) {
      const MosaicReport& m = *report.mosaic;
      fmt::print("mosaic: {}, {} x {} px at {} mm/px, rms {:.3f} px\n", m.file, m.size_px.x(),
                 m.size_px.y(), m.gsd_mm, m.rms_px);
    }
    if (report.measurements) {
      // The CMM's sigma and the deviation against both, where cmm.csv states it.
      const std::vector<MeasurementReport>& listed = *report.measurements;
      const bool with_cmm_sigma =
          std::any_of(listed.begin(), listed.end(),
                      [](const MeasurementReport& m) { return m.cmm_sigma_mm.has_value(); });
      fmt::print("{:<20} {:<9} {:>12} {:>9} {:>12} {:>10} {:>9}{}\n", "measurement", "type",
                 "value_mm", "sigma_mm", "cmm_mm", "dev_mm", "dev/sigma",
                 with_cmm_sigma ? fmt::format(" {:>9} {:>9}", "cmm_sigma", "dev/both") : "");
      for (const MeasurementReport& m : listed) {
        fmt::print("{:<20} {:<9} {:>12} {:>9} {:>12} {:>10} {:>9}{}{}\n", m.name,
                   MeasurementTypeName(m.type), Optional(m.value_mm), Optional(m.sigma_mm),
                   Optional(m.cmm_mm), Optional(m.deviation_mm),
                   Optional(m.deviation_sigma, "{:.2f}"),
                   with_cmm_sigma ? fmt::format(" {:>9} {:>9}", Optional(m.cmm_sigma_mm),
                                                Optional(m.deviation_combined_sigma, "{:.2f}"))
                                  : "",
                   m.error.empty() ? "" : "  error: " + m.error);
      }
    }
  }));
}

}  // namespace omm
