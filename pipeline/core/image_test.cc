#include "pipeline/core/image.h"

#include <cstring>
#include <vector>

#include <gtest/gtest.h>

namespace omm {
namespace {

std::vector<std::uint16_t> Samples16(const StoredImage& image) {
  std::vector<std::uint16_t> samples(image.samples.size() / 2);
  std::memcpy(samples.data(), image.samples.data(), image.samples.size());
  return samples;
}

// Equal R, G and B keep their value at both depths, over the whole range;
// alpha is dropped.
TEST(GrayFromInterleaved, GrayStaysGrayAndAlphaIsDropped) {
  std::vector<std::uint16_t> rgba;
  std::vector<std::uint16_t> expected;
  for (std::uint32_t v = 0; v <= 65535; v += 7) {
    rgba.insert(rgba.end(), {static_cast<std::uint16_t>(v), static_cast<std::uint16_t>(v),
                             static_cast<std::uint16_t>(v), static_cast<std::uint16_t>(v / 3)});
    expected.push_back(static_cast<std::uint16_t>(v));
  }
  const int width = static_cast<int>(expected.size());
  const StoredImage wide = GrayFromInterleaved(reinterpret_cast<const std::uint8_t*>(rgba.data()),
                                               rgba.size() * 2, width, 1, 4, 16);
  EXPECT_EQ(wide.bit_depth, 16);
  EXPECT_EQ(Samples16(wide), expected);

  std::vector<std::uint8_t> gray_alpha, expected8;
  for (int v = 0; v < 256; ++v) {
    gray_alpha.insert(gray_alpha.end(), {static_cast<std::uint8_t>(v), std::uint8_t{17}});
    expected8.push_back(static_cast<std::uint8_t>(v));
  }
  const StoredImage narrow =
      GrayFromInterleaved(gray_alpha.data(), gray_alpha.size(), 256, 1, 2, 8);
  EXPECT_EQ(narrow.samples, expected8);
}

// pixel^(1 / gamma): gamma 0.5 squares, 2 takes the square root; 1 and 0 stay.
TEST(LinearizeResponse, UndoesThePowerLaw) {
  ImageF pixels(1, 4);
  pixels << 0.0f, 0.25f, 0.81f, 1.0f;
  ImageF squared = pixels;
  LinearizeResponse(0.5, &squared);
  EXPECT_FLOAT_EQ(squared(0, 1), 0.0625f);
  EXPECT_FLOAT_EQ(squared(0, 2), 0.6561f);
  EXPECT_FLOAT_EQ(squared(0, 3), 1.0f);
  EXPECT_FLOAT_EQ(squared(0, 0), 0.0f);
  ImageF rooted = pixels;
  LinearizeResponse(2.0, &rooted);
  EXPECT_FLOAT_EQ(rooted(0, 1), 0.5f);
  EXPECT_FLOAT_EQ(rooted(0, 2), 0.9f);
  ImageF same = pixels;
  LinearizeResponse(1.0, &same);
  EXPECT_EQ(same, pixels);
}

// BT.601's weights: pure red, green and blue, and rows read at their stride.
TEST(GrayFromInterleaved, ColourIsWeightedByLuma) {
  const std::uint8_t rgb[] = {255, 0, 0, 0,   255, 0,  0, 0, 255, 99,  // row 0, then padding
                              0,   0, 0, 200, 100, 50, 1, 2, 3,   99};
  const StoredImage image = GrayFromInterleaved(rgb, 10, 3, 2, 3, 8);
  // 0.299, 0.587, 0.114 of 255; 0.587 * 100 + 0.299 * 200 + 0.114 * 50 = 124.2.
  EXPECT_EQ(image.samples, (std::vector<std::uint8_t>{76, 150, 29, 0, 124, 2}));
}

}  // namespace
}  // namespace omm
