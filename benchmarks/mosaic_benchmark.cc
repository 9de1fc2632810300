// The mosaic stage on the simulated demo's nine 1600 x 1200 tiles (seed 1)
// beside OpenCV's cv::Stitcher in SCANS mode on the same tiles
// (adapters/opencv/opencv_stitcher.h), timed and scored against the truth.
//
// - omm: RegisterTiles (features, matching, planar bundle adjustment with the
//   table prior; the true camera stands in for the calibration) and
//   Orthorectify at the project's gsd, 2 threads each.
// - OpenCV: cv::Stitcher::create(SCANS)->stitch, 2 threads.
// Accuracy, the same way for both: each true hole is found in the result by
// normalised cross-correlation with a patch around it from the tile where it
// is most central, then its top rim fitted (tests/rim_locator.h); a
// similarity (scale free: the Stitcher's panorama has no metric scale) and,
// for omm's mosaic, a rigid transform are fitted from the found centres to
// the truth. Counters: RMS in raw-pixel equivalents (raw px = pixel pitch *
// distance / focal length, ~0.146 mm), holes found, wall and CPU seconds.
// The locator's own floor on these textured rims is ~0.05 raw px
// (mosaic_stage_test.cc measures it in a mosaic built from the true scene).
//
// The tiles are rendered once and cached as PNG in $OMM_BENCHMARK_CACHE
// (default /tmp/omm_benchmark_cache). Delete the cache after changing the
// simulator.
#include <benchmark/benchmark.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "adapters/mrcal/lens.h"
#include "adapters/opencv/image_io.h"
#include "adapters/opencv/opencv_stitcher.h"
#include "pipeline/mosaic/orthorectify.h"
#include "pipeline/mosaic/register_tiles.h"
#include "pipeline/simulate/simulation.h"
#include "tests/rim_locator.h"

namespace omm {
namespace {

constexpr int kThreads = 2;

struct Demo {
  SimulationPlan plan;
  std::vector<ImageF> tiles;
};

const Demo& GetDemo() {
  static const Demo demo = [] {
    Demo d;
    SimulationOptions options;
    options.seed = 1;
    options.preset = "demo";
    d.plan = PlanSimulation(options);
    const char* env = std::getenv("OMM_BENCHMARK_CACHE");
    const std::filesystem::path dir =
        std::filesystem::path(env ? env : "/tmp/omm_benchmark_cache") / "demo_seed1";
    std::filesystem::create_directories(dir);
    const CameraModel& camera = d.plan.truth.camera.model;
    std::unique_ptr<RayTable> rays;
    std::unique_ptr<ProjectRenderer> renderer;
    for (size_t i = 0; i < d.plan.truth.tiles.size(); ++i) {
      const std::filesystem::path path = dir / d.plan.truth.tiles[i].image;
      if (!std::filesystem::exists(path)) {
        if (!rays) {
          RayTableSummary summary;
          rays = std::make_unique<RayTable>(
              ComputeRayTable(camera, PixelRect{0, 0, camera.width_px, camera.height_px},
                              RayOptionsFor(d.plan.options), &summary));
          renderer = std::make_unique<ProjectRenderer>(d.plan);
        }
        WriteGrayImage(path, renderer->RenderTile(static_cast<int>(i), *rays),
                       d.plan.sensor.bit_depth);
      }
      d.tiles.push_back(ReadGrayImage(path).pixels);
    }
    return d;
  }();
  return demo;
}

double ProcessCpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

// A raw pixel's size on the part, mm.
double RawPxMm(const SimulationTruth& truth) {
  const Eigen::Isometry3d part_from_cam = truth.cam_from_part.inverse();
  const double distance_mm =
      part_from_cam.translation().z() / -part_from_cam.linear().col(2).z();
  return truth.camera.pixel_pitch_um * 1e-3 * distance_mm / truth.camera.focal_length_mm;
}

struct HoleScore {
  int num_found = 0;
  double similarity_rms_raw_px = 0.0;
  double rigid_rms_raw_px = 0.0;  // in image px * gsd_mm: meaningful for a metric mosaic only
  double scale = 0.0;             // of the similarity, mm per image px
};

// The true holes found in `image` (see the header comment) and scored;
// `gsd_mm` converts image px to mm for the rigid fit.
HoleScore ScoreHoles(const Demo& demo, const ImageF& image, double gsd_mm) {
  const SimulationTruth& truth = demo.plan.truth;
  const CameraModel& camera = truth.camera.model;
  std::vector<Eigen::Vector2d> found_px, truth_mm;
  for (const HoleTruth& hole : truth.holes) {
    // The tile where the hole's centre is farthest from the border.
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
    const int half = static_cast<int>(std::ceil(1.4 * radius_px));
    if (best_tile < 0 || best_margin < half + 1) continue;
    const int c0 = static_cast<int>(std::lround(best_q.x())) - half;
    const int r0 = static_cast<int>(std::lround(best_q.y())) - half;
    const ImageF patch = demo.tiles[best_tile].block(r0, c0, 2 * half + 1, 2 * half + 1);
    if (patch.rows() >= image.rows() || patch.cols() >= image.cols()) continue;
    const Eigen::Vector2d rough =
        FindPatch(image, patch) + (best_q - Eigen::Vector2d(c0 + half, r0 + half));
    const double radius_image_px = 0.5 * hole.diameter_mm / gsd_mm;
    testing::RimLocatorOptions coarse;
    coarse.window_px = std::max(4.0, 0.2 * radius_image_px);
    const testing::RimFit first = testing::LocateDarkDiscRim(image, rough, radius_image_px, coarse);
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
    truth_mm.push_back(hole.center_part_mm);
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
  score.rigid_rms_raw_px = testing::FitPlanar2d(from_mm, to, false).rms / raw_px_mm;
  return score;
}

void BM_OmmMosaic(benchmark::State& state) {
  const Demo& demo = GetDemo();
  const SimulationTruth& truth = demo.plan.truth;
  std::vector<Eigen::Vector2d> commanded_mm;
  for (const TileTruth& tile : truth.tiles) commanded_mm.push_back(tile.commanded_mm);
  RegisterTilesOptions register_options;
  register_options.num_threads = kThreads;
  OrthoOptions ortho_options;
  ortho_options.gsd_mm = demo.plan.project.mosaic_gsd_mm;
  ortho_options.num_threads = kThreads;
  OrthoResult ortho;
  double register_s = 0.0, ortho_s = 0.0, cpu_s = 0.0;
  for (auto _ : state) {
    const double cpu0 = ProcessCpuSeconds();
    auto t0 = std::chrono::steady_clock::now();
    const TileRegistration registration = RegisterTiles(
        demo.tiles, commanded_mm, truth.table_sigma_mm, truth.camera.model, register_options);
    register_s = Seconds(t0);
    t0 = std::chrono::steady_clock::now();
    ortho = Orthorectify(truth.camera.model, registration.scene, demo.tiles, ortho_options);
    ortho_s = Seconds(t0);
    cpu_s = ProcessCpuSeconds() - cpu0;
    if (!registration.usable) state.SkipWithError(registration.brief.c_str());
    std::printf("omm: %s\n%s\n", registration.brief.c_str(), ortho.summary.brief.c_str());
  }
  const HoleScore score = ScoreHoles(demo, ortho.mosaic.pixels, ortho.mosaic.grid.gsd_mm);
  state.counters["register_s"] = register_s;
  state.counters["ortho_s"] = ortho_s;
  state.counters["total_s"] = register_s + ortho_s;
  state.counters["cpu_s"] = cpu_s;
  state.counters["holes"] = score.num_found;
  state.counters["sim_rms_raw_px"] = score.similarity_rms_raw_px;
  state.counters["rigid_rms_raw_px"] = score.rigid_rms_raw_px;
  std::printf("omm: %.2f s wall (register %.2f + ortho %.2f), %.2f CPU s; %d holes: "
              "similarity RMS %.4f raw px, rigid (metric) RMS %.4f raw px\n",
              register_s + ortho_s, register_s, ortho_s, cpu_s, score.num_found,
              score.similarity_rms_raw_px, score.rigid_rms_raw_px);
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
  const HoleScore score = ScoreHoles(demo, result.panorama, RawPxMm(demo.plan.truth));
  state.counters["total_s"] = result.seconds;
  state.counters["cpu_s"] = cpu_s;
  state.counters["holes"] = score.num_found;
  state.counters["sim_rms_raw_px"] = score.similarity_rms_raw_px;
  std::printf("cv::Stitcher SCANS: %.2f s wall, %.2f CPU s, panorama %ld x %ld px; %d holes: "
              "similarity RMS %.4f raw px (scale %.5f mm/px)\n",
              result.seconds, cpu_s, static_cast<long>(result.panorama.cols()),
              static_cast<long>(result.panorama.rows()), score.num_found,
              score.similarity_rms_raw_px, score.scale);
}

BENCHMARK(BM_OmmMosaic)->Iterations(1)->Unit(benchmark::kSecond)->UseRealTime();
BENCHMARK(BM_OpenCvStitcherScans)->Iterations(1)->Unit(benchmark::kSecond)->UseRealTime();

}  // namespace
}  // namespace omm

BENCHMARK_MAIN();
