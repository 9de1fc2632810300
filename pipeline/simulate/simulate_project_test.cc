#include "pipeline/simulate/simulate_project.h"

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>

#include <gtest/gtest.h>

#include "adapters/opencv/image_io.h"
#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/truth_json.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

// A fresh directory under the temp dir, removed afterwards.
class ScratchDir {
 public:
  ScratchDir() {
    std::random_device device;
    path_ =
        std::filesystem::temp_directory_path() / ("omm_simulate_test_" + std::to_string(device()));
    std::filesystem::create_directories(path_);
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

// Pixels whose 8-bit digital numbers differ.
int DifferingPixels(const ImageF& a, const ImageF& b) {
  if (a.rows() != b.rows() || a.cols() != b.cols()) return -1;
  return static_cast<int>(((a * 255.0f).array().round() != (b * 255.0f).array().round()).count());
}

TEST(DefaultTruthPath, SitsBesideTheProject) {
  EXPECT_EQ(DefaultTruthPath("/data/run7"), std::filesystem::path("/data/run7.truth.json"));
  EXPECT_EQ(DefaultTruthPath("/data/run7/"), std::filesystem::path("/data/run7.truth.json"));
  EXPECT_EQ(DefaultTruthPath("run7"), std::filesystem::path("run7.truth.json"));
}

TEST(SimulateProjectDirectory, RefusesBadOptionsAndNonEmptyDirectories) {
  const ScratchDir scratch;
  SimulationOptions options;
  options.preset = "no-such-preset";
  EXPECT_THROW(
      SimulateProjectDirectory(options, scratch.path() / "p", scratch.path() / "t.json", nullptr),
      InputError);
  std::ofstream(scratch.path() / "occupied.txt") << "x";
  options.preset = "demo";
  try {
    SimulateProjectDirectory(options, scratch.path(), scratch.path() / "t.json", nullptr);
    FAIL() << "expected an InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("not empty"), std::string::npos) << e.what();
  }
}

// The whole demo project, as `omm simulate` writes it: it loads as a project,
// its truth reads back, its images are exactly what the renderer makes from
// the seed, and it takes well under a minute on two cores.
TEST(SimulateProjectDirectory, WritesALoadableDeterministicProject) {
  const ScratchDir scratch;
  const std::filesystem::path dir = scratch.path() / "demo";
  SimulationOptions options;
  options.preset = "demo";
  options.seed = 3;
  int progress_calls = 0, last_done = -1;
  const auto start = std::chrono::steady_clock::now();
  const std::clock_t cpu_start = std::clock();
  const SimulationSummary summary = SimulateProjectDirectory(
      options, dir, DefaultTruthPath(dir), [&](int done, int total, const std::string&) {
        EXPECT_GE(done, last_done);
        EXPECT_LE(done, total);
        last_done = done;
        ++progress_calls;
      });
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const double cpu = static_cast<double>(std::clock() - cpu_start) / CLOCKS_PER_SEC;
  std::printf("%s\n(wall %.1f s, cpu %.1f s)\n", summary.brief.c_str(), wall, cpu);
  EXPECT_EQ(summary.num_calib_images, 20);
  EXPECT_EQ(summary.num_tiles, 9);
  EXPECT_LT(summary.max_ray_residual_px, 1e-6);
  EXPECT_GE(progress_calls, 29);

  const Project project = LoadProject(dir);
  const SimulationPlan plan = PlanSimulation(options);
  EXPECT_EQ(project.calib_images.size(), 20u);
  EXPECT_EQ(project.tiles.size(), 9u);
  EXPECT_EQ(project.image_width_px, 1600);
  EXPECT_EQ(project.image_height_px, 1200);
  EXPECT_EQ(project.features.size(), plan.truth.holes.size());
  EXPECT_EQ(project.measurements.size(), plan.truth.measurements.size());
  EXPECT_EQ(project.cmm.size(), plan.truth.measurements.size());
  EXPECT_EQ(project.camera.focal_length_mm, 12.0);
  ASSERT_TRUE(project.board.has_value());
  for (size_t i = 0; i < project.tiles.size(); ++i) {
    EXPECT_EQ(project.tiles[i].table_pos_mm, plan.truth.tiles[i].commanded_mm);
  }
  for (size_t i = 0; i < project.features.size(); ++i) {
    EXPECT_EQ(project.features[i].near_px, plan.project.features[i].near_px);
  }
  EXPECT_EQ(TruthToJson(ReadTruthJson(DefaultTruthPath(dir))), TruthToJson(plan.truth));

  // Images: a fresh render from the seed gives the files' pixels exactly.
  const CameraModel& camera = plan.truth.camera.model;
  RayTableSummary ray_summary;
  const RayTable rays = ComputeRayTable(camera, {0, 0, camera.width_px, camera.height_px},
                                        RayOptionsFor(options), &ray_summary);
  const ProjectRenderer renderer(plan);
  const GrayImage calib = ReadGrayImage(dir / "calib" / plan.truth.calib_images[5].image);
  const GrayImage tile = ReadGrayImage(dir / "tiles" / plan.truth.tiles[7].image);
  EXPECT_EQ(calib.bit_depth, 8);
  EXPECT_EQ(DifferingPixels(calib.pixels, renderer.RenderCalibImage(5, rays)), 0);
  EXPECT_EQ(DifferingPixels(tile.pixels, renderer.RenderTile(7, rays)), 0);
}

}  // namespace
}  // namespace omm
