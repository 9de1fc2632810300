#include "tests/test_util.h"

#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>

#include "adapters/opencv/image_io.h"
#include "adapters/project_io/project_writer.h"

namespace fs = std::filesystem;

namespace omm::testing {

TempDir::TempDir() {
  std::string pattern = (fs::temp_directory_path() / "omm_test_XXXXXX").string();
  if (mkdtemp(pattern.data()) == nullptr) {
    ADD_FAILURE() << "cannot create a temporary directory";
  }
  path_ = pattern;
}

TempDir::~TempDir() {
  std::error_code ec;
  fs::remove_all(path_, ec);
}

Project TinyProject(const fs::path& dir, int width_px, int height_px) {
  Project project;
  project.dir = dir;
  project.name = "tiny";
  project.camera.pixel_pitch_um = 4.5;
  project.camera.focal_length_mm = 12.0;
  project.board = BoardSpec{};
  project.table_sigma_mm = 0.01;
  project.mosaic_gsd_mm = 0.1;
  project.calib_images = {dir / "calib" / "calib_01.png", dir / "calib" / "calib_02.png"};
  project.tiles = {{"Part_01.png", {0.0, 0.0}},
                   {"Part_02.png", {108.6, 0.0}},
                   {"Part_03.png", {0.0, 80.25}},
                   {"Part_04.png", {108.6, 80.25}}};
  project.features = {{"hole_A", FeatureType::kCircle, "Part_01.png", {10.0, 12.0}, 40.0},
                      {"hole_B", FeatureType::kCircle, "Part_04.png", {20.5, 3.0}, 12.5}};
  project.measurements = {{"A_to_B", MeasurementType::kDistance, {"hole_A", "hole_B"}},
                          {"A_diameter", MeasurementType::kDiameter, {"hole_A"}}};
  project.cmm = {{"A_to_B", 202.6033}, {"A_diameter", 40.0012}};
  project.image_width_px = width_px;
  project.image_height_px = height_px;
  return project;
}

void WriteGrayPng(const fs::path& path, int width_px, int height_px) {
  fs::create_directories(path.parent_path());
  WriteGrayImage(path, ImageF::Constant(height_px, width_px, 0.5f), 8);
}

void WriteTinyProject(const Project& project) {
  WriteProjectFiles(project);
  for (const fs::path& path : project.calib_images) {
    WriteGrayPng(path, project.image_width_px, project.image_height_px);
  }
  for (const TilePosition& tile : project.tiles) {
    WriteGrayPng(project.TilePath(tile.image), project.image_width_px, project.image_height_px);
  }
}

std::string ReadTextFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

void WriteTextFile(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary | std::ios::trunc) << text;
}

void ReplaceInFile(const fs::path& path, const std::string& from, const std::string& to) {
  std::string text = ReadTextFile(path);
  const auto at = text.find(from);
  ASSERT_NE(at, std::string::npos) << "'" << from << "' is not in " << path << ":\n" << text;
  text.replace(at, from.size(), to);
  WriteTextFile(path, text);
}

CommandResult RunCommand(const std::string& command) {
  CommandResult result;
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (pipe == nullptr) return result;
  std::array<char, 4096> buffer;
  size_t n = 0;
  while ((n = fread(buffer.data(), 1, buffer.size(), pipe)) > 0)
    result.output.append(buffer.data(), n);
  const int status = pclose(pipe);
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return result;
}

fs::path OmmProgram() { return OMM_PROGRAM; }

CommandResult RunOmm(const std::string& arguments) {
  return RunCommand(OmmProgram().string() + " " + arguments);
}

fs::path SharedDataDir() {
  const char* source = std::getenv("OMM_SOURCE_DIR");
  return fs::path(source ? source : ".") / ".." / "shared" / "data";
}

}  // namespace omm::testing
