// Helpers shared by tests: temporary directories, tiny valid projects, files
// edited in place, and running the `omm` program.
#pragma once

#include <filesystem>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "adapters/process/process.h"
#include "pipeline/core/project.h"
#include "pipeline/core/report.h"
#include "pipeline/core/truth.h"

namespace omm::testing {

// A fresh empty directory under the system temp dir, removed with everything
// in it when the object goes out of scope.
class TempDir : public ScratchDir {
 public:
  TempDir() : ScratchDir("omm_test_") {}
};

// A small valid project in `dir`: a 7x7 caltab, two calibration images, a
// 2x2 grid of tiles with table positions, two circles, a distance and a
// diameter, and CMM values for both. The images are `width_px` x `height_px`
// plain gray PNGs (the loader checks files, not content).
Project TinyProject(const std::filesystem::path& dir, int width_px = 32, int height_px = 24);

// Writes `project`'s text files (WriteProjectFiles) and a gray PNG of its
// image size for every calib image and tile.
void WriteTinyProject(const Project& project);

// A gray PNG of the given size.
void WriteGrayPng(const std::filesystem::path& path, int width_px, int height_px);

// Replaces the first `from` in the text file `path` by `to`; fails the test
// if `from` is not there.
void ReplaceInFile(const std::filesystem::path& path, const std::string& from,
                   const std::string& to);
void WriteTextFile(const std::filesystem::path& path, const std::string& text);
std::string ReadTextFile(const std::filesystem::path& path);

// What spdlog's default logger says while this object lives: its lines as
// the logger's pattern formats them (the stages' warnings, for a test of
// their wording).
class LogCapture {
 public:
  LogCapture();
  ~LogCapture();
  LogCapture(const LogCapture&) = delete;
  LogCapture& operator=(const LogCapture&) = delete;
  std::string Text() const;

 private:
  struct State;
  std::unique_ptr<State> state_;
};

struct CommandResult {
  int exit_code = -1;
  std::string output;  // stdout and stderr together
};

// Runs a shell command line and captures its output.
CommandResult RunCommand(const std::string& command);

// The built `omm` program of this build tree.
std::filesystem::path OmmProgram();

// Runs that program with a command line's arguments and captures its output.
CommandResult RunOmm(const std::string& arguments);

// The real images from public sources in ../shared/data beside the
// repository (OMM_SOURCE_DIR, set by omm_test; read in place, never copied).
std::filesystem::path SharedDataDir();

// Its files of one extension (".tif"), sorted; none if it is not there.
std::vector<std::filesystem::path> SharedDataFiles(const std::string& extension);

// The report's feature centres against the truth's holes after the
// least-squares similarity fit of all of them (Umeyama: the table's scale
// and the origin gauge removed): each found hole's name and distance from
// its true centre, mm.
std::vector<std::pair<std::string, double>> HoleCentreErrorsAfterSimilarity(
    const Report& report, const SimulationTruth& truth);

// A raw pixel's size on the part: pitch * distance / focal length, mm.
double RawPxMm(const SimulationTruth& truth);

// Every measurement made, each printed with its error against the truth (raw
// px and sigmas), and within max_sigmas of its sigma (a gtest failure each).
void ExpectMeasurementsWithinSigmas(const Report& report, const SimulationTruth& truth,
                                    double max_sigmas);

}  // namespace omm::testing
