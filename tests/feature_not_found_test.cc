// `omm run` with a feature that is not where project.yaml says (issue 5: it
// gets no value and an error saying why; the other measurements still come
// out). Here a user gave hole_01's place with a third of its diameter: the
// 20 mm circle looked for inside a 60 mm hole's dark opening; and with 400
// mm, wider than a tile sees: its error asks about diameter_mm.
#include <string>

#include <gtest/gtest.h>

#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/report_json.h"
#include "pipeline/orchestration/run_project.h"
#include "tests/sim_cache.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

TEST(FeatureNotFound, ItsMeasurementsSayWhyAndTheOthersComeOut) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 104, 14);
  testing::TempDir dir;
  const fs::path project_dir = dir.path() / "ghost";
  testing::CopyProject(sim.project_dir, project_dir);
  testing::ReplaceInFile(project_dir / "project.yaml", "measurements:\n",
                         "  - name: ghost\n"
                         "    type: circle\n"
                         "    image: tile_r0c2.png\n"
                         "    near_px: [963, 434.4]\n"
                         "    diameter_mm: 20\n"
                         "  - name: giant\n"
                         "    type: circle\n"
                         "    image: tile_r0c2.png\n"
                         "    near_px: [963, 434.4]\n"
                         "    diameter_mm: 400\n"
                         "measurements:\n"
                         "  - name: dist_ghost_hole_02\n"
                         "    type: distance\n"
                         "    between: [ghost, hole_02]\n");
  RunProject(LoadProject(project_dir), RunOptions{});
  const Report report = ReadReportJson(project_dir / "out" / "report.json");
  ASSERT_TRUE(report.features && report.measurements);
  ASSERT_EQ(report.features->size(), sim.truth.holes.size() + 2);
  ASSERT_EQ(report.measurements->size(), sim.truth.measurements.size() + 1);

  const std::string ask = "no tile can see a circle of 400 mm whole (a tile sees ";
  for (const FeatureReport& f : *report.features) {
    if (f.name == "giant") {
      EXPECT_FALSE(f.centre_mm);
      EXPECT_NE(f.error.find(ask), std::string::npos) << f.error;
      EXPECT_NE(f.error.find("is its diameter_mm in project.yaml right?"), std::string::npos);
      continue;
    }
    if (f.name != "ghost") {
      EXPECT_TRUE(f.centre_mm) << f.name << ": " << f.error;
      continue;
    }
    EXPECT_FALSE(f.centre_mm || f.diameter_mm);
    EXPECT_FALSE(f.error.empty());
    EXPECT_EQ(f.error.find("diameter_mm"), std::string::npos) << f.error;  // a tile sees 20 mm
    // Looked for in the tiles that see it whole, then in the mosaic.
    const std::string* views = AsString(Member(f.extra, "views"));
    ASSERT_TRUE(views);
    EXPECT_EQ(views->rfind("not found in the mosaic: not found in the ", 0), 0u) << *views;
    EXPECT_NE(views->find("tile_r0c2.png left out: "), std::string::npos) << *views;
    EXPECT_FALSE(Member(f.extra, "fit")) << "a failed fit's brief is its error";
  }
  for (const MeasurementReport& m : *report.measurements) {
    if (m.name == "dist_ghost_hole_02") {
      EXPECT_FALSE(m.value_mm || m.sigma_mm);
      EXPECT_NE(m.error.find("ghost"), std::string::npos) << m.error;
    } else {
      EXPECT_TRUE(m.value_mm && m.sigma_mm) << m.name << ": " << m.error;
    }
  }
}

}  // namespace
}  // namespace omm
