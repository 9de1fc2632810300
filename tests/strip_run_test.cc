// `omm run` on a strip of tiles: the table moving along one line only (a
// long part seen in one row or one column of tiles). Cut from projects of
// seed 103 with known truth: the demo's middle row, then the exposure
// preset's middle column (three tiles each, the features named in them and
// the measurements between those). The registration seeds the plane from the one motion
// (pipeline/mosaic/plane_seed.h); before, the mosaic stage failed with "the
// tile-to-tile motion is not that of a plane seen from above". Every
// feature must be found, the hole centres sit within 0.05 raw px RMS of the
// truth after a similarity fit (issue 4's bound, the table's scale
// removed), and every measurement be within 3 of its sigma of the truth.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/project_writer.h"
#include "adapters/project_io/report_json.h"
#include "pipeline/orchestration/run_project.h"
#include "tests/sim_cache.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

// The project at `from`, cut to the tiles whose file name contains `keep`,
// written to `to`.
void CutProject(const fs::path& from, const fs::path& to, const std::string& keep) {
  testing::CopyProject(from, to);
  Project project = LoadProject(to);
  std::erase_if(project.tiles, [&](const TilePosition& tile) {
    if (Contains(tile.image, keep)) return false;
    fs::remove(project.TilePath(tile.image));
    return true;
  });
  std::erase_if(project.features,
                [&](const FeatureSpec& feature) { return !Contains(feature.image, keep); });
  std::erase_if(project.measurements, [&](const MeasurementSpec& measurement) {
    for (const std::string& name : measurement.features) {
      if (std::none_of(project.features.begin(), project.features.end(),
                       [&](const FeatureSpec& f) { return f.name == name; })) {
        return true;
      }
    }
    return false;
  });
  std::erase_if(project.cmm, [&](const CmmValue& value) {
    return std::none_of(project.measurements.begin(), project.measurements.end(),
                        [&](const MeasurementSpec& m) { return m.name == value.measurement; });
  });
  if (project.cmm.empty()) fs::remove(to / "cmm.csv");
  WriteProjectFiles(project);
}

void ExpectAStripRuns(const std::string& preset, const std::string& keep) {
  const testing::CachedProject sim = testing::SimulatedProject(preset, 103, 14);
  testing::TempDir dir;
  const fs::path project_dir = dir.path() / "strip";
  CutProject(sim.project_dir, project_dir, keep);
  const Project project = LoadProject(project_dir);
  ASSERT_EQ(project.tiles.size(), 3u);
  ASSERT_GE(project.features.size(), 3u);
  ASSERT_GE(project.measurements.size(), 1u);
  RunProject(project, RunOptions{});
  const Report report = ReadReportJson(project_dir / "out" / "report.json");
  ASSERT_TRUE(report.features.has_value());
  ASSERT_TRUE(report.measurements.has_value());
  const double raw_px_mm = testing::RawPxMm(sim.truth);

  const auto errors = testing::HoleCentreErrorsAfterSimilarity(report, sim.truth);
  ASSERT_EQ(errors.size(), project.features.size());
  double sum2 = 0.0;
  for (const auto& [name, error_mm] : errors) {
    std::printf("%s: %s centre %.4f raw px from the truth\n", keep.c_str(), name.c_str(),
                error_mm / raw_px_mm);
    sum2 += error_mm * error_mm;
  }
  EXPECT_LT(std::sqrt(sum2 / errors.size()) / raw_px_mm, 0.05);

  for (const MeasurementReport& m : *report.measurements) {
    ASSERT_TRUE(m.value_mm && m.sigma_mm) << m.name << ": " << m.error;
    for (const MeasurementTruth& t : sim.truth.measurements) {
      if (t.name != m.name) continue;
      const double error_mm = *m.value_mm - t.value_mm;
      std::printf("%s: %s %+.4f raw px, %+.2f sigma\n", keep.c_str(), m.name.c_str(),
                  error_mm / raw_px_mm, error_mm / *m.sigma_mm);
      EXPECT_LT(std::abs(error_mm), 3.0 * *m.sigma_mm) << m.name;
    }
  }
}

// In both, no tile of the strip sees the whole plate: the scale is the three
// table positions' (~130 ppm), which the similarity fit removes and the
// measurements' sigmas include.
TEST(StripRun, OneRowOfTiles) { ExpectAStripRuns("demo", "_r1c"); }

TEST(StripRun, OneColumnOfTiles) { ExpectAStripRuns("exposure", "c1."); }

}  // namespace
}  // namespace omm
