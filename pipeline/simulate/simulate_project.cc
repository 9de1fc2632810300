#include "pipeline/simulate/simulate_project.h"

#include <chrono>
#include <future>
#include <system_error>

#include <fmt/format.h>

#include "adapters/opencv/image_io.h"
#include "adapters/project_io/project_writer.h"
#include "adapters/project_io/truth_json.h"
#include "pipeline/core/error.h"

namespace omm {

std::filesystem::path DefaultTruthPath(const std::filesystem::path& project_dir) {
  std::filesystem::path dir = project_dir;
  if (!dir.has_filename()) dir = dir.parent_path();  // "out/" -> "out"
  dir += ".truth.json";
  return dir;
}

SimulationSummary SimulateProjectDirectory(const SimulationOptions& options,
                                           const std::filesystem::path& project_dir,
                                           const std::filesystem::path& truth_path,
                                           const ProgressCallback& progress) {
  const auto start = std::chrono::steady_clock::now();
  if (const std::string problem = options.Check(); !problem.empty()) {
    throw InputError("simulate options", problem);
  }
  std::error_code ec;
  if (std::filesystem::exists(project_dir, ec) && !std::filesystem::is_empty(project_dir, ec)) {
    throw InputError(project_dir.string(), "exists and is not empty; choose a new directory");
  }
  const std::filesystem::path dir = std::filesystem::absolute(project_dir);
  for (const char* sub : {"calib", "tiles"}) {
    std::filesystem::create_directories(dir / sub, ec);
    if (ec) throw InputError((dir / sub).string(), "cannot create directory: " + ec.message());
  }

  SimulationPlan plan = PlanSimulation(options);
  const SimulationTruth& truth = plan.truth;
  const int num_calib = static_cast<int>(truth.calib_images.size());
  const int num_tiles = static_cast<int>(truth.tiles.size());
  const int total = num_calib + num_tiles + 1;
  if (progress) progress(0, total, "computing the camera's rays");
  RayTableSummary ray_summary;
  const CameraModel& camera = truth.camera.model;
  const RayTable rays = ComputeRayTable(camera, {0, 0, camera.width_px, camera.height_px},
                                        RayOptionsFor(options), &ray_summary);
  // The truth camera is ours: a failure here is a bug, not the user's.
  if (!ray_summary.ok) throw std::logic_error("simulate: the truth lens model does not unproject");

  const ProjectRenderer renderer(plan);
  // Each image is encoded and written while the next one renders.
  std::future<void> writing;
  auto write = [&](const std::filesystem::path& path, ImageF image) {
    if (writing.valid()) writing.get();
    writing = std::async(std::launch::async,
                         [path, image = std::move(image), bits = plan.sensor.bit_depth] {
                           WriteGrayImage(path, image, bits);
                         });
  };
  int done = 1;
  for (int i = 0; i < num_calib; ++i) {
    const std::string name = truth.calib_images[i].image;
    if (progress) progress(done, total, "rendering calib/" + name);
    write(dir / "calib" / name, renderer.RenderCalibImage(i, rays));
    plan.project.calib_images.push_back(dir / "calib" / name);
    ++done;
  }
  for (int i = 0; i < num_tiles; ++i) {
    const std::string name = truth.tiles[i].image;
    if (progress) progress(done, total, "rendering tiles/" + name);
    write(dir / "tiles" / name, renderer.RenderTile(i, rays));
    ++done;
  }
  if (writing.valid()) writing.get();
  plan.project.dir = dir;
  WriteProjectFiles(plan.project);
  WriteTruthJson(truth, truth_path);
  if (progress) progress(total, total, "done");

  SimulationSummary summary;
  summary.num_calib_images = num_calib;
  summary.num_tiles = num_tiles;
  summary.num_rays = ray_summary.num_rays;
  summary.max_ray_residual_px = ray_summary.max_residual_px;
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  summary.brief = fmt::format(
      "simulated '{}' seed {}: {} calib images, {} tiles, a table of {} rays "
      "(max ray error {:.1e} px) in {:.1f} s",
      options.preset, options.seed, num_calib, num_tiles, summary.num_rays,
      summary.max_ray_residual_px, summary.seconds);
  return summary;
}

}  // namespace omm
