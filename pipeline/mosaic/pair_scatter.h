// Each pair's matches weighted by their own scatter.
//
// A match's declared sigma comes from its template's predicted covariance
// (RegisterTiles, weight_by_match_sigma), which holds the image noise but
// not a template's misfit on weak texture. Pairs matched on smooth shading
// scatter several times more than the others: on low-texture seed 228 the
// two pairs that alone placed a tile left residuals of 0.27 and 0.41 px RMS
// against 0.05-0.13 px for every other pair, and their matches were 0.4-0.5
// px RMS from the truth. A variance component per pair makes their weight
// say so.
//
// Model. A pair (a, b)'s matches are its tracks' observations in tile b
// (the anchor, the template's centre in a, is exact). Their scatter in
// units of their declared sigma is s = sqrt(sum |w S r|^2 / (2 n)) (w, S an
// observation's weight and shape, r its residual, px, over the declared
// sigma). Pairs whose s exceeds the median pair's s_m have their weights
// divided by s / s_m; the others keep theirs (the global scale of the
// declared sigma is the final adjustment's: FinalAdjustmentOptions::
// rescale_observation_sigma).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "pipeline/core/plane_scene.h"

namespace omm {

struct PairScatter {
  int tile_a = 0, tile_b = 0;  // anchor tile, matched tile
  int num_observations = 0;
  double scatter = 0.0;       // s, in units of the declared sigma
  double weight_scale = 1.0;  // what their weights were multiplied by (<= 1)
};

// Scales the weights of input's observations as above, from the residuals
// (model minus observed, px, in input order) of a solve of `input`. Track t's
// anchor is observation track_anchor_observation[t]; tracks without one
// (-1 or beyond the vector: ties, not matches) are left alone. Returns the
// pairs, by (tile_a, tile_b).
std::vector<PairScatter> WeightPairsByScatter(const std::vector<int>& track_anchor_observation,
                                              const Eigen::Matrix2Xd& residual_px,
                                              PlaneBundleInput* input);

}  // namespace omm
