// Writing the orthorectified mosaic to out/ (project-format.md: mosaic.png or
// mosaic.tif, 8 or 16 bit gray, its grid in report.json's `mosaic` section).
#pragma once

#include <filesystem>

#include "pipeline/core/report.h"
#include "pipeline/mosaic/orthorectify.h"

namespace omm {

// The report's fields of a mosaic on `grid` written to `path`: file = the
// file name of `path`, gsd_mm, size_px, origin_mm. rms_px (the
// registration's) and extra are the caller's.
MosaicReport OrthoMosaicReport(const std::filesystem::path& path, const OrthoGrid& grid);

// Writes mosaic.pixels to `path` (.png, .tif or .tiff; 8 or 16 bit) through a
// temporary file and a rename, and returns OrthoMosaicReport(path,
// mosaic.grid). Throws InputError if it cannot be written.
MosaicReport WriteOrthoMosaic(const std::filesystem::path& path, const OrthoMosaic& mosaic,
                              int bit_depth = 16);

}  // namespace omm
