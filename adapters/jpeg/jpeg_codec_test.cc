#include "adapters/jpeg/jpeg_codec.h"

#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/opencv/opencv_decode_testing.h"
#include "pipeline/core/error.h"
#include "tests/test_util.h"

namespace omm {
namespace {

using testing::PatternMat;
using testing::SameImage;
using testing::Taken;
using testing::View;

// OpenCV's gray read of a JPEG: libjpeg's own luma output, as ours.
StoredImage OpenCvGrayJpeg(std::string_view bytes) {
  const cv::Mat gray = cv::imdecode(
      cv::Mat(1, static_cast<int>(bytes.size()), CV_8U, const_cast<char*>(bytes.data())),
      cv::IMREAD_GRAYSCALE);
  StoredImage image;
  image.width = gray.cols;
  image.height = gray.rows;
  image.samples.assign(gray.data, gray.data + gray.total());
  return image;
}

TEST(JpegCodec, ColourAndGrayFilesReadAsOpenCvReadsThemGray) {
  for (const int type : {CV_8UC1, CV_8UC3}) {
    std::vector<uchar> bytes;
    ASSERT_TRUE(cv::imencode(".jpg", PatternMat(67, 45, type), bytes));
    EXPECT_TRUE(SameImage(Taken(DecodeJpeg(View(bytes), "x.jpg")), OpenCvGrayJpeg(View(bytes))))
        << type;
  }
}

TEST(JpegCodec, OtherFilesAreLeftAndBadOnesSayWhy) {
  EXPECT_FALSE(DecodeJpeg("\x89PNG not a jpeg", "x.png").has_value());
  std::vector<uchar> bytes;
  ASSERT_TRUE(cv::imencode(".jpg", PatternMat(67, 45, CV_8UC3), bytes));
  // Half the data lost, the end marker kept: libjpeg warns and decodes.
  std::vector<uchar> cut(bytes.begin(), bytes.begin() + bytes.size() / 2);
  cut.insert(cut.end(), {0xFF, 0xD9});
  EXPECT_THROW(DecodeJpeg(View(cut), "tiles/g.jpg"), InputError);
  for (const std::size_t size : {bytes.size() / 2, std::size_t{40}}) {
    try {
      DecodeJpeg(View(bytes).substr(0, size), "tiles/t.jpg");
      ADD_FAILURE() << "a JPEG of " << size << " of its " << bytes.size() << " bytes decoded";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("tiles/t.jpg: cannot decode image"), std::string::npos)
          << e.what();
    }
  }
}

// Extraneous bytes before a marker, as some cameras write: libjpeg warns,
// and the image is whole, so it is taken, sample for sample.
TEST(JpegCodec, ExtraneousBytesBeforeAMarkerAreAccepted) {
  std::vector<uchar> bytes;
  ASSERT_TRUE(cv::imencode(".jpg", PatternMat(67, 45, CV_8UC3), bytes));
  const std::optional<StoredImage> clean = DecodeJpeg(View(bytes), "x.jpg");
  ASSERT_TRUE(clean.has_value());
  std::vector<uchar> padded = bytes;
  std::size_t sos = 2;  // the start-of-scan marker, FF DA
  while (sos + 1 < padded.size() && !(padded[sos] == 0xFF && padded[sos + 1] == 0xDA)) ++sos;
  ASSERT_LT(sos + 1, padded.size());
  padded.insert(padded.begin() + static_cast<std::ptrdiff_t>(sos), {0x00, 0x00, 0x00});
  const std::optional<StoredImage> ours = DecodeJpeg(View(padded), "x.jpg");
  ASSERT_TRUE(ours.has_value());
  EXPECT_EQ(ours->samples, clean->samples);
}

// A header of more than 2^30 pixels is refused before anything is allocated.
TEST(JpegCodec, AHugeHeaderIsRefused) {
  std::vector<uchar> bytes;
  ASSERT_TRUE(cv::imencode(".jpg", PatternMat(67, 45, CV_8UC1), bytes));
  // The frame header (SOF0, FF C0): length (2), precision (1), height and
  // width (2 each, big-endian).
  std::size_t sof = 2;
  while (sof + 9 < bytes.size() && !(bytes[sof] == 0xFF && bytes[sof + 1] == 0xC0)) ++sof;
  ASSERT_LT(sof + 9, bytes.size());
  for (const std::size_t at : {sof + 5, sof + 7}) {
    bytes[at] = 0x9C;  // 40000
    bytes[at + 1] = 0x40;
  }
  try {
    DecodeJpeg(View(bytes), "tiles/huge.jpg");
    ADD_FAILURE() << "a 1.6-gigapixel header was taken";
  } catch (const InputError& e) {
    EXPECT_STREQ(e.what(), "tiles/huge.jpg: cannot decode image: too large (40000 x 40000 pixels)");
  }
}

// The real JPEGs of ../shared/data (calibration images of public data sets)
// read as OpenCV reads them gray.
TEST(JpegCodec, RealFilesReadAsOpenCvReadsThem) {
  const std::vector<std::filesystem::path> files = testing::SharedDataFiles(".jpg");
  if (files.empty()) GTEST_SKIP() << "no .jpg in " << testing::SharedDataDir();
  for (const std::filesystem::path& path : files) {
    const std::string bytes = testing::ReadTextFile(path);
    EXPECT_TRUE(SameImage(Taken(DecodeJpeg(bytes, path)), OpenCvGrayJpeg(bytes))) << path;
  }
}

}  // namespace
}  // namespace omm
