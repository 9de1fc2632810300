#include "adapters/tiff/tiff_codec.h"

#include <tiffio.h>

#include <algorithm>
#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "pipeline/core/error.h"

namespace omm {
namespace {

// A file in memory for TIFFClientOpen: read from `data`, or written into it.
struct MemoryFile {
  std::string data;
  std::string_view read;  // decoding: the caller's bytes (not copied)
  toff_t pos = 0;
  bool writing = false;
  std::string error;  // libtiff's first error message
};

std::size_t Size(const MemoryFile& f) { return f.writing ? f.data.size() : f.read.size(); }

tmsize_t ReadProc(thandle_t handle, void* buf, tmsize_t size) {
  auto* f = static_cast<MemoryFile*>(handle);
  const char* src = f->writing ? f->data.data() : f->read.data();
  const std::size_t n = Size(*f);
  if (f->pos >= n) return 0;
  const std::size_t count = std::min<std::size_t>(static_cast<std::size_t>(size), n - f->pos);
  std::memcpy(buf, src + f->pos, count);
  f->pos += count;
  return static_cast<tmsize_t>(count);
}

tmsize_t WriteProc(thandle_t handle, void* buf, tmsize_t size) {
  auto* f = static_cast<MemoryFile*>(handle);
  if (!f->writing) return 0;
  const std::size_t end = f->pos + static_cast<std::size_t>(size);
  if (end > f->data.size()) f->data.resize(end);
  std::memcpy(f->data.data() + f->pos, buf, static_cast<std::size_t>(size));
  f->pos = end;
  return size;
}

toff_t SeekProc(thandle_t handle, toff_t offset, int whence) {
  auto* f = static_cast<MemoryFile*>(handle);
  toff_t base = 0;
  if (whence == SEEK_CUR) base = f->pos;
  if (whence == SEEK_END) base = Size(*f);
  f->pos = base + offset;  // toff_t is unsigned: a negative offset wraps, the sum does not
  return f->pos;
}

int CloseProc(thandle_t) { return 0; }
toff_t SizeProc(thandle_t handle) { return Size(*static_cast<MemoryFile*>(handle)); }

int MapProc(thandle_t handle, void** base, toff_t* size) {
  auto* f = static_cast<MemoryFile*>(handle);
  if (f->writing) return 0;
  *base = const_cast<char*>(f->read.data());
  *size = f->read.size();
  return 1;
}

void UnmapProc(thandle_t, void*, toff_t) {}

int KeepError(TIFF*, void* user, const char* module, const char* fmt, va_list ap) {
  auto* f = static_cast<MemoryFile*>(user);
  if (f->error.empty()) {
    char text[512];
    std::vsnprintf(text, sizeof(text), fmt, ap);
    f->error = (module != nullptr ? std::string(module) + ": " : std::string()) + text;
  }
  return 1;  // handled: not printed
}

int IgnoreWarning(TIFF*, void*, const char*, const char*, va_list) { return 1; }

struct TiffCloser {
  void operator()(TIFF* tif) const { TIFFClose(tif); }
};
using TiffHandle = std::unique_ptr<TIFF, TiffCloser>;

TiffHandle Open(MemoryFile* file, const char* mode) {
  const std::unique_ptr<TIFFOpenOptions, decltype(&TIFFOpenOptionsFree)> options(
      TIFFOpenOptionsAlloc(), TIFFOpenOptionsFree);
  if (!options) throw std::bad_alloc();
  TIFFOpenOptionsSetErrorHandlerExtR(options.get(), KeepError, file);
  TIFFOpenOptionsSetWarningHandlerExtR(options.get(), IgnoreWarning, nullptr);
  return TiffHandle(TIFFClientOpenExt("memory", mode, file, ReadProc, WriteProc, SeekProc,
                                      CloseProc, SizeProc, MapProc, UnmapProc, options.get()));
}

// 16-bit samples, `channels` a pixel, interleaved, rows of width * channels.
bool ReadSixteenBit(TIFF* tif, int width, int height, int channels,
                    std::vector<std::uint16_t>* samples) {
  const std::size_t row = static_cast<std::size_t>(width) * channels;
  samples->assign(row * height, 0);
  if (!TIFFIsTiled(tif)) {
    for (int y = 0; y < height; ++y) {
      if (TIFFReadScanline(tif, samples->data() + y * row, static_cast<std::uint32_t>(y), 0) < 0)
        return false;
    }
    return true;
  }
  std::uint32_t tile_w = 0, tile_h = 0;
  TIFFGetField(tif, TIFFTAG_TILEWIDTH, &tile_w);
  TIFFGetField(tif, TIFFTAG_TILELENGTH, &tile_h);
  if (tile_w == 0 || tile_h == 0) return false;
  std::vector<std::uint16_t> tile(static_cast<std::size_t>(tile_w) * tile_h * channels);
  for (std::uint32_t ty = 0; ty < static_cast<std::uint32_t>(height); ty += tile_h) {
    for (std::uint32_t tx = 0; tx < static_cast<std::uint32_t>(width); tx += tile_w) {
      if (TIFFReadTile(tif, tile.data(), tx, ty, 0, 0) < 0) return false;
      const std::uint32_t w = std::min(tile_w, width - tx), h = std::min(tile_h, height - ty);
      for (std::uint32_t y = 0; y < h; ++y) {
        std::memcpy(samples->data() + (ty + y) * row + tx * channels,
                    tile.data() + static_cast<std::size_t>(y) * tile_w * channels,
                    static_cast<std::size_t>(w) * channels * sizeof(std::uint16_t));
      }
    }
  }
  return true;
}

}  // namespace

std::optional<StoredImage> DecodeTiff(std::string_view bytes, const std::filesystem::path& path) {
  if (bytes.size() < 4 || (bytes.substr(0, 4) != std::string_view("II*\0", 4) &&
                           bytes.substr(0, 4) != std::string_view("MM\0*", 4))) {
    return std::nullopt;
  }
  MemoryFile file;
  file.read = bytes;
  const auto fail = [&](const std::string& why) {
    return InputError(path.string(), "cannot decode image: " + why +
                                         (file.error.empty() ? "" : " (" + file.error + ")"));
  };
  const TiffHandle tif = Open(&file, "r");
  if (!tif) throw fail("corrupt TIFF");
  std::uint32_t width = 0, height = 0;
  std::uint16_t bits = 1, channels = 1, photometric = PHOTOMETRIC_MINISBLACK,
                format = SAMPLEFORMAT_UINT, planar = PLANARCONFIG_CONTIG;
  if (!TIFFGetField(tif.get(), TIFFTAG_IMAGEWIDTH, &width) ||
      !TIFFGetField(tif.get(), TIFFTAG_IMAGELENGTH, &height) || width == 0 || height == 0 ||
      width > 0x7fffffffu || height > 0x7fffffffu) {
    throw fail("corrupt TIFF (no image size)");
  }
  if (std::int64_t{width} * height > kMaxImagePixels) {
    throw fail("too large (" + std::to_string(width) + " x " + std::to_string(height) + " pixels)");
  }
  TIFFGetFieldDefaulted(tif.get(), TIFFTAG_BITSPERSAMPLE, &bits);
  TIFFGetFieldDefaulted(tif.get(), TIFFTAG_SAMPLESPERPIXEL, &channels);
  TIFFGetFieldDefaulted(tif.get(), TIFFTAG_SAMPLEFORMAT, &format);
  TIFFGetFieldDefaulted(tif.get(), TIFFTAG_PLANARCONFIG, &planar);
  TIFFGetField(tif.get(), TIFFTAG_PHOTOMETRIC, &photometric);
  if (format != SAMPLEFORMAT_UINT || bits > 16 || (bits > 8 && bits != 16)) {
    throw InputError(path.string(), "expected an 8- or 16-bit image (this TIFF has " +
                                        std::to_string(bits) + "-bit " +
                                        (format == SAMPLEFORMAT_UINT ? "unsigned"
                                                                     : "non-integer "
                                                                       "or signed") +
                                        " samples)");
  }
  const int w = static_cast<int>(width), h = static_cast<int>(height);
  if (bits <= 8) {
    // libtiff renders every 8-bit kind as RGBA, top row first; it stops at
    // the first strip or tile it cannot read (else it would skip it).
    std::vector<std::uint32_t> raster(static_cast<std::size_t>(width) * height);
    if (!TIFFReadRGBAImageOriented(tif.get(), width, height, raster.data(), ORIENTATION_TOPLEFT,
                                   /*stop_on_error=*/1)) {
      throw fail("cannot render this TIFF");
    }
    std::vector<std::uint8_t> rgba(raster.size() * 4);
    for (std::size_t k = 0; k < raster.size(); ++k) {
      rgba[4 * k] = static_cast<std::uint8_t>(TIFFGetR(raster[k]));
      rgba[4 * k + 1] = static_cast<std::uint8_t>(TIFFGetG(raster[k]));
      rgba[4 * k + 2] = static_cast<std::uint8_t>(TIFFGetB(raster[k]));
      rgba[4 * k + 3] = static_cast<std::uint8_t>(TIFFGetA(raster[k]));
    }
    return GrayFromInterleaved(rgba.data(), static_cast<std::size_t>(w) * 4, w, h, 4, 8);
  }
  const bool gray = photometric == PHOTOMETRIC_MINISBLACK || photometric == PHOTOMETRIC_MINISWHITE;
  const bool rgb = photometric == PHOTOMETRIC_RGB;
  if (!((gray && channels <= 2) || (rgb && (channels == 3 || channels == 4))) ||
      (planar != PLANARCONFIG_CONTIG && channels > 1)) {
    throw InputError(path.string(),
                     "16-bit TIFF of a kind not read (photometric " + std::to_string(photometric) +
                         ", " + std::to_string(channels) + " samples a pixel" +
                         (planar != PLANARCONFIG_CONTIG ? ", in separate planes" : "") +
                         "): save it as gray or RGB, interleaved");
  }
  std::vector<std::uint16_t> samples;
  if (!ReadSixteenBit(tif.get(), w, h, channels, &samples)) throw fail("corrupt TIFF");
  if (photometric == PHOTOMETRIC_MINISWHITE) {
    for (std::size_t k = 0; k < samples.size(); k += channels) samples[k] = 65535 - samples[k];
  }
  return GrayFromInterleaved(reinterpret_cast<const std::uint8_t*>(samples.data()),
                             static_cast<std::size_t>(w) * channels * 2, w, h, channels, 16);
}

std::string EncodeGrayTiff(const StoredImage& image) {
  MemoryFile file;
  file.writing = true;
  {
    const TiffHandle tif = Open(&file, "w");
    if (!tif) throw std::runtime_error("libtiff: " + file.error);
    const std::size_t row = static_cast<std::size_t>(image.width) * (image.bit_depth / 8);
    TIFFSetField(tif.get(), TIFFTAG_IMAGEWIDTH, static_cast<std::uint32_t>(image.width));
    TIFFSetField(tif.get(), TIFFTAG_IMAGELENGTH, static_cast<std::uint32_t>(image.height));
    TIFFSetField(tif.get(), TIFFTAG_BITSPERSAMPLE, static_cast<std::uint16_t>(image.bit_depth));
    TIFFSetField(tif.get(), TIFFTAG_SAMPLESPERPIXEL, std::uint16_t{1});
    TIFFSetField(tif.get(), TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
    TIFFSetField(tif.get(), TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
    TIFFSetField(tif.get(), TIFFTAG_COMPRESSION, COMPRESSION_NONE);
    TIFFSetField(tif.get(), TIFFTAG_ROWSPERSTRIP, TIFFDefaultStripSize(tif.get(), 0));
    for (int y = 0; y < image.height; ++y) {
      auto* samples = const_cast<std::uint8_t*>(image.samples.data()) + y * row;
      if (TIFFWriteScanline(tif.get(), samples, static_cast<std::uint32_t>(y), 0) < 0)
        throw std::runtime_error("libtiff: " + file.error);
    }
    if (!TIFFWriteDirectory(tif.get())) throw std::runtime_error("libtiff: " + file.error);
  }
  return std::move(file.data);
}

}  // namespace omm
