#include "pipeline/orchestration/input_hash.h"

#include <fstream>
#include <map>
#include <vector>

#include "adapters/openssl/sha256.h"
#include "pipeline/core/error.h"

namespace fs = std::filesystem;

namespace omm {

std::vector<fs::path> ProjectInputFiles(const Project& project) {
  std::vector<fs::path> files = {project.dir / "project.yaml"};
  std::error_code ec;
  for (const char* name : {"table.csv", "cmm.csv"}) {
    if (fs::is_regular_file(project.dir / name, ec)) files.push_back(project.dir / name);
  }
  files.insert(files.end(), project.calib_images.begin(), project.calib_images.end());
  for (const TilePosition& tile : project.tiles) files.push_back(project.TilePath(tile.image));
  if (project.calibration_from) {
    const CalibrationSource& from = *project.calibration_from;
    const fs::path model = from.kind == CalibrationSource::Kind::kCameraModel
                               ? from.path
                               : from.path / "out" / "camera.cameramodel";
    if (fs::is_regular_file(model, ec)) files.push_back(model);
  }
  return files;
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
  // The images' hashes as LoadProject took them from the bytes it decoded.
  std::map<fs::path, std::string> loaded;
  if (project.images) {
    for (size_t i = 0; i < project.images->calib.size(); ++i)
      loaded[project.calib_images[i]] = project.images->calib[i].sha256;
    for (size_t i = 0; i < project.images->tiles.size(); ++i)
      loaded[project.TilePath(project.tiles[i].image)] = project.images->tiles[i].sha256;
  }
  Sha256 sha;
  for (const fs::path& file : ProjectInputFiles(project)) {
    // Files outside the project (a reused calibration) keep their absolute path.
    const fs::path relative = file.lexically_relative(project.dir);
    const bool inside = !relative.empty() && *relative.begin() != "..";
    sha.Update((inside ? relative : file).generic_string());
    sha.Update(std::string_view("\0", 1));
    const auto it = loaded.find(file);
    sha.Update(it != loaded.end() ? it->second : HashFile(file));
  }
  return sha.HexDigest();
}

}  // namespace omm
