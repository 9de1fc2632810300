// `omm run --features sift` end to end (issue 4: COLMAP's SIFT as an optional
// feature source, run for real with the installed colmap), on a 12-bit
// camera's tiles stored unshifted in 16-bit files (project.yaml's
// camera.sample_bits: 12). The stage tells COLMAP the sample bits, so it is
// given the tiles over their 12-bit full scale; given the files as they are,
// it sees their high byte (at most 15 of 255) and matches nothing
// (ColmapSiftMatches.TwelveBitSamplesInSixteenBitFilesAreMatched).
#include <cmath>
#include <cstdio>
#include <string>

#include <gtest/gtest.h>

#include "adapters/opencv/image_io.h"
#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/report_json.h"
#include "tests/sim_cache.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

TEST(SiftRun, TwelveBitTilesAreRegisteredBySiftMatchesAlone) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 104, 14);
  testing::TempDir dir;
  const fs::path project_dir = dir.path() / "mono12";
  testing::CopyProject(sim.project_dir, project_dir);
  const Project rendered = LoadProject(project_dir);
  for (const TilePosition& tile : rendered.tiles) {
    const fs::path path = rendered.TilePath(tile.image);
    const GrayImage eight_bit = ReadGrayImage(path);
    ASSERT_EQ(eight_bit.bit_depth, 8);
    // Sample v of 255 stored as round(v 4095 / 255) of 65535.
    WriteGrayImage(path, eight_bit.pixels * (4095.0f / 65535.0f), 16);
  }
  testing::ReplaceInFile(project_dir / "project.yaml", "  focal_length_mm: 12\n",
                         "  focal_length_mm: 12\n  sample_bits: 12\n");

  const testing::CommandResult run = testing::RunOmm("run --features sift " + project_dir.string());
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const Report report = ReadReportJson(project_dir / "out" / "report.json");
  ASSERT_TRUE(report.mosaic && report.features && report.measurements);

  // Every overlapping pair of the 3 x 3 tiles (diagonals too) registered by
  // SIFT matches: no Harris corner was looked for.
  const std::string* brief = AsString(Member(report.mosaic->extra, "brief"));
  ASSERT_NE(brief, nullptr);
  EXPECT_NE(brief->find("20 of 20 pairs"), std::string::npos) << *brief;
  EXPECT_NE(brief->find("anchored at SIFT keypoints"), std::string::npos) << *brief;
  const ReportValue::Array* pairs = AsArray(Member(report.mosaic->extra, "pairs"));
  ASSERT_NE(pairs, nullptr);
  ASSERT_EQ(pairs->size(), 20u);
  for (const ReportValue& pair : *pairs) {
    const ReportObject* row = AsObject(&pair);
    ASSERT_NE(row, nullptr);
    EXPECT_EQ(AsBool(Member(*row, "usable")), std::optional<bool>(true));
    EXPECT_GE(AsNumber(Member(*row, "used")).value_or(0), 100);
  }

  // The holes where the truth has them (issue 4's bound), and every
  // measurement within 3 of its sigmas.
  const double raw_px_mm = testing::RawPxMm(sim.truth);
  const auto errors = testing::HoleCentreErrorsAfterSimilarity(report, sim.truth);
  ASSERT_EQ(errors.size(), sim.truth.holes.size());
  double sum2 = 0.0;
  for (const auto& [name, error_mm] : errors) {
    std::printf("%s centre %.4f raw px from the truth\n", name.c_str(), error_mm / raw_px_mm);
    sum2 += error_mm * error_mm;
  }
  EXPECT_LT(std::sqrt(sum2 / errors.size()) / raw_px_mm, 0.05);
  ASSERT_EQ(report.measurements->size(), sim.truth.measurements.size());
  testing::ExpectMeasurementsWithinSigmas(report, sim.truth, 3.0);
}

}  // namespace
}  // namespace omm
