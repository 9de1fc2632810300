// Exposure compensation of the tiles from their overlaps.
//
// Model. Tile i records a part point of (gain-free, vignetting-free) radiance
// L at its pixel q as
//     I = g_i (1 - v_i rho(q)^2) L,     rho(q) = |q - c| / R,
// c the principal point, R half the image diagonal: a gain per tile (exposure
// time, illumination) and a radial vignetting fall-off per tile (the lens's
// plus the illumination's, which moves with the table). No offset: black level
// is subtracted by the camera, and an offset next to a radial term is poorly
// determined by overlaps.
//
// Estimation. Each sample is a mosaic point seen by two or more tiles, with
// its (smoothed) intensity and rho^2 in each. Unknowns: (g_i, v_i) per tile and
// L per sample; minimise sum w (I - (a_i - b_i rho^2) L)^2, (a, b) = (g, g v),
// by Gauss-Newton in (a, b) with the radiances eliminated (variable
// projection, Golub & Pereyra): L in closed form per sample for the current
// exposures, then one step on the reduced normal equations (the Schur
// complement of the per-sample radiance blocks). Robust weights (Cauchy at
// `cauchy_sigmas` robust sigmas of the relative residual, re-estimated every
// step) discount points the tiles do not agree on (parallax
// through holes, specular spots). Only the products g L are determined: the
// gauge is the tile of median gain, whose gain is 1, so the compensated
// tiles have a typical tile's exposure. Brighter tiles are scaled down
// (their clipped samples with them: orthorectify.h draws none where another
// tile sees the point), darker ones lifted, above 1 where the gauge tile
// would have clipped. With the brightest tile as the gauge, one tile
// exposed 2.2 times the others lifted all the others 2.2 times: half of
// demo seed 281's mosaic was at full scale.
//
// Result quality: the relative residual of the same point in different tiles
// before (g = 1, v = 0) and after, and the largest per-pair median intensity
// ratio: the step a seam would show.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/camera.h"

namespace omm {

// Where rho is measured from: c = principal point, R = half the image diagonal.
struct VignettingFrame {
  Eigen::Vector2d centre_px = Eigen::Vector2d::Zero();
  double radius_px = 1.0;

  static VignettingFrame Of(const CameraModel& camera);
  double Rho2(const Eigen::Vector2d& q_px) const {
    return (q_px - centre_px).squaredNorm() / (radius_px * radius_px);
  }
};

struct TileExposure {
  double gain = 1.0;        // g
  double vignetting = 0.0;  // v: relative fall-off at rho = 1
  // Recorded intensity per unit radiance at rho^2.
  double Factor(double rho2) const { return gain * (1.0 - vignetting * rho2); }
};

// One tile's view of a sample point.
struct ExposureObservation {
  int sample = 0;  // samples are numbered 0.. in order; a sample's observations are adjacent
  int tile = 0;
  double value = 0.0;  // recorded intensity
  double rho2 = 0.0;   // rho(q)^2 of the tile pixel
};

struct ExposureOptions {
  int sample_step_px = 8;           // mosaic points sampled every this many mosaic px
  int smoothing_radius_px = 2;      // tiles are box-filtered (2r+1)^2 before sampling, tile px
  double min_border_px = 6.0;       // sample a tile only this far inside its border, tile px
  double min_value = 0.03;          // observations darker than this are not used
  double max_value = 0.97;          // ... nor brighter (saturation)
  bool estimate_vignetting = true;  // false: gains only (v = 0)
  int max_iterations = 100;         // Gauss-Newton steps
  double tolerance = 1e-5;          // stop when no g or v changes more
  double cauchy_sigmas = 3.0;       // Cauchy scale in robust sigmas of the relative residual
  // Passes over the samples are split between this many threads, in fixed
  // blocks of samples: the result does not depend on it.
  int num_threads = 2;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct ExposureSummary {
  bool usable = false;
  std::string brief;
  std::vector<TileExposure> tiles;  // per tile; the median one has gain 1
  int reference_tile = -1;          // the gauge: the tile of median gain
  int num_samples = 0;  // points seen by >= 2 tiles
  int num_observations = 0;
  int iterations = 0;
  // Within the tolerance at the end. False when max_iterations ran out or a
  // step larger than the tolerance lowered no cost (the fit is stuck, not at
  // its optimum: the exposures are then the last good ones).
  bool converged = false;
  // Robust sigma (1.4826 MAD) of the relative difference of a tile's
  // compensated intensity from the sample's consensus, before (g = 1, v = 0)
  // and after compensation.
  double relative_sigma_before = 0.0;
  double relative_sigma_after = 0.0;
  // Largest |median of ln((I_i / F_i) / (I_j / F_j))| over overlapping tile
  // pairs with >= 100 common samples (F the exposure factor): the relative
  // intensity step a hard seam between them would show.
  double max_pair_step_before = 0.0;
  double max_pair_step_after = 0.0;
  std::vector<int> tiles_without_samples;  // kept at g = 1, v = 0
};

// Fits the model to `observations` of `num_tiles` tiles. Pure; observations
// must be grouped by sample (ascending). Data failures (no overlaps) come
// back as usable = false with identity exposures.
ExposureSummary EstimateExposure(const std::vector<ExposureObservation>& observations,
                                 int num_tiles, const ExposureOptions& options);

}  // namespace omm
