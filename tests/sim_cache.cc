#include "tests/sim_cache.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <stdexcept>

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

}  // namespace

CachedProject SimulatedProject(const std::string& preset, std::uint64_t seed,
                               std::optional<int> num_calib_images, bool plate_on_part,
                               TileGrid grid, BoardType board) {
  const fs::path cache = OMM_SIM_CACHE_DIR;
  fs::create_directories(cache);
  const bool grid3 = grid.cols == 3 && grid.rows == 3;
  const std::string name =
      preset + "-" + std::to_string(seed) +
      (num_calib_images ? "-calib" + std::to_string(*num_calib_images) : "") +
      (plate_on_part ? "-plate" : "") +
      (grid3 ? "" : "-g" + std::to_string(grid.cols) + "x" + std::to_string(grid.rows)) +
      (board == BoardType::kCaltab ? "" : std::string("-") + BoardTypeName(board));
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
      if (num_calib_images) options.num_calib_images = *num_calib_images;
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
  CachedProject project;
  project.project_dir = final_dir / "project";
  project.truth_path = final_dir / "truth.json";
  project.truth = ReadTruthJson(project.truth_path);
  return project;
}

void CopyProject(const fs::path& from, const fs::path& to) {
  fs::create_directories(to);
  for (const auto& entry : fs::directory_iterator(from)) {
    if (entry.path().filename() == "out") continue;
    fs::copy(entry.path(), to / entry.path().filename(), fs::copy_options::recursive);
  }
}

}  // namespace omm::testing
