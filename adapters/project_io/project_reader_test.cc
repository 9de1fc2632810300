#include "adapters/project_io/project_reader.h"

#include <cstdint>
#include <cstring>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "adapters/opencv/image_io.h"
#include "adapters/openssl/sha256.h"
#include "adapters/project_io/project_writer.h"
#include "pipeline/core/error.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;
using ::testing::HasSubstr;

namespace omm {
namespace {

class ProjectReaderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    project_ = testing::TinyProject(dir_.path() / "job");
    testing::WriteTinyProject(project_);
  }

  fs::path File(const std::string& name) const { return project_.dir / name; }
  void Replace(const std::string& file, const std::string& from, const std::string& to) {
    testing::ReplaceInFile(File(file), from, to);
  }

  // LoadProject must throw an InputError whose message has every part.
  void ExpectError(const std::vector<std::string>& parts) {
    try {
      LoadProject(project_.dir);
      ADD_FAILURE() << "LoadProject accepted the project; expected an error with '" << parts[0]
                    << "'";
    } catch (const InputError& e) {
      for (const std::string& part : parts) EXPECT_THAT(e.what(), HasSubstr(part));
    }
  }

  testing::TempDir dir_;
  Project project_;
};

TEST_F(ProjectReaderTest, WrittenProjectReadsBackIdentically) {
  const Project read = LoadProject(project_.dir);
  EXPECT_EQ(read.dir, fs::canonical(project_.dir));
  EXPECT_EQ(read.name, project_.name);
  EXPECT_EQ(read.camera.pixel_pitch_um, project_.camera.pixel_pitch_um);
  EXPECT_EQ(read.camera.focal_length_mm, project_.camera.focal_length_mm);
  EXPECT_FALSE(read.camera.lens_model.has_value());
  EXPECT_FALSE(read.calibration_from.has_value());
  ASSERT_TRUE(read.board.has_value());
  EXPECT_EQ(read.board->type, BoardType::kCaltab);
  EXPECT_EQ(read.board->rows, 7);
  EXPECT_EQ(read.board->pitch_mm, 12.5);
  EXPECT_EQ(read.board->dot_diameter_mm, 6.25);
  EXPECT_EQ(read.board->frame_mm, 100.0);
  EXPECT_EQ(read.table_sigma_mm, project_.table_sigma_mm);
  EXPECT_EQ(read.mosaic_gsd_mm, project_.mosaic_gsd_mm);
  ASSERT_EQ(read.features.size(), 2u);
  EXPECT_EQ(read.features[1].name, "hole_B");
  EXPECT_EQ(read.features[1].image, "Part_04.png");
  EXPECT_EQ(read.features[1].near_px, Eigen::Vector2d(20.5, 3.0));
  EXPECT_EQ(read.features[1].diameter_mm, 12.5);
  ASSERT_EQ(read.measurements.size(), 2u);
  EXPECT_EQ(read.measurements[0].type, MeasurementType::kDistance);
  EXPECT_EQ(read.measurements[0].features, (std::vector<std::string>{"hole_A", "hole_B"}));
  EXPECT_EQ(read.measurements[1].type, MeasurementType::kDiameter);
  EXPECT_EQ(read.measurements[1].features, (std::vector<std::string>{"hole_A"}));
  ASSERT_EQ(read.tiles.size(), 4u);
  for (size_t i = 0; i < read.tiles.size(); ++i) {
    EXPECT_EQ(read.tiles[i].image, project_.tiles[i].image);
    EXPECT_EQ(read.tiles[i].table_pos_mm, project_.tiles[i].table_pos_mm);  // bit-identical
  }
  ASSERT_EQ(read.cmm.size(), 2u);
  EXPECT_EQ(read.cmm[0].measurement, "A_to_B");
  EXPECT_EQ(read.cmm[0].value_mm, 202.6033);
  ASSERT_EQ(read.calib_images.size(), 2u);
  EXPECT_EQ(read.calib_images[0].filename(), "calib_01.png");
  EXPECT_EQ(read.image_width_px, 32);
  EXPECT_EQ(read.image_height_px, 24);

  // Writing what was read gives the same files.
  const std::string yaml = testing::ReadTextFile(File("project.yaml"));
  const std::string table = testing::ReadTextFile(File("table.csv"));
  WriteProjectFiles(read);
  EXPECT_EQ(testing::ReadTextFile(File("project.yaml")), yaml);
  EXPECT_EQ(testing::ReadTextFile(File("table.csv")), table);
}

TEST_F(ProjectReaderTest, OptionalKeysAndChessboardAreRead) {
  project_.camera.lens_model = "LENSMODEL_OPENCV8";
  project_.board->type = BoardType::kChessboard;
  project_.cmm.clear();
  fs::remove(File("cmm.csv"));
  WriteProjectFiles(project_);
  const Project read = LoadProject(project_.dir);
  EXPECT_EQ(read.camera.lens_model, "LENSMODEL_OPENCV8");
  EXPECT_EQ(read.board->type, BoardType::kChessboard);
  EXPECT_TRUE(read.cmm.empty());
}

TEST_F(ProjectReaderTest, PlateHeightIsOptionalAndRoundTrips) {
  EXPECT_FALSE(LoadProject(project_.dir).plate_height_mm.has_value());
  project_.plate_height_mm = 2.85;
  WriteProjectFiles(project_);
  EXPECT_THAT(testing::ReadTextFile(File("project.yaml")), HasSubstr("plate_height_mm: 2.85"));
  EXPECT_EQ(LoadProject(project_.dir).plate_height_mm, 2.85);
  Replace("project.yaml", "plate_height_mm: 2.85", "plate_height_mm: -1");
  ExpectError({"project.yaml", "mosaic.plate_height_mm", "expected a number >= 0, got -1"});
}

TEST_F(ProjectReaderTest, CaltabGeometryKeysAreRead) {
  Replace("project.yaml", "frame_mm: 100", "frame_mm: 110");
  Replace("project.yaml", "triangle_mm: 12.5", "triangle_mm: 15");
  const Project read = LoadProject(project_.dir);
  EXPECT_EQ(read.board->frame_mm, 110.0);
  EXPECT_EQ(read.board->triangle_mm, 15.0);
}

TEST_F(ProjectReaderTest, MissingDirectory) {
  project_.dir = dir_.path() / "nowhere";
  ExpectError({"nowhere", "project directory not found"});
}

TEST_F(ProjectReaderTest, MissingProjectYaml) {
  fs::remove(File("project.yaml"));
  ExpectError({"project.yaml", "not found"});
}

TEST_F(ProjectReaderTest, YamlSyntaxErrorGivesTheLine) {
  Replace("project.yaml", "name: tiny", "name: [tiny");
  ExpectError({"project.yaml:", "not valid YAML"});
}

TEST_F(ProjectReaderTest, UnknownKeySuggestsTheClosest) {
  Replace("project.yaml", "pitch_mm: 12.5", "pich_mm: 12.5");
  ExpectError({"project.yaml:", "board.pich_mm", "unknown key", "did you mean 'pitch_mm'"});
}

TEST_F(ProjectReaderTest, UnknownTopLevelKeySuggestsTheClosest) {
  Replace("project.yaml", "measurements:", "measurments:");
  ExpectError({"measurments", "did you mean 'measurements'"});
}

TEST_F(ProjectReaderTest, WrongFormat) {
  Replace("project.yaml", "omm-project/1", "omm-project/2");
  ExpectError({"project.yaml:1", "key 'format'", "omm-project/1", "omm-project/2"});
}

TEST_F(ProjectReaderTest, NegativePitch) {
  Replace("project.yaml", "pitch_mm: 12.5", "pitch_mm: -12.5");
  ExpectError({"project.yaml:", "board.pitch_mm", "expected a number > 0", "-12.5"});
}

TEST_F(ProjectReaderTest, TooFewRows) {
  Replace("project.yaml", "rows: 7", "rows: 1");
  ExpectError({"board.rows", "expected an integer >= 2, got 1"});
}

TEST_F(ProjectReaderTest, FractionalRows) {
  Replace("project.yaml", "rows: 7", "rows: 7.5");
  ExpectError({"board.rows", "expected an integer, got '7.5'"});
}

TEST_F(ProjectReaderTest, NonNumericValue) {
  Replace("project.yaml", "focal_length_mm: 12", "focal_length_mm: twelve");
  ExpectError({"camera.focal_length_mm", "expected a number, got 'twelve'"});
}

TEST_F(ProjectReaderTest, MissingRequiredKey) {
  Replace("project.yaml", "pixel_pitch_um: 4.5", "");
  ExpectError({"camera.pixel_pitch_um", "required key is missing"});
}

TEST_F(ProjectReaderTest, CameraGammaIsReadAndWritten) {
  EXPECT_EQ(LoadProject(project_.dir).camera.gamma, 1.0);  // absent: linear
  project_.camera.gamma = 0.45;
  WriteProjectFiles(project_);
  EXPECT_EQ(LoadProject(project_.dir).camera.gamma, 0.45);
}

TEST_F(ProjectReaderTest, CameraGammaOutOfRangeIsRejected) {
  Replace("project.yaml", "focal_length_mm: 12", "focal_length_mm: 12\n  gamma: 0");
  ExpectError({"camera.gamma", "[0.2, 5]"});
}

TEST_F(ProjectReaderTest, CameraSampleBitsOutOfRangeIsRejected) {
  Replace("project.yaml", "focal_length_mm: 12", "focal_length_mm: 12\n  sample_bits: 17");
  ExpectError({"camera.sample_bits", "8 to 16, got 17"});
  WriteProjectFiles(project_);
  Replace("project.yaml", "focal_length_mm: 12", "focal_length_mm: 12\n  sample_bits: 7");
  ExpectError({"camera.sample_bits", "expected an integer >= 8, got 7"});
  WriteProjectFiles(project_);
  Replace("project.yaml", "focal_length_mm: 12", "focal_length_mm: 12\n  sample_bits: twelve");
  ExpectError({"camera.sample_bits", "expected an integer, got 'twelve'"});
}

// Not a mrcal name, an unknown one, and a splined model without its
// configuration: each refused on its line (the unknown one used to reach the
// calibration, which named neither the file's path nor the line).
TEST_F(ProjectReaderTest, LensModelMustBeAMrcalModelItCanUse) {
  for (const std::string model : {"OPENCV8", "LENSMODEL_FOO", "LENSMODEL_SPLINED_STEREOGRAPHIC"}) {
    WriteProjectFiles(project_);
    Replace("project.yaml", "focal_length_mm: 12", "focal_length_mm: 12\n  lens_model: " + model);
    ExpectError({"project.yaml:", "camera.lens_model", "'" + model + "'", "LENSMODEL_OPENCV8"});
  }
  WriteProjectFiles(project_);
  Replace("project.yaml", "focal_length_mm: 12",
          "focal_length_mm: 12\n  lens_model: LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_"
          "fov_x_deg=100");
  EXPECT_EQ(LoadProject(project_.dir).camera.lens_model,
            "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_fov_x_deg=100");
}

TEST_F(ProjectReaderTest, UnknownBoardTypeSuggests) {
  Replace("project.yaml", "type: caltab", "type: caltap");
  ExpectError({"board.type", "did you mean 'caltab'", "caltab, circles, chessboard"});
}

TEST_F(ProjectReaderTest, DotDiameterOnChessboardIsRejected) {
  Replace("project.yaml", "type: caltab", "type: chessboard");
  ExpectError({"board.dot_diameter_mm", "not used by a 'chessboard' board"});
}

TEST_F(ProjectReaderTest, DotsMustFitTheCaltabFrame) {
  Replace("project.yaml", "frame_mm: 100", "frame_mm: 60");
  ExpectError({"key 'board'", "more than the frame's inside"});
}

TEST_F(ProjectReaderTest, BoardMissingWhileCalibIsUsed) {
  project_.board.reset();
  WriteProjectFiles(project_);
  ExpectError({"project.yaml", "board", "calib/ is used"});
}

TEST_F(ProjectReaderTest, MissingCalibDirectory) {
  fs::remove_all(File("calib"));
  ExpectError({"calib", "not found", "calibration.from"});
}

TEST_F(ProjectReaderTest, CalibImagesOfEveryFormatReadAreListed) {
  // calib_02 as a TIFF, a third image as a PGM, and a README: every image
  // format omm reads is listed, in name order; other files are not.
  const StoredImage image = ReadStoredImage(File("calib") / "calib_02.png");
  fs::remove(File("calib") / "calib_02.png");
  WriteStoredImage(File("calib") / "calib_02.tif", image);
  std::string pgm = fmt::format("P5\n{} {}\n255\n", image.width, image.height);
  pgm.append(image.samples.begin(), image.samples.end());
  testing::WriteTextFile(File("calib") / "calib_03.pgm", pgm);
  testing::WriteTextFile(File("calib") / "README.txt", "not an image");
  const Project read = LoadProject(project_.dir);
  ASSERT_EQ(read.calib_images.size(), 3u);
  EXPECT_EQ(read.calib_images[1].filename(), "calib_02.tif");
  EXPECT_EQ(read.calib_images[2].filename(), "calib_03.pgm");
  EXPECT_EQ(ReadStoredImage(read.calib_images[2]).samples, image.samples);
}

TEST_F(ProjectReaderTest, EmptyCalibDirectory) {
  fs::remove_all(File("calib"));
  fs::create_directories(File("calib"));
  testing::WriteTextFile(File("calib") / "notes.txt", "not an image");
  ExpectError({"calib", "no images"});
}

TEST_F(ProjectReaderTest, CalibrationFromAnEarlierProject) {
  Project earlier = testing::TinyProject(dir_.path() / "setup");
  testing::WriteTinyProject(earlier);
  project_.calibration_from = CalibrationSource{CalibrationSource::Kind::kProject, earlier.dir};
  project_.board.reset();
  WriteProjectFiles(project_);
  EXPECT_THAT(testing::ReadTextFile(File("project.yaml")), HasSubstr("from: ../setup"));
  fs::remove_all(File("calib"));  // not needed any more
  const Project read = LoadProject(project_.dir);
  ASSERT_TRUE(read.calibration_from.has_value());
  EXPECT_EQ(read.calibration_from->kind, CalibrationSource::Kind::kProject);
  EXPECT_EQ(read.calibration_from->path, fs::canonical(earlier.dir));
  EXPECT_TRUE(read.calib_images.empty());
}

TEST_F(ProjectReaderTest, CalibrationFromACameraModelFile) {
  testing::WriteTextFile(dir_.path() / "lab.cameramodel", "{}");
  Replace("project.yaml", "board:", "calibration:\n  from: ../lab.cameramodel\nboard:");
  const Project read = LoadProject(project_.dir);
  ASSERT_TRUE(read.calibration_from.has_value());
  EXPECT_EQ(read.calibration_from->kind, CalibrationSource::Kind::kCameraModel);
}

TEST_F(ProjectReaderTest, CalibrationFromPointingNowhere) {
  Replace("project.yaml", "board:", "calibration:\n  from: ../setup-2026-11-20\nboard:");
  ExpectError({"calibration.from", "setup-2026-11-20", "does not exist"});
}

TEST_F(ProjectReaderTest, CalibrationFromADirectoryThatIsNoProject) {
  fs::create_directories(dir_.path() / "empty");
  Replace("project.yaml", "board:", "calibration:\n  from: ../empty\nboard:");
  ExpectError({"calibration.from", "not an omm project"});
}

TEST_F(ProjectReaderTest, MeasurementNamesAMissingFeature) {
  Replace("project.yaml", "between: [hole_A, hole_B]", "between: [hole_A, hole_C]");
  ExpectError({"measurements[0]", "'hole_C'", "not in 'features'", "did you mean 'hole_"});
}

TEST_F(ProjectReaderTest, DistanceOfOneFeature) {
  Replace("project.yaml", "between: [hole_A, hole_B]", "between: [hole_A]");
  ExpectError({"measurements[0].between", "exactly two features", "got 1 items"});
}

TEST_F(ProjectReaderTest, DiameterOfTwoFeatures) {
  Replace("project.yaml", "of: hole_A", "of: [hole_A, hole_B]");
  ExpectError({"measurements[1].of", "exactly one feature"});
}

TEST_F(ProjectReaderTest, UnknownMeasurementType) {
  Replace("project.yaml", "type: diameter", "type: diametre");
  ExpectError({"measurements[1].type", "did you mean 'diameter'"});
}

TEST_F(ProjectReaderTest, DuplicateFeatureName) {
  project_.features[1].name = "hole_A";
  project_.measurements.pop_back();
  project_.measurements[0].features = {"hole_A"};
  project_.measurements[0].type = MeasurementType::kDiameter;
  project_.cmm.clear();
  fs::remove(File("cmm.csv"));
  WriteProjectFiles(project_);
  ExpectError({"features[1].name", "duplicate feature name 'hole_A'"});
}

TEST_F(ProjectReaderTest, DuplicateMeasurementName) {
  Replace("project.yaml", "name: A_diameter", "name: A_to_B");
  ExpectError({"measurements[1].name", "duplicate measurement name 'A_to_B'"});
}

TEST_F(ProjectReaderTest, FeatureInAnImageThatIsNoTile) {
  Replace("project.yaml", "image: Part_04.png", "image: Part_05.png");
  ExpectError({"features[1].image", "'Part_05.png'", "not a tile", "did you mean"});
}

TEST_F(ProjectReaderTest, FeatureOutsideItsTile) {
  Replace("project.yaml", "[20.5, 3]", "[20.5, 300]");
  ExpectError({"features[1].near_px", "outside the 32 x 24 px tile 'Part_04.png'"});
}

TEST_F(ProjectReaderTest, TableRowWithoutImage) {
  fs::remove(project_.TilePath("Part_03.png"));
  ExpectError({"table.csv:4", "tile 'Part_03.png' has no image in tiles/"});
}

TEST_F(ProjectReaderTest, ImageWithoutTableRow) {
  testing::WriteGrayPng(project_.TilePath("Part_05.png"), 32, 24);
  ExpectError({"Part_05.png", "no row in table.csv"});
}

TEST_F(ProjectReaderTest, MissingTableCsv) {
  fs::remove(File("table.csv"));
  ExpectError({"table.csv", "not found"});
}

TEST_F(ProjectReaderTest, TableWrongHeader) {
  Replace("table.csv", "image,x_mm,y_mm", "image,x,y");
  ExpectError({"table.csv:1", "expected the header 'image, x_mm, y_mm'"});
}

TEST_F(ProjectReaderTest, TableWrongColumnCount) {
  Replace("table.csv", "Part_02.png,108.6,0", "Part_02.png,108.6");
  ExpectError({"table.csv:3", "expected 3 columns", "got 2"});
}

TEST_F(ProjectReaderTest, TableNonNumericValue) {
  Replace("table.csv", "Part_02.png,108.6,0", "Part_02.png,108.6x,0");
  ExpectError({"table.csv:3", "column 'x_mm'", "'108.6x'"});
}

TEST_F(ProjectReaderTest, TableRowWithTwoBadValuesNamesTheFirst) {
  Replace("table.csv", "Part_02.png,108.6,0", "Part_02.png,b,c");
  ExpectError({"table.csv:3", "column 'x_mm'", "got 'b'"});
}

TEST_F(ProjectReaderTest, TableWithEveryTileAtOnePlace) {
  Replace("table.csv", "Part_02.png,108.6,0", "Part_02.png,0,0");
  Replace("table.csv", "Part_03.png,0,80.25", "Part_03.png,0,0");
  Replace("table.csv", "Part_04.png,108.6,80.25", "Part_04.png,0,0");
  ExpectError({"table.csv", "every tile is at one table position"});
}

TEST_F(ProjectReaderTest, TableDuplicateTile) {
  Replace("table.csv", "Part_02.png,108.6,0", "Part_01.png,108.6,0");
  ExpectError({"table.csv:3", "'Part_01.png' is listed twice"});
}

TEST_F(ProjectReaderTest, TableMayHaveCrlfAndBlankLines) {
  std::string text = testing::ReadTextFile(File("table.csv"));
  std::string crlf;
  for (char c : text) crlf += c == '\n' ? std::string("\r\n") : std::string(1, c);
  testing::WriteTextFile(File("table.csv"), crlf + "\r\n\r\n");
  EXPECT_EQ(LoadProject(project_.dir).tiles.size(), 4u);
}

TEST_F(ProjectReaderTest, CmmUnknownName) {
  Replace("cmm.csv", "A_diameter,", "A_diametre,");
  ExpectError({"cmm.csv:3", "'A_diametre' is not a measurement", "did you mean 'A_diameter'"});
}

TEST_F(ProjectReaderTest, CmmNonNumericValue) {
  Replace("cmm.csv", "202.6033", "2O2.6033");
  ExpectError({"cmm.csv:2", "column 'value_mm'", "'2O2.6033'"});
}

TEST_F(ProjectReaderTest, CmmWrongColumnCount) {
  Replace("cmm.csv", "202.6033", "202,6033");
  ExpectError({"cmm.csv:2", "expected 2 columns"});
}

// cmm.csv's optional third column: the CMM value's 1-sigma, empty where not
// stated; written back only where some value states it.
TEST_F(ProjectReaderTest, CmmSigmaIsAnOptionalColumn) {
  EXPECT_FALSE(LoadProject(project_.dir).cmm[0].sigma_mm.has_value());
  project_.cmm[0].sigma_mm = 0.0015;
  WriteProjectFiles(project_);
  const std::string text = testing::ReadTextFile(File("cmm.csv"));
  EXPECT_EQ(text, "name,value_mm,sigma_mm\nA_to_B,202.6033,0.0015\nA_diameter,40.0012,\n");
  const Project read = LoadProject(project_.dir);
  ASSERT_EQ(read.cmm.size(), 2u);
  EXPECT_EQ(read.cmm[0].value_mm, 202.6033);
  EXPECT_EQ(read.cmm[0].sigma_mm, 0.0015);
  EXPECT_FALSE(read.cmm[1].sigma_mm.has_value());
  WriteProjectFiles(read);
  EXPECT_EQ(testing::ReadTextFile(File("cmm.csv")), text);
}

TEST_F(ProjectReaderTest, CmmSigmaMustBePositive) {
  project_.cmm[0].sigma_mm = 0.0015;
  WriteProjectFiles(project_);
  Replace("cmm.csv", "0.0015", "0");
  ExpectError({"cmm.csv:2", "column 'sigma_mm'", "expected a number > 0", "got '0'"});
  Replace("cmm.csv", "202.6033,0", "202.6033,1,5");
  ExpectError({"cmm.csv:2", "expected 3 columns"});
  Replace("cmm.csv", "202.6033,1,5", "202.6033,l.5");
  ExpectError({"cmm.csv:2", "column 'sigma_mm'", "'l.5'"});
}

TEST_F(ProjectReaderTest, CmmHeaderNamesBothForms) {
  Replace("cmm.csv", "name,value_mm", "name,value_mm,sigma");
  ExpectError({"cmm.csv:1", "expected the header 'name, value_mm' or 'name, value_mm, sigma_mm'",
               "sigma'"});
}

TEST_F(ProjectReaderTest, CmmDuplicateName) {
  Replace("cmm.csv", "A_diameter,", "A_to_B,");
  ExpectError({"cmm.csv:3", "'A_to_B' is listed twice"});
}

TEST_F(ProjectReaderTest, ImagesOfDifferentSizes) {
  testing::WriteGrayPng(project_.TilePath("Part_03.png"), 33, 24);
  ExpectError({"Part_03.png", "33 x 24", "32 x 24", "one size"});
}

TEST_F(ProjectReaderTest, CorruptImageIsNamed) {
  testing::WriteTextFile(project_.TilePath("Part_02.png"), "\x89PNG\r\n\x1a\n truncated");
  ExpectError({"Part_02.png", "cannot decode"});
}

// Read on two threads, the error is still that of the first bad file in
// order (calib/ before tiles/, file names in order), as a serial read gives.
TEST_F(ProjectReaderTest, FirstOfSeveralCorruptImagesIsNamed) {
  testing::WriteTextFile(project_.TilePath("Part_04.png"), "not a PNG at all");
  testing::WriteTextFile(project_.TilePath("Part_02.png"), "\x89PNG\r\n\x1a\n truncated");
  ExpectError({"Part_02.png", "cannot decode"});
  testing::WriteTextFile(project_.calib_images.back(), "not a PNG either");
  ExpectError({project_.calib_images.back().filename().string(), "cannot decode"});
}

TEST_F(ProjectReaderTest, MissingImageIsNamed) {
  fs::remove(project_.TilePath("Part_03.png"));
  ExpectError({"Part_03.png"});
}

// What LoadProject keeps for the stages is each file's samples and the
// SHA-256 of its bytes.
TEST_F(ProjectReaderTest, LoadedImagesAreThoseOfTheFiles) {
  const Project read = LoadProject(project_.dir);
  ASSERT_NE(read.images, nullptr);
  ASSERT_EQ(read.images->calib.size(), read.calib_images.size());
  ASSERT_EQ(read.images->tiles.size(), read.tiles.size());
  std::vector<std::pair<fs::path, const LoadedImage*>> all;
  for (size_t i = 0; i < read.calib_images.size(); ++i)
    all.emplace_back(read.calib_images[i], &read.images->calib[i]);
  for (size_t i = 0; i < read.tiles.size(); ++i)
    all.emplace_back(read.TilePath(read.tiles[i].image), &read.images->tiles[i]);
  for (const auto& [path, loaded] : all) {
    const StoredImage file = ReadStoredImage(path);
    ASSERT_NE(loaded->image, nullptr) << path;
    EXPECT_EQ(loaded->image->width, file.width) << path;
    EXPECT_EQ(loaded->image->height, file.height) << path;
    EXPECT_EQ(loaded->image->bit_depth, file.bit_depth) << path;
    EXPECT_EQ(loaded->image->samples, file.samples) << path;
    EXPECT_EQ(loaded->sha256, Sha256Hex(testing::ReadTextFile(path))) << path;
  }
}

// Every image a 16-bit file whose samples stay below 2^b: b-bit samples
// (b = 10, 12, 14); 8-bit files, or any sample at 2^14 or above: 16.
TEST_F(ProjectReaderTest, SampleBitsAreTheFewestThatHoldEverySample) {
  EXPECT_EQ(LoadProject(project_.dir).sample_bits, 16);  // 8-bit files
  std::vector<fs::path> images = project_.calib_images;
  for (const TilePosition& tile : project_.tiles) images.push_back(project_.TilePath(tile.image));
  const StoredImage last_eight_bit = ReadStoredImage(images.back());
  const auto store_as_16_bit = [&](std::uint16_t largest) {
    for (const fs::path& path : images) {
      const StoredImage eight = ReadStoredImage(path);
      std::vector<std::uint16_t> samples(eight.samples.begin(), eight.samples.end());
      samples[0] = largest;
      StoredImage sixteen{eight.width, eight.height, 16,
                          std::vector<std::uint8_t>(2 * samples.size())};
      std::memcpy(sixteen.samples.data(), samples.data(), sixteen.samples.size());
      WriteStoredImage(path, sixteen);
    }
  };
  for (const auto& [largest, bits] : {std::pair<std::uint16_t, int>{1023, 10},
                                      {1024, 12},
                                      {4095, 12},
                                      {16383, 14},
                                      {16384, 16},
                                      {65535, 16}}) {
    store_as_16_bit(largest);
    EXPECT_EQ(LoadProject(project_.dir).sample_bits, bits) << largest;
  }
  // camera.sample_bits is taken as stated: a 16-bit camera whose capture
  // stays below 2^14, a 12-bit camera whose capture stays below 2^10.
  store_as_16_bit(16000);
  project_.camera.sample_bits = 16;
  WriteProjectFiles(project_);
  EXPECT_EQ(LoadProject(project_.dir).sample_bits, 16);
  store_as_16_bit(1000);
  project_.camera.sample_bits = 12;
  WriteProjectFiles(project_);
  EXPECT_EQ(LoadProject(project_.dir).sample_bits, 12);
  // A sample beyond the stated full scale: the file is named.
  store_as_16_bit(4096);
  try {
    LoadProject(project_.dir);
    ADD_FAILURE() << "a sample of 4096 in 12-bit samples was accepted";
  } catch (const InputError& error) {
    EXPECT_THAT(error.what(), HasSubstr(images.front().filename().string()));
    EXPECT_THAT(error.what(), HasSubstr("a sample of 4096, beyond the full scale 4095 of "
                                        "project.yaml's camera.sample_bits 12"));
  }
  project_.camera.sample_bits.reset();
  WriteProjectFiles(project_);

  // One 8-bit file among them: the 16-bit ones are taken at their full scale.
  store_as_16_bit(4095);
  WriteStoredImage(images.back(), last_eight_bit);
  EXPECT_EQ(LoadProject(project_.dir).sample_bits, 16);
}

TEST_F(ProjectReaderTest, CalibrationOnlyProjectHasNoTiles) {
  project_.tiles.clear();
  project_.features.clear();
  project_.measurements.clear();
  project_.cmm.clear();
  fs::remove_all(File("tiles"));
  fs::remove(File("table.csv"));
  fs::remove(File("cmm.csv"));
  WriteProjectFiles(project_);
  const Project read = LoadProject(project_.dir);
  EXPECT_TRUE(read.tiles.empty());
  EXPECT_EQ(read.calib_images.size(), 2u);
}

}  // namespace
}  // namespace omm
