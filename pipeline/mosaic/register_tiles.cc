#include "pipeline/mosaic/register_tiles.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <functional>
#include <map>
#include <numeric>
#include <random>
#include <set>
#include <sstream>

#include <Eigen/Dense>

#include "adapters/mrcal/lens.h"
#include "pipeline/core/cubic_bspline.h"
#include "pipeline/core/error.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/core/statistics.h"
#include "pipeline/core/timing.h"
#include "pipeline/mosaic/homography.h"
#include "pipeline/mosaic/plane_adjustment.h"

namespace omm {

std::string RegisterTilesOptions::Check() const {
  for (const std::string& e :
       {harris.Check(), motion.Check(), patch.Check(), tags.Check(), bundle.Check()}) {
    if (!e.empty()) return e;
  }
  if (!(matching_blur_sigma_px >= 0)) return "matching_blur_sigma_px must be >= 0";
  if (!(min_overlap_fraction > 0 && min_overlap_fraction < 1))
    return "min_overlap_fraction must be in (0, 1)";
  if (num_probe_corners < 8) return "num_probe_corners must be >= 8";
  if (max_corners_per_pair < num_probe_corners)
    return "max_corners_per_pair must be >= num_probe_corners";
  if (max_matches_per_pair < min_pair_matches)
    return "max_matches_per_pair must be >= min_pair_matches";
  if (probe_search_radius_px < 1) return "probe_search_radius_px must be >= 1";
  if (probe_downsample_factor < 1) return "probe_downsample_factor must be >= 1";
  if (probe_half_size_px < 2) return "probe_half_size_px must be >= 2";
  if (!(probe_ransac_threshold_px > 0)) return "probe_ransac_threshold_px must be > 0";
  if (!(probe_contradiction_ncc > -1 && probe_contradiction_ncc < 1))
    return "probe_contradiction_ncc must be in (-1, 1)";
  if (!(probe_texture_ncc > -1 && probe_texture_ncc < 1))
    return "probe_texture_ncc must be in (-1, 1)";
  if (search_radius_px < 1) return "search_radius_px must be >= 1";
  if (!(ransac_threshold_px > 0)) return "ransac_threshold_px must be > 0";
  if (ransac_iterations < 1) return "ransac_iterations must be >= 1";
  if (min_pair_matches < 4) return "min_pair_matches must be >= 4";
  if (!(observation_sigma_px > 0)) return "observation_sigma_px must be > 0";
  if (!(outlier_factor > 1)) return "outlier_factor must be > 1";
  if (!(min_outlier_threshold_px > 0)) return "min_outlier_threshold_px must be > 0";
  if (rematch_passes < 0) return "rematch_passes must be >= 0";
  if (!(screening_function_tolerance >= 0 && screening_function_tolerance < 1))
    return "screening_function_tolerance must be in [0, 1)";
  if (!(relocation_min_change_px >= 0)) return "relocation_min_change_px must be >= 0";
  if (num_threads < 1) return "num_threads must be >= 1";
  return {};
}

namespace {

using Clock = std::chrono::steady_clock;

// RANSAC on a homography b ~ H a; inliers where |Transfer(H, a) - b| * scale
// <= threshold. Returns the inlier mask of the refitted model (empty if fewer
// than 4 points or no model).
std::vector<bool> RansacHomography(const Eigen::Matrix2Xd& a, const Eigen::Matrix2Xd& b,
                                   double threshold, double scale, int iterations,
                                   std::mt19937_64* rng, Eigen::Matrix3d* model) {
  const int n = static_cast<int>(a.cols());
  std::vector<bool> best;
  if (n < 4) return best;
  const auto inliers_of = [&](const Eigen::Matrix3d& h, std::vector<bool>* mask) {
    int count = 0;
    mask->assign(n, false);
    for (int i = 0; i < n; ++i) {
      const double e = (Transfer(h, a.col(i)) - b.col(i)).norm() * scale;
      if (e <= threshold) (*mask)[i] = true, ++count;
    }
    return count;
  };
  int best_count = 0;
  std::vector<bool> mask;
  std::uniform_int_distribution<int> pick(0, n - 1);
  for (int it = 0; it < iterations; ++it) {
    int idx[4];
    for (int k = 0; k < 4; ++k) {
      bool again = true;
      while (again) {
        idx[k] = pick(*rng);
        again = std::find(idx, idx + k, idx[k]) != idx + k;
      }
    }
    Eigen::Matrix<double, 2, 4> sa, sb;
    for (int k = 0; k < 4; ++k) sa.col(k) = a.col(idx[k]), sb.col(k) = b.col(idx[k]);
    const Eigen::Matrix3d h = FitHomography4(sa, sb);
    if (!h.allFinite()) continue;
    const int count = inliers_of(h, &mask);
    if (count > best_count) best_count = count, best = mask;
  }
  if (best_count < 4) return {};
  // Refit on the inliers, twice (the inlier set may grow).
  for (int pass = 0; pass < 2; ++pass) {
    Eigen::Matrix2Xd ia(2, best_count), ib(2, best_count);
    for (int i = 0, k = 0; i < n; ++i) {
      if (best[i]) ia.col(k) = a.col(i), ib.col(k) = b.col(i), ++k;
    }
    *model = FitHomography(ia, ib);
    const int count = inliers_of(*model, &mask);
    if (count < 4) return {};
    best = mask;
    best_count = count;
  }
  return best;
}

// One located correspondence: the anchor pixel of tile_a (a template centre)
// found at q_b in tile_b. `key` names the anchor (its track).
struct Match {
  int tile_a = 0, tile_b = 0;
  long long key = 0;
  Eigen::Vector2i anchor_px = Eigen::Vector2i::Zero();
  Eigen::Vector2d ray_a = Eigen::Vector2d::Zero();  // the anchor's undistorted ray (x, y; z = 1)
  Eigen::Vector2d q_b = Eigen::Vector2d::Zero();
  PatchWarp warp;                                            // of the last match
  Eigen::Matrix2d covariance_px2 = Eigen::Matrix2d::Zero();  // the last match's (PatchMatch)
  bool tag = false;
  bool sift = false;  // its anchor came from a SIFT match
  bool keep = true;
};

// A template anchor's key (its track): tile and pixel, so that a Harris
// corner and a SIFT keypoint at one pixel are one track.
long long PixelKey(int tile, const Eigen::Vector2i& pixel, int width, int height) {
  return (static_cast<long long>(tile) * height + pixel.y()) * width + pixel.x();
}
long long TagKey(int id, int k) { return -(static_cast<long long>(id) * 4 + k + 1); }

// A corner of tile a is a candidate of the pair (a, b > a) when its pixel
// moved by shift_ab = A (T_b - T_a) lies this far inside b: the commanded
// positions and A alone decide, so a tile's corners are searched only in the
// boxes of its pairs as a (none for a tile that is b in all of its pairs):
// 46 % of the demo's pixels, in whole bucketing cells.
int CandidateMarginPx(const RegisterTilesOptions& options) {
  return options.patch.half_size_px + options.probe_search_radius_px + 3;
}

// A Harris corner's place in the order a pair locates its candidates in
// (RegisterTilesOptions::max_matches_per_pair): a hash of its tile and pixel
// (MurmurHash3's 64-bit finalizer), so the same in every pair the corner is a
// candidate of.
std::uint64_t CornerPriority(int tile, const Eigen::Vector2i& pixel) {
  std::uint64_t h = (static_cast<std::uint64_t>(tile) << 40) ^
                    (static_cast<std::uint64_t>(pixel.y()) << 20) ^
                    static_cast<std::uint64_t>(pixel.x());
  h ^= h >> 33;
  h *= 0xff51afd7ed558ccdULL;
  h ^= h >> 33;
  h *= 0xc4ceb9fe1a85ec53ULL;
  h ^= h >> 33;
  return h;
}

// shift_ab = A (T_b - T_a), px.
Eigen::Vector2d PairShiftPx(const PreparedTiles& prepared, const PairRegistration& pair) {
  return prepared.motion.px_per_table_mm * (prepared.commanded_table_pos_mm[pair.tile_b] -
                                            prepared.commanded_table_pos_mm[pair.tile_a]);
}

// The pairs for the image motion: each tile with its nearest neighbour, and
// with the nearest one in a direction more than 45 deg from that (lower
// index first, each pair once). Tiles at one position are not neighbours.
std::vector<std::pair<int, int>> NeighbourPairs(const std::vector<Eigen::Vector2d>& table_mm) {
  const int num_tiles = static_cast<int>(table_mm.size());
  std::vector<std::pair<int, int>> pairs;
  for (int i = 0; i < num_tiles; ++i) {
    int first = -1, second = -1;
    for (int j = 0; j < num_tiles; ++j) {
      if (j == i) continue;
      const double d = (table_mm[j] - table_mm[i]).norm();
      if (d <= 0) continue;
      if (first < 0 || d < (table_mm[first] - table_mm[i]).norm()) first = j;
    }
    if (first < 0) continue;
    const Eigen::Vector2d u = (table_mm[first] - table_mm[i]).normalized();
    for (int j = 0; j < num_tiles; ++j) {
      const Eigen::Vector2d d = table_mm[j] - table_mm[i];
      if (j == i || d.norm() <= 0 || std::abs(u.dot(d.normalized())) > std::sqrt(0.5)) continue;
      if (second < 0 || d.norm() < (table_mm[second] - table_mm[i]).norm()) second = j;
    }
    for (int j : {first, second}) {
      if (j >= 0) pairs.emplace_back(std::min(i, j), std::max(i, j));
    }
  }
  std::sort(pairs.begin(), pairs.end());
  pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
  return pairs;
}

// Step 3's pairs: every two tiles whose images the motion `px_per_mm`
// predicts to overlap by min_overlap_fraction of a width x height image or
// more (diagonals too), with that fraction.
std::vector<PairRegistration> PairsPredictedToOverlap(const Eigen::Matrix2d& px_per_mm,
                                                      const std::vector<Eigen::Vector2d>& table_mm,
                                                      int width, int height,
                                                      double min_overlap_fraction) {
  std::vector<PairRegistration> pairs;
  const int num_tiles = static_cast<int>(table_mm.size());
  for (int i = 0; i < num_tiles; ++i) {
    for (int j = i + 1; j < num_tiles; ++j) {
      const Eigen::Vector2d d = px_per_mm * (table_mm[j] - table_mm[i]);
      const double overlap = std::max(0.0, width - std::abs(d.x())) *
                             std::max(0.0, height - std::abs(d.y())) / (double(width) * height);
      if (overlap < min_overlap_fraction) continue;
      PairRegistration pair;
      pair.tile_a = i;
      pair.tile_b = j;
      pair.predicted_overlap = overlap;
      pairs.push_back(pair);
    }
  }
  return pairs;
}

// PrepareTiles on the tiles tile_of(i), i < num_tiles, each width x height
// px: tile_of returns a reference to a tile held elsewhere, or a tile made
// for the call, which is dropped after its step 1.
template <typename TileOf>
PreparedTiles PrepareTilesFrom(int num_tiles, int width, int height, const TileOf& tile_of,
                               const std::vector<Eigen::Vector2d>& commanded_table_pos_mm,
                               const RegisterTilesOptions& options) {
  if (const std::string e = options.Check(); !e.empty())
    throw InputError("", "tile registration: " + e);
  if (static_cast<size_t>(num_tiles) != commanded_table_pos_mm.size())
    throw InputError("", "tile registration: " + std::to_string(num_tiles) + " tiles but " +
                             std::to_string(commanded_table_pos_mm.size()) + " table positions");
  PreparedTiles prepared;
  prepared.options = options;
  prepared.commanded_table_pos_mm = commanded_table_pos_mm;
  prepared.width_px = width;
  prepared.height_px = height;

  // 1. Features, each tile's with its tags: a tile made for the call lives
  // no longer than its own work.
  auto t0 = Clock::now();
  std::vector<ImageF>& normalized = prepared.normalized;
  std::vector<ImageF>& spline = prepared.spline;
  std::vector<ImageF>& coarse_probe = prepared.coarse_probe;
  std::vector<std::vector<TagDetection>>& tags = prepared.tags;
  normalized.resize(num_tiles);
  spline.resize(num_tiles);
  coarse_probe.resize(num_tiles);
  tags.resize(num_tiles);
  prepared.corners.resize(num_tiles);
  ParallelFor(num_tiles, options.num_threads, [&](int i) {
    decltype(auto) tile = tile_of(i);
    if (tile.cols() != width || tile.rows() != height)
      throw InputError("", "tile registration: tile " + std::to_string(i) + " is " +
                               std::to_string(tile.cols()) + " x " + std::to_string(tile.rows()) +
                               " px, tile 0 " + std::to_string(width) + " x " +
                               std::to_string(height));
    if (options.use_apriltags) tags[i] = DetectAprilTags36h11(tile, options.tags);
    normalized[i] = NormalizeTileIntensity(tile);
    if (options.matching_blur_sigma_px > 0)
      normalized[i] = GaussianBlur(normalized[i], options.matching_blur_sigma_px);
    spline[i] = CubicBSplineCoefficients(normalized[i]);
    coarse_probe[i] = DownsampleBox(normalized[i], options.probe_downsample_factor);
  });
  prepared.features_seconds = SecondsSince(t0);

  // 2. Image motion per table mm from nearest-neighbour pairs.
  t0 = Clock::now();
  const std::vector<std::pair<int, int>> neighbour_pairs = NeighbourPairs(commanded_table_pos_mm);
  ImageMotionOptions motion_options = options.motion;
  motion_options.num_threads = options.num_threads;
  prepared.motion =
      EstimateImageMotion(normalized, commanded_table_pos_mm, neighbour_pairs, motion_options);
  if (!prepared.motion.ok) {
    prepared.matching_seconds = SecondsSince(t0);
    return prepared;
  }

  // 3. Pairs predicted to overlap, and the Harris corners that can anchor
  // their matches.
  prepared.pairs = PairsPredictedToOverlap(prepared.motion.px_per_table_mm, commanded_table_pos_mm,
                                           width, height, options.min_overlap_fraction);
  const int candidate_margin = CandidateMarginPx(options);
  std::vector<std::vector<Eigen::AlignedBox2i>> harris_regions(num_tiles);
  for (const PairRegistration& pair : prepared.pairs) {
    const Eigen::Vector2d shift = PairShiftPx(prepared, pair);
    harris_regions[pair.tile_a].emplace_back(
        Eigen::Vector2i(static_cast<int>(std::floor(candidate_margin - shift.x())),
                        static_cast<int>(std::floor(candidate_margin - shift.y()))),
        Eigen::Vector2i(static_cast<int>(std::ceil(width - candidate_margin - shift.x())),
                        static_cast<int>(std::ceil(height - candidate_margin - shift.y()))));
  }
  if (options.features != FeatureSource::kSift) {
    ParallelFor(num_tiles, options.num_threads, [&](int i) {
      // On the matching image, so that the texture test sees the templates.
      if (!harris_regions[i].empty())
        prepared.corners[i] = DetectHarrisCorners(normalized[i], options.harris, harris_regions[i]);
    });
  }
  prepared.matching_seconds = SecondsSince(t0);
  return prepared;
}

}  // namespace

PreparedTiles PrepareTiles(const std::vector<ImageF>& tiles,
                           const std::vector<Eigen::Vector2d>& commanded_table_pos_mm,
                           const RegisterTilesOptions& options) {
  const int num_tiles = static_cast<int>(tiles.size());
  return PrepareTilesFrom(
      num_tiles, num_tiles > 0 ? static_cast<int>(tiles[0].cols()) : 0,
      num_tiles > 0 ? static_cast<int>(tiles[0].rows()) : 0,
      [&tiles](int i) -> const ImageF& { return tiles[static_cast<size_t>(i)]; },
      commanded_table_pos_mm, options);
}

PreparedTiles PrepareTiles(int num_tiles, int width_px, int height_px,
                           const std::function<ImageF(int)>& tile,
                           const std::vector<Eigen::Vector2d>& commanded_table_pos_mm,
                           const RegisterTilesOptions& options) {
  return PrepareTilesFrom(num_tiles, width_px, height_px, tile, commanded_table_pos_mm, options);
}

TileRegistration RegisterTiles(const std::vector<ImageF>& tiles,
                               const std::vector<Eigen::Vector2d>& commanded_table_pos_mm,
                               double table_sigma_mm, const CameraModel& camera,
                               const RegisterTilesOptions& options,
                               const std::vector<ColmapPairMatches>& sift_matches) {
  return RegisterTiles(PrepareTiles(tiles, commanded_table_pos_mm, options), table_sigma_mm,
                       camera, sift_matches);
}

namespace {

// An anchor of tile a to locate in tile b: its pixel and ray, the
// predicted position in b and the local warp there.
struct Candidate {
  Eigen::Vector2i pixel = Eigen::Vector2i::Zero();
  Eigen::Vector2d ray_a = Eigen::Vector2d::Zero();
  Eigen::Vector2d q_b = Eigen::Vector2d::Zero();
  PatchWarp warp;
  bool sift = false;
};

// What locating the pairs' matches reads: the prepared tiles, the camera
// and the undistorted ray of every Harris corner (the anchors).
struct MatchingInputs {
  const PreparedTiles& prepared;
  const CameraModel& camera;
  const RegisterTilesOptions& options;
  std::vector<Eigen::Matrix2Xd> corner_rays;  // per tile, of prepared.corners
};

// Undistorted rays (x, y; z = 1) of pixels; none if the lens refuses one.
Eigen::Matrix2Xd RaysOf(const CameraModel& camera, const Eigen::Matrix2Xd& q_px) {
  Eigen::Matrix3Xd v;
  if (q_px.cols() == 0 || !UnprojectPixels(camera, q_px, &v)) return Eigen::Matrix2Xd(2, 0);
  return Eigen::Matrix2Xd(v.topRows<2>());
}

MatchingInputs MatchingInputsOf(const PreparedTiles& prepared, const CameraModel& camera) {
  MatchingInputs in{prepared, camera, prepared.options, {}};
  const std::vector<std::vector<Corner>>& corners = prepared.corners;
  in.corner_rays.resize(corners.size());
  ParallelFor(static_cast<int>(corners.size()), in.options.num_threads, [&](int i) {
    Eigen::Matrix2Xd q(2, corners[i].size());
    for (size_t k = 0; k < corners[i].size(); ++k) q.col(k) = corners[i][k].pixel.cast<double>();
    in.corner_rays[i] = RaysOf(camera, q);
  });
  return in;
}

// Each candidate's position in b and warp there, predicted through a
// plane-induced homography between the rays (b ~ H a) and the lens, to
// second order (PatchWarp): dq_b/dq_a = dq_b/dray_b dray_b/dray_a
// (dq_a/dray_a)^-1, a ray being (x, y, 1), at the anchor and at the rays
// step_px from it along +-x and +-y (to first order: no unprojection), whose
// differences give the second derivatives. False if the lens refuses.
bool PredictThroughRayHomography(const CameraModel& camera, const Eigen::Matrix3d& h_rays,
                                 double step_px, std::vector<Candidate>* todo) {
  const int n = static_cast<int>(todo->size());
  if (n == 0) return true;
  Eigen::Matrix3Xd anchors(3, n);
  for (int k = 0; k < n; ++k) anchors.col(k) = (*todo)[k].ray_a.homogeneous();
  Eigen::Matrix2Xd q_a, q_b;
  Eigen::MatrixXd dqa_dp, dqb_dp;
  if (!ProjectPoints(camera, anchors, &q_a, &dqa_dp)) return false;
  // Column 5 k: candidate k's ray; 5 k + 1..4: its neighbours.
  const double s = step_px;
  const Eigen::Vector2d steps[4] = {{s, 0}, {-s, 0}, {0, s}, {0, -s}};
  Eigen::Matrix3Xd p_a(3, 5 * n), p_b(3, 5 * n);
  for (int k = 0; k < n; ++k) {
    const Eigen::Matrix2d dray_dqa = dqa_dp.block<2, 2>(2 * k, 0).inverse();
    p_a.col(5 * k) = anchors.col(k);
    for (int m = 0; m < 4; ++m)
      p_a.col(5 * k + 1 + m) = ((*todo)[k].ray_a + dray_dqa * steps[m]).homogeneous();
  }
  for (int i = 0; i < 5 * n; ++i) p_b.col(i) = Transfer(h_rays, p_a.col(i).head<2>()).homogeneous();
  if (!ProjectPoints(camera, p_a, &q_a, &dqa_dp) || !ProjectPoints(camera, p_b, &q_b, &dqb_dp))
    return false;
  const auto db_da = [&](int i) {
    return Eigen::Matrix2d(dqb_dp.block<2, 2>(2 * i, 0) *
                           TransferJacobian(h_rays, p_a.col(i).head<2>()) *
                           dqa_dp.block<2, 2>(2 * i, 0).inverse());
  };
  for (int k = 0; k < n; ++k) {
    Candidate& c = (*todo)[k];
    const int i = 5 * k;
    c.q_b = q_b.col(i);
    c.warp = PatchWarp::FromJacobians(db_da(i), db_da(i + 1), db_da(i + 2), db_da(i + 3),
                                      db_da(i + 4), s);
  }
  return true;
}

// The matches that one plane-induced homography between the undistorted
// rays explains (RANSAC, inliers within ransac_threshold_px in tile b);
// none if a matched pixel cannot be unprojected.
std::vector<Match> PlaneInliers(const MatchingInputs& in, const std::vector<Match>& matches,
                                std::mt19937_64* rng) {
  std::vector<Match> kept;
  Eigen::Matrix2Xd ra(2, matches.size()), qb(2, matches.size());
  for (size_t k = 0; k < matches.size(); ++k) {
    ra.col(k) = matches[k].ray_a;
    qb.col(k) = matches[k].q_b;
  }
  const Eigen::Matrix2Xd rb = RaysOf(in.camera, qb);
  if (rb.cols() != qb.cols()) return kept;
  Eigen::Matrix3d h_rays;
  const std::vector<bool> inliers =
      RansacHomography(ra, rb, in.options.ransac_threshold_px, in.camera.intrinsics(0),
                       in.options.ransac_iterations, rng, &h_rays);
  for (size_t k = 0; k < inliers.size(); ++k) {
    if (inliers[k]) kept.push_back(matches[k]);
  }
  return kept;
}

// The Harris corners of the pair's tile a that its shift puts inside tile b
// (indices into corners[a]); pair->num_candidates counts them all, at most
// max_corners_per_pair are returned: the strongest of every Harris cell
// first, then the second, ..., so that they stay spread over the overlap
// (candidates are in response order).
std::vector<int> PairCandidates(const MatchingInputs& in, PairRegistration* pair) {
  const PreparedTiles& prepared = in.prepared;
  const RegisterTilesOptions& options = in.options;
  const std::vector<Corner>& corners = prepared.corners[pair->tile_a];
  const int width = prepared.width_px, height = prepared.height_px;
  const int margin = CandidateMarginPx(options);
  const Eigen::Vector2d shift = PairShiftPx(prepared, *pair);
  std::vector<int> candidates;
  for (size_t k = 0; k < corners.size(); ++k) {
    const Eigen::Vector2d q = corners[k].pixel.cast<double>() + shift;
    if (q.x() >= margin && q.y() >= margin && q.x() < width - margin && q.y() < height - margin)
      candidates.push_back(static_cast<int>(k));
  }
  pair->num_candidates += static_cast<int>(candidates.size());
  if (static_cast<int>(candidates.size()) <= options.max_corners_per_pair) return candidates;
  std::map<int, int> in_cell;
  std::vector<std::pair<int, int>> ranked;  // (rank in its cell, candidate)
  for (int k : candidates) {
    const Eigen::Vector2i cell = corners[k].pixel / options.harris.cell_px;
    ranked.emplace_back(in_cell[cell.y() * width + cell.x()]++, k);
  }
  std::stable_sort(ranked.begin(), ranked.end(),
                   [](const auto& x, const auto& y) { return x.first < y.first; });
  ranked.resize(options.max_corners_per_pair);
  std::sort(ranked.begin(), ranked.end(),
            [](const auto& x, const auto& y) { return x.second < y.second; });
  candidates.clear();
  for (const auto& [rank, k] : ranked) candidates.push_back(k);
  return candidates;
}

// The probe search's radius on the downsampled images, px.
int ProbeSearchRadius(const RegisterTilesOptions& options) {
  const int f = options.probe_downsample_factor;
  return (options.probe_search_radius_px + f - 1) / f + 1;
}

// Whether a probe whose plain NCC fell short contradicts the table position
// (RegisterTilesOptions::probe_texture_ncc): its template, at `anchor` of the
// downsampled image a, shows texture of its own, and nothing around
// `predicted` in b correlates with it once each window's plane is removed.
bool ProbeContradicts(const ImageF& a, const Eigen::Vector2i& anchor, const ImageF& b,
                      const Eigen::Vector2i& predicted, const RegisterTilesOptions& options) {
  const int h = options.probe_half_size_px;
  const double self = 0.5 * (BestDetrendedNcc(a, anchor, h, a, anchor + Eigen::Vector2i(1, 0), 0) +
                             BestDetrendedNcc(a, anchor, h, a, anchor + Eigen::Vector2i(0, 1), 0));
  if (self < options.probe_texture_ncc) return false;
  return BestDetrendedNcc(a, anchor, h, b, predicted, ProbeSearchRadius(options)) <
         options.probe_contradiction_ncc;
}

// The pair's Harris candidates with their predictions in tile b, or none:
// probes (the strongest candidates, already spread by the bucketing) are
// found in b by a wide NCC search on the downsampled images, refined at full
// resolution and screened by RANSAC on a pixel homography; the plane-induced
// homography between the rays of its inliers then predicts every candidate
// (the pixel homography ignores the distortion, whose derivatives differ
// between the two tiles' image positions). Counts the probes into *pair.
std::vector<Candidate> HarrisCandidates(const MatchingInputs& in,
                                        const std::vector<int>& candidates, PairRegistration* pair,
                                        std::mt19937_64* rng) {
  const PreparedTiles& prepared = in.prepared;
  const RegisterTilesOptions& options = in.options;
  const int ta = pair->tile_a, tb = pair->tile_b;
  const std::vector<Corner>& corners = prepared.corners[ta];
  const Eigen::Vector2d shift = PairShiftPx(prepared, *pair);
  const int num_probes = std::min<int>(options.num_probe_corners, candidates.size());
  Eigen::Matrix2Xd probe_a(2, num_probes), probe_b(2, num_probes);
  int found = 0;
  const int f = options.probe_downsample_factor;
  const double centre = 0.5 * (f - 1);  // of downsampled pixel 0, in full-resolution px
  for (int k = 0; k < num_probes; ++k) {
    const Corner& c = corners[candidates[k]];
    // The downsampled pixel holding the corner, and its centre's predicted
    // (downsampled) position in b.
    const Eigen::Vector2i anchor_coarse = c.pixel / f;
    const Eigen::Vector2d offset =
        c.pixel.cast<double>() - (f * anchor_coarse.cast<double>().array() + centre).matrix();
    const Eigen::Vector2d predicted_coarse =
        ((c.pixel.cast<double>() + shift - offset).array() - centre) / f;
    const Eigen::Vector2i predicted_coarse_px(static_cast<int>(std::lround(predicted_coarse.x())),
                                              static_cast<int>(std::lround(predicted_coarse.y())));
    const NccPeak probe_peak =
        SearchNcc(prepared.coarse_probe[ta], anchor_coarse, options.probe_half_size_px,
                  prepared.coarse_probe[tb], predicted_coarse_px, ProbeSearchRadius(options));
    if (!probe_peak.ok) continue;
    ++pair->num_probes;
    if (probe_peak.ncc < options.probe_contradiction_ncc &&
        ProbeContradicts(prepared.coarse_probe[ta], anchor_coarse, prepared.coarse_probe[tb],
                         predicted_coarse_px, options))
      ++pair->num_contradicting_probes;
    const PatchMatch m = MatchPatch(
        prepared.normalized[ta], c.pixel, prepared.normalized[tb], prepared.spline[tb],
        (f * probe_peak.q_px.array() + centre).matrix() + offset, PatchWarp(), f, options.patch);
    if (!m.ok) continue;
    probe_a.col(found) = c.pixel.cast<double>();
    probe_b.col(found) = m.q_px;
    ++found;
  }
  Eigen::Matrix3d h_pixels;
  const std::vector<bool> probe_inliers = RansacHomography(
      probe_a.leftCols(found), probe_b.leftCols(found), options.probe_ransac_threshold_px, 1.0,
      options.ransac_iterations, rng, &h_pixels);
  const int num_probe_inliers =
      static_cast<int>(std::count(probe_inliers.begin(), probe_inliers.end(), true));
  Eigen::Matrix2Xd inlier_a(2, num_probe_inliers), inlier_b(2, num_probe_inliers);
  for (int k = 0, n = 0; k < static_cast<int>(probe_inliers.size()); ++k) {
    if (probe_inliers[k]) inlier_a.col(n) = probe_a.col(k), inlier_b.col(n++) = probe_b.col(k);
  }
  const Eigen::Matrix2Xd rays_a = RaysOf(in.camera, inlier_a), rays_b = RaysOf(in.camera, inlier_b);
  if (num_probe_inliers < 8 || rays_a.cols() != num_probe_inliers ||
      rays_b.cols() != num_probe_inliers)
    return {};
  std::vector<Candidate> harris;
  for (int k : candidates) {
    Candidate c;
    c.pixel = corners[k].pixel;
    c.ray_a = in.corner_rays[ta].col(k);
    harris.push_back(c);
  }
  if (!PredictThroughRayHomography(in.camera, FitHomography(rays_a, rays_b),
                                   options.patch.half_size_px, &harris))
    return {};
  return harris;
}

// The pair's candidates from COLMAP's verified matches, or none: screened on
// the rays, their homography predicts the template anchors (their keypoints
// in a rounded to pixels) in b. Counts them into pair->num_candidates.
std::vector<Candidate> SiftCandidates(const MatchingInputs& in, const ColmapPairMatches& sift,
                                      PairRegistration* pair, std::mt19937_64* rng) {
  const RegisterTilesOptions& options = in.options;
  const Eigen::Matrix2Xd rays_a = RaysOf(in.camera, sift.q_a_px),
                         rays_b = RaysOf(in.camera, sift.q_b_px);
  Eigen::Matrix3d h_rays;
  const std::vector<bool> inliers =
      rays_a.cols() == sift.q_a_px.cols() && rays_b.cols() == sift.q_b_px.cols()
          ? RansacHomography(rays_a, rays_b, options.ransac_threshold_px, in.camera.intrinsics(0),
                             options.ransac_iterations, rng, &h_rays)
          : std::vector<bool>();
  if (std::count(inliers.begin(), inliers.end(), true) < 8) return {};
  std::vector<Eigen::Vector2i> pixels;
  for (size_t k = 0; k < inliers.size(); ++k) {
    if (!inliers[k]) continue;
    pixels.emplace_back(static_cast<int>(std::lround(sift.q_a_px(0, k))),
                        static_cast<int>(std::lround(sift.q_a_px(1, k))));
  }
  pair->num_candidates += static_cast<int>(pixels.size());
  Eigen::Matrix2Xd q(2, pixels.size());
  for (size_t k = 0; k < pixels.size(); ++k) q.col(k) = pixels[k].cast<double>();
  const Eigen::Matrix2Xd anchor_rays = RaysOf(in.camera, q);
  if (anchor_rays.cols() != q.cols()) return {};
  std::vector<Candidate> from_sift;
  for (size_t k = 0; k < pixels.size(); ++k) {
    Candidate c;
    c.pixel = pixels[k];
    c.ray_a = anchor_rays.col(k);
    c.sift = true;
    from_sift.push_back(c);
  }
  if (!PredictThroughRayHomography(in.camera, h_rays, options.patch.half_size_px, &from_sift))
    return {};
  return from_sift;
}

// Every candidate located by the template match (one per anchor pixel: a
// SIFT keypoint may repeat, or coincide with a corner), the Harris ones by
// CornerPriority until max_matches_per_pair are located; returned in todo's
// order, which RANSAC samples in (a pair that locates fewer keeps the
// matches and the result it had without the limit).
std::vector<Match> LocateCandidates(const MatchingInputs& in, const PairRegistration& pair,
                                    const std::vector<Candidate>& todo) {
  const PreparedTiles& prepared = in.prepared;
  const RegisterTilesOptions& options = in.options;
  const int ta = pair.tile_a, tb = pair.tile_b;
  std::vector<int> order(todo.size());
  std::iota(order.begin(), order.end(), 0);
  {
    std::vector<std::uint64_t> priority;
    for (const Candidate& c : todo) priority.push_back(CornerPriority(ta, c.pixel));
    std::stable_sort(order.begin(), order.end(),
                     [&](int x, int y) { return priority[x] < priority[y]; });
  }
  std::vector<Match> matches;
  std::vector<int> todo_index;  // of matches[k]
  int num_harris_located = 0;
  std::set<long long> seen;
  for (const int index : order) {
    const Candidate& c = todo[index];
    if (!c.sift && num_harris_located >= options.max_matches_per_pair) continue;
    Match m;
    m.tile_a = ta;
    m.tile_b = tb;
    m.key = PixelKey(ta, c.pixel, prepared.width_px, prepared.height_px);
    if (!seen.insert(m.key).second) continue;
    m.anchor_px = c.pixel;
    m.ray_a = c.ray_a;
    m.warp = c.warp;
    m.sift = c.sift;
    const PatchMatch pm =
        MatchPatch(prepared.normalized[ta], c.pixel, prepared.normalized[tb], prepared.spline[tb],
                   c.q_b, m.warp, options.search_radius_px, options.patch);
    if (!pm.ok) continue;
    m.q_b = pm.q_px;
    m.covariance_px2 = pm.covariance_px2;
    matches.push_back(m);
    todo_index.push_back(index);
    if (!c.sift) ++num_harris_located;
  }
  std::vector<int> by_todo(matches.size());
  std::iota(by_todo.begin(), by_todo.end(), 0);
  std::sort(by_todo.begin(), by_todo.end(),
            [&](int x, int y) { return todo_index[x] < todo_index[y]; });
  std::vector<Match> in_todo_order;
  for (const int k : by_todo) in_todo_order.push_back(std::move(matches[k]));
  return in_todo_order;
}

// Tag corners by id: the first tile that sees a tag anchors it, the
// detections in the others predict it and the template match locates it.
std::vector<Match> TagMatches(const PreparedTiles& prepared) {
  const RegisterTilesOptions& options = prepared.options;
  const std::vector<std::vector<TagDetection>>& tags = prepared.tags;
  std::map<int, std::vector<std::pair<int, int>>> tag_sightings;  // id -> (tile, detection)
  for (size_t i = 0; i < tags.size(); ++i) {
    for (size_t k = 0; k < tags[i].size(); ++k)
      tag_sightings[tags[i][k].id].emplace_back(static_cast<int>(i), static_cast<int>(k));
  }
  std::vector<Match> tag_matches;
  for (const auto& [id, sightings] : tag_sightings) {
    const auto [ta, da] = sightings.front();
    for (size_t s = 1; s < sightings.size(); ++s) {
      const auto [tb, db] = sightings[s];
      for (int k = 0; k < 4; ++k) {
        const Eigen::Vector2d corner_a = tags[ta][da].corners_px.col(k);
        const Eigen::Vector2i anchor(static_cast<int>(std::lround(corner_a.x())),
                                     static_cast<int>(std::lround(corner_a.y())));
        Match m;
        m.tile_a = ta;
        m.tile_b = tb;
        m.key = TagKey(id, k);
        m.anchor_px = anchor;
        m.tag = true;
        const Eigen::Vector2d predicted =
            tags[tb][db].corners_px.col(k) + (anchor.cast<double>() - corner_a);
        const PatchMatch pm = MatchPatch(prepared.normalized[ta], anchor, prepared.normalized[tb],
                                         prepared.spline[tb], predicted, m.warp,
                                         options.search_radius_px, options.patch);
        if (!pm.ok) continue;
        m.q_b = pm.q_px;
        m.covariance_px2 = pm.covariance_px2;
        tag_matches.push_back(m);
      }
    }
  }
  return tag_matches;
}

// The tag matches added to their pairs' matches (a pair that no prediction
// made is added).
void AddTagMatches(const std::vector<Match>& tag_matches, std::vector<PairRegistration>* pairs,
                   std::vector<std::vector<Match>>* pair_matches) {
  std::map<std::pair<int, int>, int> pair_index;
  for (size_t p = 0; p < pairs->size(); ++p)
    pair_index[{(*pairs)[p].tile_a, (*pairs)[p].tile_b}] = static_cast<int>(p);
  for (const Match& m : tag_matches) {
    const auto it = pair_index.find({m.tile_a, m.tile_b});
    if (it == pair_index.end()) {
      PairRegistration pair;
      pair.tile_a = m.tile_a;
      pair.tile_b = m.tile_b;
      pair_index[{m.tile_a, m.tile_b}] = static_cast<int>(pairs->size());
      pairs->push_back(pair);
      pair_matches->emplace_back();
    }
    const int p = pair_index[{m.tile_a, m.tile_b}];
    ++(*pairs)[p].num_tag_corners;
    (*pair_matches)[p].push_back(m);
  }
}

// Why tiles without a usable pair cannot be held by table.csv alone ("; "
// before each), empty if none: a tile that overlaps no other, or whose
// image contradicts its table position (at least min_pair_matches of its
// pairs' probes, and half of them, find nothing alike).
std::string UnplacedTiles(const std::vector<PairRegistration>& pairs, int num_tiles,
                          const RegisterTilesOptions& options) {
  std::vector<int> num_usable(num_tiles, 0), num_predicted(num_tiles, 0),
      num_probes(num_tiles, 0), num_contradicting(num_tiles, 0);
  for (const PairRegistration& pair : pairs) {
    for (int t : {pair.tile_a, pair.tile_b}) {
      num_usable[t] += pair.usable;
      ++num_predicted[t];
      num_probes[t] += pair.num_probes;
      num_contradicting[t] += pair.num_contradicting_probes;
    }
  }
  std::ostringstream unplaced;
  for (int i = 0; i < num_tiles; ++i) {
    if (num_usable[i] > 0) continue;
    if (num_predicted[i] == 0) {
      unplaced << "; tile " << i << " overlaps no other tile at its table position";
    } else if (num_contradicting[i] >= options.min_pair_matches &&
               2 * num_contradicting[i] >= num_probes[i]) {
      unplaced << "; tile " << i << " matches none of its " << num_predicted[i]
               << " predicted neighbours: " << num_contradicting[i] << " of " << num_probes[i]
               << " probe templates find nothing alike (NCC < " << options.probe_contradiction_ncc
               << ") within " << options.probe_search_radius_px
               << " px of where table.csv puts them: the image does not show what its table "
                  "position says";
    }
  }
  return unplaced.str();
}

// The tracks of the kept matches (step 4): the adjustment's input, and the
// bookkeeping back to the matches.
struct Tracks {
  PlaneBundleInput input;
  std::vector<int> anchor_observation;  // per track: its anchor's observation
  // Per observation: the (pair, match) it came from; (-1, -1) for an anchor.
  std::vector<std::pair<int, int>> match_of_observation;
  std::vector<int> tag_id;  // per track: the tag id of a tag corner, else -1
};

Tracks TracksOf(const std::vector<std::vector<Match>>& pair_matches,
                const std::vector<Eigen::Vector2d>& commanded_table_pos_mm, double table_sigma_mm,
                const RegisterTilesOptions& options) {
  Tracks tracks;
  PlaneBundleInput& input = tracks.input;
  input.commanded_table_pos_mm = commanded_table_pos_mm;
  input.table_sigma_mm = table_sigma_mm;
  input.observation_sigma_px = options.observation_sigma_px;
  std::map<long long, int> track_of_key;
  for (size_t p = 0; p < pair_matches.size(); ++p) {
    for (size_t k = 0; k < pair_matches[p].size(); ++k) {
      const Match& m = pair_matches[p][k];
      if (!m.keep) continue;
      auto [it, added] = track_of_key.emplace(m.key, input.num_tracks);
      if (added) {
        ++input.num_tracks;
        tracks.anchor_observation.push_back(static_cast<int>(input.observations.size()));
        tracks.tag_id.push_back(m.tag ? static_cast<int>(-m.key - 1) / 4 : -1);
        input.observations.push_back({m.tile_a, it->second, m.anchor_px.cast<double>(), 1.0});
        tracks.match_of_observation.emplace_back(-1, -1);
      }
      TrackObservation obs{m.tile_b, it->second, m.q_b, 1.0};
      if (options.weight_by_match_sigma) {
        // Down-weighting only: weights above 1 (sigmas below
        // observation_sigma_px) stalled the first, outlier-laden solve.
        const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eigen(m.covariance_px2);
        const Eigen::Vector2d sigma = eigen.eigenvalues().cwiseMax(1e-18).cwiseSqrt();
        obs.weight = std::min(1.0, options.observation_sigma_px / sigma(0));
        obs.shape = eigen.eigenvectors() * Eigen::Vector2d(1.0, sigma(0) / sigma(1)).asDiagonal() *
                    eigen.eigenvectors().transpose();
      }
      input.observations.push_back(obs);
      tracks.match_of_observation.emplace_back(static_cast<int>(p), static_cast<int>(k));
    }
  }
  return tracks;
}

// Drops the matches whose target or anchor observation has a large residual
// (shaped as its weight: an edge's match along the edge counts less);
// returns how many.
int DropOutliers(const PlaneScene& scene, const Tracks& tracks, const RegisterTilesOptions& options,
                 std::vector<std::vector<Match>>* pair_matches) {
  int dropped = 0;
  const std::vector<TrackObservation>& observations = tracks.input.observations;
  Eigen::Matrix2Xd res = scene.residual_px;
  for (Eigen::Index k = 0; k < res.cols(); ++k) res.col(k) = observations[k].shape * res.col(k);
  std::vector<double> norms;
  for (Eigen::Index k = 0; k < res.cols(); ++k)
    if (res.col(k).allFinite()) norms.push_back(res.col(k).norm());
  if (norms.empty()) return dropped;
  const double threshold =
      std::max(options.min_outlier_threshold_px, options.outlier_factor * Median(norms));
  const auto bad = [&](int o) { return !res.col(o).allFinite() || res.col(o).norm() > threshold; };
  for (size_t o = 0; o < tracks.match_of_observation.size(); ++o) {
    const auto [p, k] = tracks.match_of_observation[o];
    if (p < 0) continue;
    const int track = observations[o].track;
    if (bad(static_cast<int>(o)) || bad(tracks.anchor_observation[track])) {
      (*pair_matches)[p][k].keep = false;
      ++dropped;
    }
  }
  return dropped;
}

// The adjusted scene's prediction of part point xy (mm) seen by tile a in
// tile b: its pixel there and the tile-to-tile warp about it, dq_b/dq_a =
// (dq_b/dP) (dq_a/dP)^-1 with dq/dP = dq/dp_cam R[:, 0:2], to second order
// from the neighbours step_px from the anchor along +-x and +-y of tile a
// (to first order; PatchWarp). False if the lens refuses.
bool PredictByScene(const CameraModel& camera, const PlaneScene& scene, double step_px, int tile_a,
                    int tile_b, const Eigen::Vector2d& xy, Eigen::Vector2d* q_b, PatchWarp* warp) {
  const Eigen::Matrix3d r = RotationFromAngleAxis(scene.cam_from_part_r);
  // Column 2 k: the point xy + dxy_mm in tile a, 2 k + 1 in b.
  const auto fill = [&](Eigen::Matrix3Xd* p_cam, int k, const Eigen::Vector2d& dxy_mm) {
    for (int e = 0; e < 2; ++e) {
      const Eigen::Vector2d& t = scene.table_pos_mm[e == 0 ? tile_a : tile_b];
      p_cam->col(2 * k + e) =
          r * Eigen::Vector3d(xy.x() + dxy_mm.x() + t.x(), xy.y() + dxy_mm.y() + t.y(), 0) +
          scene.cam_from_part_t_mm;
    }
  };
  Eigen::Matrix3Xd p_cam(3, 10);
  fill(&p_cam, 0, Eigen::Vector2d::Zero());
  Eigen::Matrix2Xd q;
  Eigen::MatrixXd dq_dp;
  if (!ProjectPoints(camera, p_cam.leftCols(2), &q, &dq_dp)) return false;
  const Eigen::Matrix2d dxy_dqa = (dq_dp.block<2, 3>(0, 0) * r.leftCols<2>()).inverse();
  const double s = step_px;
  const Eigen::Vector2d steps[4] = {{s, 0}, {-s, 0}, {0, s}, {0, -s}};
  for (int k = 0; k < 4; ++k) fill(&p_cam, k + 1, dxy_dqa * steps[k]);
  if (!ProjectPoints(camera, p_cam, &q, &dq_dp)) return false;
  const auto db_da = [&](int k) {
    const Eigen::Matrix2d dqa = dq_dp.block<2, 3>(4 * k, 0) * r.leftCols<2>();
    const Eigen::Matrix2d dqb = dq_dp.block<2, 3>(4 * k + 2, 0) * r.leftCols<2>();
    return Eigen::Matrix2d(dqb * dqa.inverse());
  };
  *q_b = q.col(1);
  *warp = PatchWarp::FromJacobians(db_da(0), db_da(1), db_da(2), db_da(3), db_da(4), s);
  return true;
}

// Every kept match located again with the warp the adjusted scene predicts
// between its tiles, where that warp moves the template's corners by at
// least relocation_min_change_px; returns the number relocated.
int RelocateMatches(const MatchingInputs& in, const PlaneScene& scene, const Tracks& tracks,
                    std::vector<std::vector<Match>>* pair_matches) {
  const PreparedTiles& prepared = in.prepared;
  const RegisterTilesOptions& options = in.options;
  std::atomic<int> num_relocated{0};
  std::vector<std::pair<int, int>> todo;
  std::vector<int> obs_index;
  for (size_t o = 0; o < tracks.match_of_observation.size(); ++o) {
    if (tracks.match_of_observation[o].first < 0) continue;
    todo.push_back(tracks.match_of_observation[o]);
    obs_index.push_back(static_cast<int>(o));
  }
  ParallelFor(static_cast<int>(todo.size()), options.num_threads, [&](int n) {
    Match& m = (*pair_matches)[todo[n].first][todo[n].second];
    const int track = tracks.input.observations[obs_index[n]].track;
    Eigen::Vector2d q_b;
    PatchWarp warp;
    const double s = options.patch.half_size_px;
    if (!PredictByScene(in.camera, scene, s, m.tile_a, m.tile_b, scene.track_xy_mm.col(track), &q_b,
                        &warp)) {
      m.keep = false;
      return;
    }
    // The template's corners move by at most |change J| h sqrt(2) + |change
    // H_k| h^2: below a small fraction of a match's sigma, the match would
    // not move.
    const double change_px = (warp.jacobian - m.warp.jacobian).norm() * s * std::sqrt(2.0) +
                             std::hypot((warp.hessian[0] - m.warp.hessian[0]).norm(),
                                        (warp.hessian[1] - m.warp.hessian[1]).norm()) *
                                 s * s;
    if (change_px < options.relocation_min_change_px) return;
    ++num_relocated;
    m.warp = warp;
    const PatchMatch pm =
        MatchPatch(prepared.normalized[m.tile_a], m.anchor_px, prepared.normalized[m.tile_b],
                   prepared.spline[m.tile_b], m.q_b, m.warp, 0, options.patch);
    if (!pm.ok) {
      m.keep = false;
      return;
    }
    m.q_b = pm.q_px;
    m.covariance_px2 = pm.covariance_px2;
  });
  return num_relocated.load();
}

// Pairs left unusable by the probes (weak texture) matched again, their
// candidates predicted by the adjusted scene and screened as before; returns
// how many became usable.
int RescuePairs(const MatchingInputs& in, const PlaneScene& scene,
                const std::vector<std::vector<int>>& pair_candidates,
                std::vector<PairRegistration>* pairs,
                std::vector<std::vector<Match>>* pair_matches) {
  const PreparedTiles& prepared = in.prepared;
  const RegisterTilesOptions& options = in.options;
  const Eigen::Matrix3d r = RotationFromAngleAxis(scene.cam_from_part_r);
  std::vector<int> todo;
  for (size_t p = 0; p < pairs->size(); ++p)
    if (!(*pairs)[p].usable && !pair_candidates[p].empty()) todo.push_back(static_cast<int>(p));
  std::atomic<int> num_rescued{0};
  ParallelFor(static_cast<int>(todo.size()), options.num_threads, [&](int n) {
    const int p = todo[n];
    PairRegistration& pair = (*pairs)[p];
    const int ta = pair.tile_a, tb = pair.tile_b;
    // Part point of a ray of tile a: s R^T d - R^T t - T_a on z = 0.
    const Eigen::Vector3d w = r.transpose() * scene.cam_from_part_t_mm;
    std::vector<Match> matches;
    for (int k : pair_candidates[p]) {
      const Eigen::Vector3d u = r.transpose() * in.corner_rays[ta].col(k).homogeneous();
      if (!(std::abs(u.z()) > 1e-12)) continue;
      const Eigen::Vector2d xy = (w.z() / u.z() * u - w).head<2>() - scene.table_pos_mm[ta];
      Match m;
      m.tile_a = ta;
      m.tile_b = tb;
      m.anchor_px = prepared.corners[ta][k].pixel;
      m.key = PixelKey(ta, m.anchor_px, prepared.width_px, prepared.height_px);
      m.ray_a = in.corner_rays[ta].col(k);
      Eigen::Vector2d q_b;
      if (!PredictByScene(in.camera, scene, options.patch.half_size_px, ta, tb, xy, &q_b, &m.warp))
        continue;
      const PatchMatch pm =
          MatchPatch(prepared.normalized[ta], m.anchor_px, prepared.normalized[tb],
                     prepared.spline[tb], q_b, m.warp, options.search_radius_px, options.patch);
      if (!pm.ok) continue;
      m.q_b = pm.q_px;
      m.covariance_px2 = pm.covariance_px2;
      matches.push_back(m);
    }
    std::mt19937_64 rng(options.ransac_seed + p);
    const std::vector<Match> kept = PlaneInliers(in, matches, &rng);
    pair.num_matched = static_cast<int>(matches.size());
    pair.num_inliers = static_cast<int>(kept.size());
    pair.usable = pair.num_inliers + pair.num_tag_corners >= options.min_pair_matches;
    if (!pair.usable) return;
    pair.rescued = true;
    (*pair_matches)[p].insert((*pair_matches)[p].end(), kept.begin(), kept.end());
    ++num_rescued;
  });
  return num_rescued.load();
}

// The registration's summary from its final tracks: each pair's used
// matches and RMS, the tiles held by their table prior, and the brief.
void Summarize(const Tracks& tracks, bool use_sift, size_t num_sift_pairs_in, int num_tiles,
               TileRegistration* result) {
  const Eigen::Matrix2Xd& res = result->scene.residual_px;
  std::vector<double> sum_sq(result->pairs.size(), 0.0);
  std::vector<int> count(result->pairs.size(), 0);
  std::vector<bool> tile_seen(num_tiles, false);
  for (size_t o = 0; o < tracks.match_of_observation.size() && res.cols() > 0; ++o) {
    tile_seen[tracks.input.observations[o].tile] = true;
    const auto [p, k] = tracks.match_of_observation[o];
    if (p < 0) continue;
    ++result->pairs[p].num_used;
    const int anchor = tracks.anchor_observation[tracks.input.observations[o].track];
    sum_sq[p] += res.col(o).squaredNorm() + res.col(anchor).squaredNorm();
    count[p] += 2;
  }
  for (size_t p = 0; p < result->pairs.size(); ++p)
    result->pairs[p].rms_px = count[p] > 0 ? std::sqrt(sum_sq[p] / count[p]) : 0.0;
  for (int i = 0; i < num_tiles; ++i)
    if (!tile_seen[i]) result->tiles_held_by_prior.push_back(i);
  result->rms_px = result->bundle.final_rms_px;
  result->table_adjustment_mm = result->bundle.table_adjustment_mm;
  result->plane_tilt_deg = result->bundle.plane_tilt_deg;
  result->usable = result->bundle.usable;
  int num_usable_pairs = 0;
  for (const PairRegistration& pair : result->pairs) num_usable_pairs += pair.usable;
  std::ostringstream brief;
  brief << "registration " << (result->usable ? "usable" : "UNUSABLE") << ": " << num_tiles
        << " tiles, " << num_usable_pairs << " of " << result->pairs.size() << " pairs, "
        << tracks.input.num_tracks << " tracks, " << tracks.input.observations.size()
        << " observations (" << result->num_dropped_observations << " dropped), RMS "
        << result->rms_px << " px";
  if (use_sift) {
    int num_sift = 0;
    for (const PairRegistration& pair : result->pairs) num_sift += pair.usable ? pair.num_sift : 0;
    brief << "; " << num_sift << " matches anchored at SIFT keypoints (" << num_sift_pairs_in
          << " SIFT pairs in)";
  }
  const int num_rescued =
      static_cast<int>(std::count_if(result->pairs.begin(), result->pairs.end(),
                                     [](const PairRegistration& p) { return p.rescued; }));
  if (num_rescued > 0)
    brief << "; " << num_rescued << " pair" << (num_rescued > 1 ? "s" : "")
          << " matched on the adjusted scene's prediction";
  if (!result->tiles_held_by_prior.empty()) {
    brief << "; held by the table prior alone: tile";
    for (int i : result->tiles_held_by_prior) brief << ' ' << i;
  }
  if (!result->usable) brief << "; " << result->bundle.brief;
  result->brief = brief.str();
}

// Step 3's matches of every pair, in parallel: Harris candidates (unless
// options.features is SIFT alone) and COLMAP's SIFT matches of the pair
// (unless it is Harris alone), located and kept where the plane model holds
// (RANSAC). The counts go into *pairs.
struct PairMatches {
  std::vector<std::vector<Match>> matches;          // per pair
  std::vector<std::vector<int>> harris_candidates;  // per pair: indices into corners[a]
};

PairMatches MatchPairs(const MatchingInputs& in, const RegisterTilesOptions& options,
                       const std::vector<ColmapPairMatches>& sift_matches,
                       std::vector<PairRegistration>* pairs) {
  const bool use_harris = options.features != FeatureSource::kSift;
  const bool use_sift = options.features != FeatureSource::kHarris;
  std::map<std::pair<int, int>, const ColmapPairMatches*> sift_of_pair;
  if (use_sift) {
    for (const ColmapPairMatches& m : sift_matches) sift_of_pair[{m.tile_a, m.tile_b}] = &m;
  }
  PairMatches matched;
  matched.matches.resize(pairs->size());
  matched.harris_candidates.resize(pairs->size());
  ParallelFor(static_cast<int>(pairs->size()), options.num_threads, [&](int p) {
    PairRegistration& pair = (*pairs)[p];
    std::mt19937_64 rng(options.ransac_seed + p);
    std::vector<Candidate> todo;
    if (use_harris) {
      matched.harris_candidates[p] = PairCandidates(in, &pair);
      todo = HarrisCandidates(in, matched.harris_candidates[p], &pair, &rng);
    }
    if (const auto it = sift_of_pair.find({pair.tile_a, pair.tile_b}); it != sift_of_pair.end()) {
      const std::vector<Candidate> from_sift = SiftCandidates(in, *it->second, &pair, &rng);
      todo.insert(todo.end(), from_sift.begin(), from_sift.end());
    }
    const std::vector<Match> matches = LocateCandidates(in, pair, todo);
    pair.num_matched = static_cast<int>(matches.size());
    std::vector<Match> kept = PlaneInliers(in, matches, &rng);
    pair.num_inliers = static_cast<int>(kept.size());
    pair.num_sift = static_cast<int>(
        std::count_if(kept.begin(), kept.end(), [](const Match& m) { return m.sift; }));
    matched.matches[p] = std::move(kept);
  });
  return matched;
}

}  // namespace

TileRegistration RegisterTiles(const PreparedTiles& prepared, double table_sigma_mm,
                               const CameraModel& camera,
                               const std::vector<ColmapPairMatches>& sift_matches) {
  const RegisterTilesOptions& options = prepared.options;
  const int num_tiles = static_cast<int>(prepared.normalized.size());
  if (num_tiles > 0 &&
      (prepared.width_px != camera.width_px || prepared.height_px != camera.height_px))
    throw InputError("", "tile registration: the tiles are " + std::to_string(prepared.width_px) +
                             " x " + std::to_string(prepared.height_px) + " px, the camera " +
                             std::to_string(camera.width_px) + " x " +
                             std::to_string(camera.height_px));
  if (!(table_sigma_mm > 0)) throw InputError("", "tile registration: table sigma must be > 0");

  TileRegistration result;
  for (const auto& t : prepared.tags) result.num_tags_detected += static_cast<int>(t.size());
  result.features_seconds = prepared.features_seconds;
  result.motion_brief = prepared.motion.brief;
  if (!prepared.motion.ok) {
    result.matching_seconds = prepared.matching_seconds;
    result.tiles_held_by_prior.resize(num_tiles);
    for (int i = 0; i < num_tiles; ++i) result.tiles_held_by_prior[i] = i;
    result.brief = "registration UNUSABLE: " + prepared.motion.brief;
    return result;
  }
  result.image_px_per_table_mm = prepared.motion.px_per_table_mm;
  result.pairs = prepared.pairs;

  // 3. (continued) The pairs matched.
  auto t0 = Clock::now();
  const MatchingInputs in = MatchingInputsOf(prepared, camera);
  const bool use_sift = options.features != FeatureSource::kHarris;
  PairMatches matched = MatchPairs(in, options, sift_matches, &result.pairs);
  std::vector<std::vector<Match>>& pair_matches = matched.matches;
  const std::vector<std::vector<int>>& pair_candidates = matched.harris_candidates;
  AddTagMatches(TagMatches(prepared), &result.pairs, &pair_matches);
  for (size_t p = 0; p < result.pairs.size(); ++p) {
    PairRegistration& pair = result.pairs[p];
    pair.usable = pair.num_inliers + pair.num_tag_corners >= options.min_pair_matches;
    if (!pair.usable) pair_matches[p].clear();
  }
  result.matching_seconds = prepared.matching_seconds + SecondsSince(t0);

  // A tile without a usable pair is placed by nothing but table.csv: only
  // acceptable when its image does not contradict it.
  if (const std::string unplaced = UnplacedTiles(result.pairs, num_tiles, options);
      !unplaced.empty()) {
    result.brief = "registration UNUSABLE: not placed by the images" + unplaced;
    return result;
  }

  // 4.-5. Tracks and adjustment, with outlier passes and relocation.
  t0 = Clock::now();
  PlaneBundleConfig config;
  Tracks tracks;
  PlaneAdjustment adjustment;
  PlaneBundleOptions screening_bundle = options.bundle;
  screening_bundle.function_tolerance =
      std::max(options.bundle.function_tolerance, options.screening_function_tolerance);
  enum class Solve { kScreening, kRelocated, kFinal };
  bool screened = false;  // the adjustment is a screening solve's
  const auto solve = [&](Solve kind) {
    tracks = TracksOf(pair_matches, prepared.commanded_table_pos_mm, table_sigma_mm, options);
    config.compute_covariance = kind == Solve::kFinal && options.compute_covariance;
    screened = kind == Solve::kScreening;
    adjustment = AdjustPlaneScene(camera, tracks.input, config,
                                  screened ? screening_bundle : options.bundle);
  };
  const auto drop_outliers = [&] {
    const int dropped = DropOutliers(adjustment.scene, tracks, options, &pair_matches);
    result.num_dropped_observations += dropped;
    return dropped;
  };
  solve(Solve::kScreening);
  if (adjustment.seed.ok && options.rescue_unusable_pairs &&
      RescuePairs(in, adjustment.scene, pair_candidates, &result.pairs, &pair_matches) > 0)
    solve(Solve::kScreening);
  if (adjustment.seed.ok) {
    int dropped = drop_outliers();
    for (int pass = 0; pass < options.rematch_passes; ++pass) {
      const int relocated = RelocateMatches(in, adjustment.scene, tracks, &pair_matches);
      result.num_relocated += relocated;
      if (relocated == 0) break;  // the final solve below sees the same matches
      solve(Solve::kRelocated);
      if (!adjustment.seed.ok) break;
      dropped = drop_outliers();
    }
    // Nothing dropped since the last solve, a full one: solving the same
    // matches again would reproduce it (the demo's third solve, a third of
    // the step).
    if (dropped > 0 || screened || options.compute_covariance || !adjustment.seed.ok)
      solve(Solve::kFinal);
  }
  result.scene = adjustment.scene;
  result.seed = adjustment.seed;
  result.bundle = adjustment.summary;
  result.adjustment_seconds = SecondsSince(t0);
  Summarize(tracks, use_sift, sift_matches.size(), num_tiles, &result);
  result.input = std::move(tracks.input);
  result.track_anchor_observation = std::move(tracks.anchor_observation);
  result.track_tag_id = std::move(tracks.tag_id);
  return result;
}

}  // namespace omm
