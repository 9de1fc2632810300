// Geometry to pixels: integrates a scene over each pixel through the ray
// table, then images it through the sensor model.
#pragma once

#include <algorithm>
#include <cassert>
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
  // Near edges a pixel's S x S blocks (one per ray) that an edge may cross
  // are integrated with (edge_supersampling / S)^2 rays each, i.e. on an
  // edge_supersampling^2 grid over the pixel, so edges are placed to ~1e-3 px
  // (edge_supersampling is used rounded down to a multiple of S). Values < 2 S
  // switch this off.
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
// called concurrently from several threads. Needs S = rays.supersampling >= 2.
//
// Every pixel first gets the mean of the scene at its 2 x 2 Gauss-Legendre
// points, (+-1/(2 sqrt 3), +-1/(2 sqrt 3)) px from its centre (their rays are
// in the ray table). Inside a region the reflectance is smooth (constant, or
// the texture, whose finest wavelength is ~5 px), and this rule integrates it
// exactly up to degree 3 in u and v, more closely than S x S midpoint samples.
//
// A pixel is integrated again if the 36 Gauss points of it and its 8
// neighbours see more than one region. They span a square that holds the
// pixel with room to spare, so an edge that crosses the pixel passes between
// two of them (a straight one always; a curved one as long as the regions
// and gaps are wider than the points' spacing, 0.6 px: the precondition on
// the scene). The pixel is then split into S x S blocks, one around each of
// its rays; each block and the ring of its neighbours' blocks around the
// pixel get the sample of their ray. A block whose 3 x 3 block neighbourhood
// sees one region takes its ray's sample (the same argument, at 1/S px); the
// others, which an edge may cross, are sampled on an n x n grid, n =
// edge_supersampling / S, through the pixel's affine ray map. Pixels on the
// border of the rect, whose neighbours' points are missing, are always
// integrated again, and their blocks on the border always sampled finely.
template <typename Scene>
ImageF IntegratePixels(const RayTable& rays, const Scene& scene,
                       const IntegrationOptions& options) {
  const PixelRect& rect = rays.rect;
  ImageF image(rect.height, rect.width);
  const int s = rays.supersampling;
  assert(s >= 2);
  // Per pixel: the region of its first Gauss point, and whether its points saw others.
  std::vector<Region> region(static_cast<std::size_t>(rect.width) * rect.height);
  std::vector<std::uint8_t> mixed(region.size());
  internal::ParallelRows(rect.height, options.num_threads, [&](int begin, int end) {
    for (int r = begin; r < end; ++r) {
      for (int c = 0; c < rect.width; ++c) {
        double sum = 0;
        bool edge = false;
        Region first = Region::kBackground;
        for (int k = 0; k < 4; ++k) {
          const Eigen::Vector2d ray = rays.GaussRay(r, c, k);
          const SceneSample sample = scene(ray.x(), ray.y());
          sum += sample.reflectance;
          if (k == 0) first = sample.region;
          edge = edge || sample.region != first;
        }
        const std::size_t pixel = rays.PixelIndex(r, c);
        image(r, c) = static_cast<float>(0.25 * sum);
        region[pixel] = first;
        mixed[pixel] = edge;
      }
    }
  });
  const int n = options.edge_supersampling / s;
  if (n < 2) return image;

  internal::ParallelRows(rect.height, options.num_threads, [&](int begin, int end) {
    // Samples of the pixel's blocks with the ring, (s + 2) x (s + 2); present:
    // the block is inside the rect.
    const int side = s + 2;
    std::vector<SceneSample> block(static_cast<std::size_t>(side) * side);
    std::vector<std::uint8_t> present(block.size());
    for (int r = begin; r < end; ++r) {
      for (int c = 0; c < rect.width; ++c) {
        const std::size_t pixel = rays.PixelIndex(r, c);
        // Pixels on the rect's border have no points beyond them: always again.
        bool edge = mixed[pixel] || r == 0 || c == 0 || r == rect.height - 1 || c == rect.width - 1;
        for (int dr = -1; dr <= 1 && !edge; ++dr) {
          for (int dc = -1; dc <= 1 && !edge; ++dc) {
            const std::size_t neighbour = rays.PixelIndex(r + dr, c + dc);
            edge = mixed[neighbour] || region[neighbour] != region[pixel];
          }
        }
        if (!edge) continue;
        for (int by = -1; by <= s; ++by) {
          const int dr = by < 0 ? -1 : (by < s ? 0 : 1), sy = by - dr * s;
          for (int bx = -1; bx <= s; ++bx) {
            const int dc = bx < 0 ? -1 : (bx < s ? 0 : 1), sx = bx - dc * s;
            const int rr = r + dr, cc = c + dc;
            const std::size_t slot = static_cast<std::size_t>(by + 1) * side + bx + 1;
            present[slot] = rr >= 0 && cc >= 0 && rr < rect.height && cc < rect.width;
            if (!present[slot]) continue;
            const Eigen::Vector2d ray = rays.Ray(rr, cc, sy * s + sx);
            block[slot] = scene(ray.x(), ray.y());
          }
        }
        const PixelRayMap map = rays.PixelMap(r, c);
        const int fine = s * n;
        double sum = 0;
        for (int by = 0; by < s; ++by) {
          for (int bx = 0; bx < s; ++bx) {
            const std::size_t centre = static_cast<std::size_t>(by + 1) * side + bx + 1;
            bool uniform = true;
            for (int dy = -1; dy <= 1; ++dy) {
              for (int dx = -1; dx <= 1; ++dx) {
                const std::size_t other = centre + dy * side + dx;
                uniform = uniform && present[other] && block[other].region == block[centre].region;
              }
            }
            if (uniform) {
              sum += block[centre].reflectance;
              continue;
            }
            double block_sum = 0;
            for (int j = 0; j < n; ++j) {
              const double v = (by * n + j + 0.5) / fine - 0.5;
              for (int i = 0; i < n; ++i) {
                const Eigen::Vector2d ray = map((bx * n + i + 0.5) / fine - 0.5, v);
                block_sum += scene(ray.x(), ray.y()).reflectance;
              }
            }
            sum += block_sum / (n * n);
          }
        }
        image(r, c) = static_cast<float>(sum / (s * s));
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
