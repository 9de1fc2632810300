// `omm run` end to end on simulated projects against their truth (issue 5):
//  - honesty of the uncertainty: over every distance and diameter of 35
//    projects (seven presets, five seeds each), z = error / sigma must
//    have a standard deviation in [0.7, 1.3] and |z| <= 2 for >= 90 %;
//  - the report: CMM deviations, 3-sigma flags, the sigma breakdown;
//  - with OMM_ACCURACY_BOUNDS (the binary omm_measure_run_accuracy_test,
//    label `acceptance`: issue 5's accuracy goal, not yet met everywhere, so
//    outside CI's gate): every error within 0.05 raw-pixel equivalents on
//    projects whose metric scale the part itself carries (the caltab lying
//    on it: `demo`), 0.1 on low-texture (with or without exposure
//    differences) and lens-mismatch; without a scale on the part the
//    table's random errors set the scale (sigma ~4.6e-5, ~0.14 raw px over
//    430 mm), so there the bound is on the diameters.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/report_json.h"
#include "pipeline/calibration/calibrate_stage.h"
#include "pipeline/orchestration/run_project.h"
#include "tests/sim_cache.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

struct ProjectSpec {
  const char* preset;
  std::uint64_t seed;
};

// Seeds 101-105 of every preset: seeds no stage was tuned on.
std::vector<ProjectSpec> Projects() {
  std::vector<ProjectSpec> projects;
  for (const char* preset : {"demo", "markers", "exposure", "low-texture", "low-texture-exposure",
                             "sparse-texture", "lens-mismatch"}) {
    for (std::uint64_t seed = 101; seed <= 105; ++seed) projects.push_back({preset, seed});
  }
  return projects;
}

struct Outcome {
  std::string project;
  std::string preset;
  MeasurementReport measurement;
  double truth_mm = 0.0;
  double raw_px_mm = 0.0;  // a raw pixel's size on the part
  double error_mm() const { return *measurement.value_mm - truth_mm; }
};

// Calibration images per project (12 usable: `omm calibrate --study` finds 12
// suffice on the demo): the calibration's uncertainty stays in the test at a
// lower rendering cost than the default 20.
constexpr int kCalibImages = 14;

// Every check in one test: ctest runs each test in its own process, and the
// 35 renders and runs are shared by all of them.
#ifdef OMM_ACCURACY_BOUNDS
TEST(MeasureRunAccuracy, ThirtyFiveProjectsWithinTheIssuesBounds) {
#else
TEST(MeasureRun, ThirtyFiveProjectsAgainstTheirTruth) {
#endif
  testing::TempDir dir;
  std::vector<Outcome> outcomes;
  std::map<std::string, Report> reports;
  for (const ProjectSpec& spec : Projects()) {
    const std::string name = std::string(spec.preset) + "-" + std::to_string(spec.seed);
    const testing::CachedProject sim =
        testing::SimulatedProject(spec.preset, spec.seed, kCalibImages);
    const fs::path project_dir = dir.path() / name;
    testing::CopyProject(sim.project_dir, project_dir);
    try {
      const RunSummary summary = RunProject(LoadProject(project_dir), RunOptions{});
      std::printf("%s: %s\n", name.c_str(), summary.Brief().c_str());
    } catch (const std::exception& e) {
      ADD_FAILURE() << name << ": " << e.what();
      continue;
    }
    const Report report = ReadReportJson(project_dir / "out" / "report.json");
    reports[name] = report;
    for (const MeasurementReport& m : *report.measurements) {
      const MeasurementTruth* truth = nullptr;
      for (const MeasurementTruth& t : sim.truth.measurements) {
        if (t.name == m.name) truth = &t;
      }
      ASSERT_NE(truth, nullptr) << name << ": no truth for " << m.name;
      if (!m.value_mm || !m.sigma_mm) {
        ADD_FAILURE() << name << ": " << m.name << ": " << m.error;
        continue;
      }
      outcomes.push_back({name, spec.preset, m, truth->value_mm, testing::RawPxMm(sim.truth)});
    }
  }
  ASSERT_GE(reports.size(), 35u);

  // The issue's statistical test of sigma.
  double sum_z2 = 0.0;
  int within_2 = 0;
  for (const Outcome& o : outcomes) {
    const double z = o.error_mm() / *o.measurement.sigma_mm;
    std::printf("%-20s %-24s error %8.2f um = %6.3f raw px, sigma %6.2f um, z %6.2f\n",
                o.project.c_str(), o.measurement.name.c_str(), o.error_mm() * 1e3,
                o.error_mm() / o.raw_px_mm, *o.measurement.sigma_mm * 1e3, z);
    sum_z2 += z * z;
    if (std::abs(z) <= 2.0) ++within_2;
  }
  const double n = static_cast<double>(outcomes.size());
  const double sd = std::sqrt(sum_z2 / n);
  std::printf("%zu measurements: sd(error / sigma) %.3f, |z| <= 2 for %.1f %%\n", outcomes.size(),
              sd, 100.0 * within_2 / n);
  EXPECT_GE(sd, 0.7);
  EXPECT_LE(sd, 1.3);
  EXPECT_GE(within_2, 0.9 * n);

#ifdef OMM_ACCURACY_BOUNDS
  // Accuracy where the part carries its own metric scale (the plate on it),
  // and for diameters everywhere.
  for (const Outcome& o : outcomes) {
    const bool loose = o.preset == "low-texture" || o.preset == "low-texture-exposure" ||
                       o.preset == "lens-mismatch";
    const double bound_raw_px = loose ? 0.1 : 0.05;
    const bool scale_on_part = o.preset == "demo";
    if (!scale_on_part && o.measurement.type == MeasurementType::kDistance) continue;
    EXPECT_LE(std::abs(o.error_mm()) / o.raw_px_mm, bound_raw_px)
        << o.project << " " << o.measurement.name;
  }
#endif

  // The CMM comparison (the simulator writes cmm.csv for every measurement).
  for (const auto& [name, report] : reports) {
    ASSERT_TRUE(report.features.has_value()) << name;
    // The perspective-bias corrections settled with the lens model used
    // (CalibrationStageOptions::bias_settle_px), a splined one included.
    const ReportObject* bias =
        AsObject(Member(report.calibration->extra, "perspective_bias_correction"));
    ASSERT_NE(bias, nullptr) << name;
    EXPECT_LT(AsNumber(Member(*bias, "last_change_px")).value_or(1.0),
              CalibrationStageOptions{}.bias_settle_px)
        << name << " (" << report.calibration->lens_model << ")";
    for (const MeasurementReport& m : *report.measurements) {
      if (!m.value_mm) continue;
      ASSERT_TRUE(m.cmm_mm.has_value()) << name << " " << m.name;
      EXPECT_DOUBLE_EQ(*m.deviation_mm, *m.value_mm - *m.cmm_mm);
      EXPECT_DOUBLE_EQ(*m.deviation_sigma, *m.deviation_mm / *m.sigma_mm);
      // The simulator states the CMM's sigma: the deviation is judged
      // against both.
      ASSERT_TRUE(m.cmm_sigma_mm && m.deviation_combined_sigma) << name << " " << m.name;
      EXPECT_DOUBLE_EQ(*m.deviation_combined_sigma,
                       *m.deviation_mm / std::hypot(*m.sigma_mm, *m.cmm_sigma_mm));
      bool flagged = false;
      for (const auto& [key, value] : m.extra) {
        if (key == "beyond_3_sigma") flagged = std::get<bool>(value.data());
      }
      EXPECT_EQ(flagged, std::abs(*m.deviation_combined_sigma) > 3.0) << name << " " << m.name;
      // Every project calibrates from its own calib/: the calibration's
      // covariance is a source of every sigma, whatever the lens model (a
      // splined model's held core once left it out: 0 on lens-mismatch).
      const ReportObject* breakdown = AsObject(Member(m.extra, "sigma_breakdown_mm"));
      ASSERT_NE(breakdown, nullptr) << name << " " << m.name;
      EXPECT_GT(AsNumber(Member(*breakdown, "calibration")).value_or(0.0), 0.0)
          << name << " " << m.name << " (" << report.calibration->lens_model << ")";
      // Independent parts: their squares sum to sigma^2.
      double sum_squares = 0.0;
      for (const char* source : {"calibration", "registration", "table", "edges"}) {
        const std::optional<double> part = AsNumber(Member(*breakdown, source));
        ASSERT_TRUE(part.has_value()) << name << " " << m.name << " " << source;
        sum_squares += *part * *part;
      }
      EXPECT_NEAR(std::sqrt(sum_squares), *m.sigma_mm, 1e-9 * *m.sigma_mm) << name << " " << m.name;
    }
  }
}

}  // namespace
}  // namespace omm
