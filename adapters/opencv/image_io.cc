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
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "adapters/png/png_codec.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

// The decoded file as gray samples at its own depth; `raw` empty: not decodable.
StoredImage ToStored(cv::Mat raw, const std::filesystem::path& path) {
  if (raw.empty()) {
    throw InputError(path.string(),
                     "cannot decode image (corrupt, truncated or not a PNG/TIFF/JPEG file)");
  }
  if (raw.depth() != CV_8U && raw.depth() != CV_16U) {
    throw InputError(path.string(), "expected an 8- or 16-bit image");
  }
  if (raw.channels() == 3) {
    cv::cvtColor(raw, raw, cv::COLOR_BGR2GRAY);
  } else if (raw.channels() == 4) {
    cv::cvtColor(raw, raw, cv::COLOR_BGRA2GRAY);
  } else if (raw.channels() != 1) {
    throw InputError(path.string(), "expected a gray or color image");
  }
  StoredImage image;
  image.width = raw.cols;
  image.height = raw.rows;
  image.bit_depth = raw.depth() == CV_16U ? 16 : 8;
  image.samples.resize(raw.total() * raw.elemSize());
  // Samples is row-major and contiguous: copy straight into its storage.
  raw.copyTo(cv::Mat(raw.rows, raw.cols, raw.type(), image.samples.data()));
  return image;
}

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
  // Gray PNGs (every image omm writes, and the usual camera image) without
  // OpenCV's libpng path: ~40 % less CPU (adapters/png).
  if (std::optional<StoredImage> png = DecodeGrayPng(file_bytes, path)) return std::move(*png);
  try {
    const cv::Mat bytes(1, static_cast<int>(file_bytes.size()), CV_8U,
                        const_cast<char*>(file_bytes.data()));
    return ToStored(cv::imdecode(bytes, cv::IMREAD_ANYDEPTH | cv::IMREAD_ANYCOLOR), path);
  } catch (const cv::Exception& e) {
    throw InputError(path.string(), std::string("cannot decode image: ") + e.what());
  }
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
  bool ok = false;
  errno = 0;  // a failed write's reason (WriteError), not an earlier call's
  std::string extension = path.extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (extension == ".png") {
    PngWriteOptions options;
    options.deflate_level = png_deflate_level;
    if (const std::string why = options.Check(); !why.empty()) throw std::invalid_argument(why);
    const std::string bytes = EncodeGrayPng(image, options);
    std::ofstream out(tmp, std::ios::binary);
    ok = static_cast<bool>(out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()))) &&
         static_cast<bool>(out.flush());
  } else {
    try {
      ok = cv::imwrite(tmp.string(), SamplesMat(image));
    } catch (const cv::Exception&) {
      ok = false;
    }
  }
  std::error_code ignored;
  if (!ok) {
    // The system's reason; none (OpenCV refused the image) is the input's.
    if (errno == 0) {
      std::filesystem::remove(tmp, ignored);
      throw InputError(path.string(), "cannot write image (OpenCV refused it)");
    }
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

std::string EncodePreviewPng(const ImageF& pixels, int max_width_px) {
  if (pixels.size() == 0 || max_width_px < 1) {
    throw std::invalid_argument("EncodePreviewPng: empty image or max_width_px < 1");
  }
  const cv::Mat as_float(static_cast<int>(pixels.rows()), static_cast<int>(pixels.cols()), CV_32F,
                         const_cast<float*>(pixels.data()));
  cv::Mat shrunk = as_float;
  if (as_float.cols > max_width_px) {
    const double scale = static_cast<double>(max_width_px) / as_float.cols;
    const int height = std::max(1, static_cast<int>(std::lround(as_float.rows * scale)));
    cv::resize(as_float, shrunk, cv::Size(max_width_px, height), 0, 0, cv::INTER_AREA);
  }
  StoredImage preview;
  preview.width = shrunk.cols;
  preview.height = shrunk.rows;
  preview.samples.resize(shrunk.total());
  cv::Mat out = SamplesMat(preview);
  shrunk.convertTo(out, CV_8U, 255.0);  // saturating, rounded
  // adapters/png rather than cv::imencode: half the CPU of the whole call on
  // the demo's mosaic (libdeflate instead of zlib), on the run's serial tail.
  return EncodeGrayPng(preview);
}

}  // namespace omm
