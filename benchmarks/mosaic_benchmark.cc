// The mosaic stage on the simulated demo's nine 1600 x 1200 tiles (seed 1)
// beside OpenCV's cv::Stitcher in SCANS mode on the same tiles
// (adapters/opencv/opencv_stitcher.h), timed and scored against the truth.
//
// - omm: RegisterTiles (features, matching, planar bundle adjustment with the
//   table prior; the true camera stands in for the calibration) and
//   Orthorectify at the project's gsd, 2 threads each.
// - OpenCV: cv::Stitcher::create(SCANS)->stitch, 2 threads.
// Accuracy, the same way for both once a hole's rough place is known (omm's
// mosaic: the truth through its grid; the Stitcher's panorama: normalised
// cross-correlation with a patch around the hole from the tile where it is
// most central): its top rim fitted (tests/rim_locator.h); a
// similarity (scale free: the Stitcher's panorama has no metric scale) and,
// for omm's mosaic, a rigid transform are fitted from the found centres to
// the truth. Counters: RMS in raw-pixel equivalents (raw px = pixel pitch *
// distance / focal length, ~0.146 mm), holes found, wall and CPU seconds.
// The locator's own floor on these textured rims is ~0.05 raw px
// (mosaic_stage_test.cc measures it in a mosaic built from the true scene).
//
// The tiles come from the tests' render cache (tests/sim_cache.h:
// build/sim-cache/demo-1, rendered on first use).
#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "adapters/mrcal/lens.h"
#include "adapters/opencv/image_io.h"
#include "adapters/opencv/opencv_stitcher.h"
#include "adapters/project_io/project_reader.h"
#include "pipeline/core/timing.h"
#include "pipeline/mosaic/orthorectify.h"
#include "pipeline/mosaic/register_tiles.h"
#include "tests/rim_locator.h"
#include "tests/sim_cache.h"

namespace omm {
namespace {

constexpr int kThreads = 2;

// The demo project (seed 1) from the tests' render cache (tests/sim_cache.h).
struct Demo {
  SimulationTruth truth;
  double mosaic_gsd_mm = 0.0;
  std::vector<ImageF> tiles;
};

const Demo& GetDemo() {
  static const Demo demo = [] {
    const testing::CachedProject cached = testing::SimulatedProject("demo", 1);
    Demo d;
    d.truth = cached.truth;
    d.mosaic_gsd_mm = LoadProject(cached.project_dir).mosaic_gsd_mm;
    for (const TileTruth& tile : d.truth.tiles)
      d.tiles.push_back(ReadGrayImage(cached.project_dir / "tiles" / tile.image).pixels);
    return d;
  }();
  return demo;
}



// A raw pixel's size on the part, mm.
double RawPxMm(const SimulationTruth& truth) {
  const Eigen::Isometry3d part_from_cam = truth.cam_from_part.inverse();
  const double distance_mm = part_from_cam.translation().z() / -part_from_cam.linear().col(2).z();
  return truth.camera.pixel_pitch_um * 1e-3 * distance_mm / truth.camera.focal_length_mm;
}

struct HoleScore {
  int num_found = 0;
  double similarity_rms_raw_px = 0.0;
  double rigid_rms_raw_px = 0.0;       // image px * gsd_mm: meaningful for a metric mosaic only
  double scale = 0.0;                  // of the similarity, mm per image px
  double similarity_max_raw_px = 0.0;  // largest residual of the similarity fit
};

// The rim of each true hole in `image` near rough_px[k] (NaN: not sought),
// scored against the truth; `gsd_mm` (mm per image px, nominal for the
// Stitcher) sizes the rims and converts px to mm for the rigid fit.
HoleScore ScoreHoles(const SimulationTruth& truth, const ImageF& image, double gsd_mm,
                     const std::vector<Eigen::Vector2d>& rough_px) {
  std::vector<Eigen::Vector2d> found_px, truth_mm;
  for (size_t k = 0; k < truth.holes.size(); ++k) {
    if (!rough_px[k].allFinite()) continue;
    const double radius_px = 0.5 * truth.holes[k].diameter_mm / gsd_mm;
    testing::RimLocatorOptions coarse;
    coarse.window_px = std::max(4.0, 0.2 * radius_px);
    const testing::RimFit first = testing::LocateDarkDiscRim(image, rough_px[k], radius_px, coarse);
    if (!first.ok) continue;
    const testing::RimFit second =
        testing::LocateDarkDiscRim(image, first.centre_px, first.radius_px);
    if (!second.ok) continue;
    testing::RimLocatorOptions fine;
    fine.window_px = 1.5;
    const testing::RimFit fit =
        testing::LocateDarkDiscRim(image, second.centre_px, second.radius_px, fine);
    if (!fit.ok) continue;
    found_px.push_back(fit.centre_px);
    truth_mm.push_back(truth.holes[k].center_part_mm);
  }
  HoleScore score;
  score.num_found = static_cast<int>(found_px.size());
  if (score.num_found < 3) return score;
  Eigen::Matrix2Xd from(2, score.num_found), from_mm(2, score.num_found), to(2, score.num_found);
  for (int k = 0; k < score.num_found; ++k) {
    // Image rows run along -Y (project-format.md): flip before fitting.
    from.col(k) = Eigen::Vector2d(found_px[k].x(), -found_px[k].y());
    from_mm.col(k) = gsd_mm * from.col(k);
    to.col(k) = truth_mm[k];
  }
  const double raw_px_mm = RawPxMm(truth);
  const testing::Planar2dFit similarity = testing::FitPlanar2d(from, to, true);
  score.similarity_rms_raw_px = similarity.rms / raw_px_mm;
  score.scale = similarity.scale;
  score.similarity_max_raw_px = similarity.residual.maxCoeff() / raw_px_mm;
  score.rigid_rms_raw_px = testing::FitPlanar2d(from_mm, to, false).rms / raw_px_mm;
  return score;
}

// Rough hole positions in omm's mosaic: the truth through the mosaic's grid,
// moved by the pipeline's origin gauge (the part point on the camera's axis
// with the table at 0, plane_scene.h); the rigid fit removes what is left.
std::vector<Eigen::Vector2d> RoughInMosaic(const SimulationTruth& truth, const OrthoGrid& grid) {
  const Eigen::Isometry3d part_from_cam = truth.cam_from_part.inverse();
  const Eigen::Vector3d c = part_from_cam.translation();
  const Eigen::Vector3d axis = part_from_cam.linear().col(2);
  const Eigen::Vector2d origin_mm = (c - c.z() / axis.z() * axis).head<2>();
  std::vector<Eigen::Vector2d> rough;
  for (const HoleTruth& hole : truth.holes) {
    rough.push_back(grid.MosaicFromPart(hole.center_part_mm - origin_mm));
  }
  return rough;
}

// Rough hole positions in the Stitcher's panorama (which keeps the tiles'
// orientation and roughly their scale): a patch around the hole from the
// tile where it is most central, found by normalised cross-correlation;
// matches below 0.7 or off a similarity fitted to the others by more than
// 10 raw px are mismatches, and those holes are predicted by that similarity.
std::vector<Eigen::Vector2d> RoughInPanorama(const Demo& demo, const ImageF& panorama) {
  const SimulationTruth& truth = demo.truth;
  const CameraModel& camera = truth.camera.model;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::vector<Eigen::Vector2d> rough(truth.holes.size(), Eigen::Vector2d(nan, nan));
  std::vector<int> matched;
  for (size_t k = 0; k < truth.holes.size(); ++k) {
    const HoleTruth& hole = truth.holes[k];
    int best_tile = -1;
    double best_margin = 0.0;
    Eigen::Vector2d best_q;
    for (size_t i = 0; i < truth.tiles.size(); ++i) {
      const Eigen::Vector3d p(hole.center_part_mm.x() + truth.tiles[i].actual_mm.x(),
                              hole.center_part_mm.y() + truth.tiles[i].actual_mm.y(), 0.0);
      Eigen::Matrix2Xd q;
      if (!ProjectPoints(camera, truth.cam_from_part * p, &q)) continue;
      const double margin = std::min(std::min(q(0, 0), camera.width_px - 1 - q(0, 0)),
                                     std::min(q(1, 0), camera.height_px - 1 - q(1, 0)));
      if (margin > best_margin) {
        best_margin = margin;
        best_tile = static_cast<int>(i);
        best_q = q.col(0);
      }
    }
    const double radius_px = 0.5 * hole.diameter_mm / RawPxMm(truth);
    const int half = static_cast<int>(std::ceil(1.4 * radius_px)) + 40;
    if (best_tile < 0 || best_margin < half + 1) continue;
    const int c0 = static_cast<int>(std::lround(best_q.x())) - half;
    const int r0 = static_cast<int>(std::lround(best_q.y())) - half;
    const ImageF patch = demo.tiles[best_tile].block(r0, c0, 2 * half + 1, 2 * half + 1);
    if (patch.rows() >= panorama.rows() || patch.cols() >= panorama.cols()) continue;
    double ncc = 0.0;
    const Eigen::Vector2d at = FindPatch(panorama, patch, &ncc);
    if (ncc < 0.7) continue;
    rough[k] = at + (best_q - Eigen::Vector2d(c0 + half, r0 + half));
    matched.push_back(static_cast<int>(k));
  }
  const double raw_px_mm = RawPxMm(truth);
  while (matched.size() >= 3) {
    Eigen::Matrix2Xd from(2, matched.size()), to(2, matched.size());
    for (size_t m = 0; m < matched.size(); ++m) {
      from.col(static_cast<Eigen::Index>(m)) = truth.holes[matched[m]].center_part_mm;
      to.col(static_cast<Eigen::Index>(m)) =
          Eigen::Vector2d(rough[matched[m]].x(), -rough[matched[m]].y());
    }
    const testing::Planar2dFit fit = testing::FitPlanar2d(from, to, true);
    Eigen::Index worst = 0;
    const double worst_px = fit.residual.maxCoeff(&worst);
    if (worst_px * raw_px_mm / fit.scale > 10 * raw_px_mm && matched.size() > 3) {
      matched.erase(matched.begin() + worst);
      continue;
    }
    const Eigen::Matrix2d rotation = Eigen::Rotation2Dd(fit.angle_rad).toRotationMatrix();
    for (size_t k = 0; k < truth.holes.size(); ++k) {
      if (std::find(matched.begin(), matched.end(), static_cast<int>(k)) != matched.end()) continue;
      const Eigen::Vector2d p = fit.scale * rotation * truth.holes[k].center_part_mm + fit.t;
      rough[k] = Eigen::Vector2d(p.x(), -p.y());
    }
    break;
  }
  return rough;
}

void BM_OmmMosaic(benchmark::State& state) {
  const Demo& demo = GetDemo();
  const SimulationTruth& truth = demo.truth;
  std::vector<Eigen::Vector2d> commanded_mm;
  for (const TileTruth& tile : truth.tiles) commanded_mm.push_back(tile.commanded_mm);
  RegisterTilesOptions register_options;
  register_options.num_threads = kThreads;
  OrthoOptions ortho_options;
  ortho_options.gsd_mm = demo.mosaic_gsd_mm;
  ortho_options.num_threads = kThreads;
  OrthoResult ortho;
  double register_s = 0.0, ortho_s = 0.0, cpu_s = 0.0;
  for (auto _ : state) {
    const double cpu0 = ProcessCpuSeconds();
    auto t0 = std::chrono::steady_clock::now();
    const TileRegistration registration = RegisterTiles(
        demo.tiles, commanded_mm, truth.table_sigma_mm, truth.camera.model, register_options);
    register_s = SecondsSince(t0);
    t0 = std::chrono::steady_clock::now();
    ortho = Orthorectify(truth.camera.model, registration.scene, demo.tiles, ortho_options);
    ortho_s = SecondsSince(t0);
    cpu_s = ProcessCpuSeconds() - cpu0;
    if (!registration.usable) state.SkipWithError(registration.brief.c_str());
    std::printf("omm: %s\n%s\n", registration.brief.c_str(), ortho.summary.brief.c_str());
  }
  const HoleScore score = ScoreHoles(truth, ortho.mosaic.pixels, ortho.mosaic.grid.gsd_mm,
                                     RoughInMosaic(truth, ortho.mosaic.grid));
  state.counters["register_s"] = register_s;
  state.counters["ortho_s"] = ortho_s;
  state.counters["total_s"] = register_s + ortho_s;
  state.counters["cpu_s"] = cpu_s;
  state.counters["holes"] = score.num_found;
  state.counters["sim_rms_raw_px"] = score.similarity_rms_raw_px;
  state.counters["rigid_rms_raw_px"] = score.rigid_rms_raw_px;
  std::printf(
      "omm: %.2f s wall (register %.2f + ortho %.2f), %.2f CPU s; %d holes: "
      "similarity RMS %.4f raw px (max %.4f), rigid (metric) RMS %.4f raw px\n",
      register_s + ortho_s, register_s, ortho_s, cpu_s, score.num_found,
      score.similarity_rms_raw_px, score.similarity_max_raw_px, score.rigid_rms_raw_px);
}

void BM_OpenCvStitcherScans(benchmark::State& state) {
  const Demo& demo = GetDemo();
  OpenCvStitcherOptions options;
  options.num_threads = kThreads;
  OpenCvStitcherResult result;
  double cpu_s = 0.0;
  for (auto _ : state) {
    const double cpu0 = ProcessCpuSeconds();
    result = StitchScans(demo.tiles, options);
    cpu_s = ProcessCpuSeconds() - cpu0;
    if (!result.ok) state.SkipWithError(result.status.c_str());
  }
  if (!result.ok) return;
  // The panorama's scale is unknown: the rough hole radius assumes ~ the tiles' own.
  const HoleScore score = ScoreHoles(demo.truth, result.panorama, RawPxMm(demo.truth),
                                     RoughInPanorama(demo, result.panorama));
  state.counters["total_s"] = result.seconds;
  state.counters["cpu_s"] = cpu_s;
  state.counters["tiles_used"] = result.tiles_used;
  state.counters["holes"] = score.num_found;
  state.counters["sim_rms_raw_px"] = score.similarity_rms_raw_px;
  std::printf(
      "cv::Stitcher SCANS: %.2f s wall, %.2f CPU s, panorama %ld x %ld px; %d holes: "
      "similarity RMS %.4f raw px, max %.4f (scale %.5f mm/px)\n",
      result.seconds, cpu_s, static_cast<long>(result.panorama.cols()),
      static_cast<long>(result.panorama.rows()), score.num_found, score.similarity_rms_raw_px,
      score.similarity_max_raw_px, score.scale);
}

BENCHMARK(BM_OmmMosaic)->Iterations(1)->Unit(benchmark::kSecond)->UseRealTime();
BENCHMARK(BM_OpenCvStitcherScans)->Iterations(1)->Unit(benchmark::kSecond)->UseRealTime();

}  // namespace
}  // namespace omm

BENCHMARK_MAIN();
