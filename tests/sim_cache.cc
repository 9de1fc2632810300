#include "tests/sim_cache.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <regex>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/project_io/truth_json.h"
#include "pipeline/simulate/simulate_project.h"

namespace omm::testing {
namespace {

namespace fs = std::filesystem;

// An exclusive flock held for the object's lifetime.
class FileLock {
 public:
  explicit FileLock(const fs::path& path) : fd_(open(path.c_str(), O_CREAT | O_RDWR, 0644)) {
    if (fd_ < 0 || flock(fd_, LOCK_EX) != 0)
      throw std::runtime_error("cannot lock " + path.string());
  }
  ~FileLock() {
    if (fd_ >= 0) close(fd_);  // closing releases the lock
  }
  FileLock(const FileLock&) = delete;
  FileLock& operator=(const FileLock&) = delete;

 private:
  int fd_;
};

// A finished render in the cache: <dir>/{project/, truth.json}.
CachedProject CachedAt(const fs::path& dir) {
  CachedProject project;
  project.project_dir = dir / "project";
  project.truth_path = dir / "truth.json";
  project.truth = ReadTruthJson(project.truth_path);
  return project;
}

// SimulationOptions::Check's least calib/ count, and the fewest tiles.
constexpr int kFewestCalibImages = 3;
constexpr TileGrid kFewestTiles{2, 1};

// The parts of a cache entry's name: <preset>-<seed><calib><plate><grid><board>.
std::string CalibSuffix(int calib_count) {
  return calib_count == SimulationOptions{}.num_calib_images
             ? ""
             : "-calib" + std::to_string(calib_count);
}
std::string GridSuffix(TileGrid grid) {
  return grid.cols == 3 && grid.rows == 3
             ? ""
             : "-g" + std::to_string(grid.cols) + "x" + std::to_string(grid.rows);
}
std::string BoardSuffix(BoardType board) {
  return board == BoardType::kCaltab ? "" : std::string("-") + BoardTypeName(board);
}

// The first (by name) finished render whose name matches `pattern`.
// Renders in progress are <name>.tmp-<pid>, renamed into place when done.
std::optional<CachedProject> FindCached(const std::regex& pattern) {
  const fs::path cache = OMM_SIM_CACHE_DIR;
  std::vector<fs::path> cached;
  if (fs::is_directory(cache)) {
    for (const fs::directory_entry& entry : fs::directory_iterator(cache)) {
      if (std::regex_match(entry.path().filename().string(), pattern))
        cached.push_back(entry.path());
    }
  }
  if (cached.empty()) return std::nullopt;
  return CachedAt(*std::min_element(cached.begin(), cached.end()));
}

}  // namespace

CachedProject SimulatedProject(const std::string& preset, std::uint64_t seed,
                               std::optional<int> num_calib_images, bool plate_on_part,
                               TileGrid grid, BoardType board) {
  const fs::path cache = OMM_SIM_CACHE_DIR;
  fs::create_directories(cache);
  // The default count asked for by number is the same project: one render.
  const int calib_count = num_calib_images.value_or(SimulationOptions{}.num_calib_images);
  const std::string name = preset + "-" + std::to_string(seed) + CalibSuffix(calib_count) +
                           (plate_on_part ? "-plate" : "") + GridSuffix(grid) + BoardSuffix(board);
  const fs::path final_dir = cache / name;
  {
    FileLock lock(cache / (name + ".lock"));
    if (!fs::exists(final_dir)) {
      const fs::path temp = cache / (name + ".tmp-" + std::to_string(getpid()));
      fs::remove_all(temp);
      fs::create_directories(temp);
      SimulationOptions options;
      options.preset = preset;
      options.seed = seed;
      options.num_calib_images = calib_count;
      options.plate_on_part = plate_on_part;
      options.grid_cols = grid.cols;
      options.grid_rows = grid.rows;
      options.board = board;
      try {
        SimulateProjectDirectory(options, temp / "project", temp / "truth.json", {});
      } catch (const std::exception& e) {
        fs::remove_all(temp);
        ADD_FAILURE() << "rendering " << name << " failed: " << e.what();
        throw;
      }
      fs::rename(temp, final_dir);
    }
  }
  return CachedAt(final_dir);
}

CachedProject SimulatedTiles(const std::string& preset, std::uint64_t seed) {
  const std::regex any_calib_count(preset + "-" + std::to_string(seed) + "(-calib[0-9]+)?");
  if (std::optional<CachedProject> cached = FindCached(any_calib_count)) return *cached;
  return SimulatedProject(preset, seed, kFewestCalibImages);
}

CachedProject SimulatedCalibration(const std::string& preset, std::uint64_t seed,
                                   std::optional<int> num_calib_images, BoardType board) {
  const int calib_count = num_calib_images.value_or(SimulationOptions{}.num_calib_images);
  const std::regex any_grid(preset + "-" + std::to_string(seed) + CalibSuffix(calib_count) +
                            "(-g[0-9]+x[0-9]+)?" + BoardSuffix(board));
  if (std::optional<CachedProject> cached = FindCached(any_grid)) return *cached;
  return SimulatedProject(preset, seed, calib_count, false, kFewestTiles, board);
}

void CopyProject(const fs::path& from, const fs::path& to) {
  fs::create_directories(to);
  for (const auto& entry : fs::directory_iterator(from)) {
    if (entry.path().filename() == "out") continue;
    fs::copy(entry.path(), to / entry.path().filename(), fs::copy_options::recursive);
  }
}

}  // namespace omm::testing
