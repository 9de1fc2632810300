#include "pipeline/mosaic/ortho_file.h"

#include "adapters/opencv/image_io.h"

namespace omm {

MosaicReport OrthoMosaicReport(const std::filesystem::path& path, const OrthoGrid& grid) {
  MosaicReport report;
  report.file = path.filename().string();
  report.gsd_mm = grid.gsd_mm;
  report.size_px = grid.size_px;
  report.origin_mm = grid.origin_mm;
  return report;
}

MosaicReport WriteOrthoMosaic(const std::filesystem::path& path, const OrthoGrid& grid,
                              const StoredImage& samples) {
  WriteStoredImage(path, samples, /*png_deflate_level=*/0);
  return OrthoMosaicReport(path, grid);
}

}  // namespace omm
