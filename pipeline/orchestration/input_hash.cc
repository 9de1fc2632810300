#include "pipeline/orchestration/input_hash.h"

#include <fstream>
#include <map>
#include <vector>

#include "adapters/openssl/sha256.h"
#include "pipeline/core/error.h"

namespace fs = std::filesystem;

namespace omm {

namespace {

// project.dir / name, if that file exists (table.csv, cmm.csv).
std::vector<fs::path> IfPresent(const Project& project, const char* name) {
  std::error_code ec;
  if (!fs::is_regular_file(project.dir / name, ec)) return {};
  return {project.dir / name};
}

// calibration.from's .cameramodel (a file, or out/camera.cameramodel of the
// project it names), if present.
std::vector<fs::path> ReusedCalibration(const Project& project) {
  if (!project.calibration_from) return {};
  const CalibrationSource& from = *project.calibration_from;
  const fs::path model = from.kind == CalibrationSource::Kind::kCameraModel
                             ? from.path
                             : from.path / "out" / "camera.cameramodel";
  std::error_code ec;
  if (!fs::is_regular_file(model, ec)) return {};
  return {model};
}

std::vector<fs::path> Tiles(const Project& project) {
  std::vector<fs::path> tiles;
  for (const TilePosition& tile : project.tiles) tiles.push_back(project.TilePath(tile.image));
  return tiles;
}

template <typename... Lists>
std::vector<fs::path> Joined(std::vector<fs::path> first, const Lists&... rest) {
  (first.insert(first.end(), rest.begin(), rest.end()), ...);
  return first;
}

// Adds each file's path relative to the project directory (a file outside it,
// a reused calibration, keeps its absolute path), a NUL byte and the
// SHA-256 of its bytes: for an image LoadProject decoded, the one it took of
// those bytes.
void AddFiles(const Project& project, const std::vector<fs::path>& files, Sha256& sha) {
  std::map<fs::path, std::string> loaded;
  if (project.images) {
    for (size_t i = 0; i < project.images->calib.size(); ++i)
      loaded[project.calib_images[i]] = project.images->calib[i].sha256;
    for (size_t i = 0; i < project.images->tiles.size(); ++i)
      loaded[project.TilePath(project.tiles[i].image)] = project.images->tiles[i].sha256;
  }
  for (const fs::path& file : files) {
    const fs::path relative = file.lexically_relative(project.dir);
    const bool inside = !relative.empty() && *relative.begin() != "..";
    sha.Update((inside ? relative : file).generic_string());
    sha.Update(std::string_view("\0", 1));
    const auto it = loaded.find(file);
    sha.Update(it != loaded.end() ? it->second : HashFile(file));
  }
}

// project.yaml's sections that `stage` reads, as key, NUL, text, NUL.
void AddYamlSections(const Project& project, Stage stage, Sha256& sha) {
  for (const auto& [key, text] : project.yaml_sections) {
    if (StageReadingYamlKey(key) != stage) continue;
    sha.Update(key);
    sha.Update(std::string_view("\0", 1));
    sha.Update(text);
    sha.Update(std::string_view("\0", 1));
  }
}

}  // namespace

std::vector<fs::path> ProjectInputFiles(const Project& project) {
  return Joined({project.dir / "project.yaml"}, IfPresent(project, "table.csv"),
                IfPresent(project, "cmm.csv"), project.calib_images, Tiles(project),
                ReusedCalibration(project));
}

std::string HashFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path.string(), "cannot read file");
  Sha256 sha;
  std::vector<char> buffer(1 << 16);
  while (in) {
    in.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
    sha.Update(buffer.data(), static_cast<std::size_t>(in.gcount()));
  }
  if (in.bad()) throw InputError(path.string(), "cannot read file");
  return sha.HexDigest();
}

std::string HashProjectInputs(const Project& project) {
  Sha256 sha;
  AddFiles(project, ProjectInputFiles(project), sha);
  return sha.HexDigest();
}

std::optional<Stage> StageReadingYamlKey(const std::string& key) {
  static const std::map<std::string, Stage> stages = {
      {"format", Stage::kCalibrate},      {"camera", Stage::kCalibrate},
      {"calibration", Stage::kCalibrate}, {"board", Stage::kCalibrate},
      {"table", Stage::kMosaic},          {"mosaic", Stage::kMosaic},
      {"features", Stage::kMosaic},       {"measurements", Stage::kMeasure}};
  const auto it = stages.find(key);
  if (it == stages.end()) return std::nullopt;
  return it->second;
}

const std::string& StageInputHashes::Of(Stage stage) const {
  switch (stage) {
    case Stage::kCalibrate: return calibrate;
    case Stage::kMosaic: return mosaic;
    case Stage::kMeasure: return measure;
  }
  return measure;  // not reached: every stage is listed
}

StageInputHashes HashStageInputs(const Project& project, FeatureSource mosaic_features) {
  StageInputHashes hashes;
  Sha256 calibrate;
  AddFiles(project, Joined(project.calib_images, ReusedCalibration(project)), calibrate);
  AddYamlSections(project, Stage::kCalibrate, calibrate);
  calibrate.Update("sample_bits " + std::to_string(project.sample_bits));
  hashes.calibrate = calibrate.HexDigest();

  Sha256 mosaic;
  mosaic.Update(hashes.calibrate);
  AddFiles(project, Joined(IfPresent(project, "table.csv"), Tiles(project)), mosaic);
  AddYamlSections(project, Stage::kMosaic, mosaic);
  mosaic.Update("features " + std::to_string(static_cast<int>(mosaic_features)));
  hashes.mosaic = mosaic.HexDigest();

  Sha256 measure;
  measure.Update(hashes.mosaic);
  AddFiles(project, IfPresent(project, "cmm.csv"), measure);
  AddYamlSections(project, Stage::kMeasure, measure);
  hashes.measure = measure.HexDigest();
  return hashes;
}

}  // namespace omm
