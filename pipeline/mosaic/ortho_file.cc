#include "pipeline/mosaic/ortho_file.h"

#include "adapters/opencv/image_io.h"

namespace omm {

MosaicReport WriteOrthoMosaic(const std::filesystem::path& path, const OrthoMosaic& mosaic,
                              int bit_depth) {
  WriteGrayImage(path, mosaic.pixels, bit_depth);
  MosaicReport report;
  report.file = path.filename().string();
  report.gsd_mm = mosaic.grid.gsd_mm;
  report.size_px = mosaic.grid.size_px;
  report.origin_mm = mosaic.grid.origin_mm;
  return report;
}

}  // namespace omm
