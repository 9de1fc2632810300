#include "adapters/jpeg/jpeg_codec.h"

#include <turbojpeg.h>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <string>

#include "pipeline/core/error.h"

namespace omm {

std::optional<StoredImage> DecodeJpeg(std::string_view bytes, const std::filesystem::path& path) {
  const auto* data = reinterpret_cast<const unsigned char*>(bytes.data());
  if (bytes.size() < 3 || data[0] != 0xFF || data[1] != 0xD8 || data[2] != 0xFF) {
    return std::nullopt;
  }
  const std::unique_ptr<void, decltype(&tjDestroy)> handle(tjInitDecompress(), tjDestroy);
  if (!handle) throw std::bad_alloc();
  // libjpeg only warns of damaged data, and decodes what it can. The one
  // warning that leaves the image whole is extraneous bytes before a marker,
  // which some cameras write (libjpeg's JWRN_EXTRANEOUS_DATA; the TurboJPEG
  // API gives the message, not the code). Any other fails the image.
  const auto check = [&](int status) {
    if (status == 0) return;
    const std::string message = tjGetErrorStr2(handle.get());
    if (tjGetErrorCode(handle.get()) == TJERR_WARNING &&
        message.find("extraneous bytes") != std::string::npos) {
      return;
    }
    throw InputError(path.string(), "cannot decode image: corrupt JPEG (" + message + ")");
  };
  int width = 0, height = 0, subsampling = 0, colorspace = 0;
  check(tjDecompressHeader3(handle.get(), data, bytes.size(), &width, &height, &subsampling,
                            &colorspace));
  if (std::int64_t{width} * height > kMaxImagePixels) {
    throw InputError(path.string(), "cannot decode image: too large (" + std::to_string(width) +
                                        " x " + std::to_string(height) + " pixels)");
  }
  StoredImage image;
  image.width = width;
  image.height = height;
  image.bit_depth = 8;
  image.samples.resize(static_cast<std::size_t>(width) * height);
  // libjpeg only warns of a truncated file, and fills the missing rows
  // gray: a file must end with its EOI marker (FF D9, padding allowed).
  const std::string_view tail =
      bytes.substr(bytes.size() - std::min<std::size_t>(bytes.size(), 64));
  if (tail.find("\xFF\xD9") == std::string_view::npos) {
    throw InputError(path.string(), "cannot decode image: truncated JPEG (no end marker)");
  }
  check(tjDecompress2(handle.get(), data, bytes.size(), image.samples.data(), width, width, height,
                      TJPF_GRAY, TJFLAG_ACCURATEDCT));
  return image;
}

}  // namespace omm
