#include "pipeline/simulate/render.h"

#include <algorithm>
#include <cmath>

namespace omm {

ImageF GaussianBlur(const ImageF& image, double sigma_px, int num_threads) {
  if (sigma_px <= 0) return image;
  const int radius = static_cast<int>(std::ceil(4 * sigma_px));
  std::vector<float> kernel(2 * radius + 1);
  double sum = 0.0;
  for (int i = -radius; i <= radius; ++i) sum += std::exp(-0.5 * i * i / (sigma_px * sigma_px));
  for (int i = -radius; i <= radius; ++i) {
    kernel[i + radius] = static_cast<float>(std::exp(-0.5 * i * i / (sigma_px * sigma_px)) / sum);
  }
  const int rows = static_cast<int>(image.rows()), cols = static_cast<int>(image.cols());
  ImageF horizontal(rows, cols), out(rows, cols);
  // Each output is the sum over the taps in kernel order, starting from 0;
  // the taps are the outer loop so that the inner one runs along a row.
  internal::ParallelRows(rows, num_threads, [&](int begin, int end) {
    for (int r = begin; r < end; ++r) {
      const float* in = &image(r, 0);
      float* acc = &horizontal(r, 0);
      std::fill(acc, acc + cols, 0.0f);
      const int lo = std::min(radius, cols), hi = std::max(lo, cols - radius);
      for (int i = -radius; i <= radius; ++i) {
        const float w = kernel[i + radius];
        for (int c = lo; c < hi; ++c) acc[c] += w * in[c + i];
      }
      auto border = [&](int c) {
        for (int i = -radius; i <= radius; ++i)
          acc[c] += kernel[i + radius] * in[std::clamp(c + i, 0, cols - 1)];
      };
      for (int c = 0; c < lo; ++c) border(c);
      for (int c = hi; c < cols; ++c) border(c);
    }
  });
  internal::ParallelRows(rows, num_threads, [&](int begin, int end) {
    for (int r = begin; r < end; ++r) {
      float* acc = &out(r, 0);
      std::fill(acc, acc + cols, 0.0f);
      for (int i = -radius; i <= radius; ++i) {
        const float w = kernel[i + radius];
        const float* in = &horizontal(std::clamp(r + i, 0, rows - 1), 0);
        for (int c = 0; c < cols; ++c) acc[c] += w * in[c];
      }
    }
  });
  return out;
}

ImageF ExposeImage(const ImageF& reflectance, const PixelRect& rect, const ExposureTruth& exposure,
                   const Eigen::Vector2d& vignetting_centre_px, double corner_radius_px,
                   const SensorModel& sensor, const NoiseSource& noise, int num_threads) {
  ImageF image = GaussianBlur(reflectance, exposure.psf_sigma_px, num_threads);
  const double levels = sensor.bit_depth > 0 ? (1 << sensor.bit_depth) - 1 : 0.0;
  const double inv_r2 = 1.0 / (corner_radius_px * corner_radius_px);
  internal::ParallelRows(rect.height, num_threads, [&](int begin, int end) {
    for (int r = begin; r < end; ++r) {
      SimRandom random(noise.seed, noise.stream * 65536 + static_cast<std::uint64_t>(rect.y0 + r));
      // Draws of the columns left of the rect, so a crop matches the image.
      for (int c = 0; noise.enabled && c < rect.x0; ++c) random.Normal();
      for (int c = 0; c < rect.width; ++c) {
        const double dx = rect.x0 + c - vignetting_centre_px.x();
        const double dy = rect.y0 + r - vignetting_centre_px.y();
        const double v = 1.0 - exposure.vignetting * (dx * dx + dy * dy) * inv_r2;
        double value = exposure.gain * v * image(r, c);
        if (noise.enabled) {
          const double electrons = std::max(0.0, value) * sensor.full_well_e;
          const double sigma_e = std::sqrt(electrons + sensor.read_noise_e * sensor.read_noise_e);
          value += random.Normal() * sigma_e / sensor.full_well_e;
        }
        value = std::clamp(value, 0.0, 1.0);
        // value >= 0: floor(x + 1/2) rounds as std::round does, and inlines.
        if (levels > 0) value = std::floor(value * levels + 0.5) / levels;
        image(r, c) = static_cast<float>(value);
      }
    }
  });
  return image;
}

}  // namespace omm
