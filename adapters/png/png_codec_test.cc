#include "adapters/png/png_codec.h"

#include <libdeflate.h>
#include <spng.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/opencv/image_io.h"
#include "adapters/opencv/opencv_decode_testing.h"
#include "pipeline/core/error.h"
#include "tests/test_util.h"

namespace omm {
namespace {

using testing::OpenCvGrayDecode;
using testing::PatternMat;
using testing::SameImage;
using testing::View;

// A smooth pattern with fine detail, so that libpng's adaptive filtering
// picks several filter types.
StoredImage Pattern(int width, int height, int bit_depth) {
  ImageF pixels(height, width);
  for (int r = 0; r < height; ++r)
    for (int c = 0; c < width; ++c)
      pixels(r, c) = 0.5f + 0.3f * static_cast<float>(std::sin(0.05 * r * c / (1 + r % 7))) +
                     0.15f * static_cast<float>(std::cos(0.9 * c + 0.4 * r));
  return QuantizeImage(pixels, bit_depth);
}

// The filter type of every row of a PNG (its IDAT chunks inflated).
std::set<int> FilterTypes(std::string_view png, int height, std::size_t stride) {
  std::string stream;
  for (std::size_t at = 8; at + 12 <= png.size();) {
    const auto* p = reinterpret_cast<const unsigned char*>(png.data() + at);
    const std::size_t length = (std::size_t{p[0]} << 24) | (p[1] << 16) | (p[2] << 8) | p[3];
    if (std::memcmp(p + 4, "IDAT", 4) == 0) stream.append(png.substr(at + 8, length));
    at += 12 + length;
  }
  std::vector<std::uint8_t> raw((stride + 1) * height);
  libdeflate_decompressor* d = libdeflate_alloc_decompressor();
  EXPECT_EQ(
      libdeflate_zlib_decompress(d, stream.data(), stream.size(), raw.data(), raw.size(), nullptr),
      LIBDEFLATE_SUCCESS);
  libdeflate_free_decompressor(d);
  std::set<int> types;
  for (int y = 0; y < height; ++y) types.insert(raw[y * (stride + 1)]);
  return types;
}

TEST(PngCodec, RoundTripsAndOpenCvReadsWhatItWrites) {
  for (const int bits : {8, 16}) {
    const StoredImage image = Pattern(61, 23, bits);
    for (const int level : {0, 1, 6}) {
      PngWriteOptions options;
      options.deflate_level = level;
      const std::string png = EncodeGrayPng(image, options);
      const std::optional<StoredImage> back = DecodeGrayPng(png, "x.png");
      ASSERT_TRUE(back.has_value());
      EXPECT_EQ(back->width, 61);
      EXPECT_EQ(back->height, 23);
      EXPECT_EQ(back->bit_depth, bits);
      EXPECT_EQ(back->samples, image.samples) << bits << " bit, level " << level;
      EXPECT_EQ(OpenCvGrayDecode(png).samples, image.samples) << bits << " bit, level " << level;
    }
  }
}

// Filters sub, up, average and Paeth (libpng's adaptive choice at OpenCV's
// explicit levels, sub at its default) decode to the samples OpenCV wrote;
// "none" is the level-0 round trip above.
TEST(PngCodec, DecodesOpenCvFilesOfEveryFilterType) {
  for (const int bits : {8, 16}) {
    const StoredImage image = Pattern(97, 64, bits);
    const cv::Mat mat(image.height, image.width, bits == 16 ? CV_16U : CV_8U,
                      const_cast<std::uint8_t*>(image.samples.data()));
    std::set<int> seen;
    for (const int level : {-1, 1, 9}) {
      std::vector<uchar> bytes;
      std::vector<int> params;
      if (level >= 0) params = {cv::IMWRITE_PNG_COMPRESSION, level};
      ASSERT_TRUE(cv::imencode(".png", mat, bytes, params));
      const std::set<int> types =
          FilterTypes(View(bytes), image.height, static_cast<std::size_t>(image.width) * bits / 8);
      seen.insert(types.begin(), types.end());
      const std::optional<StoredImage> ours = DecodeGrayPng(View(bytes), "x.png");
      ASSERT_TRUE(ours.has_value());
      EXPECT_EQ(ours->samples, image.samples) << bits << " bit, level " << level;
    }
    EXPECT_EQ(seen, (std::set<int>{1, 2, 3, 4})) << bits << " bit";
  }
}

TEST(PngCodec, OtherKindsAreLeftToTheCaller) {
  EXPECT_FALSE(DecodeGrayPng("not a png at all", "x.png").has_value());
  const cv::Mat colour(5, 7, CV_8UC3, cv::Scalar(10, 20, 30));
  std::vector<uchar> bytes;
  ASSERT_TRUE(cv::imencode(".png", colour, bytes));
  EXPECT_FALSE(DecodeGrayPng(View(bytes), "x.png").has_value());
}

// Every other kind goes through libspng: colour, alpha and 16-bit colour
// as OpenCV reads them gray, to the sample.
TEST(PngCodec, OtherKindsDecodeAsOpenCvReadsThemGray) {
  for (const int type : {CV_8UC3, CV_8UC4, CV_16UC3, CV_16UC4, CV_8UC1, CV_16UC1}) {
    std::vector<uchar> bytes;
    ASSERT_TRUE(cv::imencode(".png", PatternMat(47, 31, type), bytes));
    EXPECT_TRUE(SameImage(DecodePng(View(bytes), "x.png"), OpenCvGrayDecode(View(bytes)))) << type;
  }
}

// What OpenCV does not write, encoded by libspng: an interlaced gray PNG
// (Adam7) and a palette one read as the samples they hold.
TEST(PngCodec, InterlacedAndPaletteFilesDecode) {
  const cv::Mat gray = PatternMat(23, 19, CV_8UC1);
  for (const bool palette : {false, true}) {
    const std::unique_ptr<spng_ctx, decltype(&spng_ctx_free)> ctx(spng_ctx_new(SPNG_CTX_ENCODER),
                                                                  spng_ctx_free);
    ASSERT_EQ(spng_set_option(ctx.get(), SPNG_ENCODE_TO_BUFFER, 1), 0);
    spng_ihdr ihdr{};
    ihdr.width = 23;
    ihdr.height = 19;
    ihdr.bit_depth = 8;
    ihdr.color_type = palette ? SPNG_COLOR_TYPE_INDEXED : SPNG_COLOR_TYPE_GRAYSCALE;
    ihdr.interlace_method = palette ? SPNG_INTERLACE_NONE : SPNG_INTERLACE_ADAM7;
    ASSERT_EQ(spng_set_ihdr(ctx.get(), &ihdr), 0);
    if (palette) {  // entry k is gray k
      spng_plte plte{};
      plte.n_entries = 256;
      for (int k = 0; k < 256; ++k) {
        plte.entries[k].red = plte.entries[k].green = plte.entries[k].blue =
            static_cast<std::uint8_t>(k);
      }
      ASSERT_EQ(spng_set_plte(ctx.get(), &plte), 0);
    }
    ASSERT_EQ(
        spng_encode_image(ctx.get(), gray.data, gray.total(), SPNG_FMT_PNG, SPNG_ENCODE_FINALIZE),
        0);
    std::size_t size = 0;
    int error = 0;
    const std::unique_ptr<void, decltype(&std::free)> png(
        spng_get_png_buffer(ctx.get(), &size, &error), std::free);
    ASSERT_EQ(error, 0);
    const std::string_view bytes(static_cast<const char*>(png.get()), size);
    EXPECT_FALSE(DecodeGrayPng(bytes, "x.png").has_value());
    const StoredImage ours = DecodePng(bytes, "x.png");
    EXPECT_EQ(ours.bit_depth, 8);
    EXPECT_TRUE(ours.samples == std::vector<std::uint8_t>(gray.data, gray.data + gray.total()))
        << (palette ? "palette" : "interlaced");
  }
}

TEST(PngCodec, CorruptFilesThrow) {
  const std::string png = EncodeGrayPng(Pattern(40, 30, 8));
  std::string flipped = png;
  flipped[60] = static_cast<char>(flipped[60] ^ 1);  // inside IDAT: its CRC no longer matches
  EXPECT_THROW(DecodeGrayPng(flipped, "x.png"), InputError);
  try {
    DecodeGrayPng(png.substr(0, png.size() / 2), "x.png");
    ADD_FAILURE() << "a truncated PNG decoded";
  } catch (const InputError& e) {
    // Worded as the other decoders' failures are (project_reader's tests).
    EXPECT_STREQ(e.what(), "x.png: cannot decode image: corrupt PNG (truncated)");
  }
  std::string bad_filter = EncodeGrayPng(Pattern(40, 30, 8), PngWriteOptions{0});
  // Stored deflate: zlib header (2) and the block header (5) precede row 0's
  // filter byte; the IDAT's data starts at 8 + 25 + 8. Fix its CRC to match.
  const std::size_t idat = 8 + 25, filter_at = idat + 8 + 2 + 5;
  bad_filter[filter_at] = 7;
  const std::uint32_t length = 30 * 41 + 2 + 5 + 4;
  const std::uint32_t crc = libdeflate_crc32(0, bad_filter.data() + idat + 4, length + 4);
  for (int i = 0; i < 4; ++i)
    bad_filter[idat + 8 + length + i] = static_cast<char>(crc >> (24 - 8 * i));
  EXPECT_THROW(DecodeGrayPng(bad_filter, "x.png"), InputError);
  std::vector<uchar> colour;
  ASSERT_TRUE(cv::imencode(".png", PatternMat(40, 30, CV_8UC3), colour));
  try {
    DecodePng(View(colour).substr(0, colour.size() / 2), "tiles/c.png");
    ADD_FAILURE() << "a truncated colour PNG decoded";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("tiles/c.png: cannot decode image: corrupt PNG"),
              std::string::npos)
        << e.what();
  }
}

// A colour PNG whose header claims more than 2^30 pixels is refused before
// anything is allocated.
TEST(PngCodec, AHugeColourHeaderIsRefused) {
  std::string png = EncodeGrayPng(QuantizeImage(ImageF::Constant(2, 2, 0.5f), 8));
  // IHDR's data starts at 16: width, height (big-endian), depth, colour type.
  const unsigned char header[13] = {0, 0, 0x9c, 0x40, 0, 0, 0x9c, 0x40, 8, 2, 0, 0, 0};
  std::memcpy(png.data() + 16, header, 13);
  const std::uint32_t crc = libdeflate_crc32(0, png.data() + 12, 17);
  for (int i = 0; i < 4; ++i) png[29 + i] = static_cast<char>(crc >> (24 - 8 * i));
  EXPECT_FALSE(DecodeGrayPng(png, "x.png").has_value());  // colour: not this reader's
  try {
    DecodePng(png, "tiles/huge.png");
    ADD_FAILURE() << "a 1.6-gigapixel header was taken";
  } catch (const InputError& e) {
    EXPECT_STREQ(e.what(), "tiles/huge.png: cannot decode image: too large (40000 x 40000 pixels)");
  }
}

// The real PNGs of ../shared/data (calibration plates and microscope tiles
// from public sources, written by other encoders) decode to OpenCV's samples
// exactly, by this reader or, for the other kinds, by libspng.
TEST(PngCodec, RealFilesDecodeAsOpenCvDecodesThem) {
  const std::vector<std::filesystem::path> files = testing::SharedDataFiles(".png");
  if (files.empty()) GTEST_SKIP() << "no .png in " << testing::SharedDataDir();
  int num_gray = 0, num_other = 0;
  for (const std::filesystem::path& path : files) {
    const std::string bytes = testing::ReadTextFile(path);
    std::optional<StoredImage> ours = DecodeGrayPng(bytes, path);
    ++(ours ? num_gray : num_other);
    if (!ours) ours = DecodePng(bytes, path);
    EXPECT_TRUE(SameImage(*ours, OpenCvGrayDecode(bytes))) << path;
  }
  std::printf("%d real gray PNGs decoded here, %d other PNGs by libspng\n", num_gray, num_other);
  EXPECT_GT(num_gray, 0);
}

}  // namespace
}  // namespace omm
