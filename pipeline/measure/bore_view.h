// How the mosaic shows the bore of a through-hole: the nadir the bottom rim
// is scaled about, and whether one tile's picture covers the hole.
//
// Model. A tile's camera centre C lies at height h above the part's top
// face (Z = 0). The mosaic (orthorectify.h) draws at P whatever the tile saw
// along the ray from C through P, so a point of the bottom face (Z = -t, t
// the part's thickness) appears where that ray meets Z = 0: the bottom face
// is mapped by the homothety of centre n and ratio k = h / (h + t), n the
// nadir (the foot of the perpendicular from C onto the plane). A hole's
// bottom rim therefore shows as its top rim (c, r) scaled about n:
// (n + k (c - n), k r), exactly, whatever the camera's tilt. Where two tiles
// blend, the mosaic shows two such bottom rims, each about its own nadir.
#pragma once

#include <optional>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/lens_projection.h"
#include "pipeline/core/plane_scene.h"

namespace omm {

// The nadir of tile `tile`'s camera on the part plane, part frame mm:
// C = -R' t in the table frame, less the tile's table position.
Eigen::Vector2d TileNadirMm(const PlaneScene& scene, int tile);

// The tile whose picture the mosaic shows over the disc (centre_mm,
// radius_mm): the one whose blend weight (MosaicBlendAt with band_px, for a
// width_px x height_px imager) exceeds 1 - max_other_weight at the centre
// and at 16 points of the rim. nullopt where tiles blend over the disc or
// no tile sees part of it.
std::optional<int> RenderingTile(const LensProjection& lens, const PlaneScene& scene,
                                 const Eigen::Vector2d& centre_mm, double radius_mm, int width_px,
                                 int height_px, double band_px, double max_other_weight);

// The tiles that see the whole disc (centre_mm, radius_mm): the border
// distance of its pixel (TileBorderDistancePx) is >= min_border_px at the
// centre and at 32 points of the rim, less the most the rim bulges beyond
// the polygon of those points (its sagitta, r (1 - cos(pi / 32)) for the
// disc's radius r in tile px: 0.5 px at 108 px). Best first: by that
// distance's minimum.
std::vector<int> TilesSeeingDisc(const LensProjection& lens, const PlaneScene& scene,
                                 const Eigen::Vector2d& centre_mm, double radius_mm, int width_px,
                                 int height_px, double min_border_px);

}  // namespace omm
