// Holes as tie points of the mosaic's registration.
//
// Why. A hole's top rim lies in the part's plane, and its circle fit in one
// tile (hole_views.h) locates its centre to ~0.004-0.015 px, where a
// template match on weak texture scatters by 0.1-0.5 px. On low-texture
// parts the holes are most of what the tiles share: on low-texture seed 228
// a tile that only a hole's rim and smooth shading tied to its neighbours
// was placed 0.13 raw px off, and the measure stage then found the two views
// of a small hole it shares with a neighbour 0.12 px apart (chi2 56 for 2
// dof). A hole seen whole by two or more tiles ties them at its fit's
// precision.
//
// Cut views. A tile that sees only part of a hole's rim (cut by its border)
// adds a view fitted on the wedges it covers, up to max_cut_uncovered of
// them missing, where another tile sees the hole whole. Template matches on
// such a rim see the bore's wall on one side only, and the matches of one
// hole in one pair share a bias: 0.045 px per axis over 38 rendered
// projects, 0.2 px on low-texture seed 706, whose tile r1c0 only such
// matches tied to r1c1 (pipeline/mosaic/README.md, "Rim matches"). The
// cut view models the wall. Over 20 projects (13 low-texture) the hole
// centres' error after a similarity fit went from 0.088 to 0.041 raw px on
// seed 706 (both its renders) and from 0.029 to 0.012 on low-texture-
// exposure seed 617; it fell by up to 0.0013 raw px on 13 others, rose by up
// to 0.0004 on 3; sd(error / sigma) of the measurements went from 1.034 to
// 0.992.
//
// Model. Each view's centre c_i (part frame, through the scene it was fitted
// on) is mapped back into its tile, q_i = the pixel where that scene shows
// c_i. q_i is the image of the circle's centre point, which the scene moves
// only to second order, so the views become one more track of the plane
// bundle adjustment (pipeline/core/plane_scene.h): one part point P seen at
// q_i in tile i, with q_i's covariance the fit's (cx, cy) covariance mapped
// into tile pixels, floored (HoleTieOptions::min_sigma_px). The bore's
// bottom rim is part of each fit (its parallax is modelled), so a view
// measures the top rim alone.
//
// Double counting. The measure stage then fits the same rims on the final
// scene and adds the scene's covariance to the views' edge covariance as if
// independent. For the tie's own hole that is right to first order: with
// equal view sigmas the views' mean and their difference (what the tie
// fixes) are uncorrelated.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/camera.h"
#include "pipeline/core/plane_scene.h"
#include "pipeline/measure/hole_views.h"
#include "pipeline/mosaic/plate_on_part.h"

namespace omm {

struct HoleTieOptions {
  int min_views = 2;  // views (a tile's fit, whole or cut) a hole needs to tie their tiles
  // A tile that sees part of a hole's rim (one other tile sees it whole)
  // adds a view fitted on the wedges it covers, if at most this fraction of
  // them is uncovered (FitCutViews).
  double max_cut_uncovered = 0.75;
  // Floor of a view's centre sigma (added in quadrature), tile px: the fit's
  // covariance leaves out its model's misfit (a small hole seen near a
  // tile's nadir keeps a few thousandths of a px of bias towards it:
  // circle_measure.h, Limits). On low-texture seed 228's 26 tie views, fitted
  // on the true scene, the errors were 0.0086 px RMS per axis, rms z 0.74
  // without the floor and 0.66 with it (hole_ties_sim_test.cc).
  double min_sigma_px = 0.005;
  // A BorePrior is pooled from at least this many views that resolve the
  // wall (the measure stage's rule, hole_views.h).
  size_t min_bore_prior_views = 3;
  // After the adjustment, a tie whose views' residuals exceed this quantile
  // of chi-square (2 per view less 2 dof) is inconsistent (a view misfitted:
  // a burr, a shadow) and is dropped.
  double consistency_probability = 0.999;
  int num_threads = 2;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// A hole to tie with: where it is expected on the part and its size.
struct TieHole {
  Eigen::Vector2d near_part_mm = Eigen::Vector2d::Zero();
  double radius_mm = 0.0;  // nominal
};

struct HoleTie {
  int hole = 0;                                         // index into the holes given
  Eigen::Vector2d centre_mm = Eigen::Vector2d::Zero();  // the whole views' mean: P's initial value
  std::vector<int> tiles;                               // one per view: whole ones, then cut ones
  int num_whole = 0;                                    // views of tiles that see the hole whole
  std::vector<Eigen::Vector2d> q_px;                    // the centre in each view's tile
  std::vector<Eigen::Matrix2d> covariance_px2;          // of q_px, floored
};

// Fits every hole in the tiles that see it whole (FitHoleViews; the views
// that resolve no wall near a nadir again with the pooled BorePrior), and
// where one does, in the tiles that see part of its rim (FitCutViews); returns
// those with min_views views or more as ties. If `located_mm` is
// given, it receives every hole's centre as its views put it (their mean,
// part frame), nullopt where no tile sees it whole: where the mosaic keeps
// it whole (orthorectify.h). in.mosaic is not used. Pure; throws InputError
// for invalid options.
std::vector<HoleTie> FindHoleTies(
    const HoleViewInputs& in, const std::vector<TieHole>& holes, const HoleTieOptions& options,
    std::vector<std::optional<Eigen::Vector2d>>* located_mm = nullptr);

// A view's pixel and covariance in its tile: q = pixel(x) for the mosaic
// position x, and Cov(q) = J C J' + min_sigma_px^2 I, C the covariance of
// x (mosaic px^2), J = dq/dx by central differences over a mosaic pixel
// (the map is smooth at that scale). False where `pixel` fails.
bool CarryToTile(const std::function<std::optional<Eigen::Vector2d>(const Eigen::Vector2d&)>& pixel,
                 const Eigen::Vector2d& x, const Eigen::Matrix2d& covariance_mosaic_px2,
                 double min_sigma_px, Eigen::Vector2d* q_px, Eigen::Matrix2d* covariance_px2);

// Appends one track to `input`: the part point seen in tiles[v] at q_px[v]
// with covariance covariance_px2[v], each observation whitened
// (WhitenedObservation); its initial value point_mm to scene->track_xy_mm.
void AppendTieTrack(const Eigen::Vector2d& point_mm, const std::vector<int>& tiles,
                    const std::vector<Eigen::Vector2d>& q_px,
                    const std::vector<Eigen::Matrix2d>& covariance_px2, PlaneBundleInput* input,
                    PlaneScene* scene);

// Appends each tie to `input` as a track (observations weighted by
// input->observation_sigma_px over their sigma, shaped by their covariance)
// and its P's initial value to scene->track_xy_mm. Returns the index of the
// first appended observation.
int AddHoleTieTracks(const std::vector<HoleTie>& ties, PlaneBundleInput* input, PlaneScene* scene);

// The ties (indices) whose observations, from input index first_observation
// on (AddHoleTieTracks' order), the adjusted scene's residuals (model minus
// observed, px) leave inconsistent: sum r' C^-1 r beyond the chi-square
// quantile of options.consistency_probability for 2 (views - 1) dof.
std::vector<int> InconsistentHoleTies(const std::vector<HoleTie>& ties, int first_observation,
                                      const Eigen::Matrix2Xd& residual_px,
                                      const HoleTieOptions& options);

// The final adjustment (AdjustWithPlateAndPrior) with the ties as tracks.
// A tie InconsistentHoleTies flags loses its cut views if its whole views
// still tie, else is dropped, and the solve runs again, until none is
// flagged; if the solve with ties is unusable, it is run without them
// (ties_failed, why in `failure`).
struct TiedAdjustment {
  FinalAdjustment adjusted;       // its input: registered_input plus the kept ties' tracks
  std::vector<HoleTie> kept;      // in the given order (a tie's cut views may be left out)
  std::vector<int> dropped;       // indices into the given ties
  int num_cut_views_dropped = 0;  // of ties kept on their whole views
  int first_tie_observation = 0;  // of the kept ties' observations in adjusted.input
  bool ties_failed = false;
  std::string failure;
};
TiedAdjustment AdjustWithHoleTies(const CameraModel& camera,
                                  const PlaneBundleInput& registered_input,
                                  const PlaneScene& registered_scene, const PlateOnPart& plate,
                                  const IntrinsicsPrior& prior,
                                  const FinalAdjustmentOptions& options,
                                  const std::vector<HoleTie>& ties,
                                  const HoleTieOptions& tie_options);

}  // namespace omm
