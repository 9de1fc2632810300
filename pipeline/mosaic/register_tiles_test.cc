// RegisterTiles on simulated projects, scored against the simulator's truth:
// match positions, adjusted table positions and hole centres through the
// adjusted scene. The calibrated camera is the truth camera here (calibration
// is its own stage), so every error below is the registration's.
#include "pipeline/mosaic/register_tiles.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include "adapters/colmap/colmap_sift.h"
#include "adapters/mrcal/lens.h"
#include "adapters/opencv/image_io.h"
#include "pipeline/core/error.h"
#include "tests/sim_cache.h"

namespace omm {
namespace {

struct Rendered {
  std::filesystem::path project_dir;
  SimulationTruth truth;
  std::vector<ImageF> tiles;
  std::vector<Eigen::Vector2d> commanded_mm;
};

// "preset-seed", e.g. "low-texture-2": the cached render (tests/sim_cache.h),
// with any calib/ count (these tests take the truth camera).
Rendered Render(const std::string& name) {
  const size_t dash = name.rfind('-');
  const omm::testing::CachedProject project =
      omm::testing::SimulatedTiles(name.substr(0, dash), std::stoull(name.substr(dash + 1)));
  Rendered r;
  r.project_dir = project.project_dir;
  r.truth = project.truth;
  for (const TileTruth& tile : r.truth.tiles) {
    r.tiles.push_back(ReadGrayImage(project.project_dir / "tiles" / tile.image).pixels);
    r.commanded_mm.push_back(tile.commanded_mm);
  }
  return r;
}

Eigen::Isometry3d CamFromPartAt(const Eigen::Matrix3d& r, const Eigen::Vector3d& t,
                                const Eigen::Vector2d& table_mm) {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = r;
  pose.translation() = t + r * Eigen::Vector3d(table_mm.x(), table_mm.y(), 0);
  return pose;
}

// Part point (Z = 0) seen at pixel q by a camera at cam_from_part.
Eigen::Vector2d PartAtPixel(const CameraModel& camera, const Eigen::Isometry3d& cam_from_part,
                            const Eigen::Vector2d& q) {
  Eigen::Matrix3Xd v;
  EXPECT_TRUE(UnprojectPixels(camera, Eigen::Matrix2Xd(q), &v));
  const Eigen::Matrix3d r = cam_from_part.linear();
  Eigen::Matrix3d m;
  m << r.col(0), r.col(1), -v.col(0);
  const Eigen::Vector3d x = m.lu().solve(-cam_from_part.translation());
  return x.head<2>();
}

Eigen::Vector2d PixelOf(const CameraModel& camera, const Eigen::Isometry3d& cam_from_part,
                        const Eigen::Vector2d& part_mm) {
  Eigen::Matrix2Xd q;
  EXPECT_TRUE(ProjectPoints(camera, Eigen::Matrix3Xd(cam_from_part *
                                                     Eigen::Vector3d(part_mm.x(), part_mm.y(), 0)),
                            &q));
  return q.col(0);
}

Eigen::Isometry3d TruthPose(const SimulationTruth& truth, int tile) {
  return CamFromPartAt(truth.cam_from_part.linear(), truth.cam_from_part.translation(),
                       truth.tiles[tile].actual_mm);
}

Eigen::Isometry3d AdjustedPose(const PlaneScene& scene, int tile) {
  const Eigen::Matrix3d r =
      Eigen::AngleAxisd(scene.cam_from_part_r.norm(), scene.cam_from_part_r.normalized())
          .toRotationMatrix();
  return CamFromPartAt(r, scene.cam_from_part_t_mm, scene.table_pos_mm[tile]);
}

// Error of every non-anchor observation against the truth: the anchor pixel's
// part point (truth camera, truth plane, actual table position) projected into
// the observation's tile. Optionally tag tracks only.
std::vector<Eigen::Vector2d> MatchErrorsPx(const SimulationTruth& truth,
                                           const TileRegistration& reg, bool tags_only) {
  std::vector<Eigen::Vector2d> errors;
  const CameraModel& camera = truth.camera.model;
  std::vector<Eigen::Vector2d> part_of_track(reg.input.num_tracks);
  for (int t = 0; t < reg.input.num_tracks; ++t) {
    const TrackObservation& anchor = reg.input.observations[reg.track_anchor_observation[t]];
    part_of_track[t] = PartAtPixel(camera, TruthPose(truth, anchor.tile), anchor.q_px);
  }
  for (size_t o = 0; o < reg.input.observations.size(); ++o) {
    const TrackObservation& obs = reg.input.observations[o];
    if (reg.track_anchor_observation[obs.track] == static_cast<int>(o)) continue;
    if (tags_only && reg.track_tag_id[obs.track] < 0) continue;
    errors.push_back(obs.q_px - PixelOf(camera, TruthPose(truth, obs.tile), part_of_track[obs.track]));
  }
  return errors;
}

double Rms(const std::vector<Eigen::Vector2d>& v) {
  double sum = 0;
  for (const Eigen::Vector2d& e : v) sum += e.squaredNorm();
  return v.empty() ? 0.0 : std::sqrt(sum / v.size());
}

// Hole centres through the adjusted scene: each hole's true pixel in every
// tile that sees it, mapped to the adjusted part frame; compared with the
// true centres after the least-squares rigid 2-D fit truth -> adjusted (the
// origin gauge and the prior-held rotation about Z). RMS in raw px (mm over
// the footprint of a pixel at the working distance).
double HoleRmsRawPx(const SimulationTruth& truth, const TileRegistration& reg,
                    int* num_sightings) {
  const CameraModel& camera = truth.camera.model;
  std::vector<Eigen::Vector2d> true_mm, adjusted_mm;
  for (const HoleTruth& hole : truth.holes) {
    for (size_t i = 0; i < truth.tiles.size(); ++i) {
      const Eigen::Vector2d q =
          PixelOf(camera, TruthPose(truth, static_cast<int>(i)), hole.center_part_mm);
      if (q.x() < 0 || q.y() < 0 || q.x() > camera.width_px - 1 || q.y() > camera.height_px - 1)
        continue;
      true_mm.push_back(hole.center_part_mm);
      adjusted_mm.push_back(
          PartAtPixel(camera, AdjustedPose(reg.scene, static_cast<int>(i)), q));
    }
  }
  *num_sightings = static_cast<int>(true_mm.size());
  // Rigid fit (Kabsch in 2-D).
  Eigen::Vector2d mt = Eigen::Vector2d::Zero(), ma = Eigen::Vector2d::Zero();
  for (size_t k = 0; k < true_mm.size(); ++k) mt += true_mm[k], ma += adjusted_mm[k];
  mt /= true_mm.size();
  ma /= true_mm.size();
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (size_t k = 0; k < true_mm.size(); ++k)
    cov += (adjusted_mm[k] - ma) * (true_mm[k] - mt).transpose();
  const double angle = std::atan2(cov(1, 0) - cov(0, 1), cov(0, 0) + cov(1, 1));
  const Eigen::Matrix2d rot = Eigen::Rotation2Dd(angle).toRotationMatrix();
  std::vector<Eigen::Vector2d> residual;
  for (size_t k = 0; k < true_mm.size(); ++k)
    residual.push_back(adjusted_mm[k] - (ma + rot * (true_mm[k] - mt)));
  const double mm_per_px = truth.cam_from_part.translation().z() / camera.intrinsics(0);
  return Rms(residual) / mm_per_px;
}

double TableRmsMm(const SimulationTruth& truth, const std::vector<Eigen::Vector2d>& pos_mm) {
  std::vector<Eigen::Vector2d> d;
  for (size_t i = 0; i < truth.tiles.size(); ++i) d.push_back(pos_mm[i] - truth.tiles[i].actual_mm);
  return Rms(d) / std::sqrt(2.0);  // per axis
}

struct Scores {
  double match_rms_px = 0, hole_rms_px = 0, table_rms_mm = 0, commanded_rms_mm = 0;
  int num_matches = 0, num_hole_sightings = 0;
};

Scores Score(const Rendered& r, const TileRegistration& reg) {
  Scores s;
  const std::vector<Eigen::Vector2d> errors = MatchErrorsPx(r.truth, reg, false);
  s.match_rms_px = Rms(errors) / std::sqrt(2.0);
  s.num_matches = static_cast<int>(errors.size());
  s.hole_rms_px = HoleRmsRawPx(r.truth, reg, &s.num_hole_sightings);
  s.table_rms_mm = TableRmsMm(r.truth, reg.scene.table_pos_mm);
  s.commanded_rms_mm = TableRmsMm(r.truth, r.commanded_mm);
  std::printf(
      "%s seed %llu: %s\n  motion: %s\n  features %.2f s, matching %.2f s, adjustment %.2f s\n"
      "  match RMS %.4f px/axis over %d, hole RMS %.4f raw px over %d sightings, "
      "table RMS %.4f mm/axis (commanded %.4f), tilt %.2f deg\n",
      r.truth.preset.c_str(), static_cast<unsigned long long>(r.truth.seed), reg.brief.c_str(),
      reg.motion_brief.c_str(), reg.features_seconds, reg.matching_seconds, reg.adjustment_seconds,
      s.match_rms_px, s.num_matches, s.hole_rms_px, s.num_hole_sightings, s.table_rms_mm,
      s.commanded_rms_mm, reg.plane_tilt_deg);
  for (const PairRegistration& p : reg.pairs)
    std::printf(
        "  pair %d-%d overlap %.2f: %d candidates, %d matched, %d inliers (%d SIFT), "
        "%d tag, %d used, RMS %.4f px\n",
        p.tile_a, p.tile_b, p.predicted_overlap, p.num_candidates, p.num_matched, p.num_inliers,
        p.num_sift, p.num_tag_corners, p.num_used, p.rms_px);
  return s;
}

TileRegistration Register(const Rendered& r) {
  return RegisterTiles(r.tiles, r.commanded_mm, r.truth.table_sigma_mm, r.truth.camera.model,
                       RegisterTilesOptions());
}

// Bounds per preset. The goals: matches unbiased to 0.03 px, the mosaic good
// to 0.05 raw px. demo and markers meet them (0.0289 and 0.0299 px/axis).
// Where texture is rich, each of a 3 x 3 grid's 20 pairs locates
// max_matches_per_pair corners; 90 % of those must survive RANSAC and the
// outlier passes (demo, markers and exposure seed 1: 1909-1949 of 2000).
// exposure's darkest tiles (gain 0.6) have ~1.7x less signal over the same
// noise, so its matches scatter more (measured 0.044 px/axis), while its
// holes meet the goal. low-texture's matches scatter more (little texture
// at the templates' scale but around the holes, whose bore walls move
// between views: measured 592, 618 and 462 at 0.092, 0.116 and 0.141 px/axis
// for seeds 1-3, most of it along the rims, where the weights' shape
// discounts it; its pairs try all their candidates), but weighted by their
// predicted covariances they put its holes within the goal (measured 0.026,
// 0.040 and 0.020 raw px).
struct Bounds {
  int min_matches;
  double match_rms_px;
  double hole_rms_px;
};

Bounds BoundsFor(const std::string& preset) {
  constexpr int kNumPairs = 20;
  const int rich = 9 * kNumPairs * RegisterTilesOptions().max_matches_per_pair / 10;
  if (preset == "exposure") return {rich, 0.045, 0.05};
  if (preset == "low-texture") return {300, 0.2, 0.05};
  return {rich, 0.03, 0.05};
}

class RegisterTilesPreset : public ::testing::TestWithParam<std::string> {};

TEST_P(RegisterTilesPreset, MatchesTableAndHolesAgreeWithTruth) {
  const Rendered r = Render(GetParam());
  const Bounds bounds = BoundsFor(r.truth.preset);
  const TileRegistration reg = Register(r);
  ASSERT_TRUE(reg.usable) << reg.brief;
  EXPECT_TRUE(reg.tiles_held_by_prior.empty()) << reg.brief;
  const Scores s = Score(r, reg);
  // (a) The matcher's positions against the truth, px per axis.
  EXPECT_GT(s.num_matches, bounds.min_matches);
  EXPECT_LT(s.match_rms_px, bounds.match_rms_px);
  // (b) The adjusted table positions are better than commanded: below the
  // declared sigma (commanded - actual scatters with exactly that sigma).
  EXPECT_LT(s.table_rms_mm, r.truth.table_sigma_mm);
  // (c) The mosaic's geometry at the holes, raw px.
  EXPECT_GT(s.num_hole_sightings, 10);
  EXPECT_LT(s.hole_rms_px, bounds.hole_rms_px);
  // (d) AprilTag corners matched by id: every pair of sightings of a tag
  // gives 4 corner matches, as accurate as the corners' matches.
  if (r.truth.preset == "markers") {
    EXPECT_GT(reg.num_tags_detected, 0);
    const std::vector<Eigen::Vector2d> tag_errors = MatchErrorsPx(r.truth, reg, true);
    std::printf("  %d tag detections, %zu tag-corner matches kept, RMS %.4f px/axis\n",
                reg.num_tags_detected, tag_errors.size(), Rms(tag_errors) / std::sqrt(2.0));
    EXPECT_GE(tag_errors.size(), 8u);
    EXPECT_LT(Rms(tag_errors) / std::sqrt(2.0), 0.03);
  }
}

#ifdef OMM_TEST_MISPLACED_TILES
// table.csv lies: the images of tiles 0 and 8 (opposite corners) swapped.
// Each then shows part that its predicted neighbours do not: the
// registration must fail and name both, never place them by table.csv.
TEST(RegisterTiles, TilesThatDoNotShowTheirTablePositionFail) {
  Rendered r = Render("demo-1");
  std::swap(r.tiles[0], r.tiles[8]);
  const TileRegistration reg = Register(r);
  std::printf("%s\n  motion: %s\n", reg.brief.c_str(), reg.motion_brief.c_str());
  EXPECT_FALSE(reg.usable);
  EXPECT_NE(reg.brief.find("tile 0 matches none"), std::string::npos);
  EXPECT_NE(reg.brief.find("tile 8 matches none"), std::string::npos);
  // The other seven tiles still agree on the motion and match each other.
  for (const PairRegistration& pair : reg.pairs) {
    const bool swapped = pair.tile_a == 0 || pair.tile_b == 8;
    EXPECT_EQ(pair.usable, !swapped) << pair.tile_a << "-" << pair.tile_b;
  }
}
#endif

#ifdef OMM_TEST_TAG_GATE
// RegisterTiles' tag detection passes at 1/8 first and skips the tiles where
// that finds nothing: it must still see every tile of the markers preset
// (each holds tags), so that their tags and corners are the full pass's, bit
// for bit, and skip the demo's tiles (no tags).
TEST(RegisterTiles, TagGateSkipsTheDemoAndKeepsEveryMarkersTag) {
  const TagDetectorOptions gated = RegisterTilesOptions().tags;
  ASSERT_GT(gated.gate_decimate, 0);
  TagDetectorOptions full = gated;
  full.gate_decimate = 0;
  int num_tags = 0;
  for (const ImageF& tile : Render("markers-1").tiles) {
    const std::vector<TagDetection> expected = DetectAprilTags36h11(tile, full);
    const std::vector<TagDetection> found = DetectAprilTags36h11(tile, gated);
    EXPECT_FALSE(expected.empty());
    ASSERT_EQ(found.size(), expected.size());
    for (size_t k = 0; k < found.size(); ++k) {
      EXPECT_EQ(found[k].id, expected[k].id);
      EXPECT_EQ(found[k].corners_px, expected[k].corners_px);
    }
    num_tags += static_cast<int>(found.size());
  }
  EXPECT_GT(num_tags, 9);
  for (const ImageF& tile : Render("demo-1").tiles)
    EXPECT_TRUE(DetectAprilTags36h11(tile, gated).empty());
}

// Tiles made one at a time for PrepareTiles (each asked for once, dropped
// after its step 1) are prepared as the same tiles held together: matching
// images, tags, corners and motion bit for bit, on the markers preset, whose
// tiles hold tags. A tile of another size is refused by its index.
TEST(RegisterTiles, TilesMadeOneAtATimeArePreparedAsHeldTiles) {
  const Rendered r = Render("markers-1");
  const int num_tiles = static_cast<int>(r.tiles.size());
  const RegisterTilesOptions options;
  const PreparedTiles held = PrepareTiles(r.tiles, r.commanded_mm, options);
  std::vector<int> times_made(r.tiles.size(), 0);
  const int width = static_cast<int>(r.tiles[0].cols());
  const int height = static_cast<int>(r.tiles[0].rows());
  const PreparedTiles made = PrepareTiles(
      num_tiles, width, height,
      [&](int i) {
        ++times_made[static_cast<size_t>(i)];
        return r.tiles[static_cast<size_t>(i)];
      },
      r.commanded_mm, options);
  EXPECT_EQ(times_made, std::vector<int>(r.tiles.size(), 1));
  ASSERT_EQ(made.normalized.size(), r.tiles.size());
  int num_tags = 0;
  for (size_t i = 0; i < r.tiles.size(); ++i) {
    EXPECT_EQ(made.normalized[i], held.normalized[i]) << i;
    EXPECT_EQ(made.spline[i], held.spline[i]) << i;
    EXPECT_EQ(made.coarse_probe[i], held.coarse_probe[i]) << i;
    ASSERT_EQ(made.tags[i].size(), held.tags[i].size()) << i;
    for (size_t k = 0; k < made.tags[i].size(); ++k)
      EXPECT_EQ(made.tags[i][k].corners_px, held.tags[i][k].corners_px) << i;
    num_tags += static_cast<int>(made.tags[i].size());
    ASSERT_EQ(made.corners[i].size(), held.corners[i].size()) << i;
    for (size_t k = 0; k < made.corners[i].size(); ++k)
      EXPECT_EQ(made.corners[i][k].pixel, held.corners[i][k].pixel) << i;
  }
  EXPECT_GT(num_tags, 9);
  ASSERT_TRUE(made.motion.ok);
  EXPECT_EQ(made.motion.px_per_table_mm, held.motion.px_per_table_mm);
  EXPECT_EQ(made.pairs.size(), held.pairs.size());

  try {
    PrepareTiles(
        num_tiles, width, height,
        [&](int i) -> ImageF {
          return i == 4 ? ImageF(r.tiles[4].topLeftCorner(height / 2, width)) : r.tiles[i];
        },
        r.commanded_mm, options);
    FAIL() << "a tile of another size was prepared";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("tile 4 is"), std::string::npos) << e.what();
  }
}
#endif

#ifdef OMM_TEST_MATCH_CAP
// A pair locates at most max_matches_per_pair Harris corners, in an order
// fixed per corner: a corner located in one of its tile's pairs is located
// in the others, so the tracks keep their views (a random order per pair
// took demo-1 from 2.35 to 2.17 observations per track, and more outliers
// escaped in the shorter tracks), and the holes are as well placed as with
// every candidate located.
TEST(RegisterTiles, MatchCapKeepsTheTracksViewsAndTheHoles) {
  const Rendered r = Render("demo-1");
  const TileRegistration capped = Register(r);
  RegisterTilesOptions options;
  options.max_matches_per_pair = options.max_corners_per_pair;
  const TileRegistration all =
      RegisterTiles(r.tiles, r.commanded_mm, r.truth.table_sigma_mm, r.truth.camera.model, options);
  ASSERT_TRUE(capped.usable) << capped.brief;
  ASSERT_TRUE(all.usable) << all.brief;
  const int cap = RegisterTilesOptions().max_matches_per_pair;
  int num_at_cap = 0;
  for (const PairRegistration& pair : capped.pairs) {
    EXPECT_LE(pair.num_matched, cap) << pair.tile_a << "-" << pair.tile_b;
    num_at_cap += pair.num_matched == cap;
  }
  EXPECT_EQ(num_at_cap, static_cast<int>(capped.pairs.size()));  // rich texture: every pair
  const auto views_per_track = [](const TileRegistration& reg) {
    return static_cast<double>(reg.input.observations.size()) / reg.input.num_tracks;
  };
  std::printf("views per track %.3f capped, %.3f with every candidate\n", views_per_track(capped),
              views_per_track(all));
  EXPECT_GT(views_per_track(capped), 0.97 * views_per_track(all));
  const Scores c = Score(r, capped), a = Score(r, all);
  EXPECT_LT(c.hole_rms_px, a.hole_rms_px + 0.002);
  EXPECT_LT(c.table_rms_mm, a.table_rms_mm + 0.0005);
}
#endif

#ifdef OMM_TEST_SCREENING
// The screening solves stop early (screening_function_tolerance); a scene
// one leaves is solved in full before it is returned. Nothing is dropped or
// relocated here, so the first, screening solve would be the last; at a
// tolerance of 1e-2 it stops well short of the optimum, yet the result is
// the full solve's.
TEST(RegisterTiles, AScreeningSolveIsNeverTheLastOne) {
  const Rendered r = Render("demo-1");
  RegisterTilesOptions options;
  options.outlier_factor = 1e9;
  options.rematch_passes = 0;
  options.compute_covariance = false;
  options.screening_function_tolerance = 0.0;
  const TileRegistration full =
      RegisterTiles(r.tiles, r.commanded_mm, r.truth.table_sigma_mm, r.truth.camera.model, options);
  options.screening_function_tolerance = 1e-2;
  const TileRegistration screened =
      RegisterTiles(r.tiles, r.commanded_mm, r.truth.table_sigma_mm, r.truth.camera.model, options);
  ASSERT_TRUE(full.usable) << full.brief;
  ASSERT_TRUE(screened.usable) << screened.brief;
  EXPECT_EQ(full.num_dropped_observations, 0);
  ASSERT_EQ(full.scene.table_pos_mm.size(), screened.scene.table_pos_mm.size());
  double largest_mm = 0.0;
  for (size_t i = 0; i < full.scene.table_pos_mm.size(); ++i) {
    largest_mm = std::max(largest_mm,
                          (full.scene.table_pos_mm[i] - screened.scene.table_pos_mm[i]).norm());
  }
  EXPECT_LT(largest_mm, 1e-7);
}
#endif

#ifdef OMM_TEST_WEAK_TILE
// low-texture seed 12: tile 8's overlaps are faint texture and the part's
// edge; its probe templates correlate well with their surroundings (smooth)
// but no pair reaches min_pair_matches. The rule: such a tile is held
// by its table prior alone and the brief says so; the others register.
TEST(RegisterTiles, AWeaklyTexturedTileIsHeldByItsPriorAndReported) {
  const Rendered r = Render("low-texture-12");
  const TileRegistration reg = Register(r);
  const Scores s = Score(r, reg);
  ASSERT_TRUE(reg.usable) << reg.brief;
  EXPECT_EQ(reg.tiles_held_by_prior, std::vector<int>{8});
  EXPECT_NE(reg.brief.find("held by the table prior alone: tile 8"), std::string::npos);
  // Held: where table.csv put it. The others: better than commanded.
  EXPECT_LT((reg.scene.table_pos_mm[8] - r.commanded_mm[8]).norm(), 1e-3);
  std::vector<Eigen::Vector2d> adjusted, actual;
  for (int i = 0; i < 8; ++i) {
    adjusted.push_back(reg.scene.table_pos_mm[i]);
    actual.push_back(r.truth.tiles[i].actual_mm);
  }
  std::vector<Eigen::Vector2d> d;
  for (int i = 0; i < 8; ++i) d.push_back(adjusted[i] - actual[i]);
  EXPECT_LT(Rms(d) / std::sqrt(2.0), r.truth.table_sigma_mm);
  EXPECT_GT(s.num_hole_sightings, 10);
}
#endif

#ifdef OMM_TEST_EXPOSURE_HARRIS
// Harris "on images corrected for exposure differences": on the exposure
// preset (gains 0.6-1.15, vignetting 0.1-0.45 per tile) the corners that
// RegisterTiles detects (NormalizeTileIntensity, the matching blur, Harris)
// repeat between overlapping tiles as often as on tiles divided by their
// exact flat field g (1 - v rho^2) from the truth. Repeated: a corner of
// tile a whose true position in tile b has a corner of b within 1.5 px.
// Measured 69.5 % both ways (demo: 70.1 %); the raw tiles keep 896 corners
// instead of ~10500 (the texture test's threshold is in normalised units).
TEST(RegisterTiles, ExposureNormalisedCornersRepeatAsWithTheTrueFlatField) {
  const Rendered r = Render("exposure-1");
  const CameraModel& camera = r.truth.camera.model;
  const Eigen::Vector2d centre(camera.intrinsics[2], camera.intrinsics[3]);
  double corner_radius = 0;  // the simulator's rho = 1
  for (const Eigen::Vector2d& c : {Eigen::Vector2d(0, 0), Eigen::Vector2d(camera.width_px - 1, 0),
                                   Eigen::Vector2d(0, camera.height_px - 1),
                                   Eigen::Vector2d(camera.width_px - 1, camera.height_px - 1)})
    corner_radius = std::max(corner_radius, (c - centre).norm());
  const RegisterTilesOptions options;
  const auto detect = [&](bool flat_field) {
    std::vector<std::vector<Corner>> corners;
    for (size_t i = 0; i < r.tiles.size(); ++i) {
      ImageF tile = r.tiles[i];
      if (flat_field) {
        const ExposureTruth& e = r.truth.tiles[i].exposure;
        for (int y = 0; y < tile.rows(); ++y)
          for (int x = 0; x < tile.cols(); ++x)
            tile(y, x) /= static_cast<float>(
                e.gain * (1 - e.vignetting * (Eigen::Vector2d(x, y) - centre).squaredNorm() /
                                  (corner_radius * corner_radius)));
      }
      corners.push_back(DetectHarrisCorners(
          GaussianBlur(NormalizeTileIntensity(tile), options.matching_blur_sigma_px),
          options.harris));
    }
    return corners;
  };
  // Over the 12 neighbour pairs both ways: (corners in the overlaps, repeated).
  const auto repeatability = [&](const std::vector<std::vector<Corner>>& corners) {
    int total = 0, repeated = 0;
    for (int a = 0; a < 9; ++a) {
      for (int b = 0; b < 9; ++b) {
        const int d = std::abs(a - b);
        if (!((d == 1 && a / 3 == b / 3) || d == 3)) continue;
        for (const Corner& c : corners[a]) {
          const Eigen::Vector2d q =
              PixelOf(camera, TruthPose(r.truth, b),
                      PartAtPixel(camera, TruthPose(r.truth, a), c.pixel.cast<double>()));
          if (q.x() < 40 || q.y() < 40 || q.x() > camera.width_px - 41 ||
              q.y() > camera.height_px - 41)
            continue;
          ++total;
          repeated += std::any_of(corners[b].begin(), corners[b].end(), [&](const Corner& o) {
            return (o.pixel.cast<double>() - q).norm() < 1.5;
          });
        }
      }
    }
    return std::make_pair(total, repeated);
  };
  const auto [total, repeated] = repeatability(detect(false));
  const auto [flat_total, flat_repeated] = repeatability(detect(true));
  std::printf("normalised: %d of %d corners repeated; true flat field: %d of %d\n", repeated, total,
              flat_repeated, flat_total);
  // As many corners, as repeatable: within 1 % (~100 corners, ~10x the
  // counts' own scatter between pairs of tiles).
  EXPECT_GT(total, 0.99 * flat_total);
  EXPECT_GT(static_cast<double>(repeated) / total,
            static_cast<double>(flat_repeated) / flat_total - 0.01);
}
#endif

#ifdef OMM_TEST_SIFT
// COLMAP's SIFT as the only feature source, for real: the installed colmap
// (CPU) extracts and matches SIFT on the demo's tile files, and its verified
// matches' keypoints anchor the templates. All tiles and pairs must register
// as with Harris: the matches are template matches either way (the
// demo's bound, 0.03 px per axis), and the holes within the goal,
// 0.05 raw px (with Harris 0.027: the table prior's scale floor dominates).
TEST(RegisterTiles, SiftOnlyRegistersTheDemo) {
  const Rendered r = Render("demo-1");
  std::vector<std::filesystem::path> paths;
  for (const TileTruth& tile : r.truth.tiles) paths.push_back(r.project_dir / "tiles" / tile.image);
  ColmapSiftOptions sift_options;
  const ColmapSiftResult sift = ColmapSiftMatches(paths, sift_options);
  std::printf("%s\n", sift.brief.c_str());
  ASSERT_TRUE(sift.usable) << sift.brief;
  RegisterTilesOptions options;
  options.features = FeatureSource::kSift;
  const TileRegistration reg = RegisterTiles(r.tiles, r.commanded_mm, r.truth.table_sigma_mm,
                                             r.truth.camera.model, options, sift.matches.pairs);
  ASSERT_TRUE(reg.usable) << reg.brief;
  EXPECT_TRUE(reg.tiles_held_by_prior.empty()) << reg.brief;
  const Scores s = Score(r, reg);
  for (const PairRegistration& pair : reg.pairs) {
    EXPECT_TRUE(pair.usable) << pair.tile_a << "-" << pair.tile_b;
    EXPECT_EQ(pair.num_sift, pair.num_inliers);  // no Harris corner among them
  }
  EXPECT_LT(s.match_rms_px, 0.03);
  EXPECT_LT(s.table_rms_mm, r.truth.table_sigma_mm);
  EXPECT_LT(s.hole_rms_px, 0.05);
}
#endif


#ifdef OMM_TEST_BORE_WALL
// low-texture seed 104: the texture is too weak for Harris, so every kept
// template overlaps a hole, where the bore wall and the table seen through
// it move with the parallax (up to thickness x off-axis / height, tens of px
// between tiles); the rim's own edge profile changes with the wall band
// beside it. Plain least squares followed that content: matches 0.39
// px/axis from the truth, holes 0.19 raw px. Tukey's biweight on the
// template's pixels (PatchMatchOptions::robust_tukey_c) measured 0.133 and
// 0.060: at least halved, asserted below with the robust run's own bounds
// ~15 % above what it measured (0.134 and 0.065 before the matches were
// weighted by their covariance's shape).
TEST(RegisterTiles, RobustTemplateWeightsKeepTheBoreWallFromBiasingRimMatches) {
  const Rendered r = Render("low-texture-104");
  RegisterTilesOptions plain;
  plain.patch.robust_tukey_c = 0;
  const TileRegistration plain_reg = RegisterTiles(r.tiles, r.commanded_mm, r.truth.table_sigma_mm,
                                                   r.truth.camera.model, plain);
  const TileRegistration reg = Register(r);
  ASSERT_TRUE(plain_reg.usable) << plain_reg.brief;
  ASSERT_TRUE(reg.usable) << reg.brief;
  EXPECT_TRUE(reg.tiles_held_by_prior.empty()) << reg.brief;
  const Scores p = Score(r, plain_reg), s = Score(r, reg);
  // Nearly as many template matches pass the plane screening as without
  // the weights: the reweighting costs at most 1 % of them (463 and 459 with
  // the first-order warp; 472 and 475 with the second-order one, which
  // gained the plain run more). (The outlier passes then keep fewer of the
  // plain run's: their threshold follows the median residual.)
  const auto inliers = [](const TileRegistration& g) {
    int n = 0;
    for (const PairRegistration& pair : g.pairs) n += pair.num_inliers;
    return n;
  };
  EXPECT_GE(inliers(reg), 0.99 * inliers(plain_reg));
  EXPECT_LT(s.match_rms_px, 0.5 * p.match_rms_px);
  EXPECT_LT(s.match_rms_px, 0.155);
  EXPECT_GT(s.num_hole_sightings, 10);
  EXPECT_LT(s.hole_rms_px, 0.5 * p.hole_rms_px);
  EXPECT_LT(s.hole_rms_px, 0.075);
  EXPECT_LT(s.table_rms_mm, r.truth.table_sigma_mm);
}

// The adjusted table positions against the truth's after a similarity fit
// (the scale is the table prior's, the same for every preset): what the
// matches between the tiles put right, raw px RMS over the tiles.
double TableSimilarityRmsRawPx(const SimulationTruth& truth, const TileRegistration& reg) {
  const int n = static_cast<int>(truth.tiles.size());
  Eigen::MatrixXd actual(2, n), adjusted(2, n);  // dynamic: GCC 12 misreads umeyama's fixed sizes
  for (int i = 0; i < n; ++i) {
    actual.col(i) = truth.tiles[i].actual_mm;
    adjusted.col(i) = reg.scene.table_pos_mm[i];
  }
  const Eigen::MatrixXd fit = Eigen::umeyama(actual, adjusted, true);
  const Eigen::MatrixXd residual =
      adjusted - ((fit.topLeftCorner(2, 2) * actual).colwise() + fit.topRightCorner(2, 1).col(0));
  const double mm_per_px = truth.cam_from_part.translation().z() / truth.camera.model.intrinsics(0);
  return std::sqrt(residual.colwise().squaredNorm().mean()) / mm_per_px;
}

// Nearly every low-texture match lies on a hole's rim, which locates it
// across the rim (0.03-0.08 px from the truth) far better than along it
// (0.09-0.17 px; seeds 101-105). Weighted isotropically, the matches along
// the rims left the tiles 0.035 (seed 102) and 0.038 (seed 104) raw px from
// the truth after a similarity fit, against 0.001-0.004 on the richly
// textured presets; the weights shaped by each match's covariance
// (RegisterTilesOptions::weight_by_match_sigma) measured 0.0068 and 0.0210.
// Bounds ~20 % above those.
TEST(RegisterTiles, RimMatchesWeightedAcrossTheRimPlaceTheTiles) {
  for (const auto& [name, bound] : {std::pair<std::string, double>{"low-texture-102", 0.0085},
                                    std::pair<std::string, double>{"low-texture-104", 0.025}}) {
    const Rendered r = Render(name);
    const TileRegistration reg = Register(r);
    ASSERT_TRUE(reg.usable) << reg.brief;
    EXPECT_TRUE(reg.tiles_held_by_prior.empty()) << reg.brief;
    const double rms = TableSimilarityRmsRawPx(r.truth, reg);
    std::printf("%s: tiles %.4f raw px from the truth after a similarity fit\n", name.c_str(), rms);
    EXPECT_LT(rms, bound) << name;
  }
}
#endif

#ifdef OMM_TEST_RESCUE
// Weak texture where the coarse probes find too few of a pair's motion
// (template matches need 8 probe inliers): low-texture-exposure seed 203
// leaves tile 8 without a usable pair (held by its table prior), seed 207 of
// low-texture keeps all tiles on 11 of 20 pairs, some tiles hanging on one.
// Matched again after the first adjustment, each candidate predicted by the
// adjusted scene (rescue_unusable_pairs), those pairs register: the holes
// within the 0.05 raw px, which neither reaches without.
TEST(RegisterTiles, PairsTheProbesMissAreMatchedOnTheAdjustedScene) {
  for (const char* name : {"low-texture-exposure-203", "low-texture-207"}) {
    const Rendered r = Render(name);
    RegisterTilesOptions without;
    without.rescue_unusable_pairs = false;
    const TileRegistration before = RegisterTiles(r.tiles, r.commanded_mm, r.truth.table_sigma_mm,
                                                  r.truth.camera.model, without);
    const TileRegistration reg = Register(r);
    ASSERT_TRUE(before.usable) << before.brief;
    ASSERT_TRUE(reg.usable) << reg.brief;
    const Scores b = Score(r, before), s = Score(r, reg);
    EXPECT_GT(b.hole_rms_px, 0.05) << name;
    EXPECT_LT(s.hole_rms_px, 0.05) << name;
    EXPECT_LT(s.table_rms_mm, r.truth.table_sigma_mm) << name;
    EXPECT_TRUE(reg.tiles_held_by_prior.empty()) << reg.brief;
    int num_rescued = 0;
    for (const PairRegistration& pair : reg.pairs) {
      if (!pair.rescued) continue;
      ++num_rescued;
      EXPECT_TRUE(pair.usable);
    }
    EXPECT_GT(num_rescued, 0) << name;
  }
}
#endif

#ifdef OMM_TEST_PRESETS
// Three binaries of two cached projects each: OMM_TEST_PRESETS names them.
INSTANTIATE_TEST_SUITE_P(Presets, RegisterTilesPreset, ::testing::Values(OMM_TEST_PRESETS),
                         [](const ::testing::TestParamInfo<std::string>& param) {
                           std::string name = param.param;
                           std::erase(name, '-');
                           return name;
                         });
#else
GTEST_ALLOW_UNINSTANTIATED_PARAMETERIZED_TEST(RegisterTilesPreset);
#endif

}  // namespace
}  // namespace omm
