#include "adapters/netpbm/pnm_codec.h"

#include <cctype>
#include <cstdint>
#include <string>
#include <vector>

#include "pipeline/core/error.h"

namespace omm {
namespace {

// Reads the next decimal number at `*at`, after white space and # comments.
bool NextNumber(std::string_view bytes, std::size_t* at, std::uint64_t* value) {
  while (*at < bytes.size()) {
    const unsigned char c = static_cast<unsigned char>(bytes[*at]);
    if (c == '#') {
      while (*at < bytes.size() && bytes[*at] != '\n' && bytes[*at] != '\r') ++*at;
    } else if (std::isspace(c)) {
      ++*at;
    } else {
      break;
    }
  }
  std::size_t digits = 0;
  *value = 0;
  while (*at < bytes.size() && std::isdigit(static_cast<unsigned char>(bytes[*at]))) {
    if (++digits > 9) return false;  // beyond any image size or maxval
    *value = *value * 10 + static_cast<std::uint64_t>(bytes[*at] - '0');
    ++*at;
  }
  return digits > 0;
}

}  // namespace

std::optional<StoredImage> DecodePnm(std::string_view bytes, const std::filesystem::path& path) {
  if (bytes.size() < 2 || bytes[0] != 'P') return std::nullopt;
  const char kind = bytes[1];
  if (kind != '2' && kind != '3' && kind != '5' && kind != '6') return std::nullopt;
  const auto corrupt = [&](const std::string& why) {
    return InputError(path.string(), "cannot decode image: corrupt PGM/PPM (" + why + ")");
  };
  const bool plain = kind == '2' || kind == '3';
  const int channels = kind == '3' || kind == '6' ? 3 : 1;
  std::size_t at = 2;
  std::uint64_t width = 0, height = 0, maxval = 0;
  if (!NextNumber(bytes, &at, &width) || !NextNumber(bytes, &at, &height) ||
      !NextNumber(bytes, &at, &maxval) || width == 0 || height == 0 || maxval == 0 ||
      maxval > 65535) {
    throw corrupt("bad header");
  }
  if (width * height > static_cast<std::uint64_t>(kMaxImagePixels)) {
    throw InputError(path.string(), "cannot decode image: too large (" + std::to_string(width) +
                                        " x " + std::to_string(height) + " pixels)");
  }
  const int bit_depth = maxval < 256 ? 8 : 16;
  const std::size_t count = static_cast<std::size_t>(width * height) * channels;
  // Each sample takes a byte at least (two in a plain file, with its
  // separator): fewer bytes than that is a truncated file, not an
  // allocation to attempt.
  if (count > bytes.size() - at) throw corrupt("truncated");
  std::vector<std::uint16_t> wide(bit_depth == 16 ? count : 0);
  std::vector<std::uint8_t> narrow(bit_depth == 8 ? count : 0);
  const auto store = [&](std::size_t k, std::uint64_t v) {
    if (v > maxval) throw corrupt("a sample beyond maxval");
    if (bit_depth == 8)
      narrow[k] = static_cast<std::uint8_t>(v);
    else
      wide[k] = static_cast<std::uint16_t>(v);
  };
  if (plain) {
    for (std::size_t k = 0; k < count; ++k) {
      std::uint64_t v = 0;
      if (!NextNumber(bytes, &at, &v)) throw corrupt("too few samples");
      store(k, v);
    }
  } else {
    // One white-space byte ends the header; 16-bit samples are big-endian.
    ++at;
    const std::size_t bytes_per_sample = bit_depth / 8;
    if (at > bytes.size() || (bytes.size() - at) / bytes_per_sample < count) {
      throw corrupt("truncated");
    }
    const auto* data = reinterpret_cast<const unsigned char*>(bytes.data()) + at;
    for (std::size_t k = 0; k < count; ++k) {
      store(k, bit_depth == 8 ? data[k] : (std::uint64_t{data[2 * k]} << 8) | data[2 * k + 1]);
    }
  }
  const auto* samples =
      bit_depth == 8 ? narrow.data() : reinterpret_cast<const std::uint8_t*>(wide.data());
  return GrayFromInterleaved(samples, static_cast<std::size_t>(width) * channels * (bit_depth / 8),
                             static_cast<int>(width), static_cast<int>(height), channels,
                             bit_depth);
}

}  // namespace omm
