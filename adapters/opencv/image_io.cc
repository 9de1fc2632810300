#include "adapters/opencv/image_io.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <optional>
#include <stdexcept>
#include <system_error>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "adapters/jpeg/jpeg_codec.h"
#include "adapters/netpbm/pnm_codec.h"
#include "adapters/png/png_codec.h"
#include "adapters/tiff/tiff_codec.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

// A cv::Mat header over the image's samples (no copy).
cv::Mat SamplesMat(const StoredImage& image) {
  return cv::Mat(image.height, image.width, image.bit_depth == 16 ? CV_16U : CV_8U,
                 const_cast<std::uint8_t*>(image.samples.data()));
}

}  // namespace

StoredImage ReadStoredImage(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw InputError(path.string(), "image file not found");
  }
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  std::string bytes(static_cast<std::size_t>(std::max<std::streamoff>(0, in.tellg())), '\0');
  in.seekg(0);
  if (!in.read(bytes.data(), static_cast<std::streamsize>(bytes.size())))
    throw InputError(path.string(), "cannot read image file");
  return DecodeImage(bytes, path);
}

StoredImage DecodeImage(std::string_view file_bytes, const std::filesystem::path& path) {
  // Gray PNGs (every image omm writes, and the usual camera image) by
  // adapters/png's own decoder: ~40 % less CPU than a PNG library's.
  if (std::optional<StoredImage> png = DecodeGrayPng(file_bytes, path)) return std::move(*png);
  if (file_bytes.starts_with("\x89PNG")) return DecodePng(file_bytes, path);
  if (std::optional<StoredImage> tiff = DecodeTiff(file_bytes, path)) return std::move(*tiff);
  if (std::optional<StoredImage> jpeg = DecodeJpeg(file_bytes, path)) return std::move(*jpeg);
  if (std::optional<StoredImage> pnm = DecodePnm(file_bytes, path)) return std::move(*pnm);
  throw InputError(path.string(), "cannot decode image: not a PNG, TIFF, JPEG, PGM or PPM file");
}

GrayImage ToGrayImage(const StoredImage& image) {
  GrayImage gray;
  gray.bit_depth = image.bit_depth;
  gray.pixels.resize(image.height, image.width);
  // ImageF is row-major and contiguous: convert straight into its storage.
  cv::Mat as_float(image.height, image.width, CV_32F, gray.pixels.data());
  SamplesMat(image).convertTo(as_float, CV_32F, 1.0 / ((1 << image.bit_depth) - 1));
  return gray;
}

GrayImage ReadGrayImage(const std::filesystem::path& path) {
  return ToGrayImage(ReadStoredImage(path));
}

StoredImage QuantizeImage(const ImageF& pixels, int bit_depth) {
  if (bit_depth != 8 && bit_depth != 16) {
    throw std::invalid_argument("QuantizeImage: bit_depth must be 8 or 16");
  }
  StoredImage image;
  image.width = static_cast<int>(pixels.cols());
  image.height = static_cast<int>(pixels.rows());
  image.bit_depth = bit_depth;
  image.samples.resize(pixels.size() * (bit_depth / 8));
  const cv::Mat as_float(image.height, image.width, CV_32F, const_cast<float*>(pixels.data()));
  cv::Mat out = SamplesMat(image);
  as_float.convertTo(out, out.type(), (1 << bit_depth) - 1);  // saturating, rounded
  return image;
}

void WriteStoredImage(const std::filesystem::path& path, const StoredImage& image,
                      int png_deflate_level) {
  std::filesystem::path tmp = path;
  tmp += ".tmp" + path.extension().string();
  std::string extension = path.extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  std::string bytes;
  if (extension == ".png") {
    PngWriteOptions options;
    options.deflate_level = png_deflate_level;
    if (const std::string why = options.Check(); !why.empty()) throw std::invalid_argument(why);
    bytes = EncodeGrayPng(image, options);
  } else if (extension == ".tif" || extension == ".tiff") {
    bytes = EncodeGrayTiff(image);
  } else {
    throw InputError(path.string(), "cannot write image: expected a .png, .tif or .tiff file");
  }
  errno = 0;  // a failed write's reason (WriteError), not an earlier call's
  std::ofstream out(tmp, std::ios::binary);
  const bool ok =
      static_cast<bool>(out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()))) &&
      static_cast<bool>(out.flush());
  std::error_code ignored;
  if (!ok) {
    const std::system_error failed = WriteError(path, "cannot write image");
    std::filesystem::remove(tmp, ignored);
    throw failed;
  }
  std::error_code failed;
  std::filesystem::rename(tmp, path, failed);
  if (failed) {
    std::filesystem::remove(tmp, ignored);
    throw std::system_error(failed, path.string() + ": cannot write image");
  }
}

void WriteGrayImage(const std::filesystem::path& path, const ImageF& pixels, int bit_depth) {
  if (bit_depth != 8 && bit_depth != 16) {
    throw InputError(path.string(), "can write 8- or 16-bit images only");
  }
  WriteStoredImage(path, QuantizeImage(pixels, bit_depth));
}

std::string EncodePreviewPng(const StoredImage& image, int max_width_px) {
  if (image.width < 1 || image.height < 1 || max_width_px < 1) {
    throw std::invalid_argument("EncodePreviewPng: empty image or max_width_px < 1");
  }
  // Shrunk as stored (8 or 16 bits): converting the whole image to float
  // first took most of the call on the demo's mosaic, on the run's serial tail.
  const cv::Mat samples = SamplesMat(image);
  cv::Mat shrunk = samples;
  if (samples.cols > max_width_px) {
    const double scale = static_cast<double>(max_width_px) / samples.cols;
    const int height = std::max(1, static_cast<int>(std::lround(samples.rows * scale)));
    cv::resize(samples, shrunk, cv::Size(max_width_px, height), 0, 0, cv::INTER_AREA);
  }
  StoredImage preview;
  preview.width = shrunk.cols;
  preview.height = shrunk.rows;
  preview.samples.resize(shrunk.total());
  cv::Mat out = SamplesMat(preview);
  shrunk.convertTo(out, CV_8U, 255.0 / ((1 << image.bit_depth) - 1));  // rounded
  // adapters/png rather than cv::imencode: half the CPU of the whole call on
  // the demo's mosaic (libdeflate instead of zlib), on the run's serial tail.
  return EncodeGrayPng(preview);
}

}  // namespace omm
