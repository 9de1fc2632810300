// Matching between two tiles of the mosaic: the coarse translation between
// two overlapping tiles, and the sub-pixel position in one tile of a small
// patch of another (NCC search, then least-squares template matching).
// Pure kernels on ImageF; pixels follow the pipeline's convention.
#pragma once

#include <string>

#include <Eigen/Core>

#include "pipeline/core/image.h"

namespace omm {

struct TranslationSearchOptions {
  int coarse_max_size_px = 96;   // the exhaustive search runs on images downsampled to this
  double min_overlap_fraction = 0.08;  // shifts overlapping less of the image are not tried
  int finest_factor = 2;         // refinement stops at this downsampling factor

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct TranslationEstimate {
  bool ok = false;
  // Image content at q in `a` is at q + shift_px in `b`, px (to ~finest_factor).
  Eigen::Vector2d shift_px = Eigen::Vector2d::Zero();
  double ncc = 0.0;          // NCC of the overlap at the final level
  double overlap_fraction = 0.0;
};

// The translation between two tiles of the same size by an exhaustive NCC
// search over all shifts of the coarsest level (box-downsampled, so that the
// larger side is <= coarse_max_size_px), refined by a +-2 search at each finer
// level (factors divided by 2) down to finest_factor. Normalised images
// (NormalizeTileIntensity) keep a bright background from dominating.
TranslationEstimate EstimateTranslation(const ImageF& a, const ImageF& b,
                                        const TranslationSearchOptions& options);

// The integer position of best normalised cross-correlation of a template
// from `reference` ((2 half_size_px + 1)^2 pixels centred at the integer
// anchor_px) in `target`, over the integer centres within +-radius_px (per
// axis) of center_px, with the quadratic peak of the NCC surface (per axis,
// clamped to +-0.5 px) where the neighbours exist. ok is false when the
// template or the searched window leaves its image, or the template is flat.
struct NccPeak {
  bool ok = false;
  Eigen::Vector2i pixel = Eigen::Vector2i::Zero();  // best integer centre in target
  Eigen::Vector2d q_px = Eigen::Vector2d::Zero();   // with the quadratic peak
  double ncc = -2.0;                                // at `pixel`
  double target_mean = 0.0, target_std = 0.0;       // of the target window at `pixel`
};
NccPeak SearchNcc(const ImageF& reference, const Eigen::Vector2i& anchor_px, int half_size_px,
                  const ImageF& target, const Eigen::Vector2i& center_px, int radius_px);

struct PatchMatchOptions {
  int half_size_px = 15;  // the template is (2 h + 1)^2 pixels of the reference tile
  double min_ncc = 0.8;   // NCC of the template and the matched, resampled patch
  // The template's intensity standard deviation must reach this (units of the
  // normalised tile: robust sigmas of the tile), else it has no texture.
  double min_template_std = 0.15;
  int max_iterations = 15;            // Gauss-Newton iterations of the template match
  double convergence_px = 1e-4;       // stop when the update is below this, px
  double max_refinement_px = 1.5;     // the refined position may move this far from the NCC peak

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct PatchMatch {
  bool ok = false;
  Eigen::Vector2d q_px = Eigen::Vector2d::Zero();  // the anchor's position in the target tile
  double ncc = 0.0;                                // after refinement
  double residual_rms = 0.0;  // RMS of gain * target + offset - template (normalised units)
  // Predicted 1-sigma of q_px per axis, px: sqrt(trace(C) / 2) of the position
  // block C of the least-squares covariance s^2 N^-1 (N the normal matrix,
  // s^2 the residual variance): small where the texture is strong.
  double sigma_px = 0.0;
  int iterations = 0;
};

// Finds the patch of `reference` centred at pixel `anchor_px` in `target`.
// 1. NCC at every integer offset within +-search_radius_px of the prediction
//    (a translation of the raw template); with search_radius_px = 0 the
//    prediction is taken as sub-pixel exact and step 2 starts there (a
//    relocation of a match already refined);
// 2. least-squares template matching (Gruen 1985) from the best offset:
//      min over q, g, o  sum_x (g T(q + J x) + o - R(anchor + x))^2,
//    x over the template's integer offsets, R the reference tile's raw pixels,
//    T the target's cubic B-spline interpolant (BSplineCoefficients), J = dq_target /
//    dq_reference the local affine of the tile-to-tile map (the prediction's
//    Jacobian, e.g. from the plane-induced homography), held fixed: only the
//    position, gain and offset are estimated. The template is never resampled,
//    so the anchor is exact and only the target is interpolated.
// `target_spline` is BSplineCoefficients(target).
PatchMatch MatchPatch(const ImageF& reference, const Eigen::Vector2i& anchor_px,
                      const ImageF& target, const ImageF& target_spline,
                      const Eigen::Vector2d& predicted_q_px,
                      const Eigen::Matrix2d& dtarget_dreference, int search_radius_px,
                      const PatchMatchOptions& options);

}  // namespace omm
