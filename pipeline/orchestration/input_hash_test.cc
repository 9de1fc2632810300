#include "pipeline/orchestration/input_hash.h"

#include <string>

#include <gtest/gtest.h>

#include "adapters/opencv/image_io.h"
#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/project_writer.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

TEST(InputHash, SeesEveryInput) {
  testing::TempDir dir;
  testing::WriteTinyProject(testing::TinyProject(dir.path() / "job"));
  const Project project = LoadProject(dir.path() / "job");
  const std::string hash = HashProjectInputs(project);
  EXPECT_EQ(hash.size(), 64u);
  EXPECT_EQ(HashProjectInputs(project), hash);  // deterministic
  // The images' hashes LoadProject kept are those of the files.
  Project unloaded = project;
  unloaded.images.reset();
  EXPECT_EQ(HashProjectInputs(unloaded), hash);
  // 2 calib images + 4 tiles + project.yaml, table.csv, cmm.csv.
  EXPECT_EQ(ProjectInputFiles(project).size(), 9u);

  testing::WriteGrayPng(project.TilePath("Part_02.png"), 32, 24);  // same bytes
  EXPECT_EQ(HashProjectInputs(LoadProject(project.dir)), hash);
  WriteGrayImage(project.TilePath("Part_02.png"), ImageF::Constant(24, 32, 0.25f), 8);
  EXPECT_NE(HashProjectInputs(LoadProject(project.dir)), hash);
  // A loaded project's images are hashed as the bytes it decoded: the hash
  // names the pixels a run used, whatever happened to the file since.
  EXPECT_EQ(HashProjectInputs(project), hash);
  EXPECT_NE(HashProjectInputs(unloaded), hash);
}

// Each input invalidates the stage that reads it and the later ones, and
// nothing else: the tiny project edited one input at a time.
class StageInputsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    testing::WriteTinyProject(tiny_);
    before_ = Hashes();
  }

  StageInputHashes Hashes(FeatureSource features = FeatureSource::kHarris) const {
    return HashStageInputs(LoadProject(tiny_.dir), features);
  }

  // The stages whose hash differs from the unedited project's, e.g.
  // "mosaic measure"; the edits are undone for the next.
  std::string Changed(const StageInputHashes& after) {
    std::string changed;
    for (const Stage stage : AllStages()) {
      if (after.Of(stage) == before_.Of(stage)) continue;
      if (!changed.empty()) changed += ' ';
      changed += StageName(stage);
    }
    testing::WriteTinyProject(testing::TinyProject(tiny_.dir));
    tiny_ = testing::TinyProject(tiny_.dir);
    return changed;
  }
  std::string Changed() { return Changed(Hashes()); }

  testing::TempDir dir_;
  Project tiny_ = testing::TinyProject(dir_.path() / "job");
  StageInputHashes before_;
};

TEST_F(StageInputsTest, CmmValuesAndMeasurementsAreTheMeasureStagesAlone) {
  testing::ReplaceInFile(tiny_.dir / "cmm.csv", "202.6033", "202.6034");
  EXPECT_EQ(Changed(), "measure");
  fs::remove(tiny_.dir / "cmm.csv");
  EXPECT_EQ(Changed(), "measure");
  tiny_.measurements.push_back({"B_diameter", MeasurementType::kDiameter, {"hole_B"}});
  WriteProjectFiles(tiny_);
  EXPECT_EQ(Changed(), "measure");
}

TEST_F(StageInputsTest, TilesTableFeaturesAndTheFeatureSourceAreTheMosaicsOn) {
  WriteGrayImage(tiny_.TilePath("Part_03.png"), ImageF::Constant(24, 32, 0.25f), 8);
  EXPECT_EQ(Changed(), "mosaic measure");
  testing::ReplaceInFile(tiny_.dir / "table.csv", "108.6", "108.7");
  EXPECT_EQ(Changed(), "mosaic measure");
  tiny_.table_sigma_mm = 0.02;
  WriteProjectFiles(tiny_);
  EXPECT_EQ(Changed(), "mosaic measure");
  tiny_.mosaic_gsd_mm = 0.2;
  WriteProjectFiles(tiny_);
  EXPECT_EQ(Changed(), "mosaic measure");
  // The holes seen by two tiles tie them.
  tiny_.features[1].near_px.x() += 1.0;
  WriteProjectFiles(tiny_);
  EXPECT_EQ(Changed(), "mosaic measure");
  EXPECT_EQ(Changed(Hashes(FeatureSource::kSift)), "mosaic measure");
}

TEST_F(StageInputsTest, CalibrationInputsAreEveryStagesOn) {
  WriteGrayImage(tiny_.calib_images[1], ImageF::Constant(24, 32, 0.25f), 8);
  EXPECT_EQ(Changed(), "calibrate mosaic measure");
  fs::remove(tiny_.calib_images[1]);
  EXPECT_EQ(Changed(), "calibrate mosaic measure");
  tiny_.camera.gamma = 0.5;
  WriteProjectFiles(tiny_);
  EXPECT_EQ(Changed(), "calibrate mosaic measure");
  tiny_.board->pitch_mm += 0.5;
  WriteProjectFiles(tiny_);
  EXPECT_EQ(Changed(), "calibrate mosaic measure");
  // 16-bit images whose samples stay below 2^12 read as 12-bit ones.
  const ImageF dim = ImageF::Constant(24, 32, 3000.0f / 65535.0f);
  for (const TilePosition& tile : tiny_.tiles) WriteGrayImage(tiny_.TilePath(tile.image), dim, 16);
  for (const fs::path& calib : tiny_.calib_images) WriteGrayImage(calib, dim, 16);
  ASSERT_EQ(LoadProject(tiny_.dir).sample_bits, 12);
  EXPECT_EQ(Changed(), "calibrate mosaic measure");
}

// project.yaml counts by content: comments, layout and the project's name
// (a label of the report) leave every stage current.
TEST_F(StageInputsTest, CommentsAndTheNameAreNoStagesInput) {
  testing::WriteTextFile(tiny_.dir / "project.yaml",
                         "# measured on 2026-12-01\n" +
                             testing::ReadTextFile(tiny_.dir / "project.yaml") + "\n\n# end\n");
  EXPECT_EQ(Changed(), "");
  tiny_.name = "renamed";
  WriteProjectFiles(tiny_);
  EXPECT_EQ(Changed(), "");
}

// A key the reader accepts but no stage's hash covered would leave results
// current after that key changed.
TEST(StageReadingYamlKey, EveryKeyButTheNameIsAStagesInput) {
  for (const std::string& key : ProjectYamlKeys()) {
    EXPECT_EQ(StageReadingYamlKey(key).has_value(), key != "name") << key;
  }
  EXPECT_FALSE(StageReadingYamlKey("no_such_key").has_value());
}

}  // namespace
}  // namespace omm
