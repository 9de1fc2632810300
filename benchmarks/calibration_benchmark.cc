// Calibration of the simulated demo (seed 1, 1600 x 1200, ~18 usable caltab
// images): omm's stage against OpenCV's pipeline, on 2 threads each.
//
// - omm: DetectPlate on every image (2 threads), CalibrateCamera with the
//   project's lens model (LENSMODEL_OPENCV8), one perspective-bias correction
//   from that solve's camera and poses, and a re-solve.
// - OpenCV: findCirclesGrid (2 threads) + calibrateCamera, 5 and 8 distortions.
// Accuracy: ProjectionDiffRms (adapters/mrcal/projection_diff.h) between the
// calibrated and the true camera at the 390 mm working distance, rigid
// transform fitted, reported as the counter diff_px.
//
// The images are rendered once (~30 s) and cached as PNG in
// $OMM_BENCHMARK_CACHE (default /tmp/omm_benchmark_cache); the 8-bit images
// are exact in PNG. Delete the cache after changing the simulator.
#include <atomic>
#include <memory>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include <benchmark/benchmark.h>

#include "adapters/mrcal/calibrate.h"
#include "adapters/mrcal/projection_diff.h"
#include "adapters/opencv/image_io.h"
#include "adapters/opencv/opencv_calibration.h"
#include "adapters/opencv/plate_detector.h"
#include "pipeline/calibration/perspective_bias.h"
#include "pipeline/simulate/simulation.h"

namespace omm {
namespace {

constexpr double kWorkingDistanceMm = 390.0;
constexpr int kThreads = 2;

struct Demo {
  SimulationPlan plan;
  std::vector<GrayImage> images;
  std::vector<std::string> names;
};

const Demo& GetDemo() {
  static const Demo demo = [] {
    Demo d;
    SimulationOptions options;
    options.seed = 1;
    options.preset = "demo";
    d.plan = PlanSimulation(options);
    const char* env = std::getenv("OMM_BENCHMARK_CACHE");
    const std::filesystem::path dir =
        std::filesystem::path(env ? env : "/tmp/omm_benchmark_cache") / "demo_seed1";
    std::filesystem::create_directories(dir);
    const CameraModel& camera = d.plan.truth.camera.model;
    std::unique_ptr<RayTable> rays;
    std::unique_ptr<ProjectRenderer> renderer;
    for (size_t i = 0; i < d.plan.truth.calib_images.size(); ++i) {
      const std::string& name = d.plan.truth.calib_images[i].image;
      const std::filesystem::path path = dir / name;
      if (!std::filesystem::exists(path)) {
        if (!rays) {
          RayTableSummary summary;
          rays = std::make_unique<RayTable>(ComputeRayTable(
              camera, PixelRect{0, 0, camera.width_px, camera.height_px}, RayOptionsFor(d.plan.options), &summary));
          renderer = std::make_unique<ProjectRenderer>(d.plan);
        }
        WriteGrayImage(path, renderer->RenderCalibImage(static_cast<int>(i), *rays), d.plan.sensor.bit_depth);
      }
      d.images.push_back(ReadGrayImage(path));
      d.names.push_back(name);
    }
    return d;
  }();
  return demo;
}

// CPU time of the whole process (all threads), s: on a shared machine the
// wall time also counts other processes' load; the CPU time does not.
double ProcessCpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

struct OursResult {
  CalibrationResult result;
  double detect_s = 0.0, solve_s = 0.0, correct_s = 0.0, resolve_s = 0.0;
};

OursResult RunOurs(const Demo& demo) {
  OursResult out;
  const BoardSpec& board = demo.plan.truth.board;
  auto t0 = std::chrono::steady_clock::now();
  std::vector<PlateObservation> observations(demo.images.size());
  std::atomic<size_t> next{0};
  auto worker = [&] {
    for (size_t i = next++; i < demo.images.size(); i = next++) {
      observations[i] = DetectPlate(demo.images[i], board);
      observations[i].image = demo.names[i];
    }
  };
  std::thread helper(worker);
  worker();
  helper.join();
  out.detect_s = Seconds(t0);

  CalibrationOptions options;
  options.lens_model = demo.plan.project.camera.lens_model.value_or("LENSMODEL_OPENCV8");
  options.focal_length_mm = demo.plan.project.camera.focal_length_mm;
  options.pixel_pitch_um = demo.plan.project.camera.pixel_pitch_um;
  options.width_px = demo.plan.truth.camera.model.width_px;
  options.height_px = demo.plan.truth.camera.model.height_px;
  t0 = std::chrono::steady_clock::now();
  const CalibrationResult first = CalibrateCamera(board, observations, options);
  out.solve_s = Seconds(t0);

  t0 = std::chrono::steady_clock::now();
  std::vector<PlateObservation> corrected = observations;
  size_t used = 0;
  for (PlateObservation& o : corrected) {
    if (!o.usable) continue;
    o = CorrectPerspectiveBias(o, board, first.camera, first.cam_from_plate[used++]);
  }
  out.correct_s = Seconds(t0);
  t0 = std::chrono::steady_clock::now();
  out.result = CalibrateCamera(board, corrected, options);
  out.resolve_s = Seconds(t0);
  return out;
}

void BM_OmmDetectAndCalibrate(benchmark::State& state) {
  const Demo& demo = GetDemo();
  OursResult out;
  double cpu_s = 0.0;
  for (auto _ : state) {
    const double cpu0 = ProcessCpuSeconds();
    out = RunOurs(demo);
    cpu_s += ProcessCpuSeconds() - cpu0;
  }
  state.counters["cpu_s"] = cpu_s / static_cast<double>(state.iterations());
  if (!out.result.usable) {
    state.SkipWithError(out.result.brief.c_str());
    return;
  }
  state.counters["detect_s"] = out.detect_s;
  state.counters["solve_s"] = out.solve_s;
  state.counters["bias_s"] = out.correct_s;
  state.counters["resolve_s"] = out.resolve_s;
  state.counters["images"] = static_cast<double>(out.result.per_image.size());
  state.counters["rms_px"] = out.result.rms_px;
  state.counters["diff_px"] =
      ProjectionDiffRms(out.result.camera, demo.plan.truth.camera.model, kWorkingDistanceMm);
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
    out = OpenCvCalibrate(demo.images, demo.names, demo.plan.truth.board, options);
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
  state.counters["diff_px"] = ProjectionDiffRms(out.camera, demo.plan.truth.camera.model, kWorkingDistanceMm);
  state.SetLabel(out.camera.lens_model);
}

BENCHMARK(BM_OmmDetectAndCalibrate)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(3);
BENCHMARK(BM_OpenCvFindCirclesGridAndCalibrate)
    ->Arg(0)
    ->Arg(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(3);

}  // namespace
}  // namespace omm

BENCHMARK_MAIN();
