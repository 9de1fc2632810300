// Where the mosaic puts a point of the part, and how that place moves when
// the adjusted scene is wrong: the geometric half of a measurement's
// uncertainty (the other half is the edge fit's, circle_measure.h).
//
// Model (plane_scene.h). Tile i saw the part point P at the pixel
//     q = L(R (P + T_i) + t; k),
// L the lens model with intrinsics k. The mosaic (orthorectify.h) draws at
// P-hat whatever the adjusted scene theta-hat = [r, t, T_i, k]-hat maps to q, so
// a feature seen at q appears at the P-hat that solves
// q = L(R-hat (P-hat + T_i-hat) + t-hat; k-hat). To first order, for a scene
// error d_theta with q fixed,
//     d P-hat = -(dq/dP)^-1 (dq/dtheta) d_theta = S d_theta,
// dq/dP = dq/dp_cam R[:, 0:2] (P has Z = 0). theta is PlaneScene::covariance's
// vector [r (3), t (3), T_0 (2), ..., T_{n-1} (2), per plate (5), k (N)]; S
// is 2 x that size, nonzero in r, t, T_i and k only. Cov(P-hat) from the scene
// is S Cov(theta) S'.
//
// In an overlap the mosaic blends tiles (orthorectify.h's weights), so a
// feature there is a weighted average of the tiles' pictures of it and moves
// with the weighted average of their S: BlendedSceneSensitivity.
//
// d r enters through R(r + d r) (the angle-axis vector itself, as the
// adjustment perturbs it); dq/dr is taken by central differences
// (the rotation is smooth; step 1e-7 rad, error ~1e-9 relative), the rest
// analytically from LensProjection's Jacobians.
#pragma once

#include <optional>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/lens_projection.h"
#include "pipeline/core/plane_scene.h"
#include "pipeline/core/tile_pixels.h"

namespace omm {

// S = d P-hat / d theta (2 x PlaneSceneCovarianceSize(...)) of the part point
// P seen by tile `tile` (header comment). nullopt where the lens cannot
// project P.
std::optional<Eigen::MatrixXd> SceneSensitivity(const LensProjection& lens, const PlaneScene& scene,
                                                int tile, const Eigen::Vector2d& part_mm);

// The tiles the mosaic blends at P and their normalised weights, as
// ResampleMosaic computes them (TileBorderDistancePx, TileBlendWeight with
// band_px), for an imager of width_px x height_px. Empty if no tile sees P.
std::vector<std::pair<int, double>> MosaicBlendAt(const LensProjection& lens,
                                                  const PlaneScene& scene,
                                                  const Eigen::Vector2d& part_mm, int width_px,
                                                  int height_px, double band_px);

// Sum over MosaicBlendAt's tiles of weight x SceneSensitivity; nullopt if no
// tile sees P.
std::optional<Eigen::MatrixXd> BlendedSceneSensitivity(const LensProjection& lens,
                                                       const PlaneScene& scene,
                                                       const Eigen::Vector2d& part_mm, int width_px,
                                                       int height_px, double band_px);

}  // namespace omm
