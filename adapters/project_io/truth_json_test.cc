#include "adapters/project_io/truth_json.h"

#include <filesystem>

#include <unistd.h>

#include <gtest/gtest.h>

#include "pipeline/core/error.h"

namespace omm {
namespace {

Eigen::Isometry3d SomePose(double a, double z) {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() =
      Eigen::AngleAxisd(a, Eigen::Vector3d(0.3, -0.2, 1.0).normalized()).toRotationMatrix();
  pose.translation() << 0.1 * a, -1.0 / 3.0, z;
  return pose;
}

SimulationTruth SomeTruth() {
  SimulationTruth truth;
  truth.preset = "demo";
  truth.seed = 18446744073709551557ull;  // needs all 64 bits
  truth.camera.model.lens_model = "LENSMODEL_OPENCV8";
  truth.camera.model.intrinsics = Eigen::VectorXd::LinSpaced(12, 0.1, 2666.6666666666665);
  truth.camera.model.width_px = 1600;
  truth.camera.model.height_px = 1200;
  truth.camera.pixel_pitch_um = 4.4871;
  truth.camera.focal_length_mm = 12.1 / 3.0;
  truth.camera.psf_sigma_px = 0.77;
  truth.plate_size_mm = 120.0;
  truth.calib_images.push_back(
      {"calib_00.png", CalibImageTruth::Kind::kFull, SomePose(0.4, 390.0), {1.02, 0.15, 0.8}});
  truth.calib_images.push_back({"calib_01.png",
                                CalibImageTruth::Kind::kPlateAbsent,
                                Eigen::Isometry3d::Identity(),
                                {0.97, 0.15, 0.7}});
  truth.cam_from_part = SomePose(2.9, 391.25);
  truth.part_min_mm << -1.5, 0.25;
  truth.part_max_mm << 451.0, 449.0;
  truth.part_thickness_mm = 12.0;
  truth.table_sigma_mm = 0.02;
  TileTruth tile;
  tile.image = "tile_r0c1.png";
  tile.grid_row = 0;
  tile.grid_col = 1;
  tile.commanded_mm << 140.5, -20.0;
  tile.actual_mm << 140.5 + 1e-17, -20.0123456789;
  tile.exposure = {0.8, 0.3, 0.75};
  truth.tiles.push_back(tile);
  truth.holes.push_back({"hole_01", Eigen::Vector2d(12.25, 300.125), 20.0131, 20.0});
  MarkerTruth marker;
  marker.id = 586;
  marker.corners_part_mm << 0, 20, 20, 0, 0, 0, 20, 20.000000000000004;
  marker.tag_size_mm = 20.0;
  marker.paper_size_mm = 30.0;
  truth.markers.push_back(marker);
  truth.part_from_plate = SomePose(-1.0, 0.0);
  truth.measurements.push_back({"hole_01_to_hole_02", 212.34567890123});
  return truth;
}

void ExpectPoseEq(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  EXPECT_EQ(a.matrix(), b.matrix());
}

// Written and read back, every number is bit-identical.
TEST(TruthJson, RoundTripIsExact) {
  const SimulationTruth truth = SomeTruth();
  const std::filesystem::path path =
      std::filesystem::temp_directory_path() /
      ("omm_truth_json_test_" + std::to_string(::getpid()) + ".json");
  WriteTruthJson(truth, path);
  const SimulationTruth back = ReadTruthJson(path);
  std::filesystem::remove(path);

  EXPECT_EQ(back.preset, truth.preset);
  EXPECT_EQ(back.seed, truth.seed);
  EXPECT_EQ(back.camera.model.lens_model, truth.camera.model.lens_model);
  EXPECT_EQ(back.camera.model.intrinsics, truth.camera.model.intrinsics);
  EXPECT_EQ(back.camera.model.width_px, 1600);
  EXPECT_EQ(back.camera.model.height_px, 1200);
  EXPECT_EQ(back.camera.pixel_pitch_um, truth.camera.pixel_pitch_um);
  EXPECT_EQ(back.camera.focal_length_mm, truth.camera.focal_length_mm);
  EXPECT_EQ(back.camera.psf_sigma_px, truth.camera.psf_sigma_px);
  EXPECT_EQ(back.board.type, BoardType::kCaltab);
  EXPECT_EQ(back.board.frame_bar_mm, truth.board.frame_bar_mm);
  EXPECT_EQ(back.plate_size_mm, truth.plate_size_mm);
  ASSERT_EQ(back.calib_images.size(), 2u);
  EXPECT_EQ(back.calib_images[0].image, "calib_00.png");
  EXPECT_EQ(back.calib_images[1].kind, CalibImageTruth::Kind::kPlateAbsent);
  ExpectPoseEq(back.calib_images[0].cam_from_plate, truth.calib_images[0].cam_from_plate);
  EXPECT_EQ(back.calib_images[0].exposure.gain, 1.02);
  ExpectPoseEq(back.cam_from_part, truth.cam_from_part);
  EXPECT_EQ(back.part_min_mm, truth.part_min_mm);
  EXPECT_EQ(back.part_max_mm, truth.part_max_mm);
  EXPECT_EQ(back.part_thickness_mm, 12.0);
  EXPECT_EQ(back.table_sigma_mm, 0.02);
  ASSERT_EQ(back.tiles.size(), 1u);
  EXPECT_EQ(back.tiles[0].grid_col, 1);
  EXPECT_EQ(back.tiles[0].commanded_mm, truth.tiles[0].commanded_mm);
  EXPECT_EQ(back.tiles[0].actual_mm, truth.tiles[0].actual_mm);
  EXPECT_EQ(back.tiles[0].exposure.vignetting, 0.3);
  ASSERT_EQ(back.holes.size(), 1u);
  EXPECT_EQ(back.holes[0].center_part_mm, truth.holes[0].center_part_mm);
  EXPECT_EQ(back.holes[0].diameter_mm, truth.holes[0].diameter_mm);
  ASSERT_EQ(back.markers.size(), 1u);
  EXPECT_EQ(back.markers[0].id, 586);
  EXPECT_EQ(back.markers[0].corners_part_mm, truth.markers[0].corners_part_mm);
  ASSERT_TRUE(back.part_from_plate.has_value());
  ExpectPoseEq(*back.part_from_plate, *truth.part_from_plate);
  ASSERT_EQ(back.measurements.size(), 1u);
  EXPECT_EQ(back.measurements[0].value_mm, truth.measurements[0].value_mm);
}

TEST(TruthJson, AbsentPlateOnPartStaysAbsent) {
  SimulationTruth truth = SomeTruth();
  truth.part_from_plate.reset();
  EXPECT_FALSE(TruthFromJson(TruthToJson(truth), "t.json").part_from_plate.has_value());
}

TEST(TruthJson, MalformedInputNamesTheKey) {
  std::string text = TruthToJson(SomeTruth());
  const std::string key = "\"thickness_mm\": 12.0";
  const size_t at = text.find(key);
  ASSERT_NE(at, std::string::npos);
  text.replace(at, key.size(), "\"thickness_mm\": \"thick\"");
  try {
    TruthFromJson(text, "t.json");
    FAIL() << "expected an InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("part.thickness_mm"), std::string::npos) << e.what();
  }
  EXPECT_THROW(TruthFromJson("{", "t.json"), InputError);
  EXPECT_THROW(TruthFromJson("{\"format\": \"omm-truth/2\"}", "t.json"), InputError);
}

}  // namespace
}  // namespace omm
