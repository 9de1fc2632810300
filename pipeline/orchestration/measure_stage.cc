// Runner of the measure stage (see stage.h): the mosaic, the adjusted scene
// (mosaic/scene.json) and project.yaml's features and measurements in;
// report.features and report.measurements out, each value with its 1-sigma
// and that sigma's breakdown by source (pipeline/measure/
// measurement_uncertainty.h), and the CMM comparison when cmm.csv is given.
//
// Each feature is looked for where its tile and near_px put it: the pixel is
// mapped onto the part through the adjusted scene, and that part point into
// the mosaic. A feature that is not found, cut by the mosaic's border or
// poorly fitted gets an error; the measurements that need it get an error
// naming it, the others are still made.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "adapters/mrcal/mrcal_lens_projection.h"
#include "adapters/opencv/image_io.h"
#include "adapters/project_io/scene_json.h"
#include "pipeline/core/error.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/core/timing.h"
#include "pipeline/measure/bore_view.h"
#include "pipeline/measure/circle_measure.h"
#include "pipeline/measure/measurement_uncertainty.h"
#include "pipeline/measure/scene_sensitivity.h"
#include "pipeline/mosaic/orthorectify.h"
#include "pipeline/orchestration/stage.h"

namespace omm {
namespace {

namespace fs = std::filesystem;

constexpr const char* kSceneName = "mosaic/scene.json";
// A deviation from the CMM beyond this many sigmas is flagged.
constexpr double kFlagSigmas = 3.0;

ReportValue Pair(const Eigen::Vector2d& v) { return ReportValue::Array{v.x(), v.y()}; }

ReportValue BreakdownReport(const SigmaBreakdown& sigma) {
  return ReportObject{{"calibration", sigma.calibration_mm},
                      {"registration", sigma.registration_mm},
                      {"edges", sigma.edges_mm}};
}

// A feature as found (or not), with what the measurements need of it.
struct LocatedFeature {
  FeatureReport report;
  std::optional<CircleFeatureValue> value;  // none if not found
  int value_index = -1;  // into the propagation's features; -1 if not found
};

// Hole fits run on this many threads (the 2-core machine the stages target).
constexpr int kNumThreads = 2;
// A hole is one tile's picture where the other tiles' blend weights sum to
// less than this: their ghost bottom rim is under the mosaic's noise.
constexpr double kMaxOtherTileWeight = 0.01;

// Pure in its inputs: features are located concurrently.
LocatedFeature LocateFeature(const FeatureSpec& spec, const SavedScene& saved,
                             const LensProjection& lens, const OrthoGrid& grid,
                             const ImageF& mosaic, const CameraModel& camera, double source_px) {
  LocatedFeature located;
  FeatureReport& report = located.report;
  report.name = spec.name;
  report.type = spec.type;
  const auto tile_it = std::find(saved.tile_images.begin(), saved.tile_images.end(), spec.image);
  if (tile_it == saved.tile_images.end()) {
    report.error = fmt::format("tile {} is not in the mosaic's scene", spec.image);
    return located;
  }
  const int tile = static_cast<int>(tile_it - saved.tile_images.begin());
  const auto near_part = PartPointOfTilePixel(lens, saved.scene, tile, spec.near_px);
  if (!near_part) {
    report.error = fmt::format("near_px [{}, {}] of {} does not map onto the part",
                               spec.near_px.x(), spec.near_px.y(), spec.image);
    return located;
  }
  const Eigen::Vector2d expected_px = grid.MosaicFromPart(*near_part);
  CircleMeasureOptions options;
  options.source_px = source_px;
  // The bore's bottom rim shows scaled about the nadir of the tile the
  // mosaic takes the hole from (bore_view.h); where tiles blend there are
  // two such rims and the kernel fits one free circle instead.
  const auto rendering =
      RenderingTile(lens, saved.scene, *near_part, 0.5 * spec.diameter_mm, camera.width_px,
                    camera.height_px, OrthoOptions{}.blend_band_px, kMaxOtherTileWeight);
  std::optional<Eigen::Vector2d> nadir_px;
  if (rendering) nadir_px = grid.MosaicFromPart(TileNadirMm(saved.scene, *rendering));
  const CircleMeasurement circle =
      MeasureCircle(mosaic, expected_px, 0.5 * spec.diameter_mm / grid.gsd_mm, options, nadir_px);
  report.extra = {{"expected_mosaic_px", Pair(expected_px)}, {"fit", circle.Brief()}};
  std::string bore = "no bore wall resolved";
  if (circle.bottom_rim_scale > 0.0) {
    bore = fmt::format(
        "bottom rim scaled by {:.4f} about {}'s nadir; wall too narrow on {} of {} wedges{}",
        circle.bottom_rim_scale, saved.tile_images[*rendering], circle.num_narrow_wall,
        circle.num_wedges, circle.narrow_wall_skipped ? ", left out" : "");
  } else if (circle.bottom_rim_modelled) {
    bore = nadir_px ? "bottom rim fitted free: its scale about the nadir did not settle"
                    : "tiles blend over the hole: bottom rim fitted free";
  }
  report.extra.emplace_back("bore", bore);
  if (!circle.ok) {
    report.error = circle.error;
    return located;
  }
  CircleFeatureValue value;
  value.centre_mm = grid.PartFromMosaic(circle.centre_px);
  value.diameter_mm = 2.0 * circle.radius_px * grid.gsd_mm;
  // (col, row, r) px -> (x, y, D) mm: x along +col, y along -row.
  const Eigen::Matrix3d to_mm =
      Eigen::Vector3d(grid.gsd_mm, -grid.gsd_mm, 2.0 * grid.gsd_mm).asDiagonal();
  value.edge_covariance = to_mm * circle.covariance_px2 * to_mm.transpose();
  const auto sensitivity =
      CircleSceneSensitivity(lens, saved.scene, value.centre_mm, value.diameter_mm, camera.width_px,
                             camera.height_px, OrthoOptions{}.blend_band_px);
  if (!sensitivity) {
    report.error = "the circle is not seen whole by the tiles";
    return located;
  }
  value.scene_sensitivity = *sensitivity;
  report.centre_mm = value.centre_mm;
  report.diameter_mm = value.diameter_mm;
  report.extra.emplace_back("mosaic_px", Pair(circle.centre_px));
  report.extra.emplace_back("radius_px", circle.radius_px);
  report.extra.emplace_back("edge_points", circle.num_edge_points);
  report.extra.emplace_back("inliers", circle.num_inliers);
  report.extra.emplace_back("rms_px", circle.rms_px);
  located.value = std::move(value);
  return located;
}

}  // namespace

void RunMeasureStage(StageContext& context) {
  const Project& project = context.project;
  const auto stage_start = std::chrono::steady_clock::now();
  if (!context.report.mosaic) {
    throw InputError((context.out_dir / "report.json").string(),
                     "no mosaic for these inputs: run `omm mosaic` (or `omm run`) first");
  }
  const MosaicReport& mosaic_report = *context.report.mosaic;
  const fs::path scene_path = context.Input(kSceneName);
  // This run's mosaic is in memory (its file may still be being written).
  const fs::path mosaic_path = context.mosaic ? context.staging_dir / mosaic_report.file
                                              : context.Input(mosaic_report.file);
  if (scene_path.empty() || mosaic_path.empty()) {
    throw InputError(context.out_dir.string(),
                     fmt::format("{} or {} is missing: run `omm mosaic` (or `omm run`) first",
                                 kSceneName, mosaic_report.file));
  }
  const SavedScene saved = ReadSceneJson(scene_path);
  if (saved.lens_model.empty()) {
    throw InputError(scene_path.string(),
                     "no lens_model: written by an older omm; rerun `omm mosaic`");
  }
  const CameraModel camera{saved.lens_model, saved.scene.intrinsics, project.image_width_px,
                           project.image_height_px};
  const MrcalLensProjection lens(camera);
  const GrayImage mosaic =
      context.mosaic ? ToGrayImage(*context.mosaic) : ReadGrayImage(mosaic_path);
  const OrthoGrid grid{mosaic_report.gsd_mm, mosaic_report.origin_mm, mosaic_report.size_px};
  if (mosaic.width() != grid.size_px.x() || mosaic.height() != grid.size_px.y()) {
    throw InputError(mosaic_path.string(),
                     fmt::format("{}x{} px, but report.json's mosaic is {}x{} px", mosaic.width(),
                                 mosaic.height(), grid.size_px.x(), grid.size_px.y()));
  }
  // Raw tile pixels per mosaic pixel: how far the mosaic's edge noise is correlated.
  double source_px = 1.0;
  for (const auto& [key, value] : mosaic_report.extra) {
    if (key != "ortho") continue;
    for (const auto& [name, member] : std::get<ReportObject>(value.data())) {
      if (name == "tile_px_per_mosaic_px" && std::holds_alternative<double>(member.data()))
        source_px = 1.0 / std::get<double>(member.data());
    }
  }

  const int num_features = static_cast<int>(project.features.size());
  std::vector<LocatedFeature> located(num_features);
  std::mutex progress_mutex;
  int num_located = 0;
  ParallelFor(num_features, kNumThreads, [&](int i) {
    const FeatureSpec& spec = project.features[i];
    located[i] = LocateFeature(spec, saved, lens, grid, mosaic.pixels, camera, source_px);
    const std::lock_guard lock(progress_mutex);
    if (context.progress) context.progress(++num_located, num_features + 1, "located " + spec.name);
  });
  std::vector<CircleFeatureValue> values;
  std::map<std::string, int> by_name;
  for (int i = 0; i < num_features; ++i) {
    by_name[project.features[i].name] = i;
    LocatedFeature& feature = located[i];
    if (feature.value) {
      feature.value_index = static_cast<int>(values.size());
      values.push_back(std::move(*feature.value));
    }
    if (!feature.report.error.empty())
      spdlog::warn("measure: {}: {}", project.features[i].name, feature.report.error);
  }

  const int num_tiles = static_cast<int>(saved.scene.table_pos_mm.size());
  const int num_plates = static_cast<int>(saved.scene.plates.size());
  const bool have_covariance = saved.scene.covariance.size() > 0;
  Eigen::MatrixXd scene_covariance = saved.scene.covariance;
  if (!have_covariance) {
    const int size = PlaneSceneCovarianceSize(num_tiles, num_plates, camera.intrinsics.size());
    scene_covariance = Eigen::MatrixXd::Zero(size, size);
  }
  const MeasurementPropagation propagation(
      values, scene_covariance, PlaneSceneCovarianceIntrinsicsIndex(num_tiles, num_plates));

  for (LocatedFeature& feature : located) {
    if (feature.value_index < 0) continue;
    const int k = feature.value_index;
    SigmaBreakdown diameter_sigma;
    propagation.Diameter(k, &diameter_sigma);
    feature.report.centre_sigma_mm = propagation.CentreSigma(k);
    feature.report.diameter_sigma_mm = diameter_sigma.total_mm;
  }

  std::vector<MeasurementReport> measurements;
  int num_made = 0, num_flagged = 0;
  for (const MeasurementSpec& spec : project.measurements) {
    MeasurementReport m;
    m.name = spec.name;
    m.type = spec.type;
    std::vector<int> indices;
    for (const std::string& name : spec.features) {
      const LocatedFeature& feature = located[by_name.at(name)];
      if (feature.value_index < 0) {
        m.error = fmt::format("feature {}: {}", name, feature.report.error);
        break;
      }
      indices.push_back(feature.value_index);
    }
    if (m.error.empty()) {
      SigmaBreakdown sigma;
      m.value_mm = spec.type == MeasurementType::kDistance
                       ? propagation.Distance(indices[0], indices[1], &sigma)
                       : propagation.Diameter(indices[0], &sigma);
      if (have_covariance) {
        m.sigma_mm = sigma.total_mm;
        m.extra.emplace_back("sigma_breakdown_mm", BreakdownReport(sigma));
      } else {
        m.extra.emplace_back("sigma_note",
                             "mosaic/scene.json has no covariance: sigma not computed");
      }
      ++num_made;
    }
    for (const CmmValue& cmm : project.cmm) {
      if (cmm.measurement != spec.name) continue;
      m.cmm_mm = cmm.value_mm;
      if (m.value_mm) {
        m.deviation_mm = *m.value_mm - cmm.value_mm;
        if (m.sigma_mm && *m.sigma_mm > 0.0) {
          m.deviation_sigma = *m.deviation_mm / *m.sigma_mm;
          const bool flagged = std::abs(*m.deviation_sigma) > kFlagSigmas;
          m.extra.emplace_back("beyond_3_sigma", flagged);
          if (flagged) {
            ++num_flagged;
            spdlog::warn("measure: {} deviates from the CMM by {:.4f} mm ({:.1f} sigma)", m.name,
                         *m.deviation_mm, *m.deviation_sigma);
          }
        }
      }
    }
    measurements.push_back(std::move(m));
  }

  std::vector<FeatureReport> features;
  for (LocatedFeature& feature : located) features.push_back(std::move(feature.report));
  const int num_found = static_cast<int>(values.size());
  context.report.features = std::move(features);
  context.report.measurements = std::move(measurements);
  const std::string brief = fmt::format(
      "{}/{} features found, {}/{} measurements made, {} beyond {} sigma of the CMM", num_found,
      num_features, num_made, project.measurements.size(), num_flagged, kFlagSigmas);
  spdlog::info("measure: {}", brief);
  context.report.extra.erase(
      std::remove_if(context.report.extra.begin(), context.report.extra.end(),
                     [](const auto& member) { return member.first == "measure"; }),
      context.report.extra.end());
  context.report.extra.emplace_back("measure",
                                    ReportObject{{"brief", brief},
                                                 {"intrinsics_refined", saved.intrinsics_refined},
                                                 {"seconds", SecondsSince(stage_start)}});
  if (context.progress) context.progress(num_features + 1, num_features + 1, "measure done");
}

}  // namespace omm
