// Matching between two tiles of the mosaic: the coarse translation between
// two overlapping tiles, and the sub-pixel position in one tile of a small
// patch of another (NCC search, then least-squares template matching).
// Pure kernels on ImageF; pixels follow the pipeline's convention.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/image.h"

namespace omm {

struct ImageMotionOptions {
  int coarse_max_size_px = 96;         // the exhaustive search runs on tiles downsampled to this
  double min_overlap_fraction = 0.08;  // shifts overlapping less of the image are not scored
  int finest_factor = 4;               // refinement stops at this downsampling factor
  // Every level minus the Gaussian blur of the coarsest by this sigma
  // (coarsest px; 0: off), so that shading and vignetting do not correlate.
  double coarse_highpass_sigma_px = 4.0;
  int peaks_per_pair = 4;  // candidate shifts per pair: its strongest local NCC maxima
  // A pair agrees with a motion when its shift is within this fraction of
  // the predicted shift's length plus tolerance_px of the prediction (the
  // lens distortion and the tilt make the motion vary over the image).
  double tolerance_fraction = 0.05;
  double tolerance_px = 8.0;
  // The best candidate's evidence over a clearly different one's (step 3
  // below) must reach this factor, else the motion is ambiguous (not ok).
  // Measured 3.1-8.7 on the simulator's presets.
  double min_margin = 1.5;
  int num_threads = 1;  // the tiles' pyramids and the pairs' surfaces on this many threads

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// The translation between two tiles at the final level.
struct TranslationEstimate {
  bool ok = false;
  // Image content at q in tile a is at q + shift_px in tile b, px (to ~finest_factor).
  Eigen::Vector2d shift_px = Eigen::Vector2d::Zero();
  double ncc = 0.0;          // NCC of the overlap at the final level
  double overlap_fraction = 0.0;
};

struct ImageMotionEstimate {
  bool ok = false;
  // A: the image motion per table millimetre (shift_ij ~ A (T_j - T_i)).
  Eigen::Matrix2d px_per_table_mm = Eigen::Matrix2d::Zero();
  bool mirrored = false;  // the consensus similarity's handedness (det A < 0)
  double score = 0.0;     // the best candidate's evidence (sum of z over all pairs)
  double margin = 0.0;    // the smallest ratio of step 3 (infinity: no different candidate)
  double finest_margin = 0.0;                    // step 3b's, where step 3's fell short (else 0)
  std::vector<TranslationEstimate> pair_shifts;  // per input pair, refined around A's prediction
  std::vector<bool> pair_agrees;                 // its shift agrees with A
  int num_agreeing = 0;
  std::string brief;  // one line: what was found, or why not
};

// The image motion per table millimetre, A (2 x 2, px/mm), from the tiles
// (normalised: NormalizeTileIntensity) taken at table positions table_mm and
// the pairs of them that are neighbours on the table (each expected to
// overlap by a good part of the image).
// 1. Every pair's NCC over all shifts of the coarsest level (tiles
//    box-downsampled so that the larger side is <= coarse_max_size_px; all
//    levels high-passed) and its peaks_per_pair strongest local maxima.
// 2. Each peak with each handedness is a candidate similarity A = s R(theta)
//    diag(1, +-1) (the camera's unknown scale, rotation about its axis and
//    mirror; the table's axes orthogonal). A candidate's evidence is the sum
//    over all pairs of Fisher's z = atanh(NCC) (clamped to [0, atanh 0.99])
//    at the shift it predicts (the best within the tolerance). Weak texture,
//    or one dark region lined up in a small overlap, gives single pairs
//    spurious peaks; only the true motion lines up the peaks of all pairs.
// 3. Against every clearly different candidate (half the pairs' shifts or
//    more found elsewhere), the best one's evidence on the pairs where they
//    differ must be min_margin times the other's: a mirrored motion, say,
//    agrees on the pairs along one table axis and differs on the others.
// 3b. Where that fails, the best candidate and those it does not beat so
//    (one of each set of coarse shifts) are followed down the pyramids, and
//    the one with the most evidence at the finest level must beat the others
//    there by min_margin on the pairs where they differ. What every tile
//    shows alike (a strip's part edges along the motion, the background
//    beside them) lines up at a false shift in all pairs of a strip, whose
//    table displacements are all alike; at the coarsest level it can match
//    the texture of the true overlap, at the finest it does not.
// 4. Each pair's shift refined coarse-to-fine (a +-(ratio + 1) search per
//    level) from the best candidate's down to finest_factor; A is the
//    least-squares fit to the pairs that agree with the candidate (within
//    the tolerance): affine when their table displacements span both axes,
//    else the similarity.
// Precondition: options.Check() is empty; tiles of one size; pairs index tiles.
ImageMotionEstimate EstimateImageMotion(const std::vector<ImageF>& tiles,
                                        const std::vector<Eigen::Vector2d>& table_mm,
                                        const std::vector<std::pair<int, int>>& pairs,
                                        const ImageMotionOptions& options);

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

// The best NCC of the same template in `target` over the integer centres
// within +-radius_px of center_px, with each window's least-squares plane
// (a + b x + c y) removed first: blind to shading that differs linearly
// between the two windows (vignetting at opposite borders of two tiles, an
// exposure ramp), which plain NCC counts against a faint texture. -2 where
// a window leaves its image or is a plane.
double BestDetrendedNcc(const ImageF& reference, const Eigen::Vector2i& anchor_px, int half_size_px,
                        const ImageF& target, const Eigen::Vector2i& center_px, int radius_px);

struct PatchMatchOptions {
  int half_size_px = 15;  // the template is (2 h + 1)^2 pixels of the reference tile
  double min_ncc = 0.8;   // NCC of the template and the matched, resampled patch
  // The template's intensity standard deviation must reach this (units of the
  // normalised tile: robust sigmas of the tile), else it has no texture.
  double min_template_std = 0.15;
  int max_iterations = 15;            // Gauss-Newton iterations of the template match
  // Stop when the position's remaining error is below this, px: the update,
  // or the sum of the next ones predicted from the last two's contraction.
  // 1e-3 px is a few % of a match's sigma (0.02-0.17 px) and saves a
  // resampling of the patch for most matches (1e-4: a quarter more samples).
  double convergence_px = 1e-3;
  double max_refinement_px = 1.5;     // the refined position may move this far from the NCC peak
  // Template pixels whose residual exceeds this many robust sigmas (1.4826
  // MAD) get no weight (Tukey's biweight, iterated from the plain
  // least-squares solution): content that does not follow the plane between
  // the two views (a bore's wall and the table seen through it, which move
  // with the parallax) must not pull the match. 0: plain least squares.
  double robust_tukey_c = 4.685;
  // Iterations of the reweighted phase: it converges linearly, and stopping
  // it early (15) rejected a third of the low-texture preset's rim templates.
  int max_robust_iterations = 50;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// The map of a template offset x (reference px, from the anchor) to the
// target, about the anchor's image there, to second order:
//   w(x) = J x + 1/2 (x^T H_0 x, x^T H_1 x),
// J = dq_target / dq_reference, H_k = d^2 q_target,k / dq_reference^2. The
// second-order term matters: a translation fitted under J alone lands at the
// anchor's image plus the template's (gradient-weighted) mean of it, ~1/2
// <x_i^2> (H_k(0, 0) + H_k(1, 1)) = 40 px^2 times the map's Laplacian for a
// 31 x 31 template. Between two tiles the lens makes that Laplacian ~8 k1 d /
// f^2 (displacement d, radial coefficient k1 over f^2 px^2), along d and the
// same everywhere: every match's displacement comes out short or long by a
// fixed fraction (barrel: short; 4 ppm on the demo's lens, 23 ppm on the
// lens-mismatch preset's), which the adjustment reads as a height.
struct PatchWarp {
  Eigen::Matrix2d jacobian = Eigen::Matrix2d::Identity();
  // H_0, H_1 (symmetric), px^-1.
  Eigen::Matrix2d hessian[2] = {Eigen::Matrix2d::Zero(), Eigen::Matrix2d::Zero()};

  Eigen::Vector2d Offset(const Eigen::Vector2d& x) const {
    return jacobian * x + 0.5 * Eigen::Vector2d(x.dot(hessian[0] * x), x.dot(hessian[1] * x));
  }
  // The warp at the anchor from the map's Jacobians there (j) and at the
  // anchor plus and minus step_px along x (j_px, j_mx) and along y (j_py,
  // j_my): H by central differences of J, symmetrised.
  static PatchWarp FromJacobians(const Eigen::Matrix2d& j, const Eigen::Matrix2d& j_px,
                                 const Eigen::Matrix2d& j_mx, const Eigen::Matrix2d& j_py,
                                 const Eigen::Matrix2d& j_my, double step_px);
};

struct PatchMatch {
  bool ok = false;
  Eigen::Vector2d q_px = Eigen::Vector2d::Zero();  // the anchor's position in the target tile
  double ncc = 0.0;                                // after refinement
  double residual_rms = 0.0;  // RMS of gain * target + offset - template (normalised units)
  // Predicted covariance of q_px, px^2: the position block of the
  // least-squares covariance s^2 N^-1 (N the normal matrix, s^2 the residual
  // variance): small where the texture is strong; on an edge, small across
  // it and large along it.
  Eigen::Matrix2d covariance_px2 = Eigen::Matrix2d::Zero();
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
//    T the target's cubic B-spline interpolant (CubicBSplineCoefficients), J x
//    standing for warp.Offset(x): the tile-to-tile map about the anchor to
//    second order (the prediction's, e.g. through the plane-induced
//    homography and the lens), held fixed: only the position, gain and offset
//    are estimated. The template is never resampled, so the anchor is exact
//    and only the target is interpolated;
// 3. (options.robust_tukey_c > 0) the same, iteratively reweighted from step
//    2's solution with Tukey's biweight of each pixel's residual (scale
//    1.4826 MAD), to its fixed point: pixels whose content differs between
//    the views beyond the plane's warp (a bore's wall and what is seen
//    through it) stop pulling the match. covariance_px2 then comes from the
//    weighted normal matrix and weighted residual variance.
// `target_spline` is CubicBSplineCoefficients(target).
PatchMatch MatchPatch(const ImageF& reference, const Eigen::Vector2i& anchor_px,
                      const ImageF& target, const ImageF& target_spline,
                      const Eigen::Vector2d& predicted_q_px, const PatchWarp& warp,
                      int search_radius_px, const PatchMatchOptions& options);

}  // namespace omm
