#include "pipeline/measure/synthetic_hole.h"

#include <cmath>
#include <random>

#include "pipeline/simulate/texture.h"

namespace omm::testing {

ImageF RenderSyntheticHole(const SyntheticHole& hole) {
  std::optional<SurfaceTexture> texture;
  if (hole.texture_seed) texture.emplace(TextureStyle::kRich, *hole.texture_seed);
  const Eigen::Vector2d bottom_centre = hole.centre_px + hole.bottom_shift_px;
  // The scene at (x, y); the texture varies little within a pixel, so it is
  // taken at the pixel's centre (`surface_here`), the boundaries exactly.
  auto scene = [&](double x, double y, float surface_here) -> float {
    const Eigen::Vector2d p(x, y);
    if ((p - hole.centre_px).squaredNorm() <= hole.radius_px * hole.radius_px) {
      return (p - bottom_centre).squaredNorm() <= hole.bottom_radius_px * hole.bottom_radius_px
                 ? hole.table
                 : hole.wall;
    }
    for (const SyntheticHole::Blob& blob : hole.blobs) {
      if ((p - blob.centre_px).squaredNorm() <= blob.radius_px * blob.radius_px) return blob.level;
    }
    return surface_here;
  };
  // Pixels within a px of a boundary are integrated finely.
  auto near = [](const Eigen::Vector2d& p, const Eigen::Vector2d& c, double r) {
    return std::abs((p - c).norm() - r) < 1.0;
  };
  ImageF area(hole.height_px, hole.width_px);
  for (int row = 0; row < hole.height_px; ++row) {
    for (int col = 0; col < hole.width_px; ++col) {
      const Eigen::Vector2d p(col, row);
      const float surface_here =
          texture ? texture->Reflectance(hole.texture_offset_mm.x() + col * hole.gsd_mm,
                                         hole.texture_offset_mm.y() + row * hole.gsd_mm)
                  : hole.surface;
      bool edge =
          near(p, hole.centre_px, hole.radius_px) || near(p, bottom_centre, hole.bottom_radius_px);
      for (const SyntheticHole::Blob& blob : hole.blobs)
        edge = edge || near(p, blob.centre_px, blob.radius_px);
      const int n = edge ? hole.supersampling : 1;
      double sum = 0.0;
      for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
          sum += scene(col - 0.5 + (j + 0.5) / n, row - 0.5 + (i + 0.5) / n, surface_here);
        }
      }
      area(row, col) = static_cast<float>(sum / (n * n));
    }
  }
  // Separable Gaussian PSF, borders clamped.
  const int half = static_cast<int>(std::ceil(4.0 * hole.psf_sigma_px));
  Eigen::VectorXd kernel(2 * half + 1);
  double total = 0.0;
  for (int i = -half; i <= half; ++i) {
    kernel(i + half) = std::exp(-0.5 * i * i / (hole.psf_sigma_px * hole.psf_sigma_px));
    total += kernel(i + half);
  }
  kernel /= total;
  auto clamp = [](int i, int size) { return std::min(std::max(i, 0), size - 1); };
  ImageF rows_blurred(hole.height_px, hole.width_px), image(hole.height_px, hole.width_px);
  for (int row = 0; row < hole.height_px; ++row) {
    for (int col = 0; col < hole.width_px; ++col) {
      double sum = 0.0;
      for (int i = -half; i <= half; ++i)
        sum += kernel(i + half) * area(row, clamp(col + i, hole.width_px));
      rows_blurred(row, col) = static_cast<float>(sum);
    }
  }
  std::mt19937_64 rng(hole.noise_seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  for (int row = 0; row < hole.height_px; ++row) {
    for (int col = 0; col < hole.width_px; ++col) {
      double sum = 0.0;
      for (int i = -half; i <= half; ++i)
        sum += kernel(i + half) * rows_blurred(clamp(row + i, hole.height_px), col);
      const Eigen::Vector2d p(col, row);
      if (hole.seam_normal.dot(p) > hole.seam_offset_px) sum *= hole.seam_gain;
      sum += hole.noise_sigma * noise(rng);
      if (hole.uncovered_normal.dot(p) > hole.uncovered_offset_px) sum = 0.0;
      image(row, col) = static_cast<float>(sum);
    }
  }
  return image;
}

}  // namespace omm::testing
