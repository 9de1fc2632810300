#include "adapters/netpbm/pnm_codec.h"

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

StoredImage Decoded(std::string_view bytes) { return Taken(DecodePnm(bytes, "x.pgm")); }

// OpenCV writes binary P5 / P6 (16-bit big-endian for CV_16U).
TEST(PnmCodec, OpenCvFilesReadAsOpenCvReadsThem) {
  for (const int type : {CV_8UC1, CV_16UC1, CV_8UC3, CV_16UC3}) {
    std::vector<uchar> bytes;
    ASSERT_TRUE(
        cv::imencode(CV_MAT_CN(type) == 1 ? ".pgm" : ".ppm", PatternMat(29, 17, type), bytes));
    EXPECT_TRUE(SameImage(Decoded(View(bytes)), OpenCvGrayDecode(View(bytes)))) << type;
  }
}

// Plain (ASCII) files, comments in the header, a maxval that is not full
// scale (samples kept as they are).
TEST(PnmCodec, PlainFilesAndCommentsRead) {
  const StoredImage gray = Decoded("P2 # a comment\n3 2\n# another\n1000\n0 1 2\n997 998 1000\n");
  EXPECT_EQ(gray.bit_depth, 16);
  ASSERT_EQ(gray.samples.size(), 12u);
  std::uint16_t samples[6];
  std::memcpy(samples, gray.samples.data(), sizeof(samples));
  EXPECT_EQ(std::vector<std::uint16_t>(samples, samples + 6),
            (std::vector<std::uint16_t>{0, 1, 2, 997, 998, 1000}));
  const StoredImage colour = Decoded("P3 2 1 255  255 0 0  10 10 10");
  EXPECT_EQ(colour.bit_depth, 8);
  // 0.299 of red (OpenCV's rounding), and a gray pixel kept.
  EXPECT_EQ(colour.samples, (std::vector<std::uint8_t>{76, 10}));
}

TEST(PnmCodec, OtherFilesAreLeftAndBadOnesSayWhy) {
  EXPECT_FALSE(DecodePnm("\x89PNG not a pgm", "x.png").has_value());
  EXPECT_FALSE(DecodePnm("P4 1-bit bitmaps are not read here", "x.pbm").has_value());
  for (const char* bad :
       {"P5 3 2\n255\nabc", "P5 3 x 255\n", "P2 2 1 9\n3 10", "P5 0 2 255\n", "P6 2 2 70000\n"}) {
    try {
      DecodePnm(bad, "tiles/t.pgm");
      ADD_FAILURE() << "decoded: " << bad;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("tiles/t.pgm: cannot decode image: corrupt PGM/PPM"),
                std::string::npos)
          << e.what();
    }
  }
}

// A header of more than 2^30 pixels is refused before anything is allocated.
TEST(PnmCodec, AHugeHeaderIsRefused) {
  try {
    DecodePnm("P5 40000 40000 255\n", "tiles/huge.pgm");
    ADD_FAILURE() << "a 1.6-gigapixel header was taken";
  } catch (const InputError& e) {
    EXPECT_STREQ(e.what(), "tiles/huge.pgm: cannot decode image: too large (40000 x 40000 pixels)");
  }
}

// The real PGMs of ../shared/data (ViSP's circle-grid images) read as OpenCV
// reads them.
TEST(PnmCodec, RealFilesReadAsOpenCvReadsThem) {
  const std::vector<std::filesystem::path> files = testing::SharedDataFiles(".pgm");
  if (files.empty()) GTEST_SKIP() << "no .pgm in " << testing::SharedDataDir();
  for (const std::filesystem::path& path : files) {
    const std::string bytes = testing::ReadTextFile(path);
    EXPECT_TRUE(Decoded(bytes).samples == OpenCvGrayDecode(bytes).samples) << path;
  }
}

}  // namespace
}  // namespace omm
