#include "adapters/tiff/tiff_codec.h"

#include <tiffio.h>

#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/opencv/opencv_decode_testing.h"
#include "pipeline/core/error.h"
#include "tests/test_util.h"

namespace omm {
namespace {

using testing::OpenCvGrayDecode;
using testing::PatternMat;
using testing::SameImage;
using testing::Taken;
using testing::View;

StoredImage Decoded(std::string_view bytes) { return Taken(DecodeTiff(bytes, "x.tif")); }

TEST(TiffCodec, GrayRoundTripIsExactAndOpenCvReadsIt) {
  for (const int type : {CV_8UC1, CV_16UC1}) {
    const cv::Mat mat = PatternMat(61, 23, type);
    StoredImage image;
    image.width = 61;
    image.height = 23;
    image.bit_depth = type == CV_16UC1 ? 16 : 8;
    image.samples.assign(mat.data, mat.data + mat.total() * mat.elemSize());
    const std::string bytes = EncodeGrayTiff(image);
    const StoredImage ours = Decoded(bytes);
    EXPECT_EQ(ours.width, 61);
    EXPECT_EQ(ours.height, 23);
    EXPECT_EQ(ours.bit_depth, image.bit_depth);
    EXPECT_EQ(ours.samples, image.samples) << image.bit_depth << " bit";
    EXPECT_EQ(OpenCvGrayDecode(bytes).samples, image.samples) << image.bit_depth << " bit";
  }
}

// OpenCV writes TIFFs LZW-compressed, in strips; colour ones read as its
// cvtColor makes them gray, to the sample.
TEST(TiffCodec, OpenCvFilesOfEveryDepthAndColourReadAsOpenCvReadsThem) {
  for (const int type : {CV_8UC1, CV_8UC3, CV_8UC4, CV_16UC1, CV_16UC3, CV_16UC4}) {
    std::vector<uchar> bytes;
    ASSERT_TRUE(cv::imencode(".tiff", PatternMat(47, 31, type), bytes));
    EXPECT_TRUE(SameImage(Decoded(View(bytes)), OpenCvGrayDecode(View(bytes)))) << type;
  }
}

// What OpenCV does not write: 16-bit tiles (edges cut by the image) and a
// white-is-zero gray, through libtiff directly.
TEST(TiffCodec, SixteenBitTilesAndWhiteIsZeroRead) {
  const int width = 40, height = 37;  // tiles of 16 x 16: the last ones are cut
  const cv::Mat mat = PatternMat(width, height, CV_16UC1);
  const testing::TempDir dir;
  for (const bool white_is_zero : {false, true}) {
    const std::filesystem::path path = dir.path() / "tiles.tif";
    TIFF* tif = TIFFOpen(path.c_str(), "w");
    ASSERT_NE(tif, nullptr);
    TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, width);
    TIFFSetField(tif, TIFFTAG_IMAGELENGTH, height);
    TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 16);
    TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC,
                 white_is_zero ? PHOTOMETRIC_MINISWHITE : PHOTOMETRIC_MINISBLACK);
    TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_ADOBE_DEFLATE);
    TIFFSetField(tif, TIFFTAG_TILEWIDTH, 16);
    TIFFSetField(tif, TIFFTAG_TILELENGTH, 16);
    std::vector<std::uint16_t> tile(16 * 16);
    for (int ty = 0; ty < height; ty += 16) {
      for (int tx = 0; tx < width; tx += 16) {
        for (int y = 0; y < 16; ++y)
          for (int x = 0; x < 16; ++x) {
            const std::uint16_t v = ty + y < height && tx + x < width
                                        ? mat.at<ushort>(ty + y, tx + x)
                                        : std::uint16_t{0};
            tile[y * 16 + x] = white_is_zero ? static_cast<std::uint16_t>(65535 - v) : v;
          }
        ASSERT_GE(TIFFWriteTile(tif, tile.data(), tx, ty, 0, 0), 0);
      }
    }
    TIFFClose(tif);
    const StoredImage ours = Decoded(testing::ReadTextFile(path));
    EXPECT_EQ(ours.bit_depth, 16);
    ASSERT_EQ(ours.samples.size(), mat.total() * 2);
    EXPECT_EQ(0, std::memcmp(ours.samples.data(), mat.data, ours.samples.size()))
        << (white_is_zero ? "white is zero" : "black is zero");
  }
}

TEST(TiffCodec, OtherFilesAreLeftAndBadOnesSayWhy) {
  EXPECT_FALSE(DecodeTiff("\x89PNG not a tiff", "x.png").has_value());
  std::vector<uchar> bytes;
  ASSERT_TRUE(cv::imencode(".tiff", PatternMat(47, 31, CV_16UC1), bytes));
  try {
    DecodeTiff(View(bytes).substr(0, bytes.size() / 2), "tiles/t.tif");
    ADD_FAILURE() << "a truncated TIFF decoded";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("tiles/t.tif: cannot decode image"), std::string::npos)
        << e.what();
  }
  // An 8-bit file whose LZW data is garbled: the strip that fails to decode
  // fails the image (libtiff would otherwise skip it).
  ASSERT_TRUE(cv::imencode(".tiff", PatternMat(47, 31, CV_8UC1), bytes));
  for (std::size_t k = 8; k < bytes.size() / 2; ++k) bytes[k] = 0xFF;
  EXPECT_THROW(DecodeTiff(View(bytes), "tiles/t.tif"), InputError);
  cv::Mat floats(5, 7, CV_32F, cv::Scalar(0.5));
  ASSERT_TRUE(cv::imencode(".tiff", floats, bytes));
  try {
    DecodeTiff(View(bytes), "tiles/f.tif");
    ADD_FAILURE() << "a float TIFF decoded";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("expected an 8- or 16-bit image"), std::string::npos)
        << e.what();
  }
}

// A header of more than 2^30 pixels is refused before anything is allocated.
TEST(TiffCodec, AHugeHeaderIsRefused) {
  StoredImage image;
  image.width = image.height = 2;
  image.samples.assign(4, 7);
  std::string tiff = EncodeGrayTiff(image);
  ASSERT_EQ(tiff.substr(0, 4), std::string_view("II*\0", 4));  // little-endian
  const auto read16 = [&](std::size_t at) {
    return static_cast<unsigned>(static_cast<unsigned char>(tiff[at])) |
           static_cast<unsigned>(static_cast<unsigned char>(tiff[at + 1])) << 8;
  };
  const std::size_t ifd = read16(4) | read16(6) << 16;
  int patched = 0;
  // Entries of 12 bytes: tag, type (3 short, 4 long), count, value.
  for (unsigned k = 0; k < read16(ifd); ++k) {
    const std::size_t entry = ifd + 2 + 12 * k;
    if (read16(entry) != 256 && read16(entry) != 257) continue;  // ImageWidth, ImageLength
    ASSERT_TRUE(read16(entry + 2) == 3 || read16(entry + 2) == 4);
    const char value[4] = {'\x40', '\x9C', 0, 0};  // 40000
    tiff.replace(entry + 8, read16(entry + 2) == 3 ? 2 : 4, value, read16(entry + 2) == 3 ? 2 : 4);
    ++patched;
  }
  ASSERT_EQ(patched, 2);
  try {
    DecodeTiff(tiff, "tiles/huge.tif");
    ADD_FAILURE() << "a 1.6-gigapixel header was taken";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(
                  "tiles/huge.tif: cannot decode image: too large (40000 x 40000 pixels)"),
              std::string::npos)
        << e.what();
  }
}

// The real TIFFs of ../shared/data (16-bit microscope tiles) read as OpenCV
// reads them.
TEST(TiffCodec, RealFilesReadAsOpenCvReadsThem) {
  const std::vector<std::filesystem::path> files = testing::SharedDataFiles(".tif");
  if (files.empty()) GTEST_SKIP() << "no .tif in " << testing::SharedDataDir();
  for (const std::filesystem::path& path : files) {
    const std::string bytes = testing::ReadTextFile(path);
    EXPECT_TRUE(SameImage(Decoded(bytes), OpenCvGrayDecode(bytes))) << path;
  }
}

}  // namespace
}  // namespace omm
