// PNG files (ISO/IEC 15948, "PNG Second Edition").
//
// Gray ones, the usual camera image and every image omm writes, are read and
// written with libdeflate's whole-buffer zlib streams and CRC-32 instead of a
// PNG library's row-by-row path: decoding the demo's 8-bit 1600 x 1200 images
// takes ~8 ms instead of ~18 ms (CPU), and a 16-bit mosaic is written without
// a per-row filter search. Only the common kind is handled so (DecodeGrayPng):
// gray (colour type 0), 8 or 16 bits, not interlaced, no transparency chunk.
// Every other PNG goes through libspng (DecodePng).
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>

#include "pipeline/core/image.h"

namespace omm {

// The image in a gray, 8- or 16-bit, non-interlaced PNG file's bytes
// (samples as StoredImage holds them: 16-bit ones native-endian). nullopt if
// `bytes` is not a PNG of that kind (another colour type, bit depth or
// interlace, a tRNS or unknown critical chunk, or no PNG signature). Throws
// InputError naming `path` when it is one but corrupt: a chunk past the end,
// a CRC mismatch, a zlib stream that does not inflate to exactly the rows,
// an unknown filter type.
std::optional<StoredImage> DecodeGrayPng(std::string_view bytes, const std::filesystem::path& path);

// The image in any PNG file's bytes, through libspng, as gray samples: 8-bit
// for files of 1 to 8 bits (palette expanded, gray of fewer bits scaled to 8),
// 16-bit for 16-bit files; alpha and transparency ignored; colour converted
// by GrayFromInterleaved (pipeline/core/image.h). Throws InputError naming
// `path` if the bytes are not a PNG or it is corrupt.
StoredImage DecodePng(std::string_view bytes, const std::filesystem::path& path);

struct PngWriteOptions {
  // libdeflate's level: 0 stores the rows uncompressed (a 16-bit mosaic
  // ~1.28x larger, ~5x less CPU than level 1); 1 (fastest) .. 12 (smallest)
  // compress rows filtered by "sub" (each byte minus the one a sample left).
  int deflate_level = 1;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// The bytes of a PNG file of `image` (8- or 16-bit gray): IHDR, one IDAT,
// IEND. Precondition: image.samples holds width * height samples and
// options.Check() is empty.
std::string EncodeGrayPng(const StoredImage& image, const PngWriteOptions& options = {});

}  // namespace omm
