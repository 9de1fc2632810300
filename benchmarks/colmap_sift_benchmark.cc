// COLMAP's SIFT (adapters/colmap/colmap_sift.h, `--features sift`) on the
// simulated demo's nine 1600 x 1200 tiles (seed 1), the 20 pairs of grid
// neighbours (diagonals too) matched, on 2 threads: extraction and matching
// timed (counters, seconds) with SiftExtraction.first_octave at COLMAP's
// default -1 (the image doubled first) and at omm's 0
// (ColmapSiftOptions::first_octave), with the keypoints and verified
// matches each gives. Runs the installed `colmap`.
//
// The tiles come from the tests' render cache (tests/sim_cache.h:
// build/sim-cache/demo-1, rendered on first use).
#include <cstdlib>
#include <filesystem>
#include <numeric>
#include <utility>
#include <vector>

#include <benchmark/benchmark.h>

#include "adapters/colmap/colmap_sift.h"
#include "tests/sim_cache.h"

namespace omm {
namespace {

struct DemoTilePaths {
  std::vector<std::filesystem::path> paths;
  std::vector<std::pair<int, int>> neighbours;  // grid neighbours, diagonals included
};

const DemoTilePaths& GetDemoTilePaths() {
  static const DemoTilePaths demo = [] {
    const testing::CachedProject cached = testing::SimulatedProject("demo", 1);
    DemoTilePaths d;
    const std::vector<TileTruth>& tiles = cached.truth.tiles;
    for (const TileTruth& tile : tiles) d.paths.push_back(cached.project_dir / "tiles" / tile.image);
    for (int a = 0; a < static_cast<int>(tiles.size()); ++a) {
      for (int b = a + 1; b < static_cast<int>(tiles.size()); ++b) {
        if (std::abs(tiles[a].grid_row - tiles[b].grid_row) <= 1 &&
            std::abs(tiles[a].grid_col - tiles[b].grid_col) <= 1)
          d.neighbours.emplace_back(a, b);
      }
    }
    return d;
  }();
  return demo;
}

// state.range(0): SiftExtraction.first_octave.
void BM_ColmapSiftDemo(benchmark::State& state) {
  const DemoTilePaths& demo = GetDemoTilePaths();
  ColmapSiftOptions options;
  options.first_octave = static_cast<int>(state.range(0));
  double extraction = 0, matching = 0, keypoints = 0, matches = 0;
  for (auto _ : state) {
    const ColmapSiftResult result = ColmapSiftMatches(demo.paths, options, demo.neighbours);
    if (!result.usable) state.SkipWithError(result.brief.c_str());
    extraction += result.extraction_seconds;
    matching += result.matching_seconds;
    const std::vector<int>& per_tile = result.matches.num_keypoints;
    keypoints = std::accumulate(per_tile.begin(), per_tile.end(), 0.0);
    matches = result.matches.num_matches;
  }
  const double n = static_cast<double>(state.iterations());
  state.counters["extraction_s"] = extraction / n;
  state.counters["matching_s"] = matching / n;
  state.counters["keypoints"] = keypoints;
  state.counters["matches"] = matches;
}

BENCHMARK(BM_ColmapSiftDemo)
    ->ArgName("first_octave")
    ->Arg(-1)
    ->Arg(0)
    ->Unit(benchmark::kSecond)
    ->UseRealTime()
    ->Iterations(1);

}  // namespace
}  // namespace omm

BENCHMARK_MAIN();
