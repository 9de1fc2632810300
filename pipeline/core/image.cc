#include "pipeline/core/image.h"

#include <cassert>
#include <cstring>

namespace omm {

void LinearizeResponse(double gamma, ImageF* pixels) {
  if (gamma == 1.0) return;
  const float exponent = static_cast<float>(1.0 / gamma);
  *pixels = pixels->array().max(0.0f).pow(exponent).matrix();
}
namespace {

template <typename Sample>
void ToGray(const std::uint8_t* rows, std::size_t row_stride_bytes, int width, int height,
            int channels, std::uint8_t* out) {
  // BT.601's weights in units of 2^-15 (OpenCV's RY15, GY15, BY15). They sum
  // to 2^15, so gray stays gray, and 65535 times that fits 32 bits.
  constexpr std::uint32_t kR = 9798, kG = 19235, kB = 3735;
  constexpr int kShift = 15;
  static_assert(kR + kG + kB == 1u << kShift);
  constexpr std::uint32_t kHalf = 1u << (kShift - 1);
  for (int y = 0; y < height; ++y) {
    const std::uint8_t* row = rows + static_cast<std::size_t>(y) * row_stride_bytes;
    for (int x = 0; x < width; ++x) {
      Sample px[4];
      std::memcpy(px, row + static_cast<std::size_t>(x) * channels * sizeof(Sample),
                  channels * sizeof(Sample));
      const Sample gray =
          channels >= 3
              ? static_cast<Sample>((kR * px[0] + kG * px[1] + kB * px[2] + kHalf) >> kShift)
              : px[0];
      std::memcpy(out + (static_cast<std::size_t>(y) * width + x) * sizeof(Sample), &gray,
                  sizeof(Sample));
    }
  }
}

}  // namespace

StoredImage GrayFromInterleaved(const std::uint8_t* rows, std::size_t row_stride_bytes, int width,
                                int height, int channels, int bit_depth) {
  assert(channels >= 1 && channels <= 4);
  assert(bit_depth == 8 || bit_depth == 16);
  StoredImage image;
  image.width = width;
  image.height = height;
  image.bit_depth = bit_depth;
  image.samples.resize(static_cast<std::size_t>(width) * height * (bit_depth / 8));
  if (bit_depth == 8) {
    ToGray<std::uint8_t>(rows, row_stride_bytes, width, height, channels, image.samples.data());
  } else {
    ToGray<std::uint16_t>(rows, row_stride_bytes, width, height, channels, image.samples.data());
  }
  return image;
}

}  // namespace omm
