// Procedural surface textures of the simulated workpiece: smooth, analytic
// functions of the part-frame position, so every tile sees exactly the same
// surface wherever it lands in the image.
//
// The building block is 2-D gradient noise (Perlin 2002, "Improving noise":
// random unit gradients on the integer lattice, blended with the quintic
// 6t^5 - 15t^4 + 10t^3, so the field is C2 and nearly band-limited to
// wavelengths >= ~1 lattice cell). A texture sums octaves of it (fractal
// Brownian motion), each rotated and shifted so that no lattice direction
// dominates, and maps the sum to a reflectance in [0, 1].
#pragma once

#include <array>
#include <cstdint>
#include <vector>

namespace omm {

// One gradient-noise field, value in about [-0.7, 0.7], zero mean. Lattice
// hashing through a 4096-entry permutation: the field repeats only after 4096
// cells.
class GradientNoise {
 public:
  explicit GradientNoise(std::uint64_t seed);
  // The field at the N points (x[k], y[k]) (N = 2 or 4) into value[k]: the
  // arithmetic of one point at a time, laid out so that the compiler
  // evaluates the points side by side (SIMD).
  template <int N>
  void Evaluate(const double* x, const double* y, double* value) const;

 private:
  static constexpr int kSize = 4096;
  std::vector<std::uint16_t> perm_;  // 2 * kSize entries: perm_[i + kSize] = perm_[i]
};

enum class TextureStyle {
  kRich,    // cast/milled-looking blotches with many corners (Harris + NCC)
  kLow,     // weak, smooth shading: few usable corners
  kSparse,  // a plain surface with sparse dark specks
};

struct TextureOctave {
  double frequency_per_mm = 0.0;  // lattice cells per mm
  double amplitude = 0.0;
  double cos_a = 1.0, sin_a = 0.0;        // rotation of this octave's lattice
  double offset_x = 0.0, offset_y = 0.0;  // shift, lattice cells
};

// A workpiece surface texture: reflectance R(x, y) of part-frame (x, y) mm.
class SurfaceTexture {
 public:
  SurfaceTexture(TextureStyle style, std::uint64_t seed);
  float Reflectance(double x_mm, double y_mm) const;

 private:
  double Octaves(double x_mm, double y_mm) const;
  template <int N>
  double SumOctaves(double x_mm, double y_mm) const;

  TextureStyle style_;
  GradientNoise noise_;
  std::vector<TextureOctave> octaves_;
};

}  // namespace omm
