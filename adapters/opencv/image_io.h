// Image files: read from PNG (adapters/png), TIFF (adapters/tiff), JPEG
// (adapters/jpeg), PGM or PPM (adapters/netpbm), written as PNG or TIFF; and
// their samples converted to and from the pipeline's floats (OpenCV).
//
// Not through OpenCV's imgcodecs: in Debian it pulls in GDAL and its ~120
// libraries, which took ~70 ms of every omm process's start (omm --version:
// 98 ms with it; a binary linking OpenCV's other modules starts in 5 ms).
#pragma once

#include <filesystem>
#include <string>
#include <string_view>

#include "adapters/png/png_codec.h"
#include "pipeline/core/image.h"

namespace omm {

// Reads an 8- or 16-bit gray or color image as gray in [0, 1]:
// ToGrayImage(ReadStoredImage(path)). Throws InputError naming the file when
// it is missing, unreadable, corrupt or of another depth.
GrayImage ReadGrayImage(const std::filesystem::path& path);

// Reads an 8- or 16-bit gray or color image file's samples, color converted
// to gray at the file's depth. Throws InputError like ReadGrayImage.
StoredImage ReadStoredImage(const std::filesystem::path& path);

// The same from the file's bytes already in memory; `path` only names the
// file in errors.
StoredImage DecodeImage(std::string_view file_bytes, const std::filesystem::path& path);

// The samples scaled to [0, 1] of full scale (255 or 65535), bit_depth kept:
// the one conversion every image read goes through.
GrayImage ToGrayImage(const StoredImage& image);

// `pixels` clamped to [0, 1] and rounded to the nearest digital number of
// `bit_depth` (8 or 16) bits: the samples WriteGrayImage writes.
StoredImage QuantizeImage(const ImageF& pixels, int bit_depth);

// Writes `image` as a gray PNG or TIFF (by extension) at its depth, through a
// temporary file beside `path` and a rename, so a reader never sees a
// half-written file. A PNG is written by adapters/png at libdeflate's
// `png_deflate_level` (PngWriteOptions: 0 stores it uncompressed, fastest).
// Throws InputError if it cannot be written.
void WriteStoredImage(const std::filesystem::path& path, const StoredImage& image,
                      int png_deflate_level = PngWriteOptions{}.deflate_level);

// WriteStoredImage(path, QuantizeImage(pixels, bit_depth)).
void WriteGrayImage(const std::filesystem::path& path, const ImageF& pixels, int bit_depth);

// An 8-bit gray PNG file's bytes, in memory, of `image` shrunk by area
// averaging (cv::INTER_AREA, on the stored samples) to max_width_px wide,
// aspect kept (height rounded, at least 1 px); an image no wider is encoded
// as it is. For previews embedded in other files (report.html).
std::string EncodePreviewPng(const StoredImage& image, int max_width_px);

}  // namespace omm
