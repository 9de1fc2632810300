#include "pipeline/simulate/texture.h"

#include <algorithm>
#include <cassert>
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

template <int N>
void GradientNoise::Evaluate(const double* x, const double* y, double* value) const {
  double tx[N], ty[N];
  int ix[N], iy[N];
  for (int k = 0; k < N; ++k) {
    const double fx = std::floor(x[k]), fy = std::floor(y[k]);
    tx[k] = x[k] - fx;
    ty[k] = y[k] - fy;
    ix[k] = static_cast<int>(static_cast<long long>(fx) & (kSize - 1));
    iy[k] = static_cast<int>(static_cast<long long>(fy) & (kSize - 1));
  }
  // Gradients of the corners (0, 0), (1, 0), (0, 1), (1, 1) of each cell.
  double gx[4][N], gy[4][N];
  for (int k = 0; k < N; ++k) {
    const int a = perm_[ix[k]] + iy[k], b = perm_[ix[k] + 1] + iy[k];
    const int g[4] = {perm_[a] & 15, perm_[b] & 15, perm_[a + 1] & 15, perm_[b + 1] & 15};
    for (int c = 0; c < 4; ++c) {
      gx[c][k] = kGradients.gx[g[c]];
      gy[c][k] = kGradients.gy[g[c]];
    }
  }
  for (int k = 0; k < N; ++k) {
    const double c00 = gx[0][k] * tx[k] + gy[0][k] * ty[k];
    const double c10 = gx[1][k] * (tx[k] - 1) + gy[1][k] * ty[k];
    const double c01 = gx[2][k] * tx[k] + gy[2][k] * (ty[k] - 1);
    const double c11 = gx[3][k] * (tx[k] - 1) + gy[3][k] * (ty[k] - 1);
    const double u = Fade(tx[k]), v = Fade(ty[k]);
    const double n0 = c00 + u * (c10 - c00);
    const double n1 = c01 + u * (c11 - c01);
    value[k] = n0 + v * (n1 - n0);
  }
}

template void GradientNoise::Evaluate<2>(const double*, const double*, double*) const;
template void GradientNoise::Evaluate<4>(const double*, const double*, double*) const;

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

template <int N>
double SurfaceTexture::SumOctaves(double x_mm, double y_mm) const {
  double x[N], y[N], value[N];
  for (int k = 0; k < N; ++k) {
    const TextureOctave& o = octaves_[k];
    const double fx = o.frequency_per_mm * x_mm, fy = o.frequency_per_mm * y_mm;
    x[k] = o.cos_a * fx - o.sin_a * fy + o.offset_x;
    y[k] = o.sin_a * fx + o.cos_a * fy + o.offset_y;
  }
  noise_.Evaluate<N>(x, y, value);
  double sum = 0.0;
  for (int k = 0; k < N; ++k) sum += octaves_[k].amplitude * value[k];
  return sum;
}

double SurfaceTexture::Octaves(double x_mm, double y_mm) const {
  // The octave count is a compile-time constant in the kernel, so that it vectorises.
  assert(octaves_.size() == 2 || octaves_.size() == 4);
  return octaves_.size() == 4 ? SumOctaves<4>(x_mm, y_mm) : SumOctaves<2>(x_mm, y_mm);
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
