// RegisterTiles on the simulated demo's nine 1600 x 1200 tiles (seed 1, the
// truth camera), on 2 threads: features, matching and the planar bundle
// adjustment, timed per step (counters, seconds) beside the process CPU time.
// Beside it, the planar adjustment alone at the real problem's size (3000
// synthetic tracks on nine tiles): solve and covariance.
//
// The tiles come from the tests' render cache (tests/sim_cache.h:
// build/sim-cache/demo-1, rendered on first use).
#include <vector>

#include <benchmark/benchmark.h>

#include "adapters/opencv/image_io.h"
#include "pipeline/core/timing.h"
#include "pipeline/mosaic/plane_adjustment.h"
#include "pipeline/mosaic/register_tiles.h"
#include "pipeline/mosaic/synthetic_plane.h"
#include "tests/sim_cache.h"

namespace omm {
namespace {

// The demo project (seed 1) from the tests' render cache (tests/sim_cache.h).
struct DemoTiles {
  SimulationTruth truth;
  std::vector<ImageF> tiles;
  std::vector<Eigen::Vector2d> commanded_mm;
};

const DemoTiles& GetDemoTiles() {
  static const DemoTiles demo = [] {
    const testing::CachedProject cached = testing::SimulatedProject("demo", 1);
    DemoTiles d;
    d.truth = cached.truth;
    for (const TileTruth& tile : d.truth.tiles) {
      d.tiles.push_back(ReadGrayImage(cached.project_dir / "tiles" / tile.image).pixels);
      d.commanded_mm.push_back(tile.commanded_mm);
    }
    return d;
  }();
  return demo;
}


void BM_RegisterTilesDemo(benchmark::State& state) {
  const DemoTiles& demo = GetDemoTiles();
  RegisterTilesOptions options;
  options.num_threads = 2;
  options.bundle.num_threads = 2;
  double features = 0, matching = 0, adjustment = 0, cpu = 0, rms = 0;
  for (auto _ : state) {
    const double cpu0 = ProcessCpuSeconds();
    const TileRegistration reg = RegisterTiles(
        demo.tiles, demo.commanded_mm, demo.truth.table_sigma_mm, demo.truth.camera.model, options);
    cpu += ProcessCpuSeconds() - cpu0;
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

void BM_PlaneAdjustment3000Tracks(benchmark::State& state) {
  SyntheticPlaneOptions options;
  options.num_tracks = 3000;
  const SyntheticPlane s = MakeSyntheticPlane(options);
  double solve = 0, covariance = 0;
  for (auto _ : state) {
    const PlaneAdjustment a = AdjustPlaneScene(s.camera, s.input, {}, PlaneBundleOptions{});
    if (!a.summary.usable) state.SkipWithError(a.summary.brief.c_str());
    solve += a.summary.solve_seconds;
    covariance += a.summary.covariance_seconds;
  }
  const double n = static_cast<double>(state.iterations());
  state.counters["solve_s"] = solve / n;
  state.counters["covariance_s"] = covariance / n;
  state.counters["observations"] = static_cast<double>(s.input.observations.size());
}

BENCHMARK(BM_PlaneAdjustment3000Tracks)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(3);

}  // namespace
}  // namespace omm

BENCHMARK_MAIN();
