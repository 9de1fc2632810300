// Overlaps as tie points of a tile that nothing else places, or that one
// neighbour alone does.
//
// Why. A tile whose pairs all lack good matches and which sees no hole
// whole with a neighbour (low-texture seed 201: shading of 20-40 mm, the
// part's outer edge) is held by its table prior alone, 0.14 raw px per axis
// at sigma 0.02 mm, and its holes are measured that far off. Its overlaps
// still fix it: the direct alignment of the two tiles' pictures of each
// overlap (pipeline/mosaic/overlap_alignment.h) uses every pixel's
// gradient, so a straight edge fixes it across the edge and the shading,
// over ~10^5 pixels, in every direction, each with its covariance. A tile
// that matches or a hole tie to one neighbour only place has no check on
// them (a corner tile of a low-texture 4 x 3 grid, placed by 14 matches
// with one neighbour); its other overlaps are aligned too.
//
// Model. For a tile b to place and a placed tile a whose footprint meets
// b's (OverlapsToAlign), both are orthorectified over the overlap on
// `geometry`'s grid through the registered scene (RenderTilePatch, no
// exposure: the alignment fits its own gain field), holes masked (their
// walls move with the view; 1.5 nominal radii about the near point, plus
// hole_margin_px). The alignment's shift s (b's content at x + s is a's at
// x) becomes one track: the part point at the overlap's centroid x, seen in
// a at q_a (where the scene shows x; a is placed: only the floor as
// covariance) and in b at q_b (where the scene shows x + s, covariance
// J Cov(s) J' plus the floor, J = dq_b/dx).
// A shift that the table prior makes implausible (chi-square of s against
// Cov(s) plus the prior's 2 sigma^2 per axis beyond consistency_probability)
// is not used.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/image.h"
#include "pipeline/core/plane_scene.h"
#include "pipeline/measure/hole_ties.h"
#include "pipeline/mosaic/orthorectify.h"
#include "pipeline/mosaic/overlap_alignment.h"

namespace omm {

struct OverlapTieOptions {
  OverlapAlignmentOptions alignment;
  // Each hole is masked out to 1.5 times its nominal radius about its near
  // point (within a quarter of the diameter of the centre) plus this, grid px.
  double hole_margin_px = 3.0;
  // Floor of each view's sigma, added in quadrature, tile px.
  double min_sigma_px = 0.01;
  // Quantile of chi-square (2 dof) beyond which a shift contradicts the prior.
  double consistency_probability = 0.999;
  int num_threads = 2;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct OverlapTie {
  int tile_a = 0;              // placed
  int tile_b = 0;              // to place: aligned to tile_a
  OverlapAlignment alignment;  // shift and its covariance, geometry's grid px
  bool used = false;
  std::string why;          // if not used
  double prior_chi2 = 0.0;  // of the shift against its covariance and the prior's
  Eigen::Vector2d point_mm = Eigen::Vector2d::Zero();  // the track's initial part point
  Eigen::Vector2d q_a_px = Eigen::Vector2d::Zero(), q_b_px = Eigen::Vector2d::Zero();
  Eigen::Matrix2d covariance_a_px2 = Eigen::Matrix2d::Zero();
  Eigen::Matrix2d covariance_b_px2 = Eigen::Matrix2d::Zero();
};

// The overlaps to align, (placed tile a, tile b to place): each held tile
// b's with every tile a not held whose footprint's box meets b's; and each
// weakly placed tile b's (not held, linked to one tile at most: `links`
// holds the unordered pairs (lower index first) of tiles that usable
// matches or a hole tie join) with every such a it is not linked to, the
// overlap of two weak tiles once. In the order of b, then a.
std::vector<std::pair<int, int>> OverlapsToAlign(const OrthoGeometry& geometry,
                                                 const std::vector<int>& held,
                                                 const std::vector<std::pair<int, int>>& links);

// One tie per pair of OverlapsToAlign, in its order. geometry: on the
// registered scene; tiles: gray [0, 1]; holes: masked (near_part_mm,
// radius_mm). Pure; throws InputError for invalid options.
std::vector<OverlapTie> FindOverlapTies(const OrthoGeometry& geometry,
                                        const std::vector<ImageF>& tiles,
                                        const std::vector<std::pair<int, int>>& pairs,
                                        const std::vector<TieHole>& holes, double table_sigma_mm,
                                        const OverlapTieOptions& options);

// Appends each used tie to `input` as a track of two views (AppendTieTrack).
void AddOverlapTieTracks(const std::vector<OverlapTie>& ties, PlaneBundleInput* input,
                         PlaneScene* scene);

}  // namespace omm
