// TIFF files through libtiff (Debian's libtiff 4.5), in memory.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>

#include "pipeline/core/image.h"

namespace omm {

// The first image of a TIFF file's bytes as gray samples of its depth:
// 8-bit files of any photometric interpretation libtiff renders as RGBA
// (gray, RGB, palette, YCbCr, 1- to 8-bit), and 16-bit unsigned gray or RGB
// (each with one extra sample at most), interleaved or of one sample, in
// strips or tiles; alpha is ignored, colour converted by GrayFromInterleaved
// (pipeline/core/image.h), a white-is-zero gray inverted. nullopt if the
// bytes do not start with a TIFF header. Throws InputError naming `path` if
// it is corrupt, or of another kind (float or signed samples, 32 bits, ...).
std::optional<StoredImage> DecodeTiff(std::string_view bytes, const std::filesystem::path& path);

// The bytes of a TIFF file of `image` (8- or 16-bit gray), uncompressed, in
// libtiff's default strips. Throws std::runtime_error if libtiff fails.
std::string EncodeGrayTiff(const StoredImage& image);

}  // namespace omm
