// `omm --threads N run`: the results do not depend on the thread count. The
// work split over threads is per item (image, tile, pair, hole, row block),
// each item's result written to its own place and combined in item order, so
// one thread and three give the same bits in every output file (slow: two
// runs of a rendered project, AprilTags and a plate on the part included).
// The project is MeasureRun's render of markers seed 101 (14 calib/ images).
#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/project_io/report_json.h"
#include "tests/sim_cache.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

// The files under `dir`, relative to it, sorted.
std::vector<fs::path> FilesUnder(const fs::path& dir) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::recursive_directory_iterator(dir))
    if (entry.is_regular_file()) files.push_back(fs::relative(entry.path(), dir));
  std::sort(files.begin(), files.end());
  return files;
}

TEST(ThreadCount, OneThreadAndThreeGiveTheSameOutputs) {
  const testing::CachedProject sim = testing::SimulatedProject("markers", 101, 14);
  testing::TempDir dir;
  const fs::path one = dir.path() / "one", three = dir.path() / "three";
  testing::CopyProject(sim.project_dir, one);
  testing::CopyProject(sim.project_dir, three);
  const testing::CommandResult run_one = testing::RunOmm("-q --threads 1 run " + one.string());
  ASSERT_EQ(run_one.exit_code, 0) << run_one.output;
  const testing::CommandResult run_three = testing::RunOmm("-q --threads 3 run " + three.string());
  ASSERT_EQ(run_three.exit_code, 0) << run_three.output;

  const std::vector<fs::path> files = FilesUnder(one / "out");
  ASSERT_EQ(files, FilesUnder(three / "out"));
  for (const fs::path& file : files) {
    // The reports hold run times and their project's path.
    if (file == "report.json" || file == "report.html") continue;
    EXPECT_TRUE(testing::ReadTextFile(one / "out" / file) ==
                testing::ReadTextFile(three / "out" / file))
        << file << " differs";
  }
  const Report report_one = ReadReportJson(one / "out" / "report.json");
  const Report report_three = ReadReportJson(three / "out" / "report.json");
  ASSERT_TRUE(report_one.measurements && report_three.measurements);
  ASSERT_EQ(report_one.measurements->size(), report_three.measurements->size());
  for (size_t i = 0; i < report_one.measurements->size(); ++i) {
    const auto& a = (*report_one.measurements)[i];
    const auto& b = (*report_three.measurements)[i];
    EXPECT_EQ(a.name, b.name);
    EXPECT_EQ(a.value_mm, b.value_mm) << a.name;
    EXPECT_EQ(a.sigma_mm, b.sigma_mm) << a.name;
  }
}

}  // namespace
}  // namespace omm
