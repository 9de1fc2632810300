// Test support: a top view of one through-hole with known truth, rendered
// the way the mosaic shows holes (pipeline/simulate/scene.cc's materials).
//
// Scene (image px, pixel centres at integers): the top rim is the circle
// (centre_px, radius_px). Inside it the bore wall shows where the bottom
// rim, the circle (centre_px + bottom_shift_px, bottom_radius_px), does not
// cover: a ring of width ~(radius - bottom_radius) shifted towards one side
// (perspective: the bottom face is farther from the camera). Through the
// bottom opening the table shows. Outside the rim: the simulator's surface
// texture (SurfaceTexture, kRich) at `gsd_mm` per px, or a flat level.
// Extras: dark blobs (burrs, specks) centred on given points, a brightness
// factor on one side of a line (a seam between tiles of different
// exposure), and uncovered pixels (exactly 0) on one side of another line.
//
// Pixels are integrated over their area (supersampled near the rims and
// blobs; the texture, smooth at the pixel scale, taken at the pixel's
// centre), blurred by a Gaussian PSF, then given Gaussian noise.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/image.h"

namespace omm::testing {

struct SyntheticHole {
  int width_px = 160, height_px = 160;
  Eigen::Vector2d centre_px{80.0, 80.0};
  double radius_px = 50.0;
  Eigen::Vector2d bottom_shift_px{0.0, 0.0};  // bottom rim's centre - top rim's centre
  double bottom_radius_px = 50.0;             // == radius_px: no wall when not shifted
  float table = 0.04f;                        // seen through the hole
  float wall = 0.16f;                         // the bore wall
  // Surface: the simulator's rich texture (seed) or, without one, `surface`.
  std::optional<std::uint64_t> texture_seed;
  double gsd_mm = 0.15;  // texture scale: mm per px
  Eigen::Vector2d texture_offset_mm{0.0, 0.0};
  float surface = 0.5f;
  struct Blob {
    Eigen::Vector2d centre_px;
    double radius_px;
    float level;
  };
  std::vector<Blob> blobs;  // drawn over the surface only (not into the hole)
  // Seam: pixels p with seam_normal . p > seam_offset are multiplied by seam_gain.
  Eigen::Vector2d seam_normal{1.0, 0.0};
  double seam_offset_px = 1e9;
  double seam_gain = 1.0;
  // Uncovered: pixels p with uncovered_normal . p > uncovered_offset are 0.
  Eigen::Vector2d uncovered_normal{1.0, 0.0};
  double uncovered_offset_px = 1e9;
  double psf_sigma_px = 0.7;
  double noise_sigma = 0.0;  // image units
  std::uint64_t noise_seed = 1;
  int supersampling = 8;  // per axis, near boundaries
};

ImageF RenderSyntheticHole(const SyntheticHole& hole);

}  // namespace omm::testing
