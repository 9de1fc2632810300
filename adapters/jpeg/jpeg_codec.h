// JPEG files read through libjpeg-turbo's TurboJPEG API (Debian's
// libturbojpeg 2.1).
#pragma once

#include <filesystem>
#include <optional>
#include <string_view>

#include "pipeline/core/image.h"

namespace omm {

// The image of a JPEG file's bytes as 8-bit gray samples: a colour JPEG's
// luma (its Y channel, as libjpeg decodes YCbCr to gray), with the accurate
// integer DCT. nullopt if the bytes do not start with a JPEG marker (FF D8 FF).
// Throws InputError naming `path` if it is corrupt, truncated (no end marker)
// or damaged: libjpeg's warnings fail it too, but for extraneous bytes before
// a marker, which some cameras write and which leave the image whole.
std::optional<StoredImage> DecodeJpeg(std::string_view bytes, const std::filesystem::path& path);

}  // namespace omm
