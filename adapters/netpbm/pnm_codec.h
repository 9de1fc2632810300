// PGM and PPM files (Netpbm): a header and raw samples, as some machine-
// vision tools save their images. Read by our own few lines: the format is a
// text header and the samples (netpbm.sourceforge.net/doc/pgm.html, ppm.html);
// a library would add a dependency for nothing.
#pragma once

#include <filesystem>
#include <optional>
#include <string_view>

#include "pipeline/core/image.h"

namespace omm {

// The image of a PGM or PPM file's bytes (binary P5 / P6 or plain P2 / P3),
// as gray samples: 8-bit when its maxval is below 256, else 16-bit; samples
// as the file holds them (not rescaled to full range); a PPM's colour
// converted by GrayFromInterleaved (pipeline/core/image.h). nullopt if the
// bytes do not start with P2, P3, P5 or P6. Throws InputError naming `path`
// if the header is malformed or the samples are short or beyond maxval.
std::optional<StoredImage> DecodePnm(std::string_view bytes, const std::filesystem::path& path);

}  // namespace omm
