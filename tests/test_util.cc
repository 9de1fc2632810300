#include "tests/test_util.h"

#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>

#include <Eigen/Geometry>

#include "adapters/opencv/image_io.h"
#include "adapters/project_io/project_writer.h"

namespace fs = std::filesystem;

namespace omm::testing {

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

struct LogCapture::State {
  std::ostringstream text;
  std::shared_ptr<spdlog::sinks::ostream_sink_mt> sink =
      std::make_shared<spdlog::sinks::ostream_sink_mt>(text);
};

LogCapture::LogCapture() : state_(std::make_unique<State>()) {
  spdlog::default_logger()->sinks().push_back(state_->sink);
}

LogCapture::~LogCapture() {
  std::vector<spdlog::sink_ptr>& sinks = spdlog::default_logger()->sinks();
  sinks.erase(std::remove(sinks.begin(), sinks.end(), state_->sink), sinks.end());
}

std::string LogCapture::Text() const {
  state_->sink->flush();
  return state_->text.str();
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

std::vector<fs::path> SharedDataFiles(const std::string& extension) {
  std::vector<fs::path> files;
  if (!fs::is_directory(SharedDataDir())) return files;
  for (const auto& entry : fs::recursive_directory_iterator(SharedDataDir())) {
    if (entry.path().extension() == extension) files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

double RawPxMm(const SimulationTruth& truth) {
  const Eigen::Isometry3d part_from_cam = truth.cam_from_part.inverse();
  const double distance_mm = part_from_cam.translation().z() / -part_from_cam.linear().col(2).z();
  return truth.camera.pixel_pitch_um * 1e-3 * distance_mm / truth.camera.focal_length_mm;
}

std::vector<std::pair<std::string, double>> HoleCentreErrorsAfterSimilarity(
    const Report& report, const SimulationTruth& truth) {
  std::vector<std::pair<std::string, double>> errors;
  if (!report.features) return errors;
  // Dynamic sizes: GCC 12 warns (-Wstringop-overread) inside Eigen's
  // umeyama for 2 x N fixed-row matrices.
  Eigen::MatrixXd measured(2, 0), expected(2, 0);
  for (const FeatureReport& feature : *report.features) {
    const auto hole = std::find_if(truth.holes.begin(), truth.holes.end(),
                                   [&](const HoleTruth& h) { return h.name == feature.name; });
    if (!feature.centre_mm || hole == truth.holes.end()) continue;
    measured.conservativeResize(2, measured.cols() + 1);
    expected.conservativeResize(2, expected.cols() + 1);
    measured.col(measured.cols() - 1) = *feature.centre_mm;
    expected.col(expected.cols() - 1) = hole->center_part_mm;
    errors.emplace_back(feature.name, 0.0);
  }
  if (errors.size() < 3) return {};
  const Eigen::MatrixXd fit = Eigen::umeyama(measured, expected, true);
  const Eigen::MatrixXd residual =
      expected - ((fit.topLeftCorner(2, 2) * measured).colwise() + fit.topRightCorner(2, 1).col(0));
  for (size_t i = 0; i < errors.size(); ++i)
    errors[i].second = residual.col(static_cast<Eigen::Index>(i)).norm();
  return errors;
}

void ExpectMeasurementsWithinSigmas(const Report& report, const SimulationTruth& truth,
                                    double max_sigmas) {
  ASSERT_TRUE(report.measurements.has_value());
  const double raw_px_mm = RawPxMm(truth);
  for (const MeasurementReport& m : *report.measurements) {
    ASSERT_TRUE(m.value_mm && m.sigma_mm) << m.name << ": " << m.error;
    for (const MeasurementTruth& t : truth.measurements) {
      if (t.name != m.name) continue;
      const double error_mm = *m.value_mm - t.value_mm;
      std::printf("%s %+.4f raw px, %+.2f sigma\n", m.name.c_str(), error_mm / raw_px_mm,
                  error_mm / *m.sigma_mm);
      EXPECT_LT(std::abs(error_mm), max_sigmas * *m.sigma_mm) << m.name;
    }
  }
}

}  // namespace omm::testing
