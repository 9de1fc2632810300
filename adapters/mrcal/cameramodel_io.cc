#include "adapters/mrcal/cameramodel_io.h"

#include <cerrno>
#include <cstdlib>
#include <fstream>
#include <memory>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/mrcal_c.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

constexpr char kRegionKey[] = "'valid_intrinsics_region'";

std::string ReadText(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

// The file's valid_intrinsics_region (empty if it has none), its closing
// vertex dropped. Throws InputError if the key is there but not a list of
// at least 3 [x, y] pairs.
Eigen::Matrix2Xd ReadRegion(const std::filesystem::path& path) {
  const std::string text = ReadText(path);
  const size_t key = text.find(kRegionKey);
  if (key == std::string::npos) return {};
  // The list: from the first '[' after the key to its matching ']' (mrcal's
  // reader, which ran first, refuses a value that is not a balanced list).
  const size_t open = text.find('[', key);
  size_t close = open;
  for (int depth = 0; close < text.size(); ++close) {
    depth += text[close] == '[' ? 1 : text[close] == ']' ? -1 : 0;
    if (depth == 0) break;
  }
  if (open == std::string::npos || close >= text.size()) {
    throw InputError(path.string(), "valid_intrinsics_region: not a list of [x, y] vertices");
  }
  const std::string list = text.substr(open, close - open + 1);
  static const std::regex number(R"([-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)");
  std::vector<double> values;
  for (auto it = std::sregex_iterator(list.begin(), list.end(), number);
       it != std::sregex_iterator(); ++it) {
    values.push_back(std::stod(it->str()));
  }
  auto n = static_cast<Eigen::Index>(values.size() / 2);
  if (values.size() % 2 != 0 || n < 3) {
    throw InputError(path.string(),
                     "valid_intrinsics_region: not a list of at least 3 [x, y] "
                     "vertices");
  }
  Eigen::Matrix2Xd region = Eigen::Map<const Eigen::Matrix2Xd>(values.data(), 2, n);
  if (n > 3 && region.col(0) == region.col(n - 1)) --n;
  return region.leftCols(n);
}

// Adds the region to the file mrcal wrote, a Python dict literal whose last
// entry has no trailing comma: after that entry, closed as mrcal writes it.
void WriteRegion(const std::filesystem::path& path, const Eigen::Matrix2Xd& region) {
  std::string text = ReadText(path);
  const size_t brace = text.rfind('}');
  const size_t last =
      brace == std::string::npos ? brace : text.find_last_not_of(" \t\r\n", brace - 1);
  if (last == std::string::npos) {
    throw InputError(path.string(), "mrcal wrote no camera model to add the region to");
  }
  std::ostringstream entry;
  entry.precision(10);
  entry << (text[last] == ',' || text[last] == '{' ? "" : ",") << "\n  " << kRegionKey << ": [\n";
  for (Eigen::Index k = 0; k <= region.cols(); ++k) {
    const Eigen::Index v = k % region.cols();
    entry << "    [ " << region(0, v) << ", " << region(1, v) << " ],\n";
  }
  entry << "  ]\n";
  text.replace(last + 1, brace - last - 1, entry.str());
  errno = 0;  // a failed write's reason (WriteError), not an earlier call's
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
  if (!out) throw WriteError(path, "cannot write the camera model's region");
}

}  // namespace

void WriteCameraModel(const std::filesystem::path& path, const CameraModel& camera) {
  mrcal_lensmodel_t lensmodel;
  if (!mrcal_lensmodel_from_name(&lensmodel, camera.lens_model.c_str()) ||
      !mrcal_lensmodel_type_is_valid(lensmodel.type)) {
    throw InputError(path.string(), "cannot write lens model '" + camera.lens_model + "'");
  }
  const int n = mrcal_lensmodel_num_params(&lensmodel);
  if (camera.intrinsics.size() != n || camera.width_px <= 0 || camera.height_px <= 0) {
    throw InputError(path.string(), "camera has " + std::to_string(camera.intrinsics.size()) +
                                        " intrinsics for " + camera.lens_model + " (expected " +
                                        std::to_string(n) + ") or no imager size");
  }
  // mrcal_cameramodel_t ends in a flexible array of intrinsics.
  const size_t bytes = sizeof(mrcal_cameramodel_t) + n * sizeof(double);
  std::unique_ptr<void, decltype(&std::free)> buffer(std::calloc(1, bytes), &std::free);
  auto* model = static_cast<mrcal_cameramodel_t*>(buffer.get());
  model->imagersize[0] = static_cast<unsigned>(camera.width_px);
  model->imagersize[1] = static_cast<unsigned>(camera.height_px);
  model->lensmodel = lensmodel;
  for (int k = 0; k < n; ++k) model->intrinsics[k] = camera.intrinsics[k];
  errno = 0;  // a failed write's reason (WriteError), not an earlier call's
  if (!mrcal_write_cameramodel_file(path.c_str(), model)) {
    throw WriteError(path, "mrcal could not write the camera model");
  }
  if (camera.valid_region_px.cols() >= 3) WriteRegion(path, camera.valid_region_px);
}

CameraModel ReadCameraModel(const std::filesystem::path& path) {
  mrcal_cameramodel_t* model = mrcal_read_cameramodel_file(path.c_str());
  if (model == nullptr) {
    throw InputError(path.string(), "not a readable mrcal .cameramodel file");
  }
  CameraModel camera;
  char name[1024];
  const bool named = mrcal_lensmodel_name(name, sizeof(name), &model->lensmodel);
  const int n = mrcal_lensmodel_num_params(&model->lensmodel);
  if (named) {
    camera.lens_model = name;
    camera.intrinsics = Eigen::Map<const Eigen::VectorXd>(model->intrinsics, n);
    camera.width_px = static_cast<int>(model->imagersize[0]);
    camera.height_px = static_cast<int>(model->imagersize[1]);
  }
  mrcal_free_cameramodel(&model);
  if (!named) throw InputError(path.string(), "mrcal cannot name the file's lens model");
  camera.valid_region_px = ReadRegion(path);
  return camera;
}

}  // namespace omm
