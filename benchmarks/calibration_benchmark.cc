// Calibration of the simulated demo (seed 1, 1600 x 1200, ~18 usable caltab
// images): omm's calibration stage against OpenCV's pipeline, on 2 threads
// each.
//
// - omm: RunCalibration (pipeline/calibration/calibrate_stage.h), the stage
//   as `omm calibrate` runs it on the images in memory: plate detection, mrcal
//   solves with the perspective-bias rounds and the lens-model choice, and
//   the projection uncertainty.
// - OpenCV: findCirclesGrid (2 threads) + calibrateCamera, 5 and 8 distortions.
// Accuracy: ProjectionDiffRms (adapters/mrcal/projection_diff.h) between the
// calibrated and the true camera at the 390 mm working distance, rigid
// transform fitted, reported as the counter diff_px.
//
// The project comes from the tests' render cache (tests/sim_cache.h).
#include <filesystem>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

#include "adapters/mrcal/projection_diff.h"
#include "adapters/opencv/image_io.h"
#include "adapters/opencv/opencv_calibration.h"
#include "adapters/project_io/project_reader.h"
#include "pipeline/calibration/calibrate_stage.h"
#include "pipeline/core/timing.h"
#include "tests/sim_cache.h"

namespace omm {
namespace {

constexpr double kWorkingDistanceMm = 390.0;
constexpr int kThreads = 2;

struct Demo {
  SimulationTruth truth;
  Project project;
  std::vector<NamedImage> images;
  std::vector<GrayImage> pixels;  // OpenCV's input: the same images
  std::vector<std::string> names;
};

const Demo& GetDemo() {
  static const Demo demo = [] {
    const testing::CachedProject cached = testing::SimulatedProject("demo", 1);
    Demo d;
    d.truth = cached.truth;
    d.project = LoadProject(cached.project_dir);
    for (const std::filesystem::path& path : d.project.calib_images) {
      d.images.push_back({path.filename().string(), ReadGrayImage(path)});
      d.pixels.push_back(d.images.back().image);
      d.names.push_back(d.images.back().name);
    }
    return d;
  }();
  return demo;
}

void BM_OmmCalibrationStage(benchmark::State& state) {
  const Demo& demo = GetDemo();
  CalibrationStageOptions options;
  options.num_threads = kThreads;
  CalibrationStageSummary out;
  double cpu_s = 0.0;
  for (auto _ : state) {
    const double cpu0 = ProcessCpuSeconds();
    out = RunCalibration(demo.images, *demo.project.board, demo.project.camera, options);
    cpu_s += ProcessCpuSeconds() - cpu0;
  }
  state.counters["cpu_s"] = cpu_s / static_cast<double>(state.iterations());
  if (!out.usable) {
    state.SkipWithError(out.brief.c_str());
    return;
  }
  state.counters["detect_s"] = out.detection_seconds;
  state.counters["lens_choice_s"] = out.lens_choice_seconds;
  state.counters["total_s"] = out.total_seconds;
  state.counters["images"] = static_cast<double>(out.result.per_image.size());
  state.counters["rms_px"] = out.result.rms_px;
  state.counters["diff_px"] =
      ProjectionDiffRms(out.result.camera, demo.truth.camera.model, kWorkingDistanceMm);
  state.SetLabel(out.result.camera.lens_model);
}

void BM_OpenCvFindCirclesGridAndCalibrate(benchmark::State& state) {
  const Demo& demo = GetDemo();
  OpenCvCalibrationOptions options;
  options.rational_model = state.range(0) != 0;
  options.num_threads = kThreads;
  OpenCvCalibration out;
  double cpu_s = 0.0;
  for (auto _ : state) {
    const double cpu0 = ProcessCpuSeconds();
    out = OpenCvCalibrate(demo.pixels, demo.names, *demo.project.board, options);
    cpu_s += ProcessCpuSeconds() - cpu0;
  }
  state.counters["cpu_s"] = cpu_s / static_cast<double>(state.iterations());
  if (!out.usable) {
    state.SkipWithError(out.brief.c_str());
    return;
  }
  int used = 0;
  for (const OpenCvImageStatus& status : out.per_image) used += status.used;
  state.counters["detect_s"] = out.detection_seconds;
  state.counters["solve_s"] = out.solve_seconds;
  state.counters["images"] = used;
  state.counters["rms_px"] = out.rms_px;
  state.counters["diff_px"] = ProjectionDiffRms(out.camera, demo.truth.camera.model, kWorkingDistanceMm);
  state.SetLabel(out.camera.lens_model);
}

BENCHMARK(BM_OmmCalibrationStage)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(3);
BENCHMARK(BM_OpenCvFindCirclesGridAndCalibrate)
    ->Arg(0)
    ->Arg(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(3);

}  // namespace
}  // namespace omm

BENCHMARK_MAIN();
