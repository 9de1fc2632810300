// Geometry to pixels: integrates a scene over each pixel through the ray
// table, then images it through the sensor model.
#pragma once

#include <algorithm>
#include <cstdint>
#include <thread>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/image.h"
#include "pipeline/core/truth.h"
#include "pipeline/simulate/random.h"
#include "pipeline/simulate/ray_table.h"
#include "pipeline/simulate/scene.h"

namespace omm {

struct IntegrationOptions {
  // Pixels near an edge are integrated again with edge_supersampling^2 rays,
  // so edges are placed to ~1e-3 px while smooth texture costs only S x S
  // rays per pixel. Values <= S switch this off.
  int edge_supersampling = 16;
  int num_threads = 2;  // the result does not depend on it
};

namespace internal {

// Runs rows(begin, end) over [0, height) on num_threads threads, in
// interleaved blocks so that scenes whose cost varies over the image balance.
template <typename Rows>
void ParallelRows(int height, int num_threads, const Rows& rows) {
  num_threads = std::clamp(num_threads, 1, std::max(1, height));
  constexpr int kBlock = 16;
  std::vector<std::thread> threads;
  for (int t = 0; t < num_threads; ++t) {
    threads.emplace_back([&, t] {
      for (int b = t * kBlock; b < height; b += num_threads * kBlock)
        rows(b, std::min(b + kBlock, height));
    });
  }
  for (std::thread& thread : threads) thread.join();
}

}  // namespace internal

// The scene's reflectance integrated over each pixel of rays.rect (a box
// aperture). `scene` is a callable SceneSample(double x, double y) (scene.h),
// called concurrently from several threads.
//
// Every pixel first gets the mean over its S x S rays. A pixel is then
// integrated again with edge_supersampling^2 rays if its rays see more than
// one region, or a neighbour's (8-neighbourhood) do, or a neighbour's rays see
// another region than its own: an edge that only clips the margin between a
// pixel's outer rays and its border leaves no trace in that pixel's own rays,
// but does in its neighbours'. The finer rays come from the affine map
// q -> (x/z, y/z) fitted to the pixel's own S x S rays (the lens map is that
// smooth: over a pixel it departs from affine by < 1e-4 px).
template <typename Scene>
ImageF IntegratePixels(const RayTable& rays, const Scene& scene,
                       const IntegrationOptions& options) {
  const PixelRect& rect = rays.rect;
  ImageF image(rect.height, rect.width);
  const int s = rays.supersampling;
  const int per_pixel = rays.SamplesPerPixel();
  const int fine = options.edge_supersampling;
  // Per pixel: the region of its first ray, and whether its rays saw others.
  std::vector<Region> region(static_cast<std::size_t>(rect.width) * rect.height);
  std::vector<std::uint8_t> mixed(region.size());
  internal::ParallelRows(rect.height, options.num_threads, [&](int begin, int end) {
    for (int r = begin; r < end; ++r) {
      for (int c = 0; c < rect.width; ++c) {
        const std::size_t pixel = rays.PixelIndex(r, c);
        const double bx = rays.base_xy[2 * pixel], by = rays.base_xy[2 * pixel + 1];
        const float* offset = rays.offset_xy.data() + 2 * pixel * per_pixel;
        const SceneSample first = scene(bx + offset[0], by + offset[1]);
        double sum = first.reflectance;
        bool edge = false;
        for (int k = 1; k < per_pixel; ++k) {
          const SceneSample sample = scene(bx + offset[2 * k], by + offset[2 * k + 1]);
          sum += sample.reflectance;
          edge = edge || sample.region != first.region;
        }
        image(r, c) = static_cast<float>(sum / per_pixel);
        region[pixel] = first.region;
        mixed[pixel] = edge;
      }
    }
  });
  if (fine <= s) return image;

  internal::ParallelRows(rect.height, options.num_threads, [&](int begin, int end) {
    for (int r = begin; r < end; ++r) {
      for (int c = 0; c < rect.width; ++c) {
        const std::size_t pixel = rays.PixelIndex(r, c);
        bool edge = mixed[pixel];
        for (int dr = -1; dr <= 1 && !edge; ++dr) {
          for (int dc = -1; dc <= 1 && !edge; ++dc) {
            const int rr = r + dr, cc = c + dc;
            if (rr < 0 || cc < 0 || rr >= rect.height || cc >= rect.width) continue;
            const std::size_t neighbour = rays.PixelIndex(rr, cc);
            edge = mixed[neighbour] || region[neighbour] != region[pixel];
          }
        }
        if (!edge) continue;
        // Affine fit ray = centre + u a_u + v a_v, (u, v) the ray's offset from
        // the pixel centre in px; the rays form a symmetric grid, so the least-
        // squares fit separates into a mean and two moments.
        const double bx = rays.base_xy[2 * pixel], by = rays.base_xy[2 * pixel + 1];
        const float* offset = rays.offset_xy.data() + 2 * pixel * per_pixel;
        Eigen::Vector2d centre = Eigen::Vector2d::Zero(), a_u = centre, a_v = centre;
        double uu = 0;
        for (int k = 0; k < per_pixel; ++k) {
          const Eigen::Vector2d ray(offset[2 * k], offset[2 * k + 1]);
          const double u = (k % s + 0.5) / s - 0.5, v = (k / s + 0.5) / s - 0.5;
          centre += ray;
          a_u += u * ray;
          a_v += v * ray;
          uu += u * u;
        }
        centre = centre / per_pixel + Eigen::Vector2d(bx, by);
        a_u /= uu;
        a_v /= uu;
        double sum = 0;
        for (int j = 0; j < fine; ++j) {
          const double v = (j + 0.5) / fine - 0.5;
          for (int i = 0; i < fine; ++i) {
            const double u = (i + 0.5) / fine - 0.5;
            const Eigen::Vector2d ray = centre + u * a_u + v * a_v;
            sum += scene(ray.x(), ray.y()).reflectance;
          }
        }
        image(r, c) = static_cast<float>(sum / (fine * fine));
      }
    }
  });
  return image;
}

// The sensor: photo-electrons, read noise and the ADC.
struct SensorModel {
  double full_well_e = 12000.0;  // electrons at digital full scale
  double read_noise_e = 10.0;    // read noise, electrons rms
  int bit_depth = 8;             // ADC bits; 0 keeps the float values (tests)
};

// Where the noise of an image comes from: row r (of the whole image) draws
// from its own stream SimRandom(seed, stream * 65536 + r), so rows can be
// exposed in parallel and a crop gets the same noise as the whole image.
struct NoiseSource {
  bool enabled = false;
  std::uint64_t seed = 0;
  std::uint64_t stream = 0;
};

// Images the integrated reflectance of `rect` (reflectance.rows() = rect
// height): irradiance = V(q) (g * reflectance) (Gaussian PSF, sigma
// exposure.psf_sigma_px, borders clamped), with the vignetting
// V(q) = 1 - exposure.vignetting * |q - centre|^2 / corner_radius_px^2 and the
// gain g = exposure.gain; then, if noise.enabled, shot noise (Gaussian with
// the Poisson variance of irradiance * full_well_e electrons) and read noise;
// then clamped to [0, 1] and quantised to the ADC's levels.
ImageF ExposeImage(const ImageF& reflectance, const PixelRect& rect, const ExposureTruth& exposure,
                   const Eigen::Vector2d& vignetting_centre_px, double corner_radius_px,
                   const SensorModel& sensor, const NoiseSource& noise, int num_threads);

// Separable Gaussian blur, kernel radius ceil(4 sigma), normalised; the image
// borders are extended by their edge values. sigma <= 0 returns the input.
ImageF GaussianBlur(const ImageF& image, double sigma_px, int num_threads);

}  // namespace omm
