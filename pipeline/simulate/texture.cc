#include "pipeline/simulate/texture.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <utility>

#include "pipeline/simulate/random.h"

namespace omm {
namespace {

double Fade(double t) { return t * t * t * (t * (t * 6 - 15) + 10); }

// 16 gradient directions, evenly spread: no axis is preferred.
struct Gradients {
  std::array<double, 16> gx, gy;
  Gradients() {
    for (int k = 0; k < 16; ++k) {
      gx[k] = std::cos(2 * std::numbers::pi * (k + 0.5) / 16);
      gy[k] = std::sin(2 * std::numbers::pi * (k + 0.5) / 16);
    }
  }
};
const Gradients kGradients;

double SmoothStep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3 - 2 * t);
}

}  // namespace

GradientNoise::GradientNoise(std::uint64_t seed) : perm_(2 * kSize) {
  SimRandom random(seed, 0x7e47);
  for (int i = 0; i < kSize; ++i) perm_[i] = static_cast<std::uint16_t>(i);
  for (int i = kSize - 1; i > 0; --i) std::swap(perm_[i], perm_[random.UniformInt(i + 1)]);
  for (int i = 0; i < kSize; ++i) perm_[i + kSize] = perm_[i];
}

double GradientNoise::operator()(double x, double y) const {
  const double fx = std::floor(x), fy = std::floor(y);
  const double tx = x - fx, ty = y - fy;
  const int ix = static_cast<int>(static_cast<long long>(fx) & (kSize - 1));
  const int iy = static_cast<int>(static_cast<long long>(fy) & (kSize - 1));
  auto corner = [&](int dx, int dy) {
    const int g = perm_[perm_[ix + dx] + iy + dy] & 15;
    return kGradients.gx[g] * (tx - dx) + kGradients.gy[g] * (ty - dy);
  };
  const double u = Fade(tx), v = Fade(ty);
  const double n0 = corner(0, 0) + u * (corner(1, 0) - corner(0, 0));
  const double n1 = corner(0, 1) + u * (corner(1, 1) - corner(0, 1));
  return n0 + v * (n1 - n0);
}

SurfaceTexture::SurfaceTexture(TextureStyle style, std::uint64_t seed)
    : style_(style), noise_(seed) {
  SimRandom random(seed, 0x7e48);
  // (finest-octave wavelength, number of octaves, amplitude ratio per octave)
  double wavelength_mm = 0.0;
  int num_octaves = 0;
  double persistence = 0.0;
  switch (style) {
    case TextureStyle::kRich:
      wavelength_mm = 0.7, num_octaves = 4, persistence = 1.5;  // 0.7 .. 5.6 mm
      break;
    case TextureStyle::kLow:
      wavelength_mm = 20.0, num_octaves = 2, persistence = 2.0;  // 20 .. 40 mm
      break;
    case TextureStyle::kSparse:
      wavelength_mm = 2.5, num_octaves = 2, persistence = 2.0;  // specks of ~1-2 mm
      break;
  }
  double amplitude = 1.0;
  for (int o = 0; o < num_octaves; ++o) {
    const double angle = random.Uniform(0, 2 * std::numbers::pi);
    octaves_.push_back({1.0 / wavelength_mm, amplitude, std::cos(angle), std::sin(angle),
                        random.Uniform(0, 1000), random.Uniform(0, 1000)});
    wavelength_mm *= 2;
    amplitude *= persistence;
  }
  // Normalise so the sum has about the range of one octave.
  double total = 0.0;
  for (const TextureOctave& octave : octaves_) total += octave.amplitude;
  for (TextureOctave& octave : octaves_) octave.amplitude /= total;
}

double SurfaceTexture::Octaves(double x_mm, double y_mm) const {
  double sum = 0.0;
  for (const TextureOctave& o : octaves_) {
    const double x = o.frequency_per_mm * x_mm, y = o.frequency_per_mm * y_mm;
    sum += o.amplitude *
           noise_(o.cos_a * x - o.sin_a * y + o.offset_x, o.sin_a * x + o.cos_a * y + o.offset_y);
  }
  return sum;
}

float SurfaceTexture::Reflectance(double x_mm, double y_mm) const {
  const double n = Octaves(x_mm, y_mm);
  switch (style_) {
    case TextureStyle::kRich:
      // The soft threshold x / sqrt(1 + x^2) (a cheap tanh) turns blotches
      // into blobs with well-defined but smooth rims: corners for Harris.
      return static_cast<float>(0.5 + 0.25 * (5.0 * n) / std::sqrt(1.0 + 25.0 * n * n));
    case TextureStyle::kLow: return static_cast<float>(0.55 + 0.06 * n);
    case TextureStyle::kSparse: return static_cast<float>(0.62 - 0.4 * SmoothStep(0.28, 0.4, n));
  }
  return 0.5f;
}

}  // namespace omm
