// The mosaic stage's registration of the tiles: features, matching, robust
// estimation, tracks and the planar bundle adjustment, from images and values
// (no file I/O).
//
// Pipeline (design.md, "Planar mosaic"; the paper's Harris + NCC method;
// steps 1-2 and the corners of step 3 need no camera: PrepareTiles):
// 1. Each tile is normalised (NormalizeTileIntensity) and blurred for
//    matching; AprilTag 36h11 markers are detected if enabled.
// 2. The image motion per table millimetre, A (2 x 2, px/mm: it holds the
//    camera's unknown rotation about its axis, a possible mirror and the
//    scale), from the tiles that are nearest neighbours on the table
//    (EstimateImageMotion): the similarity on which the coarse NCC peaks of
//    all neighbour pairs agree best, then shift_ij ~ A (T_j - T_i) fitted to
//    the pairs' refined shifts.
// 3. Every pair (i < j) that A and the commanded positions predict to
//    overlap, diagonals too. Each tile's Harris corners (textured,
//    grid-bucketed) are found only where they can be anchors: in the
//    bucketing cells that meet the part of tile i that A puts inside a tile
//    j > i (46 % of the demo's pixels). Anchors (template centres in i) and
//    their predictions in j come from
//    - Harris: a few strong corners of i are found in j with a wide NCC
//      search (on downsampled images, then refined at full resolution), a
//      pixel homography screens them (RANSAC), and the plane-induced
//      homography between the rays of its inliers, through the lens,
//      predicts every corner of i inside j and the local affine there;
//    - SIFT (options.features): COLMAP's verified matches of the pair,
//      screened by RANSAC on the same ray homography, which predicts their
//      keypoints in i rounded to pixels.
//    Each anchor is then matched in a small window and refined by
//    least-squares template matching warped by that affine, its pixels
//    robustly weighted so that content off the plane (a bore) does not pull
//    it (MatchPatch);
//    the matches are screened by RANSAC on the plane-induced homography
//    between the undistorted rays of the two tiles. Tag corners are matched
//    by id (the detections predict, the template match locates). A pair with
//    fewer than min_pair_matches is dropped.
// 4. Tracks: an anchor of tile i (its integer pixel, exact; a corner and a
//    SIFT keypoint at one pixel are one) and its matches in every j > i; a
//    tag corner likewise from the first tile that
//    sees the tag. Every observation of a track is the same part point,
//    because each is located against the same template.
// 5. AdjustPlaneScene (seed + robust bundle adjustment; each match weighted
//    by its template match's predicted covariance, so that weak texture
//    counts less — this halved the low-texture preset's hole error — and a
//    match on an edge counts across the edge only). Pairs the probes left
//    unusable (weak texture: too few probes found at the coarse level) are
//    then matched again, every candidate predicted through the adjusted
//    scene (good to the table prior's ~0.2 px even for a tile held by it)
//    and screened as above, and the scene re-solved with those that reach
//    min_pair_matches (rescue_unusable_pairs). Then observations
//    whose residual exceeds outlier_factor x the median residual are dropped
//    and the scene re-solved; then (rematch_passes) every match is relocated
//    with the affine the adjusted plane model predicts between the two tiles
//    and the scene solved again (each from its first position, refined;
//    only the matches whose affine that changes by relocation_min_change_px).
// A tile without a usable pair fails the registration (unusable, the brief
// names it) if it overlaps no other tile, or if its image contradicts
// table.csv: at least min_pair_matches of its pairs' probe templates, and at
// least half of them, find nothing alike (NCC below
// probe_contradiction_ncc, also with each window's shading plane removed,
// where the template shows texture of its own) anywhere in the probe search,
// as when the wrong image is listed. Otherwise (weak or no texture: smooth patches correlate
// well with their surroundings, so their probes do not contradict) and for
// a tile whose observations the outlier passes all dropped, the tile is held
// by its table prior alone; the summary lists it (tiles_held_by_prior) and
// its brief says so.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "adapters/apriltag/tag_detector.h"
#include "adapters/colmap/colmap_sift.h"
#include "pipeline/core/camera.h"
#include "pipeline/core/image.h"
#include "pipeline/core/plane_scene.h"
#include "pipeline/mosaic/plane_seed.h"
#include "pipeline/mosaic/tile_features.h"
#include "pipeline/mosaic/tile_matching.h"

namespace omm {

// Where the template anchors come from (every anchor is then located by the
// same template match, screened and adjusted alike).
enum class FeatureSource {
  kHarris,         // Harris corners; per pair, probes find the motion that predicts them
  kSift,           // keypoints of COLMAP's verified SIFT matches (adapters/colmap/colmap_sift.h)
  kHarrisAndSift,  // both
};

struct RegisterTilesOptions {
  FeatureSource features = FeatureSource::kHarris;
  HarrisOptions harris;
  ImageMotionOptions motion;
  PatchMatchOptions patch;
  bool use_apriltags = true;  // match AprilTag 36h11 corners by id where tags are seen
  // Quads found at 1/3 resolution: half the CPU of 1/2 (0.27 -> 0.16 s over
  // the demo's nine tiles, which have no tags) and the same tags on the
  // markers preset (20 mm tags, ~130 px; 1/4 loses some at the tile edges).
  // Only the corners' ids matter: the matcher then locates them. A first
  // pass at 1/6 skips the tiles without tags (TagDetectorOptions).
  TagDetectorOptions tags = {.quad_decimate = 3.0, .gate_decimate = 6.0};

  // Pairs whose predicted overlap is below this fraction of the image are not matched.
  double min_overlap_fraction = 0.03;
  // Both tiles of a pair are matched after a Gaussian blur of this sigma, px:
  // it suppresses the content near the Nyquist frequency, where the
  // undersampled tiles carry aliases that bias sub-pixel matches periodically
  // with the fractional position (0 to keep the raw pixels).
  double matching_blur_sigma_px = 1.0;
  int num_probe_corners = 60;      // per pair: corners matched with the wide window
  // Per pair, at most this many Harris corners are matched (the strongest of
  // every cell first): beyond ~250 the holes do not improve (on the demo
  // 6100 -> 4100 observations leave them at 0.027 raw px; the table prior's
  // scale floor dominates), the time does.
  int max_corners_per_pair = 250;
  // Of those, each pair locates at most this many, taking the corners in an
  // order fixed per corner (a hash of its tile and pixel, the same in every
  // pair: a corner located in one pair is located in its others, so its
  // track keeps its views). Where texture is rich every pair reaches it; a
  // weak pair tries all its candidates. On lens-mismatch seed 341, whose
  // final adjustment refines 164 intrinsics on every track, `omm run` took
  // 5.0 -> 4.0 s (means of four interleaved runs); on demo-1 and markers-1
  // the matches' error against the truth was 0.0283 and 0.0288 px per axis
  // with every candidate located and 0.0289 and 0.0299 with 100 (the hashed
  // subset alone 0.0280: a few outliers more escape with fewer views), the
  // holes 0.0269 -> 0.0267 and 0.0303 -> 0.0300 raw px. A random order per
  // pair split the tracks (2.35 -> 2.17 views each) and gave 0.0300 and
  // 0.0321; the strongest of every cell first favoured hole rims (0.032).
  int max_matches_per_pair = 100;
  int probe_search_radius_px = 20;  // +- around the A-predicted position, px
  // The wide probe search runs on the matching images box-downsampled by this
  // factor (a template of probe_half_size_px there), then +-factor px at full
  // resolution: ~30x less work than the full-resolution search.
  int probe_downsample_factor = 4;
  int probe_half_size_px = 5;  // at the downsampled level, px
  double probe_ransac_threshold_px = 3.0;  // pixel homography of the probes, px
  // A probe whose best NCC in the whole probe search is below this
  // contradicts the table position (the other tile shows nothing alike
  // there). Demo with two tiles' images swapped: ~70 % of the swapped pairs'
  // probes, median NCC 0.35-0.65; correct pairs, rich or weak texture: the
  // median is 0.83-0.99 even where too few probes pass the template match.
  double probe_contradiction_ncc = 0.7;
  // ... and only if its template shows texture of its own: with each
  // window's plane removed (shading that differs between the tiles), its NCC
  // with itself one pixel over (mean of x and y) reaches this (noise: ~0),
  // and the best such NCC in the probe search also stays below
  // probe_contradiction_ncc. On low texture with vignetting, opposite shading
  // ramps at two tiles' borders kept a faint texture's plain NCC at 0.1-0.7
  // where the tiles did match (a 6 x 6 low-texture-exposure grid, seed 950:
  // six tiles "contradicted"); their templates, the shading removed, were
  // noise (self NCC 0.02-0.47), the demo's texture 0.68-0.89 (1-99 %).
  double probe_texture_ncc = 0.6;
  int search_radius_px = 1;                // +- around the ray-homography-predicted position, px
  // Plane-induced homography on undistorted rays: inlier distance, px (measured
  // in the target tile with the camera's fx).
  double ransac_threshold_px = 1.0;
  int ransac_iterations = 400;
  std::uint64_t ransac_seed = 1;  // the RANSAC's samples are drawn from this seed
  // A pair with fewer inliers is dropped (reported). Ten plane-consistent
  // template matches (NCC >= patch.min_ncc, within ransac_threshold_px of one
  // ray homography) do not happen by chance; the low-texture preset's
  // weakest tiles (seed 3) hang on pairs of 10-13.
  int min_pair_matches = 10;

  // Bundle adjustment: the observations' sigma and the outlier pass.
  double observation_sigma_px = 0.05;  // 1-sigma of a matched position, px
  // Weight each match's observation by its predicted covariance C
  // (PatchMatch::covariance_px2): min(1, observation_sigma_px / sigma_min)
  // along C's stiffest direction and sigma_min / sigma_max of that across
  // it (TrackObservation::shape), so that weak texture counts less and a
  // match on an edge counts across the edge only (anchors keep 1). A hole's
  // rim, where nearly all of the low-texture preset's matches lie, locates
  // them ~10x worse along it (0.09-0.17 px against 0.03-0.08 px across on
  // seeds 101-105); isotropic weights left its adjusted table positions
  // 0.032 raw px RMS from the truth after a similarity fit, these 0.015.
  bool weight_by_match_sigma = true;
  double outlier_factor = 4.0;         // drop |residual| > this x the median |residual|
  double min_outlier_threshold_px = 0.1;  // ... but never below this, px
  // Pairs the probes left unusable are matched again after the first
  // adjustment, every candidate predicted by the adjusted scene (step 5).
  // Over 34 low-texture projects (seeds 101-105, 201-212) the worst hole
  // errors, 0.076 and 0.111 raw px (a tile held), came down to 0.020 and
  // 0.025; no project's got worse by more than 0.001. Textured projects
  // have no unusable pair.
  bool rescue_unusable_pairs = true;
  int rematch_passes = 1;  // relocations with the adjusted plane model's affine
  // ... of the matches whose template corners that affine moves by at least
  // this, px (the others would not move: their affine came from the probes'
  // plane-induced homography and the lens already).
  double relocation_min_change_px = 0.02;
  bool compute_covariance = true;  // the final scene's covariance (PlaneScene::covariance)
  PlaneBundleOptions bundle;
  // The solves before the outlier pass (the first, and the one after the
  // rescue) only screen the matches: they stop at this relative cost change
  // (bundle.function_tolerance if larger), and a scene they leave is solved
  // again before it is returned. The first solve still carries the outliers,
  // and the robust loss converges linearly on them: lens-mismatch seed 284
  // took 13 iterations to 1e-12, 4 to 1e-6.
  double screening_function_tolerance = 1e-6;

  int num_threads = 2;  // features and matching run on this many threads (motion.num_threads too)

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// What happened between two tiles.
struct PairRegistration {
  int tile_a = 0, tile_b = 0;       // tile_a < tile_b
  double predicted_overlap = 0.0;   // fraction of the image, from A and the commanded positions
  int num_candidates = 0;           // corners of a predicted inside b
  int num_probes = 0;               // of them, searched with the wide probe window
  int num_contradicting_probes = 0; // ... whose best NCC is below probe_contradiction_ncc
  // Of the last attempt: the rescue's for a pair the probes left unusable.
  int num_matched = 0;              // accepted by the template match
  int num_inliers = 0;              // after the plane-induced-homography RANSAC
  int num_sift = 0;                 // of them, anchored at SIFT keypoints
  int num_tag_corners = 0;          // tag corners matched by id
  int num_used = 0;                 // matches in the final adjustment
  double rms_px = 0.0;              // final residual RMS of the used matches' observations
  bool usable = false;              // false: too few matches; its matches were dropped
  bool rescued = false;             // usable once matched on the adjusted scene's prediction
};

struct TileRegistration {
  bool usable = false;
  std::string brief;  // one line: tiles, tracks, RMS, held tiles, why unusable

  PlaneScene scene;          // the adjusted scene (tracks: the final input's)
  PlaneBundleInput input;    // the final observations (kept ones; weights as weight_by_match_sigma)
  PlaneSeedSummary seed;
  PlaneBundleSummary bundle;
  // Per track of `input`: index of its anchor observation (the template's
  // centre, an integer pixel) in input.observations.
  std::vector<int> track_anchor_observation;
  std::vector<int> track_tag_id;  // per track: the AprilTag id of a tag corner, else -1
  std::vector<PairRegistration> pairs;
  std::vector<int> tiles_held_by_prior;  // no observation kept: table prior only
  Eigen::Matrix2d image_px_per_table_mm = Eigen::Matrix2d::Zero();  // A
  std::string motion_brief;       // how A was found (EstimateImageMotion's brief)
  int num_tags_detected = 0;      // tag detections over all tiles
  int num_dropped_observations = 0;  // by the outlier passes
  int num_relocated = 0;  // matches relocated with the adjusted plane's affine (all passes)
  double rms_px = 0.0;               // final RMS reprojection error of used observations
  std::vector<Eigen::Vector2d> table_adjustment_mm;  // adjusted minus commanded, per tile
  double plane_tilt_deg = 0.0;
  // Wall time of steps 1 (normalisation, blur, tags), 2-3 (image motion,
  // Harris corners once A is known, matching) and 4-5; PrepareTiles' part
  // may have run beside the calibration.
  double features_seconds = 0.0, matching_seconds = 0.0, adjustment_seconds = 0.0;
};

// The registration's work that needs no camera: step 1, the image motion A,
// the pairs it predicts to overlap and their Harris corners. `omm run`
// prepares the tiles while the camera is calibrated (its solves leave a core
// idle), RegisterTiles then takes them over.
struct PreparedTiles {
  RegisterTilesOptions options;  // what they were prepared with, and RegisterTiles runs with
  std::vector<Eigen::Vector2d> commanded_table_pos_mm;
  int width_px = 0, height_px = 0;  // of every tile
  // Per tile: the matching image (normalised, blurred), its cubic B-spline
  // coefficients, the probe search's downsampled image, its tags and its
  // Harris corners.
  std::vector<ImageF> normalized, spline, coarse_probe;
  std::vector<std::vector<TagDetection>> tags;
  std::vector<std::vector<Corner>> corners;
  ImageMotionEstimate motion;
  std::vector<PairRegistration> pairs;  // predicted to overlap (none unless motion.ok)
  double features_seconds = 0.0;        // step 1
  double matching_seconds = 0.0;        // A, the pairs, the corners
};

// Step 1, A, the pairs and their corners of `tiles` (gray, all one size)
// taken at `commanded_table_pos_mm`. Throws InputError for invalid options or
// input (sizes); a failure to find A comes back in motion (RegisterTiles
// then reports it).
PreparedTiles PrepareTiles(const std::vector<ImageF>& tiles,
                           const std::vector<Eigen::Vector2d>& commanded_table_pos_mm,
                           const RegisterTilesOptions& options);
// The same on the tiles tile(i), i < num_tiles, each made when its step 1
// starts and dropped when it ends, so that the tiles are not held beside
// their matching images: a 6 x 6 grid's 36 tiles of 1600 x 1200 px are
// 276 MB, as much again as those images or their coefficients. Also throws
// what `tile` throws, and InputError for a tile not width_px x height_px.
PreparedTiles PrepareTiles(int num_tiles, int width_px, int height_px,
                           const std::function<ImageF(int)>& tile,
                           const std::vector<Eigen::Vector2d>& commanded_table_pos_mm,
                           const RegisterTilesOptions& options);

// The rest of the registration of `prepared` (with prepared.options), with
// the table's sigma per axis `table_sigma_mm` and the calibrated `camera`.
// Throws InputError for invalid input (the tiles' size not the camera's);
// data failures come back in the result (usable, brief). sift_matches (used
// unless the options' features is kHarris): COLMAP's verified SIFT matches
// between the tiles (ColmapSiftMatches on the tile files), pairs by tile
// index.
TileRegistration RegisterTiles(const PreparedTiles& prepared, double table_sigma_mm,
                               const CameraModel& camera,
                               const std::vector<ColmapPairMatches>& sift_matches = {});

// PrepareTiles, then RegisterTiles: registers `tiles` (gray, all
// camera.width_px x camera.height_px) taken at `commanded_table_pos_mm`
// (table.csv) with the calibrated `camera`.
TileRegistration RegisterTiles(const std::vector<ImageF>& tiles,
                               const std::vector<Eigen::Vector2d>& commanded_table_pos_mm,
                               double table_sigma_mm, const CameraModel& camera,
                               const RegisterTilesOptions& options,
                               const std::vector<ColmapPairMatches>& sift_matches = {});

}  // namespace omm
