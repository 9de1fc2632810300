// Simulated projects rendered once per build tree and shared by every test
// process: $build/sim-cache/<preset>-<seed>/{project/, truth.json}.
//
// Rendering takes ~10 s CPU per project, so tests that need one call
// SimulatedProject(): the first caller renders into a temporary directory and
// renames it into place under an exclusive lock (flock on <name>.lock), so
// parallel ctest processes neither render twice nor see a half-written
// project. The cached project is read-only by convention: a test that runs
// `omm` on it copies it first (CopyProject).
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>

#include "pipeline/core/board.h"
#include "pipeline/core/truth.h"

namespace omm::testing {

struct CachedProject {
  std::filesystem::path project_dir;
  std::filesystem::path truth_path;
  SimulationTruth truth;
};

// Renders (or finds) the project of `preset` and `seed` with the simulator's
// defaults, or with num_calib_images calib/ images if given and not the
// default (cached apart, as <preset>-<seed>-calib<N>), with the plate on the
// part if asked (a -plate suffix; the demo preset always has it), and on a
// grid of cols x rows tiles (a -g<cols>x<rows> suffix unless 3 x 3), with a
// calibration plate of another board than the caltab if asked (a -circles or
// -chessboard suffix, SimulatedBoard). Fails the calling test (ADD_FAILURE)
// and throws if rendering fails.
struct TileGrid {
  int cols = 3, rows = 3;
};
CachedProject SimulatedProject(const std::string& preset, std::uint64_t seed,
                               std::optional<int> num_calib_images = std::nullopt,
                               bool plate_on_part = false, TileGrid grid = {},
                               BoardType board = BoardType::kCaltab);

// For a test that reads a project's tiles, table.csv and truth but not its
// calib/ images: any cached render of `preset` and `seed` on the default grid
// and board without a plate on the part serves, whatever its calib/ count
// (that count changes nothing else, PlanSimulation's streams); with none
// cached, it renders the fewest calib/ images (3).
CachedProject SimulatedTiles(const std::string& preset, std::uint64_t seed);

// For a test that reads a project's calib/ images and truth camera but not
// its tiles: any cached render of `preset`, `seed`, that calib/ count and
// board without a plate on the part serves, whatever its tile grid (the grid
// changes nothing of calib/); with none cached, it renders the fewest tiles
// (2 x 1).
CachedProject SimulatedCalibration(const std::string& preset, std::uint64_t seed,
                                   std::optional<int> num_calib_images = std::nullopt,
                                   BoardType board = BoardType::kCaltab);

// Copies a project's inputs (everything but out/) into `to` (created).
void CopyProject(const std::filesystem::path& from, const std::filesystem::path& to);

}  // namespace omm::testing
