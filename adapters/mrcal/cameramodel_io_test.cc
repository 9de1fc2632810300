#include "adapters/mrcal/cameramodel_io.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <iterator>
#include <string>

#include <nlohmann/json.hpp>

#include "adapters/mrcal/lens.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

namespace fs = std::filesystem;

CameraModel Camera() {
  CameraModel camera;
  camera.lens_model = "LENSMODEL_OPENCV8";
  camera.intrinsics.resize(12);
  camera.intrinsics << 2667.125, 2665.5, 815.3, 588.7, -0.12, 0.09, 0.0004, -0.0003, 0.01, 0.002,
      -0.001, 0.003;
  camera.width_px = 1600;
  camera.height_px = 1200;
  camera.valid_region_px.resize(2, 4);
  camera.valid_region_px << 140.25, 1460.5, 1400.0, 160.0, 120.0, 110.75, 1080.0, 1090.125;
  return camera;
}

fs::path TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("omm_" + name + "_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  return dir;
}

TEST(CameraModelIo, WriteReadRoundTrip) {
  const fs::path dir = TempDir("cameramodel_rt");
  const CameraModel camera = Camera();
  WriteCameraModel(dir / "camera.cameramodel", camera);
  const CameraModel back = ReadCameraModel(dir / "camera.cameramodel");
  EXPECT_EQ(back.lens_model, camera.lens_model);
  EXPECT_EQ(back.width_px, camera.width_px);
  EXPECT_EQ(back.height_px, camera.height_px);
  // mrcal writes the intrinsics in text; allow the last digits.
  EXPECT_LT((back.intrinsics - camera.intrinsics).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_EQ(back.valid_region_px, camera.valid_region_px);
  // Without a region the file has none, and reads back without one.
  CameraModel bare = Camera();
  bare.valid_region_px.resize(2, 0);
  WriteCameraModel(dir / "bare.cameramodel", bare);
  EXPECT_EQ(ReadCameraModel(dir / "bare.cameramodel").valid_region_px.cols(), 0);
  fs::remove_all(dir);
}

TEST(CameraModelIo, BadFileThrowsNamingIt) {
  const fs::path dir = TempDir("cameramodel_bad");
  std::ofstream(dir / "broken.cameramodel") << "{ 'lensmodel': 'LENSMODEL_NOPE' }\n";
  try {
    ReadCameraModel(dir / "broken.cameramodel");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.where(), (dir / "broken.cameramodel").string());
  }
  EXPECT_THROW(ReadCameraModel(dir / "missing.cameramodel"), InputError);
  CameraModel wrong = Camera();
  wrong.intrinsics.conservativeResize(8);
  EXPECT_THROW(WriteCameraModel(dir / "wrong.cameramodel", wrong), InputError);
  // A region that is not a polygon.
  WriteCameraModel(dir / "region.cameramodel", Camera());
  std::ifstream in(dir / "region.cameramodel");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t key = text.find("'valid_intrinsics_region'");
  ASSERT_NE(key, std::string::npos);
  text = text.substr(0, key) + "'valid_intrinsics_region': [ [ 1, 2 ], [ 3 ] ]\n}\n";
  std::ofstream(dir / "region.cameramodel") << text;
  EXPECT_THROW(ReadCameraModel(dir / "region.cameramodel"), InputError);
  fs::remove_all(dir);
}

// python3-mrcal loads what we wrote, projects exactly as we do and reads our
// valid_intrinsics_region (closed, as mrcal writes it).
TEST(CameraModelIo, PythonMrcalProjectsLikeUs) {
  const fs::path dir = TempDir("cameramodel_py");
  const CameraModel camera = Camera();
  WriteCameraModel(dir / "camera.cameramodel", camera);
  Eigen::Matrix3Xd p(3, 5);
  p << 0.0, 110.0, -120.0, 95.0, -3.5, 0.0, 85.0, -90.0, -70.0, 1.25, 390.0, 380.0, 400.0,
      395.0, 391.0;
  nlohmann::json points;
  for (int i = 0; i < p.cols(); ++i) points["p_cam"].push_back({p(0, i), p(1, i), p(2, i)});
  std::ofstream(dir / "points.json") << points.dump();
  const std::string script =
      std::string(std::getenv("OMM_SOURCE_DIR")) + "/adapters/mrcal/testdata/project_with_mrcal.py";
  const std::string command = "/usr/bin/python3 " + script + " " +
                              (dir / "camera.cameramodel").string() + " " +
                              (dir / "points.json").string() + " " + (dir / "q.json").string();
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  const nlohmann::json out = nlohmann::json::parse(std::ifstream(dir / "q.json"));
  EXPECT_EQ(out["lens_model"], camera.lens_model);
  EXPECT_EQ(out["imagersize"][0], 1600);
  const nlohmann::json& region = out["valid_intrinsics_region"];
  ASSERT_EQ(region.size(), camera.valid_region_px.cols() + 1u);
  for (size_t i = 0; i < region.size(); ++i) {
    const auto v = static_cast<Eigen::Index>(i % camera.valid_region_px.cols());
    EXPECT_EQ(region[i][0].get<double>(), camera.valid_region_px(0, v));
    EXPECT_EQ(region[i][1].get<double>(), camera.valid_region_px(1, v));
  }
  Eigen::Matrix2Xd q;
  ASSERT_TRUE(ProjectPoints(camera, p, &q));
  for (int i = 0; i < p.cols(); ++i) {
    EXPECT_NEAR(out["q_px"][i][0].get<double>(), q(0, i), 1e-6);
    EXPECT_NEAR(out["q_px"][i][1].get<double>(), q(1, i), 1e-6);
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace omm
