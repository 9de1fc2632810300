#include "adapters/png/png_codec.h"

#include <libdeflate.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "adapters/opencv/image_io.h"
#include "pipeline/core/error.h"
#include "tests/test_util.h"

namespace omm {
namespace {

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

std::string_view View(const std::vector<uchar>& bytes) {
  return {reinterpret_cast<const char*>(bytes.data()), bytes.size()};
}

StoredImage OpenCvDecode(std::string_view bytes) {
  const cv::Mat raw = cv::imdecode(
      cv::Mat(1, static_cast<int>(bytes.size()), CV_8U, const_cast<char*>(bytes.data())),
      cv::IMREAD_ANYDEPTH | cv::IMREAD_ANYCOLOR);
  StoredImage image;
  image.width = raw.cols;
  image.height = raw.rows;
  image.bit_depth = raw.depth() == CV_16U ? 16 : 8;
  image.samples.assign(raw.data, raw.data + raw.total() * raw.elemSize());
  return image;
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
      EXPECT_EQ(OpenCvDecode(png).samples, image.samples) << bits << " bit, level " << level;
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
}

// The real PNGs of ../shared/data (calibration plates and microscope tiles
// from public sources, written by other encoders): every one this reader
// takes decodes to OpenCV's samples exactly; the others are left to OpenCV.
TEST(PngCodec, RealFilesDecodeAsOpenCvDecodesThem) {
  const std::filesystem::path data = testing::SharedDataDir();
  if (!std::filesystem::is_directory(data)) GTEST_SKIP() << data << " is not there";
  int num_taken = 0, num_left = 0;
  for (const auto& entry : std::filesystem::recursive_directory_iterator(data)) {
    if (entry.path().extension() != ".png") continue;
    std::ifstream file(entry.path(), std::ios::binary);
    const std::string bytes{std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>()};
    const std::optional<StoredImage> ours = DecodeGrayPng(bytes, entry.path());
    if (!ours) {
      ++num_left;
      continue;
    }
    ++num_taken;
    const StoredImage theirs = OpenCvDecode(bytes);
    EXPECT_EQ(ours->width, theirs.width) << entry.path();
    EXPECT_EQ(ours->height, theirs.height) << entry.path();
    EXPECT_EQ(ours->bit_depth, theirs.bit_depth) << entry.path();
    EXPECT_TRUE(ours->samples == theirs.samples) << entry.path();
  }
  std::printf("%d real PNGs decoded here, %d left to OpenCV\n", num_taken, num_left);
  EXPECT_GT(num_taken, 0);
}

}  // namespace
}  // namespace omm
