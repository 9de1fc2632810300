// Reading and writing images (PNG, TIFF, JPEG) through OpenCV's imgcodecs.
#pragma once

#include <filesystem>
#include <string>

#include "pipeline/core/image.h"

namespace omm {

// Reads an 8- or 16-bit gray or color image as gray in [0, 1]. Throws
// InputError naming the file when it is missing, unreadable, corrupt or of
// another depth.
GrayImage ReadGrayImage(const std::filesystem::path& path);

// Width and height of an image file from its header (no pixel decoding where
// the format allows). Throws InputError like ReadGrayImage.
Eigen::Vector2i ReadImageSize(const std::filesystem::path& path);

// Writes `image` as an 8- or 16-bit gray PNG or TIFF (by extension), values
// clamped to [0, 1] and rounded to the nearest digital number. Writes to a
// temporary file beside `path` and renames it, so a reader never sees a
// half-written file. Throws InputError if it cannot be written.
void WriteGrayImage(const std::filesystem::path& path, const ImageF& pixels, int bit_depth);

// An 8-bit gray PNG file's bytes, in memory, of `pixels` (values clamped to
// [0, 1]) shrunk by area averaging (cv::INTER_AREA) to max_width_px wide,
// aspect kept (height rounded, at least 1 px); an image no wider is encoded
// as it is. For previews embedded in other files (report.html).
std::string EncodePreviewPng(const ImageF& pixels, int max_width_px);

}  // namespace omm
