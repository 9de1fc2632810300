#include "pipeline/orchestration/stage.h"

#include <algorithm>
#include <optional>

#include <fmt/format.h>

#include "adapters/opencv/image_io.h"
#include "pipeline/core/error.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/mosaic/plate_on_part.h"
#include "pipeline/mosaic/tile_features.h"

namespace omm {

const char* StageName(Stage stage) {
  switch (stage) {
    case Stage::kCalibrate: return "calibrate";
    case Stage::kMosaic: return "mosaic";
    case Stage::kMeasure: return "measure";
  }
  return "?";
}

std::string StageNames(const std::vector<Stage>& stages) {
  std::string joined;
  for (const Stage stage : stages)
    joined += (joined.empty() ? "" : ", ") + std::string(StageName(stage));
  return joined;
}

std::vector<Stage> AllStages() { return {Stage::kCalibrate, Stage::kMosaic, Stage::kMeasure}; }

std::vector<std::string> StageOutputFiles(Stage stage, const Report& report) {
  switch (stage) {
    case Stage::kCalibrate: return {kCameraModelName};
    case Stage::kMosaic:
      if (!report.mosaic) return {kSceneName};
      return {kSceneName, report.mosaic->file};
    case Stage::kMeasure: return {};
  }
  return {};
}

GrayImage ProjectGrayImage(const Project& project, const StoredImage* decoded,
                           const std::filesystem::path& path) {
  GrayImage image = decoded ? ToGrayImage(*decoded) : ReadGrayImage(path);
  if (image.bit_depth == 16 && project.sample_bits < 16) {
    // Back to the samples (exact in float), then over their full scale: a
    // sample at it is 1 exactly, as saturation is told (ortho_patch.h).
    const auto full_scale = static_cast<float>((1 << project.sample_bits) - 1);
    image.pixels = (image.pixels.array() * 65535.0f).round() / full_scale;
  }
  LinearizeResponse(project.camera.gamma, &image.pixels);
  return image;
}

ImageF TileImage(const Project& project, int tile) {
  const std::filesystem::path path = project.TilePath(project.tiles[tile].image);
  GrayImage image = ProjectGrayImage(
      project, project.images ? project.images->tiles[tile].image.get() : nullptr, path);
  if (const std::optional<double> level = BlankImageLevel(image.pixels)) {
    throw InputError(path.string(),
                     fmt::format("blank: almost every pixel is {:.1f} % of full scale, no "
                                 "picture of the part (a failed capture?)",
                                 100.0 * *level));
  }
  return std::move(image.pixels);
}

std::vector<ImageF> TileImages(const Project& project, int num_threads) {
  std::vector<ImageF> tiles(project.tiles.size());
  ParallelFor(static_cast<int>(tiles.size()), num_threads,
              [&](int i) { tiles[i] = TileImage(project, i); });
  return tiles;
}

void CheckTileSize(const Project& project, int tile, int width_px, int height_px,
                   const CameraModel& camera) {
  if (width_px != camera.width_px || height_px != camera.height_px) {
    throw InputError(project.TilePath(project.tiles[tile].image).string(),
                     fmt::format("{}x{} px, but the calibrated camera's imager is {}x{} px",
                                 width_px, height_px, camera.width_px, camera.height_px));
  }
}

void CheckTileSizes(const Project& project, const std::vector<ImageF>& tiles,
                    const CameraModel& camera) {
  for (size_t i = 0; i < tiles.size(); ++i) {
    CheckTileSize(project, static_cast<int>(i), static_cast<int>(tiles[i].cols()),
                  static_cast<int>(tiles[i].rows()), camera);
  }
}

std::vector<ImageF> TileImages(const Project& project, const CameraModel& camera, int num_threads) {
  std::vector<ImageF> tiles = TileImages(project, num_threads);
  CheckTileSizes(project, tiles, camera);
  return tiles;
}

std::filesystem::path StageContext::Published(const std::filesystem::path& path) const {
  const std::filesystem::path relative = path.lexically_relative(staging_dir);
  if (relative.empty() || *relative.begin() == "..") return path;
  return out_dir / relative;
}

bool StageContext::StaleInOut(Stage stage) const {
  return std::find(stale_in_out.begin(), stale_in_out.end(), stage) != stale_in_out.end();
}

std::filesystem::path StageContext::Input(const std::string& name) const {
  std::error_code ec;
  if (std::filesystem::exists(staging_dir / name, ec)) return staging_dir / name;
  if (std::filesystem::exists(out_dir / name, ec)) return out_dir / name;
  return {};
}

Eigen::Matrix2Xd CalibratedRegionPx(const SolveRecord& record) {
  std::vector<Eigen::Vector2d> marks;
  for (const SolveImage& image : record.images) {
    for (Eigen::Index m = 0; m < image.q_px.cols(); ++m) {
      const auto k = static_cast<size_t>(m);
      if (image.weight(m) > 0 && !(k < image.outlier.size() && image.outlier[k]))
        marks.push_back(image.q_px.col(m));
    }
  }
  Eigen::Matrix2Xd points(2, static_cast<Eigen::Index>(marks.size()));
  for (size_t k = 0; k < marks.size(); ++k) points.col(static_cast<Eigen::Index>(k)) = marks[k];
  return ConvexHull(points);
}

}  // namespace omm
