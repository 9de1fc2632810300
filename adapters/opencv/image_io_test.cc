#include "adapters/opencv/image_io.h"

#include <fstream>

#include <gtest/gtest.h>

#include "pipeline/core/error.h"

namespace omm {
namespace {

std::filesystem::path TempDir() {
  auto dir = std::filesystem::temp_directory_path() / "omm_image_io_test";
  std::filesystem::create_directories(dir);
  return dir;
}

TEST(ImageIo, SixteenBitRoundTripIsExact) {
  ImageF pixels(3, 5);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 5; ++c) pixels(r, c) = static_cast<float>((r * 5 + c) * 4099 % 65536) / 65535.f;
  const auto path = TempDir() / "round_trip.png";
  WriteGrayImage(path, pixels, 16);
  const GrayImage read = ReadGrayImage(path);
  EXPECT_EQ(read.bit_depth, 16);
  ASSERT_EQ(read.width(), 5);
  ASSERT_EQ(read.height(), 3);
  EXPECT_LT((read.pixels - pixels).cwiseAbs().maxCoeff(), 0.5f / 65535.f);
  EXPECT_EQ(ReadImageSize(path), Eigen::Vector2i(5, 3));
}

TEST(ImageIo, MissingAndCorruptFilesNameTheFile) {
  const auto missing = TempDir() / "missing.png";
  try {
    ReadGrayImage(missing);
    FAIL() << "no error for a missing file";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("missing.png"), std::string::npos);
  }
  const auto corrupt = TempDir() / "corrupt.png";
  std::ofstream(corrupt) << "\x89PNG this is not an image";
  EXPECT_THROW(ReadGrayImage(corrupt), InputError);
}

}  // namespace
}  // namespace omm
