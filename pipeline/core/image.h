// A gray image as the pipeline sees it, whatever the file's format.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace omm {

// Row-major so that (row, col) addressing matches image files; rows = height.
using ImageF = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// Mosaics and their patches (orthorectify.h, ortho_patch.h) mark the pixels
// no tile sees as 0 (project-format.md). A seen pixel is at least this, the
// 16-bit mosaic file's first level: black ones (a through-hole over a black
// table, a camera whose black level clips) stay seen, also when read back.
inline constexpr float kDarkestCovered = 1.0f / 65535.0f;

// A mask over an image's pixels (1: set), row-major like ImageF.
using ImageMask = Eigen::Matrix<std::uint8_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

struct GrayImage {
  // Intensities scaled to [0, 1] of the file's full scale (255 or 65535).
  ImageF pixels;
  // Bits per sample in the file the image came from (8 or 16); the digital
  // number of a pixel is pixels * (2^bit_depth - 1).
  int bit_depth = 8;

  int width() const { return static_cast<int>(pixels.cols()); }
  int height() const { return static_cast<int>(pixels.rows()); }
};

// An image's gray samples as its file holds them: digital numbers of 8 or 16
// bits. What is kept of an image between stages (1 or 2 bytes a pixel, not
// GrayImage's 4); adapters/opencv/image_io.h converts it to a GrayImage
// exactly as reading the file would.
struct StoredImage {
  int width = 0;
  int height = 0;
  int bit_depth = 8;  // 8 or 16
  // Row-major, width * height * bit_depth / 8 bytes; 16-bit samples are
  // native-endian std::uint16_t.
  std::vector<std::uint8_t> samples;
};

// Image readers refuse a header of more pixels than this, as OpenCV's
// imgcodecs does (CV_IO_MAX_IMAGE_PIXELS): a corrupt or hostile header, not
// an allocation to attempt.
inline constexpr std::int64_t kMaxImagePixels = std::int64_t{1} << 30;

// Interleaved samples, `channels` a pixel (1 gray, 2 gray + alpha, 3 RGB,
// 4 RGBA) of `bit_depth` 8 or 16 (16-bit native-endian), rows
// `row_stride_bytes` apart, as gray samples of the same depth: alpha dropped,
// colour weighted by ITU-R BT.601's luma, 0.299 R + 0.587 G + 0.114 B, in
// 15-bit fixed point, rounded. Those are OpenCV 4.6's cv::cvtColor RGB2GRAY
// numbers: a colour file reads as it did when OpenCV decoded it.
StoredImage GrayFromInterleaved(const std::uint8_t* rows, std::size_t row_stride_bytes, int width,
                                int height, int channels, int bit_depth);

// Undoes a camera's gamma (GenICam's Gamma: pixel = linear^gamma, both in
// [0, 1] of full scale): every pixel becomes pixel^(1 / gamma), so that the
// edges' mid-level crossings, the exposure gains and the noise model see
// linear intensities. gamma > 0; 1 leaves the image as it is.
void LinearizeResponse(double gamma, ImageF* pixels);

}  // namespace omm
