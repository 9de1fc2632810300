#include "adapters/project_io/scene_json.h"

#include <gtest/gtest.h>

#include "pipeline/core/error.h"

namespace omm {
namespace {

SavedScene Example() {
  SavedScene saved;
  PlaneScene& scene = saved.scene;
  scene.cam_from_part_r = {3.1, 0.01, -0.02};
  scene.cam_from_part_t_mm = {0.0, 0.0, 390.123456789012};
  scene.table_pos_mm = {{0.1, -0.2}, {100.0 / 3.0, 1e-7}};
  scene.plates.push_back({1.0, 2.0, 0.3, 0.0, 1.0001});
  scene.intrinsics = Eigen::VectorXd::LinSpaced(4, 1.0, 2.0);
  const int n = PlaneSceneCovarianceSize(2, 1, 4);
  const Eigen::MatrixXd a = Eigen::MatrixXd::Random(n, n);
  scene.covariance = a * a.transpose();
  saved.tile_images = {"a.png", "b.png"};
  saved.commanded_table_pos_mm = {{0.0, 0.0}, {33.3, 0.0}};
  saved.tiles_held_by_prior = {1};
  saved.tiles_without_table_prior = {0};
  saved.table_sigma_mm = 0.02;
  saved.rms_px = 0.031;
  saved.lens_model = "LENSMODEL_OPENCV4";
  saved.intrinsics_refined = true;
  const Eigen::MatrixXd b = Eigen::MatrixXd::Random(4, 4);
  saved.intrinsics_information = b * b.transpose();
  return saved;
}

// Written and read back, every double comes back bit-identical.
TEST(SceneJson, RoundTripIsExact) {
  const SavedScene saved = Example();
  const SavedScene back = SceneFromJson(SceneToJson(saved), "test");
  EXPECT_EQ(back.scene.cam_from_part_r, saved.scene.cam_from_part_r);
  EXPECT_EQ(back.scene.cam_from_part_t_mm, saved.scene.cam_from_part_t_mm);
  EXPECT_EQ(back.scene.table_pos_mm, saved.scene.table_pos_mm);
  ASSERT_EQ(back.scene.plates.size(), 1u);
  EXPECT_EQ(back.scene.plates[0].scale, saved.scene.plates[0].scale);
  EXPECT_EQ(back.scene.intrinsics, saved.scene.intrinsics);
  EXPECT_EQ(back.scene.covariance, saved.scene.covariance);
  EXPECT_EQ(back.tile_images, saved.tile_images);
  EXPECT_EQ(back.commanded_table_pos_mm, saved.commanded_table_pos_mm);
  EXPECT_EQ(back.tiles_held_by_prior, saved.tiles_held_by_prior);
  EXPECT_EQ(back.tiles_without_table_prior, saved.tiles_without_table_prior);
  EXPECT_EQ(back.table_sigma_mm, saved.table_sigma_mm);
  EXPECT_EQ(back.rms_px, saved.rms_px);
  EXPECT_EQ(back.lens_model, saved.lens_model);
  EXPECT_EQ(back.intrinsics_refined, saved.intrinsics_refined);
  EXPECT_EQ(back.intrinsics_information, saved.intrinsics_information);
}

// A file from before lens_model, intrinsics_refined and table_prior_used:
// the intrinsics were held, every table prior used.
TEST(SceneJson, OlderFilesHeldTheIntrinsicsAndUsedEveryTablePrior) {
  std::string text = SceneToJson(Example());
  for (const std::string key :
       {"\"lens_model\": \"LENSMODEL_OPENCV4\",", "\"intrinsics_refined\": true,",
        ",\n      \"table_prior_used\": false", ",\n      \"table_prior_used\": true"}) {
    const size_t at = text.find(key);
    ASSERT_NE(at, std::string::npos) << key;
    text.erase(at, key.size());
  }
  const SavedScene back = SceneFromJson(text, "test");
  EXPECT_EQ(back.lens_model, "");
  EXPECT_FALSE(back.intrinsics_refined);
  EXPECT_TRUE(back.tiles_without_table_prior.empty());
}

TEST(SceneJson, NoCovarianceIsNull) {
  SavedScene saved = Example();
  saved.scene.covariance.resize(0, 0);
  EXPECT_EQ(SceneFromJson(SceneToJson(saved), "test").scene.covariance.size(), 0);
}

// Refined intrinsics need the prior they were refined under (the measure
// stage's sigma breakdown reads it): a file without it says to rerun.
TEST(SceneJson, RefinedIntrinsicsNeedTheirPriorsInformation) {
  std::string text = SceneToJson(Example());
  const size_t at = text.find("\"intrinsics_information\"");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, 24, "\"intrinsics_informatioX\"");
  try {
    SceneFromJson(text, "scene.json");
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("intrinsics_information"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("omm mosaic"), std::string::npos) << e.what();
  }
}

TEST(SceneJson, MalformedInputNamesTheKey) {
  std::string text = SceneToJson(Example());
  text.replace(text.find("\"adjusted_mm\""), 13, "\"adjusted_xx\"");
  try {
    SceneFromJson(text, "scene.json");
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("tiles[0].adjusted_mm"), std::string::npos) << e.what();
  }
  EXPECT_THROW(SceneFromJson("{", "scene.json"), InputError);
}

}  // namespace
}  // namespace omm
