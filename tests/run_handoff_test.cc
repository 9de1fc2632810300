// `omm run` hands the mosaic to the measure stage in memory (and writes
// mosaic.png on another thread); `omm measure` alone reads the file back.
// Both must measure the same pixels: on a rendered demo project, the measure
// stage rerun alone on the run's out/ reproduces every feature and
// measurement bit for bit (slow: needs a render).
#include <filesystem>

#include <gtest/gtest.h>

#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/report_json.h"
#include "pipeline/orchestration/run_project.h"
#include "tests/sim_cache.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

TEST(RunHandoff, MeasureAloneReproducesTheRunExactly) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 101, 14);
  testing::TempDir dir;
  const fs::path project_dir = dir.path() / "demo";
  testing::CopyProject(sim.project_dir, project_dir);

  RunProject(LoadProject(project_dir), RunOptions{});
  const Report run = ReadReportJson(project_dir / "out" / "report.json");
  RunOptions measure_only;
  measure_only.stages = {Stage::kMeasure};
  RunProject(LoadProject(project_dir), measure_only);
  const Report alone = ReadReportJson(project_dir / "out" / "report.json");

  ASSERT_TRUE(run.features && alone.features && run.measurements && alone.measurements);
  ASSERT_EQ(run.features->size(), alone.features->size());
  int num_found = 0;
  for (size_t i = 0; i < run.features->size(); ++i) {
    const FeatureReport& a = (*run.features)[i];
    const FeatureReport& b = (*alone.features)[i];
    EXPECT_EQ(a.error, b.error) << a.name;
    EXPECT_EQ(a.centre_mm, b.centre_mm) << a.name;
    EXPECT_EQ(a.diameter_mm, b.diameter_mm) << a.name;
    EXPECT_EQ(a.centre_sigma_mm, b.centre_sigma_mm) << a.name;
    EXPECT_EQ(a.diameter_sigma_mm, b.diameter_sigma_mm) << a.name;
    num_found += a.centre_mm.has_value();
  }
  ASSERT_EQ(run.measurements->size(), alone.measurements->size());
  int num_made = 0;
  for (size_t i = 0; i < run.measurements->size(); ++i) {
    const MeasurementReport& a = (*run.measurements)[i];
    const MeasurementReport& b = (*alone.measurements)[i];
    EXPECT_EQ(a.value_mm, b.value_mm) << a.name;
    EXPECT_EQ(a.sigma_mm, b.sigma_mm) << a.name;
    num_made += a.value_mm.has_value();
  }
  // Not a comparison of two empty lists: the demo's holes are all found.
  EXPECT_EQ(num_found, static_cast<int>(run.features->size()));
  EXPECT_EQ(num_made, static_cast<int>(run.measurements->size()));
}

}  // namespace
}  // namespace omm
