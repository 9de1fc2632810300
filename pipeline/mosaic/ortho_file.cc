#include "pipeline/mosaic/ortho_file.h"

#include <fmt/format.h>

#include "adapters/opencv/image_io.h"
#include "adapters/project_io/text_file.h"

namespace omm {

MosaicReport OrthoMosaicReport(const std::filesystem::path& path, const OrthoGrid& grid) {
  MosaicReport report;
  report.file = path.filename().string();
  report.gsd_mm = grid.gsd_mm;
  report.size_px = grid.size_px;
  report.origin_mm = grid.origin_mm;
  return report;
}

std::string WorldFileText(const OrthoGrid& grid) {
  const Eigen::Vector2d first_centre = grid.PartFromMosaic(Eigen::Vector2d::Zero());
  // fmt's shortest form that reads back as the same double (0.15, not
  // 0.14999999999999999): each number reads back as the double computed.
  return fmt::format("{}\n0\n0\n{}\n{}\n{}\n", grid.gsd_mm, -grid.gsd_mm, first_centre.x(),
                     first_centre.y());
}

std::filesystem::path WorldFilePath(const std::filesystem::path& mosaic_path) {
  const std::string extension = mosaic_path.extension().string();  // ".png"
  std::filesystem::path path = mosaic_path;
  if (extension.size() < 3) return path.replace_extension(".wld");
  return path.replace_extension(std::string{'.', extension[1], extension.back(), 'w'});
}

MosaicReport WriteOrthoMosaic(const std::filesystem::path& path, const OrthoGrid& grid,
                              const StoredImage& samples) {
  WriteStoredImage(path, samples, /*png_deflate_level=*/0);
  WriteTextFileAtomically(WorldFilePath(path), WorldFileText(grid));
  return OrthoMosaicReport(path, grid);
}

}  // namespace omm
