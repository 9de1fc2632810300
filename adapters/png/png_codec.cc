#include "adapters/png/png_codec.h"

#include <libdeflate.h>
#include <spng.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include <algorithm>
#include <cassert>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "pipeline/core/error.h"

namespace omm {
namespace {

constexpr unsigned char kSignature[8] = {137, 80, 78, 71, 13, 10, 26, 10};

std::uint32_t ReadBigEndian32(const unsigned char* p) {
  return (std::uint32_t{p[0]} << 24) | (std::uint32_t{p[1]} << 16) | (std::uint32_t{p[2]} << 8) |
         std::uint32_t{p[3]};
}

void AppendBigEndian32(std::uint32_t x, std::string* out) {
  const char bytes[4] = {static_cast<char>(x >> 24), static_cast<char>(x >> 16),
                         static_cast<char>(x >> 8), static_cast<char>(x)};
  out->append(bytes, 4);
}

// Length, type, data and the CRC-32 of type and data.
void AppendChunk(const char type[4], const unsigned char* data, std::size_t size,
                 std::string* out) {
  AppendBigEndian32(static_cast<std::uint32_t>(size), out);
  const std::size_t start = out->size();
  out->append(type, 4);
  out->append(reinterpret_cast<const char*>(data), size);
  AppendBigEndian32(libdeflate_crc32(0, out->data() + start, size + 4), out);
}

struct DecompressorDeleter {
  void operator()(libdeflate_decompressor* d) const { libdeflate_free_decompressor(d); }
};
struct CompressorDeleter {
  void operator()(libdeflate_compressor* c) const { libdeflate_free_compressor(c); }
};

// Filter "sub" undone: row[k] += row[k - bpp], a running sum at lag bpp.
// Byte by byte it is one long dependency chain (a quarter of the decoding
// time of an 8-bit image): with SSE2, a prefix sum over 16 bytes in log
// steps plus the carry of the previous 16.
template <int kBpp>
void UndoSub(std::uint8_t* row, std::size_t n) {
  std::size_t k = 0;
#if defined(__SSE2__)
  __m128i carry = _mm_setzero_si128();  // the previous block's last sample, in every lane
  for (; k + 16 <= n; k += 16) {
    __m128i x = _mm_loadu_si128(reinterpret_cast<const __m128i*>(row + k));
    if constexpr (kBpp == 1) x = _mm_add_epi8(x, _mm_slli_si128(x, 1));
    x = _mm_add_epi8(x, _mm_slli_si128(x, 2));
    x = _mm_add_epi8(x, _mm_slli_si128(x, 4));
    x = _mm_add_epi8(x, _mm_slli_si128(x, 8));
    x = _mm_add_epi8(x, carry);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(row + k), x);
    if constexpr (kBpp == 1) {
      carry = _mm_set1_epi8(static_cast<char>(row[k + 15]));
    } else {
      carry = _mm_shuffle_epi32(_mm_shufflelo_epi16(_mm_srli_si128(x, 14), 0), 0);
    }
  }
#endif
  for (; k < n; ++k) row[k] += k >= static_cast<std::size_t>(kBpp) ? row[k - kBpp] : 0;
}

std::uint8_t Paeth(int a, int b, int c) {
  const int p = a + b - c, pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
  return static_cast<std::uint8_t>(pa <= pb && pa <= pc ? a : pb <= pc ? b : c);
}

// Undoes the row's filter in place (PNG spec 9.2); `prev` is the previous
// row, already unfiltered (zeros for the first). bpp: bytes per sample.
bool Unfilter(int type, int bpp, std::uint8_t* row, const std::uint8_t* prev, std::size_t n) {
  switch (type) {
    case 0: return true;
    case 1:  // sub
      bpp == 1 ? UndoSub<1>(row, n) : UndoSub<2>(row, n);
      return true;
    case 2:  // up
      for (std::size_t k = 0; k < n; ++k) row[k] += prev[k];
      return true;
    case 3:  // average
      for (std::size_t k = 0; k < n; ++k) {
        const int left = k >= static_cast<std::size_t>(bpp) ? row[k - bpp] : 0;
        row[k] += static_cast<std::uint8_t>((left + prev[k]) >> 1);
      }
      return true;
    case 4:  // Paeth
      for (std::size_t k = 0; k < n; ++k) {
        const bool first = k < static_cast<std::size_t>(bpp);
        row[k] += Paeth(first ? 0 : row[k - bpp], prev[k], first ? 0 : prev[k - bpp]);
      }
      return true;
    default: return false;
  }
}

}  // namespace

std::optional<StoredImage> DecodeGrayPng(std::string_view bytes,
                                         const std::filesystem::path& path) {
  const auto* data = reinterpret_cast<const unsigned char*>(bytes.data());
  if (bytes.size() < 8 || std::memcmp(data, kSignature, 8) != 0) return std::nullopt;
  auto corrupt = [&](const std::string& why) {
    return InputError(path.string(), "cannot decode image: corrupt PNG (" + why + ")");
  };
  StoredImage image;
  bool header = false, end = false;
  // The zlib stream: the IDAT chunks' data in order (one view when there is one chunk).
  std::string_view stream;
  std::string joined;
  int num_idat = 0;
  for (std::size_t at = 8; !end;) {
    if (bytes.size() - at < 12) throw corrupt("truncated");
    const std::uint32_t length = ReadBigEndian32(data + at);
    const unsigned char* type = data + at + 4;
    if (length > bytes.size() - at - 12) throw corrupt("truncated");
    const unsigned char* body = type + 4;
    if (libdeflate_crc32(0, type, length + 4) != ReadBigEndian32(body + length))
      throw corrupt("CRC mismatch in a chunk");
    at += 12 + length;
    const std::string_view name(reinterpret_cast<const char*>(type), 4);
    if (!header) {
      if (name != "IHDR" || length != 13) throw corrupt("no IHDR chunk first");
      const std::uint32_t width = ReadBigEndian32(body), height = ReadBigEndian32(body + 4);
      const int depth = body[8], colour = body[9], interlace = body[12];
      if (width == 0 || height == 0 || width > 0x7fffffffu || height > 0x7fffffffu ||
          body[10] != 0 || body[11] != 0)
        throw corrupt("bad IHDR");
      if (colour != 0 || (depth != 8 && depth != 16) || interlace != 0) return std::nullopt;
      image.width = static_cast<int>(width);
      image.height = static_cast<int>(height);
      image.bit_depth = depth;
      header = true;
    } else if (name == "IDAT") {
      ++num_idat;
      const std::string_view chunk(reinterpret_cast<const char*>(body), length);
      if (num_idat == 1) {
        stream = chunk;
      } else {
        if (num_idat == 2) joined = stream;
        joined += chunk;
        stream = joined;
      }
    } else if (name == "IEND") {
      end = true;
    } else if (name == "tRNS" || (type[0] & 0x20) == 0) {
      return std::nullopt;  // transparency, or a critical chunk this reader does not know
    }
  }
  if (num_idat == 0) throw corrupt("no IDAT chunk");

  const int bpp = image.bit_depth / 8;
  const std::size_t stride = static_cast<std::size_t>(image.width) * bpp;
  const std::size_t raw_size = (stride + 1) * static_cast<std::size_t>(image.height);
  // Deflate expands at most ~1032:1: a larger image is a corrupt header, not
  // an allocation to attempt.
  if (raw_size / 1032 > stream.size() + 64) throw corrupt("too little image data for its size");
  std::vector<std::uint8_t> raw(raw_size);
  const std::unique_ptr<libdeflate_decompressor, DecompressorDeleter> decompressor(
      libdeflate_alloc_decompressor());
  if (!decompressor) throw std::bad_alloc();
  if (libdeflate_zlib_decompress(decompressor.get(), stream.data(), stream.size(), raw.data(),
                                 raw.size(), nullptr) != LIBDEFLATE_SUCCESS)
    throw corrupt("the image data does not inflate to its rows");

  image.samples.resize(stride * static_cast<std::size_t>(image.height));
  const std::vector<std::uint8_t> zeros(stride, 0);
  const std::uint8_t* prev = zeros.data();
  for (int y = 0; y < image.height; ++y) {
    std::uint8_t* row = raw.data() + static_cast<std::size_t>(y) * (stride + 1);
    if (!Unfilter(row[0], bpp, row + 1, prev, stride)) throw corrupt("unknown filter type");
    std::uint8_t* out = image.samples.data() + static_cast<std::size_t>(y) * stride;
    if (bpp == 1) {
      std::memcpy(out, row + 1, stride);
    } else {
      // Big-endian in the file, native in StoredImage (memcpy: no aliasing).
      for (int x = 0; x < image.width; ++x) {
        const auto sample = static_cast<std::uint16_t>((row[1 + 2 * x] << 8) | row[2 + 2 * x]);
        std::memcpy(out + 2 * x, &sample, 2);
      }
    }
    prev = row + 1;
  }
  return image;
}

StoredImage DecodePng(std::string_view bytes, const std::filesystem::path& path) {
  const std::unique_ptr<spng_ctx, decltype(&spng_ctx_free)> ctx(spng_ctx_new(0), spng_ctx_free);
  if (!ctx) throw std::bad_alloc();
  const auto fail = [&](int error) {
    return InputError(path.string(), std::string("cannot decode image: corrupt PNG (") +
                                         spng_strerror(error) + ")");
  };
  spng_ihdr ihdr{};
  if (int e = spng_set_png_buffer(ctx.get(), bytes.data(), bytes.size()); e != 0) throw fail(e);
  if (int e = spng_get_ihdr(ctx.get(), &ihdr); e != 0) throw fail(e);
  if (std::int64_t{ihdr.width} * ihdr.height > kMaxImagePixels) {
    throw InputError(path.string(), "cannot decode image: too large (" +
                                        std::to_string(ihdr.width) + " x " +
                                        std::to_string(ihdr.height) + " pixels)");
  }
  // Formats libspng converts every colour type to (host-endian samples).
  int format = SPNG_FMT_RGBA8, channels = 4;
  if (ihdr.bit_depth == 16) {
    format = SPNG_FMT_RGBA16;
  } else if (ihdr.color_type == SPNG_COLOR_TYPE_GRAYSCALE) {
    format = SPNG_FMT_G8;
    channels = 1;
  } else if (ihdr.color_type == SPNG_COLOR_TYPE_GRAYSCALE_ALPHA) {
    format = SPNG_FMT_GA8;
    channels = 2;
  }
  std::size_t size = 0;
  if (int e = spng_decoded_image_size(ctx.get(), format, &size); e != 0) throw fail(e);
  std::vector<std::uint8_t> decoded(size);
  if (int e = spng_decode_image(ctx.get(), decoded.data(), size, format, 0); e != 0) throw fail(e);
  const int bit_depth = ihdr.bit_depth == 16 ? 16 : 8;
  const std::size_t stride = std::size_t{ihdr.width} * channels * (bit_depth / 8);
  return GrayFromInterleaved(decoded.data(), stride, static_cast<int>(ihdr.width),
                             static_cast<int>(ihdr.height), channels, bit_depth);
}

std::string PngWriteOptions::Check() const {
  if (deflate_level < 0 || deflate_level > 12) return "deflate_level must be in [0, 12]";
  return "";
}

std::string EncodeGrayPng(const StoredImage& image, const PngWriteOptions& options) {
  assert(options.Check().empty());
  assert(image.bit_depth == 8 || image.bit_depth == 16);
  const int bpp = image.bit_depth / 8;
  const std::size_t stride = static_cast<std::size_t>(image.width) * bpp;
  assert(image.samples.size() == stride * static_cast<std::size_t>(image.height));
  // Stored rows gain nothing from a filter; compressed ones gain ~8 % from sub.
  const bool sub = options.deflate_level > 0;
  std::vector<std::uint8_t> raw((stride + 1) * static_cast<std::size_t>(image.height));
  for (int y = 0; y < image.height; ++y) {
    std::uint8_t* row = raw.data() + static_cast<std::size_t>(y) * (stride + 1);
    const std::uint8_t* in = image.samples.data() + static_cast<std::size_t>(y) * stride;
    row[0] = sub ? 1 : 0;
    if (bpp == 1) {
      std::memcpy(row + 1, in, stride);
    } else {
      for (int x = 0; x < image.width; ++x) {
        std::uint16_t sample;
        std::memcpy(&sample, in + 2 * x, 2);
        row[1 + 2 * x] = static_cast<std::uint8_t>(sample >> 8);
        row[2 + 2 * x] = static_cast<std::uint8_t>(sample);
      }
    }
    if (sub) {
      for (std::size_t k = stride; k > static_cast<std::size_t>(bpp); --k) row[k] -= row[k - bpp];
    }
  }
  const std::unique_ptr<libdeflate_compressor, CompressorDeleter> compressor(
      libdeflate_alloc_compressor(options.deflate_level));
  if (!compressor) throw std::bad_alloc();
  std::vector<std::uint8_t> zlib(libdeflate_zlib_compress_bound(compressor.get(), raw.size()));
  const std::size_t zlib_size =
      libdeflate_zlib_compress(compressor.get(), raw.data(), raw.size(), zlib.data(), zlib.size());
  assert(zlib_size > 0);  // the bound always suffices

  std::string out(reinterpret_cast<const char*>(kSignature), 8);
  out.reserve(8 + 25 + 12 + zlib_size + 12);
  unsigned char header[13] = {};
  for (int i = 0; i < 4; ++i) {
    header[i] = static_cast<unsigned char>(static_cast<std::uint32_t>(image.width) >> (24 - 8 * i));
    header[4 + i] =
        static_cast<unsigned char>(static_cast<std::uint32_t>(image.height) >> (24 - 8 * i));
  }
  header[8] = static_cast<unsigned char>(image.bit_depth);  // colour type 0: gray; no interlace
  AppendChunk("IHDR", header, sizeof(header), &out);
  // Chunks hold at most 2^31 - 1 bytes.
  constexpr std::size_t kMaxChunk = std::size_t{1} << 30;
  for (std::size_t at = 0; at < zlib_size; at += kMaxChunk)
    AppendChunk("IDAT", zlib.data() + at, std::min(kMaxChunk, zlib_size - at), &out);
  AppendChunk("IEND", header, 0, &out);
  return out;
}

}  // namespace omm
