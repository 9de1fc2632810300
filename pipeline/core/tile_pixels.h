// Where a planar scene (plane_scene.h) shows a point of the part in a tile,
// and back: the map every stage uses to go between a tile's pixels and the
// part frame, through the lens model (lens_projection.h).
#pragma once

#include <optional>

#include <Eigen/Core>

#include "pipeline/core/lens_projection.h"
#include "pipeline/core/plane_scene.h"

namespace omm {

// The camera-frame point (mm) of the part point P (Z = 0, mm) in tile
// `tile`, R (P + T_tile) + t, with the plane's rotation given as
// `cam_from_part_r` (angle-axis; scene.cam_from_part_r or a perturbation).
Eigen::Vector3d CameraPointOfPartPoint(const Eigen::Vector3d& cam_from_part_r,
                                       const PlaneScene& scene, int tile,
                                       const Eigen::Vector2d& part_mm);

// Pixel of the part point P (Z = 0, mm) in tile `tile` under `scene`
// (scene.intrinsics); nullopt where the lens cannot project it, or where the
// pixel is not the point's: far outside the image a polynomial lens model
// (OPENCV8's rational one) folds back and maps the point into the image,
// and the pixel's own part point (PartPointOfTilePixel) is another. That
// fold had a tile on the far side of the mosaic count as seeing a hole
// (lens-mismatch seed 347: taken first, its fit failed, "100 % of the rim
// not covered").
std::optional<Eigen::Vector2d> TilePixelOfPartPoint(const LensProjection& lens,
                                                    const PlaneScene& scene, int tile,
                                                    const Eigen::Vector2d& part_mm);

// The part point (Z = 0, mm) tile `tile` saw at q_px: the ray's intersection
// with the top surface, refined by Gauss-Newton on the lens model to
// 1e-9 px. nullopt if the ray misses the plane or the iteration fails.
std::optional<Eigen::Vector2d> PartPointOfTilePixel(const LensProjection& lens,
                                                    const PlaneScene& scene, int tile,
                                                    const Eigen::Vector2d& q_px);

}  // namespace omm
