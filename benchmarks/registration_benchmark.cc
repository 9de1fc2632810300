// RegisterTiles on the simulated demo's nine 1600 x 1200 tiles (seed 1, the
// truth camera), on 2 threads: features, matching and the planar bundle
// adjustment, timed per step (counters, seconds) beside the process CPU time.
//
// The tiles are rendered once (~40 s) and cached as 16-bit PNG in
// $OMM_BENCHMARK_CACHE (default /tmp/omm_benchmark_cache)/demo_seed1/tiles;
// delete the cache after changing the simulator.
#include <ctime>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

#include "adapters/opencv/image_io.h"
#include "pipeline/mosaic/register_tiles.h"
#include "pipeline/simulate/simulation.h"

namespace omm {
namespace {

struct DemoTiles {
  SimulationPlan plan;
  std::vector<ImageF> tiles;
  std::vector<Eigen::Vector2d> commanded_mm;
};

const DemoTiles& GetDemoTiles() {
  static const DemoTiles demo = [] {
    DemoTiles d;
    SimulationOptions options;
    options.seed = 1;
    options.preset = "demo";
    d.plan = PlanSimulation(options);
    const char* env = std::getenv("OMM_BENCHMARK_CACHE");
    const std::filesystem::path dir =
        std::filesystem::path(env ? env : "/tmp/omm_benchmark_cache") / "demo_seed1" / "tiles";
    std::filesystem::create_directories(dir);
    const CameraModel& camera = d.plan.truth.camera.model;
    std::unique_ptr<RayTable> rays;
    std::unique_ptr<ProjectRenderer> renderer;
    for (size_t i = 0; i < d.plan.truth.tiles.size(); ++i) {
      const std::filesystem::path path = dir / d.plan.truth.tiles[i].image;
      if (!std::filesystem::exists(path)) {
        if (!rays) {
          RayTableSummary summary;
          rays = std::make_unique<RayTable>(
              ComputeRayTable(camera, PixelRect{0, 0, camera.width_px, camera.height_px},
                              RayOptionsFor(d.plan.options), &summary));
          renderer = std::make_unique<ProjectRenderer>(d.plan);
        }
        WriteGrayImage(path, renderer->RenderTile(static_cast<int>(i), *rays), 16);
      }
      d.tiles.push_back(ReadGrayImage(path).pixels);
      d.commanded_mm.push_back(d.plan.truth.tiles[i].commanded_mm);
    }
    return d;
  }();
  return demo;
}

double CpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

void BM_RegisterTilesDemo(benchmark::State& state) {
  const DemoTiles& demo = GetDemoTiles();
  RegisterTilesOptions options;
  options.num_threads = 2;
  options.bundle.num_threads = 2;
  double features = 0, matching = 0, adjustment = 0, cpu = 0, rms = 0;
  for (auto _ : state) {
    const double cpu0 = CpuSeconds();
    const TileRegistration reg =
        RegisterTiles(demo.tiles, demo.commanded_mm, demo.plan.truth.table_sigma_mm,
                      demo.plan.truth.camera.model, options);
    cpu += CpuSeconds() - cpu0;
    if (!reg.usable) state.SkipWithError(reg.brief.c_str());
    features += reg.features_seconds;
    matching += reg.matching_seconds;
    adjustment += reg.adjustment_seconds;
    rms = reg.rms_px;
  }
  const double n = static_cast<double>(state.iterations());
  state.counters["features_s"] = features / n;
  state.counters["matching_s"] = matching / n;
  state.counters["adjustment_s"] = adjustment / n;
  state.counters["cpu_s"] = cpu / n;
  state.counters["rms_px"] = rms;
}

BENCHMARK(BM_RegisterTilesDemo)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(3);

}  // namespace
}  // namespace omm

BENCHMARK_MAIN();
