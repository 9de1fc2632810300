#include "adapters/opencv/image_io.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "pipeline/core/error.h"
#include "tests/test_util.h"

namespace omm {
namespace {

// Each test's files, removed with it.
class ImageIo : public ::testing::Test {
 protected:
  std::filesystem::path TempDir() const { return dir_.path(); }

  // Decodes a PNG held in memory through the file reader.
  GrayImage DecodePng(const std::string& bytes, const std::string& name) {
    const auto path = TempDir() / name;
    std::ofstream(path, std::ios::binary) << bytes;
    return ReadGrayImage(path);
  }

 private:
  testing::TempDir dir_;
};

TEST_F(ImageIo, SixteenBitRoundTripIsExact) {
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
}

// What a run keeps in memory is what the file holds: the quantised samples
// written and read back are identical, and decoding the file's bytes in memory
// gives the same samples and, through ToGrayImage, the same floats bit for bit.
TEST_F(ImageIo, QuantisedSamplesMatchTheFileExactly) {
  for (const int bits : {8, 16}) {
    ImageF pixels(37, 53);
    for (int r = 0; r < 37; ++r)
      for (int c = 0; c < 53; ++c)
        pixels(r, c) = static_cast<float>(std::sin(0.37 * r + 0.11 * c * c)) * 0.6f + 0.45f;
    const StoredImage quantised = QuantizeImage(pixels, bits);
    EXPECT_EQ(quantised.bit_depth, bits);
    const auto path = TempDir() / ("quantised_" + std::to_string(bits) + ".png");
    WriteStoredImage(path, quantised);
    const StoredImage read = ReadStoredImage(path);
    EXPECT_EQ(read.width, 53);
    EXPECT_EQ(read.height, 37);
    EXPECT_EQ(read.bit_depth, bits);
    EXPECT_EQ(read.samples, quantised.samples) << bits << " bit";

    std::ifstream in(path, std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(DecodeImage(bytes, path).samples, read.samples) << bits << " bit";
    const GrayImage from_memory = ToGrayImage(quantised);
    const GrayImage from_file = ReadGrayImage(path);
    EXPECT_EQ(from_memory.bit_depth, bits);
    EXPECT_TRUE((from_memory.pixels.array() == from_file.pixels.array()).all()) << bits << " bit";
    // Clamped and rounded to the nearest digital number.
    const float full_scale = static_cast<float>((1 << bits) - 1);
    EXPECT_LE((from_memory.pixels - pixels.cwiseMax(0.f).cwiseMin(1.f)).cwiseAbs().maxCoeff(),
              0.5f / full_scale + 1e-7f);
  }
}

// A TIFF, written or read, holds the same samples as a PNG: the file's
// format does not change what a run sees.
TEST_F(ImageIo, TiffRoundTripIsExact) {
  for (const int bits : {8, 16}) {
    ImageF pixels(19, 31);
    for (int r = 0; r < 19; ++r)
      for (int c = 0; c < 31; ++c) pixels(r, c) = static_cast<float>((r * 31 + c) % 97) / 96.f;
    const StoredImage quantised = QuantizeImage(pixels, bits);
    for (const char* name : {"x.tif", "x.TIFF"}) {
      const auto path = TempDir() / name;
      WriteStoredImage(path, quantised);
      const StoredImage read = ReadStoredImage(path);
      EXPECT_EQ(read.bit_depth, bits);
      EXPECT_EQ(read.samples, quantised.samples) << name << ", " << bits << " bit";
    }
  }
}

// Files are told apart by their bytes, not their names; bytes of no format
// read here, or a name of no format written here, say which ones are.
TEST_F(ImageIo, FormatsAreToldByContentAndOthersNamed) {
  const StoredImage image = QuantizeImage(ImageF::Constant(3, 4, 0.25f), 8);
  WriteStoredImage(TempDir() / "real.tif", image);
  std::filesystem::rename(TempDir() / "real.tif", TempDir() / "named.png");
  EXPECT_EQ(ReadStoredImage(TempDir() / "named.png").samples, image.samples);
  try {
    DecodeImage("BM a bitmap", "tiles/t.bmp");
    FAIL() << "a BMP decoded";
  } catch (const InputError& e) {
    EXPECT_STREQ(e.what(),
                 "tiles/t.bmp: cannot decode image: not a PNG, TIFF, JPEG, PGM or PPM file");
  }
  try {
    WriteStoredImage(TempDir() / "x.jpg", image);
    FAIL() << "a JPEG written";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("expected a .png, .tif or .tiff file"), std::string::npos)
        << e.what();
  }
  EXPECT_FALSE(std::filesystem::exists(TempDir() / "x.jpg"));
}

TEST_F(ImageIo, CorruptBytesInMemoryNameTheFile) {
  try {
    DecodeImage("\x89PNG this is not an image", "tiles/broken.png");
    FAIL() << "no error for corrupt bytes";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("tiles/broken.png"), std::string::npos);
  }
}

TEST_F(ImageIo, MissingAndCorruptFilesNameTheFile) {
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

// A file the system will not write (here: its directory does not exist)
// names itself and the system's reason, in either format.
TEST_F(ImageIo, AnImageThatCannotBeWrittenSaysWhy) {
  const ImageF pixels = ImageF::Constant(4, 6, 0.5f);
  for (const char* name : {"x.png", "x.tif"}) {
    const auto path = TempDir() / "no_such_dir" / name;
    try {
      WriteGrayImage(path, pixels, 16);
      FAIL() << "no error for " << name;
    } catch (const std::system_error& e) {
      EXPECT_NE(std::string(e.what()).find(path.string() + ": cannot write image"),
                std::string::npos)
          << e.what();
      EXPECT_NE(std::string(e.what()).find("No such file or directory"), std::string::npos)
          << e.what();
    }
  }
}

// A 16-bit image of the given samples, row-major.
StoredImage Stored16(int height, int width, const std::vector<std::uint16_t>& values) {
  StoredImage image;
  image.width = width;
  image.height = height;
  image.bit_depth = 16;
  image.samples.resize(values.size() * 2);
  std::memcpy(image.samples.data(), values.data(), image.samples.size());
  return image;
}

TEST_F(ImageIo, PreviewPngIsTheBlockMeanAtEightBits) {
  // 30 x 21 px shrunk to 10 px wide: exactly 3 x 3 blocks, so INTER_AREA is
  // each block's mean, rounded to 16 bits, then to 8: within half a digital
  // number of 8 bits and half of 16.
  std::vector<std::uint16_t> values(21 * 30);
  for (int r = 0; r < 21; ++r)
    for (int c = 0; c < 30; ++c)
      values[r * 30 + c] = static_cast<std::uint16_t>((r * 7 + c * 13) % 29 * 2260);
  const GrayImage preview =
      DecodePng(EncodePreviewPng(Stored16(21, 30, values), 10), "preview.png");
  EXPECT_EQ(preview.bit_depth, 8);
  ASSERT_EQ(preview.width(), 10);
  ASSERT_EQ(preview.height(), 7);
  for (int r = 0; r < 7; ++r) {
    for (int c = 0; c < 10; ++c) {
      double sum = 0.0;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) sum += values[(3 * r + i) * 30 + 3 * c + j];
      const double mean = sum / 9 / 65535;
      EXPECT_NEAR(preview.pixels(r, c), mean, 0.5 / 255 + 0.5 / 65535 + 1e-6) << r << "," << c;
    }
  }
}

TEST_F(ImageIo, PreviewPngKeepsANarrowImage) {
  const std::vector<std::uint16_t> values = {0, 13107, 39321, 65535, 1000, 64000};
  const GrayImage preview = DecodePng(EncodePreviewPng(Stored16(2, 3, values), 1200), "narrow.png");
  ASSERT_EQ(preview.width(), 3);
  ASSERT_EQ(preview.height(), 2);
  for (int k = 0; k < 6; ++k)
    EXPECT_NEAR(preview.pixels(k / 3, k % 3), values[k] / 65535.0, 0.5 / 255 + 1e-6) << k;

  // 8-bit samples are the preview's as they are.
  StoredImage eight;
  eight.width = 3;
  eight.height = 2;
  eight.bit_depth = 8;
  eight.samples = {0, 51, 128, 200, 254, 255};
  const std::string bytes = EncodePreviewPng(eight, 1200);
  EXPECT_EQ(DecodeImage(bytes, "eight.png").samples, eight.samples);
}

}  // namespace
}  // namespace omm
