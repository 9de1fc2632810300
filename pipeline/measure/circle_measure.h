// Centre and radius of a round hole in a top-view image (the orthorectified
// mosaic), with the covariance of the edge fit.
//
// Scene. A through-hole is a dark disc in a textured, brighter surface. The
// part is thick and seen in perspective, so inside the top rim the bore
// wall shows as a gray band between the top rim and the bottom rim (which
// looks smaller and is shifted away from the camera's axis): a ring when the
// axis passes through the hole, a crescent otherwise. Only the OUTERMOST
// dark-to-bright step along a ray from the centre is the top rim.
//
// Procedure.
//  1. Coarse centre: every pixel's gradient g in an annulus around the
//     expected circle votes for a centre at p - R g/|g| (R the nominal
//     radius; the gradient of a dark disc points outwards), weighted by |g|;
//     the peak of the smoothed vote map within the search square wins.
//     Texture votes spread out; the bottom rim has less contrast.
//  2. Edges in wedges: the annulus about the current circle is cut into
//     wedges of `wedge_arc_px` of arc. Along each wedge's centre ray the
//     outermost strong rise within +- band is the rim's coarse place; then a
//     blurred step is fitted to the wedge's own pixels (value against radial
//     distance d, no interpolation) by Levenberg-damped Gauss-Newton:
//         f(d) = a + c0 Phi(z0) + go Rout(u0)                 rim and surface
//                + gi Rin(u0)  or  c1 (Phi(z1) - Phi(z0))      inside: ramp or wall
//     u_j = d - x_j, z_j = u_j / s, s the blur (PSF, pixel, resampling),
//     Rout(u) = u Phi(u/s) + s phi(u/s) and Rin(u) = u Phi(-u/s) - s phi(u/s)
//     the blurred ramps. The ramp go absorbs the surface texture's slope at
//     the rim, which moves a mid-level or a gradient-maximum edge by
//     ~ slope s^2 / contrast. The wall term is the band [x1, x0] between the
//     bottom rim x1 and the top rim x0 (none where x1 >= x0: wall hidden).
//     Passes: (a) the rim with an inside ramp, s free (the blur); (b) the
//     same, and where a bottom rim shows (a rise farther in, or a shoulder
//     on the rim's flank: a narrow wall merges with the rim) a fit of both
//     steps that must explain the same pixels clearly better (RMS < 0.7x);
//     the resolved bottom-rim points (x0 - x1 > 2 s) give the bottom rim's
//     circle: given the nadir n of the tile the mosaic shows the hole from,
//     it is the top rim scaled about n, (n + k (c - n), k r) (bore_view.h),
//     and its one unknown k = h / (h + t) is fitted to those points (Gauss-
//     Newton, Huber then Tukey weights; refitted against the top rim after
//     every pass); without a nadir (or if k does not settle in (0, 1)), a
//     free circle by a robust fit; (c) the wall term with x1 from that
//     circle (else the ramp), until the circle settles. A wedge is dropped
//     when its fit is not a clean step: contrast below `min_contrast`, RMS
//     above `max_profile_rms_ratio` x the median, x0 more than 1 px off the
//     coarse place, or it touches uncovered pixels. With the nadir's circle,
//     pass (c) also leaves out the wedges where the wall shows narrower than
//     `min_wall_blurs` blurs (its width is (1 - k)(r - |c - n| cos a), a the
//     angle from the direction to the nadir) if the rest span half the rim
//     or more: such a band merges with the rim's step and its free contrast
//     trades against x0 (on texture, edges there scatter by 0.2-0.4 px and
//     sit ~0.15 px in; a ring wall 2.0 blurs wide leaves the radius 0.020
//     px small, 2.3 blurs 0.011 px, 2.5 blurs or wider ~0.008 px: r 200 px,
//     10 textures). The circle is fitted to the rest; its covariance grows
//     with the gap (the sensitivity S below has no rows there).
//  3. Robust circle fit to the edge points c + (r + x0) n(theta): Gauss-Newton
//     on the radial distances, Huber then Tukey biweight IRLS with the scale
//     from the median absolute residual.
//  4. The rim of a blurred disc lies s^2 / 2r inside the geometric one (the
//     blur kernel's mass beyond a curved edge): the radius gets + s^2 / 2r.
//
// Limits. A wall ring narrower than ~2 s merges with the rim and cannot be
// told from a wider blur. With the demo's 12 mm part seen from 410 mm at
// 0.15 mm per px (ring 2.9 % of the radius, s ~0.8 px) that is a hole under
// ~16 mm diameter with the camera's axis within ~2 radii of its centre:
// measured on synthetic holes, radius up to 0.17 px small (8 mm hole, axis
// through it) and centre up to 0.07 px off, which the covariance does not
// cover (8 mm, k 0.97, s 0.8 px, the simulator's sensor noise: radius -0.17
// px with the axis through the centre, -0.10 px with it 1.1 radii away,
// unbiased from ~2 radii; k is then not resolved, and given the true k the
// held bottom rim still leaves -0.13 and -0.06 px: the wall's contrast
// trades against x0). Given a BorePrior (k and the wall's level that other
// views resolved; MeasureCircle's comment) those wedges are fitted with the
// wall tied to the rim: radius within 0.003 px over 60 textures, the centre
// ~0.01 px away from the nadir (NarrowRingNearTheAxisIsUnbiasedGiven-
// TheBorePrior); a wall level off by e moves the radius by ~+2 e px and the
// centre by ~-2.4 e px along the nadir's direction, which the covariance
// includes for the prior's wall_contrast_sigma. Far from the axis a crescent wider than the bottom
// rim's reach leaves no bias (WideCrescentFarFromTheNadirDoesNotBiasTheFit);
// an 8-12 mm hole's radius scatters by ~0.011 px per tile view, as its
// covariance says (399 views in 128 simulated projects: rms error / sigma
// 1.05); with noise alone a 2 px wedge's x0 scatters by ~0.09 px, the
// Cramer-Rao bound of its six-parameter step fit (x0 alone: 0.02 px; the two
// ramps cost most of it). Larger holes with the nadir near the rim show such
// a narrow arc on one side: without a nadir (none given, or tiles blending
// over the hole), or when it is more than half the rim, it stays in the fit:
// for a 60 mm hole with the nadir 0.97 r from its centre, over 30 textures,
// the centre 0.020 px away from the nadir and the diameter 0.023 px small
// (0.008 and 0.010 px with the nadir). A resolved wall 2-5 px wide moves the
// rim by 0.005-0.01 px, inwards or outwards with the blur's SHAPE: the step
// model assumes a Gaussian, a real blur (pixel box, the mosaic's B-spline)
// leaves a residual odd about the rim, and the wall model's one-sided terms
// (outer ramp, wall step) absorb part of it where the ramp-only model's
// two-sided ramps do not (1-D fits on exact profiles: Gaussian 0,
// synthetic_hole's kernel -0.008 to -0.010 px, a simulated tile resampled by
// the B-spline +0.005 to +0.007 px). The term is the outer ramp go: without
// it those 1-D fits are within 0.002 px, but texture slopes then move x0 by
// ~4 px per unit of slope. Not covered by the covariance either. Tried in
// 2-D (a synthetic 100 px hole resampled on a rotated grid, walls all
// around, 48-96 holes per cell), none landed:
// - blur = Gaussian * source-pixel box * B-spline kernel along the pixel
//   axes (exact in 1-D): -0.005 to -0.014 px against the Gaussian's +0.001
//   to +0.005;
// - the same per wedge direction (both kernels projected on the normal in
//   source-pixel axes): -0.001 to -0.007;
// - with the PSF as the simulator applies it, a sampled Gaussian on the
//   pixels, instead of a continuous one: within 0.0016 px on flat walls.
//   That models our renderer, not a lens, so it is not used; on textured
//   walls every model above still read +0.002 to +0.005 px.
//
// Covariance of (cx, cy, r). The fit is linear in the edge points' radial
// moves e: delta = S e, S = -(J'WJ)^-1 J'W (3 x n, W the final IRLS
// weights). Edge errors are correlated along the arc: the mosaic resamples
// raw pixels (`source_px`), and the surface texture next to the rim moves
// neighbouring edge points together. Modelled as a stationary sequence along
// the arc, Cov = f S S', f the errors' spectral density at the circle's
// frequencies (0 and 1 per turn), estimated from the residuals' pooled
// autocovariance with the bias of the three fitted components removed
// (EstimateEdgeErrorSpectrum in the .cc). Checked against the scatter over
// seeded texture and noise draws (circle_measure_test.cc).
//
// Pixel convention: (0, 0) is the centre of the top-left pixel; image(row,
// col) is the value at (x = col, y = row). Pixels equal to 0 are "no tile
// sees this": a wedge whose rim band touches one (or leaves the image) is
// uncovered, and too many uncovered wedges make the hole "cut by the mosaic
// border". A wedge whose rim step would read saturated pixels (clipped at
// the camera's full scale: a mask given beside the image) is left out: a
// clipped bright side moves the step's mid-level crossing. Where more than
// max_saturated_fraction of the rim is so, the hole is "rim saturated".
#pragma once

#include <optional>
#include <string>

#include <Eigen/Core>

#include "pipeline/core/image.h"

namespace omm {

struct CircleMeasureOptions {
  double search_fraction = 0.25;         // expected centre within this fraction of the diameter ...
  double search_margin_px = 5.0;         // ... plus this, px
  double rim_band_px = 4.0;              // first pass: rim searched within radius +- this, px
  double profile_half_width_px = 3.0;    // step model fitted to pixels within edge +- this, px
  double wedge_arc_px = 2.0;             // arc length of one wedge at the rim, px
  int min_wedges = 48;                   // at least this many wedges, whatever the radius
  double min_contrast = 0.05;            // surface minus inside level at the rim, image units
  double max_profile_rms_ratio = 3.0;    // wedge dropped above this x the median wedge fit RMS
  double tukey_sigmas = 4.685;           // biweight cut-off, robust sigmas of the residuals
  double max_uncovered_fraction = 0.02;  // of the wedges touching uncovered (0) or off-image pixels
  double max_saturated_fraction = 0.5;   // ... or whose rim step reads saturated ones
  double min_found_fraction = 0.3;       // inliers below this fraction of the wedges: not found
  double min_inlier_fraction = 0.6;      // ... below this: poor fit
  double max_radius_deviation = 0.05;    // |r / nominal - 1| above this: not the expected hole
  double max_rms_px = 0.5;               // inlier RMS above this: not a rim (not found), px
  double source_px = 1.0;       // size of a source (raw) pixel in image px: noise correlation floor
  double min_wall_blurs = 2.5;  // with a nadir: walls showing narrower, in blurs, left out
  int max_passes = 5;           // edge + fit passes at most
  double converged_px = 5e-3;   // stop when a pass moves centre and radius less, px

  // Empty if valid, else what is wrong.
  std::string Check() const;
  // How far from the expected centre the centre is looked for, px.
  double SearchPx(double nominal_radius_px) const {
    return search_fraction * 2.0 * nominal_radius_px + search_margin_px;
  }
  // How far beyond the circle a fit reads pixels, px: its rays end at the
  // rim band plus the step profile's half width plus 1, and each sample
  // there reads a 2 x 2 block reaching sqrt(2) farther; rounded up.
  double ReachPx() const { return rim_band_px + profile_half_width_px + 3.0; }
};

struct CircleMeasurement {
  bool ok = false;
  std::string
      error;  // when !ok: "not found near the expected position", "cut by ...", "poor fit: ..."
  Eigen::Vector2d centre_px = Eigen::Vector2d::Zero();
  double radius_px = 0.0;
  // Covariance of (cx, cy, r), px^2, from the edge points' scatter and its
  // correlation along the arc (header comment).
  Eigen::Matrix3d covariance_px2 = Eigen::Matrix3d::Zero();
  int num_wedges = 0;                // wedges cast in the last pass
  int num_uncovered = 0;             // ... touching uncovered or off-image pixels
  int num_saturated = 0;             // ... whose rim step reads saturated pixels, left out
  int num_edge_points = 0;           // ... giving a clean step
  int num_inliers = 0;               // edge points kept by the robust fit
  double rms_px = 0.0;               // RMS radial residual of the inliers
  double edge_sigma_px = 0.0;        // blur of the rim (median fitted s)
  double contrast = 0.0;             // median step height at the rim, image units
  double correlation_px = 0.0;       // arc length per independent edge error, px
  int num_bottom_rim_points = 0;     // wedges where the bore wall's bottom rim was resolved
  bool bottom_rim_modelled = false;  // ... enough for its circle, used in the later passes
  double bottom_rim_scale = 0.0;  // k, the bottom rim about the nadir (0: none given or not found)
  int num_narrow_wall = 0;  // wedges whose wall shows narrower than min_wall_blurs (nadir model)
  bool narrow_wall_skipped = false;  // ... left out of the fit (they leave half the rim or more)
  bool bore_prior_used = false;      // k and the narrow wall's level from the BorePrior given
  double wall_contrast = 0.0;  // wall minus hole level where this view resolved it (0: nowhere)
  int passes = 0;                    // edge + fit passes run
  Eigen::Vector2d coarse_centre_px = Eigen::Vector2d::Zero();  // step 1's centre

  std::string Brief() const;  // one line for a log or a report
};

// What the other holes of a project say of the bore (the measure stage pools
// their views where the wall was resolved): the bottom rim's scale k about
// the nadir (one plane, one thickness) and the wall's level.
struct BorePrior {
  double bottom_rim_scale = 0.0;  // k, in (0, 1)
  double wall_contrast = 0.0;     // wall minus hole level, image units
  // Its 1-sigma for this hole (the spread of the pooled views' levels): the
  // covariance of a view that uses the prior includes what it moves.
  double wall_contrast_sigma = 0.0;
};

// Measures the dark round hole of nominal radius `nominal_radius_px` whose
// centre is expected near `expected_centre_px` (within the options' search
// square). `nadir_px`, if given, is the nadir of the camera whose picture
// shows the hole, image px (bore_view.h): the bore's bottom rim is modelled
// about it. `prior`, used only with a nadir, where this view resolves no
// bottom rim and the prior's k puts a wall narrower than min_wall_blurs on
// more than half the rim (the Limits above): the later passes take the
// bottom rim from its k and fit those narrow wedges with the wall tied to
// the rim, x1 = x0 - w(a), at its level (no free wall contrast to trade
// against x0). `saturated`, if given, marks the image's pixels whose value
// is clipped (the header's saturation). A data failure is a result with
// ok = false and `error` set.
// Preconditions: options.Check() is empty, nominal_radius_px > 0, saturated
// (if given) of the image's size.
CircleMeasurement MeasureCircle(const ImageF& image, const Eigen::Vector2d& expected_centre_px,
                                double nominal_radius_px, const CircleMeasureOptions& options = {},
                                const std::optional<Eigen::Vector2d>& nadir_px = std::nullopt,
                                const std::optional<BorePrior>& prior = std::nullopt,
                                const ImageMask* saturated = nullptr);

}  // namespace omm
