// Runner of the measure stage (see stage.h): the mosaic, the adjusted scene
// (mosaic/scene.json) and project.yaml's features and measurements in;
// report.features and report.measurements out, each value with its 1-sigma
// and that sigma's breakdown by source (pipeline/measure/
// measurement_uncertainty.h), and the CMM comparison when cmm.csv is given.
//
// Each feature is looked for where its tile and near_px put it: the pixel is
// mapped onto the part through the adjusted scene, and that part point into
// the mosaic's grid. A hole is measured in every tile that sees it whole,
// each tile alone on the mosaic's grid (LocateFeature; on a finer one at
// the tiles' resolution if the mosaic's is coarser: MeasurementGeometry, whose
// pixels the fits' notes then give), and in the blended mosaic only where no
// tile does. A feature that is not found, cut by the
// mosaic's border or poorly fitted gets an error; the measurements that
// need it get an error naming it, the others are still made.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <memory>
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
#include "pipeline/core/statistics.h"
#include "pipeline/core/tile_pixels.h"
#include "pipeline/core/timing.h"
#include "pipeline/measure/circle_measure.h"
#include "pipeline/measure/hole_views.h"
#include "pipeline/measure/measurement_uncertainty.h"
#include "pipeline/measure/scene_sensitivity.h"
#include "pipeline/mosaic/orthorectify.h"
#include "pipeline/orchestration/stage.h"

namespace omm {
namespace {

namespace fs = std::filesystem;

// A deviation from the CMM beyond this many sigmas (of both values where the
// CMM's is stated: JudgedDeviationSigma) is flagged.
constexpr double kFlagSigmas = 3.0;

ReportValue Pair(const Eigen::Vector2d& v) { return ReportValue::Array{v.x(), v.y()}; }

ReportValue BreakdownReport(const SigmaBreakdown& sigma) {
  return ReportObject{{"calibration", sigma.calibration_mm},
                      {"registration", sigma.registration_mm},
                      {"table", sigma.table_mm},
                      {"edges", sigma.edges_mm}};
}

// A feature as found (or not), with what the measurements need of it.
struct LocatedFeature {
  FeatureReport report;
  std::optional<CircleFeatureValue> value;  // none if not found
  int value_index = -1;                     // into the propagation's features; -1 if not found
  BoreEvidence bore;                        // of its fits (for a BorePrior)
  // The views' note where they disagree (warned of once the feature is
  // final: a hole with an unresolved bore is located twice); else empty.
  std::string views_disagree;
};

// Each tile's exposure as the mosaic divided it out (report.json's mosaic
// tiles rows); identity for a tile without one (not compensated).
std::vector<TileExposure> TileExposures(const MosaicReport& mosaic,
                                        const std::vector<std::string>& tile_images) {
  std::vector<TileExposure> exposure(tile_images.size());
  const ReportValue::Array* rows = AsArray(Member(mosaic.extra, "tiles"));
  if (rows == nullptr) return exposure;
  for (const ReportValue& row : *rows) {
    const ReportObject* tile = AsObject(&row);
    const std::string* image = tile ? AsString(Member(*tile, "image")) : nullptr;
    if (image == nullptr) continue;
    const auto it = std::find(tile_images.begin(), tile_images.end(), *image);
    if (it == tile_images.end()) continue;
    TileExposure& e = exposure[it - tile_images.begin()];
    e.gain = AsNumber(Member(*tile, "exposure_gain")).value_or(e.gain);
    e.vignetting = AsNumber(Member(*tile, "vignetting")).value_or(e.vignetting);
  }
  return exposure;
}

// The part of a hole's edge error the tiles share (CombineCircleViews): they
// show the same surface texture at the rim. Over 246 holes seen whole by 2-4
// tiles in 30 simulated projects, the views' diameters disagreed by a pooled
// chi2 / dof of 0.79 modelled as independent (0.96 with this fraction), and
// the combined diameters' sd(error / sigma) was 1.07 (1.00 with it).
constexpr double kSharedEdgeFraction = 0.2;
// Views of a hole whose chi-square exceeds this quantile disagree (CombineCircleViews).
constexpr double kConsistencyProbability = 0.999;
// A BorePrior is pooled from at least this many views that resolve the wall.
constexpr size_t kMinBorePriorViews = 3;

std::string BoreNote(const HoleFit& fit, const SavedScene& saved) {
  const CircleMeasurement& circle = fit.circle;
  if (circle.bore_prior_used) {
    return fmt::format(
        "{}; bottom rim scaled by the project's {:.4f} about {}'s nadir; wall too narrow on {} of "
        "{} wedges, tied to the rim at the project's level",
        circle.bottom_rim_modelled ? "bore wall too narrow to resolve" : "no bore wall resolved",
        circle.bottom_rim_scale, saved.tile_images[*fit.nadir_tile], circle.num_narrow_wall,
        circle.num_wedges);
  }
  if (circle.bottom_rim_scale > 0.0) {
    return fmt::format(
        "bottom rim scaled by {:.4f} about {}'s nadir; wall too narrow on {} of {} wedges{}",
        circle.bottom_rim_scale, saved.tile_images[*fit.nadir_tile], circle.num_narrow_wall,
        circle.num_wedges, circle.narrow_wall_skipped ? ", left out" : "");
  }
  if (circle.bottom_rim_modelled) {
    return fit.nadir_tile ? "bottom rim fitted free: its scale about the nadir did not settle"
                          : "tiles blend over the hole: bottom rim fitted free";
  }
  return "no bore wall resolved";
}

// "; tile_X left out: why" for each tile that sees the hole whole and failed to fit it.
std::string FailedViewsNote(const std::vector<HoleFit>& failed, const SavedScene& saved) {
  std::string note;
  for (const HoleFit& fit : failed)
    note += fmt::format("; {} left out: {}", saved.tile_images[*fit.tile], fit.circle.error);
  return note;
}

// The report's notes on a hole measured in tiles: which tiles, their bores
// and fits, the tiles that failed, and whether the views agree (where they
// do not, *views_disagree is the note).
void AddTileViewNotes(const HoleViews& views, const CombinedCircle& combined,
                      const Eigen::Matrix3d& to_mm, const OrthoGrid& grid, const SavedScene& saved,
                      FeatureReport* report, std::string* views_disagree) {
  const std::vector<HoleFit>& fits = views.fits;
  const std::vector<HoleFit>& failed = views.failed;
  const CircleFeatureValue& value = combined.value;
  std::string views_note =
      fmt::format("measured in {} tile{}{}:", fits.size(), fits.size() > 1 ? "s" : "",
                  views.partial ? fmt::format(" that see{} part of the rim (those that see it "
                                              "whole clipped it)",
                                              fits.size() > 1 ? "" : "s")
                                : "");
  std::string bore_note;
  ReportObject tile_fits;
  for (size_t i = 0; i < fits.size(); ++i) {
    const HoleFit& fit = fits[i];
    const std::string& name = saved.tile_images[*fit.tile];
    std::string uncovered;
    if (fit.circle.num_uncovered > 0 && fit.circle.num_wedges > 0)
      uncovered = fmt::format("{:.0f} % of the rim not covered, ",
                              100.0 * fit.circle.num_uncovered / fit.circle.num_wedges);
    views_note +=
        fmt::format("{} {} ({}{})", i > 0 ? "," : "", name, uncovered,
                    fit.circle.bore_prior_used
                        ? fmt::format("{}, project's k {:.4f}",
                                      fit.circle.bottom_rim_modelled ? "bore wall too narrow"
                                                                     : "no bore wall resolved",
                                      fit.circle.bottom_rim_scale)
                    : fit.circle.bottom_rim_scale > 0.0
                        ? fmt::format("bottom rim k {:.4f}", fit.circle.bottom_rim_scale)
                        : std::string(fit.circle.bottom_rim_modelled ? "bottom rim free"
                                                                     : "no bore wall resolved"));
    bore_note += (i > 0 ? "; " : "") + name + ": " + BoreNote(fit, saved);
    tile_fits.emplace_back(name, fit.circle.Brief());
  }
  views_note += FailedViewsNote(failed, saved);
  if (fits.size() > 1) {
    const Eigen::Matrix3d cov_px =
        to_mm.inverse() * value.edge_covariance * to_mm.inverse().transpose();
    const Eigen::Vector2d centre_px = grid.MosaicFromPart(value.centre_mm);
    const auto agreement = [](const char* what, const ViewAgreement& a) {
      std::string note = fmt::format("{} {}: chi2 {:.1f} for {} dof ({:.1f} % bound {:.1f})", what,
                                     a.consistent ? "agree" : "disagree", a.chi2, a.dof,
                                     100.0 * kConsistencyProbability,
                                     ChiSquareQuantile(kConsistencyProbability, a.dof));
      if (!a.consistent) note += fmt::format(", edge sigma x{:.2f}", std::sqrt(a.inflation));
      return note;
    };
    views_note += "; " + agreement("centres", combined.centre) + "; " +
                  agreement("diameters", combined.diameter);
    if (!combined.centre.consistent || !combined.diameter.consistent) *views_disagree = views_note;
    report->extra.emplace_back(
        "fit",
        fmt::format("combined: centre ({:.3f}, {:.3f}) px, r {:.3f} px, sigma ({:.4f}, "
                    "{:.4f}, {:.4f}) px",
                    centre_px.x(), centre_px.y(), 0.5 * value.diameter_mm / grid.gsd_mm,
                    std::sqrt(cov_px(0, 0)), std::sqrt(cov_px(1, 1)), std::sqrt(cov_px(2, 2))));
  } else {
    report->extra.emplace_back("fit", fits[0].circle.Brief());
  }
  report->extra.emplace_back("bore", bore_note);
  report->extra.emplace_back("views", views_note);
  report->extra.emplace_back("tile_fits", std::move(tile_fits));
}

// Where a nominal circle is wider than a tile's view of the part (`tile`'s
// extent along its rows and columns through its centre), no tile can see it
// whole, and its fit fails "cut by the mosaic border" or "not found": the
// likelier cause is project.yaml's diameter_mm. That, to append to the
// error; else empty.
std::string NoTileCouldSeeIt(const FeatureSpec& spec, const HoleViewInputs& in,
                             const PlaneScene& scene, int tile) {
  const double w = in.camera.width_px, h = in.camera.height_px;
  const auto extent_mm = [&](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    const auto pa = PartPointOfTilePixel(in.lens, scene, tile, a);
    const auto pb = PartPointOfTilePixel(in.lens, scene, tile, b);
    return pa && pb ? (*pa - *pb).norm() : 0.0;
  };
  const double across_mm = extent_mm({0.0, 0.5 * h}, {w, 0.5 * h});
  const double down_mm = extent_mm({0.5 * w, 0.0}, {0.5 * w, h});
  if (!(across_mm > 0.0 && down_mm > 0.0) || spec.diameter_mm <= std::min(across_mm, down_mm))
    return "";
  return fmt::format(
      "; no tile can see a circle of {:g} mm whole (a tile sees {:.0f} x {:.0f} mm of the "
      "part): is its diameter_mm in project.yaml right?",
      spec.diameter_mm, across_mm, down_mm);
}

// Pure in its inputs: features are located concurrently.
//
// A hole that some tiles see whole (with the fit's reach) is measured in
// each of them alone (hole_views.h): pictures with their own
// noise, each with one bottom rim about its own nadir, combined by their
// edge covariances (CombineCircleViews). The blended mosaic is measured only
// where no tile sees the hole whole.
LocatedFeature LocateFeature(const FeatureSpec& spec, const HoleViewInputs& in,
                             const SavedScene& saved) {
  const OrthoGrid& grid = in.geometry.grid;  // the views' px
  const OrthoGrid& mosaic_grid = in.mosaic_grid ? *in.mosaic_grid : grid;
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
  const auto near_part = PartPointOfTilePixel(in.lens, saved.scene, tile, spec.near_px);
  if (!near_part) {
    report.error = fmt::format("near_px [{}, {}] of {} does not map onto the part",
                               spec.near_px.x(), spec.near_px.y(), spec.image);
    return located;
  }
  const Eigen::Vector2d expected_px = mosaic_grid.MosaicFromPart(*near_part);
  report.extra = {{"expected_mosaic_px", Pair(expected_px)}};
  const double radius_mm = 0.5 * spec.diameter_mm;

  HoleViews views_found = FitHoleViews(in, *near_part, radius_mm);
  std::vector<HoleFit>& fits = views_found.fits;
  if (const HoleFit* saturated = views_found.SaturatedFit(); fits.empty() && saturated) {
    const HoleFit& fit = *saturated;
    report.error = fmt::format("{} in {}", fit.circle.error, saved.tile_images[*fit.tile]);
    return located;
  }
  if (fits.empty()) {
    HoleFit fit = views_found.mosaic_fit ? std::move(*views_found.mosaic_fit)
                                         : FitHoleInMosaic(in, *near_part, radius_mm);
    const int num_seeing = views_found.num_seeing;
    const char* outcome = fit.circle.ok ? "measured in the mosaic" : "not found in the mosaic";
    report.extra.emplace_back(
        "views", num_seeing == 0 ? fmt::format("{}: no tile sees the hole whole", outcome)
                                 : fmt::format("{}: not found in the {} tile{} that see it whole{}",
                                               outcome, num_seeing, num_seeing > 1 ? "s" : "",
                                               FailedViewsNote(views_found.failed, saved)));
    if (!fit.circle.ok) {
      report.error = fit.circle.error + NoTileCouldSeeIt(spec, in, saved.scene, tile);
      return located;
    }
    report.extra.emplace_back("fit", fit.circle.Brief());
    report.extra.emplace_back("bore", BoreNote(fit, saved));
    fits.push_back(std::move(fit));
  }
  located.bore = BoreEvidenceOf(fits);

  // Per fit: (cx, cy, D) mm, its edge covariance and scene sensitivity.
  // (col, row, r) px -> (x, y, D) mm: x along +col, y along -row.
  const Eigen::Matrix3d to_mm =
      Eigen::Vector3d(grid.gsd_mm, -grid.gsd_mm, 2.0 * grid.gsd_mm).asDiagonal();
  std::vector<CircleFeatureValue> views;
  for (const HoleFit& fit : fits) {
    CircleFeatureValue value;
    value.centre_mm = grid.PartFromMosaic(fit.circle.centre_px);
    value.diameter_mm = 2.0 * fit.circle.radius_px * grid.gsd_mm;
    value.edge_covariance = to_mm * fit.circle.covariance_px2 * to_mm.transpose();
    const auto sensitivity =
        fit.tile ? TileCircleSceneSensitivity(in.lens, saved.scene, *fit.tile, value.centre_mm,
                                              value.diameter_mm)
                 : CircleSceneSensitivity(in.lens, saved.scene, value.centre_mm, value.diameter_mm,
                                          in.camera.width_px, in.camera.height_px,
                                          OrthoOptions{}.blend_band_px);
    if (!sensitivity) {
      report.error = "the circle is not seen whole by the tiles";
      return located;
    }
    value.scene_sensitivity = *sensitivity;
    views.push_back(std::move(value));
  }
  const CombinedCircle combined = CombineCircleViews(views, saved.scene.covariance,
                                                     kSharedEdgeFraction, kConsistencyProbability);
  CircleFeatureValue value = combined.value;
  const Eigen::Vector2d centre_px = mosaic_grid.MosaicFromPart(value.centre_mm);
  const double combined_radius_px = 0.5 * value.diameter_mm / mosaic_grid.gsd_mm;

  int num_edge_points = 0, num_inliers = 0;
  double sum_squares = 0.0;
  for (const HoleFit& fit : fits) {
    num_edge_points += fit.circle.num_edge_points;
    num_inliers += fit.circle.num_inliers;
    sum_squares += fit.circle.num_inliers * fit.circle.rms_px * fit.circle.rms_px;
  }
  if (fits[0].tile) {
    AddTileViewNotes(views_found, combined, to_mm, grid, saved, &report, &located.views_disagree);
  }
  report.centre_mm = value.centre_mm;
  report.diameter_mm = value.diameter_mm;
  report.extra.emplace_back("num_views", static_cast<int>(fits.size()));
  report.extra.emplace_back("mosaic_px", Pair(centre_px));
  report.extra.emplace_back("radius_px", combined_radius_px);
  report.extra.emplace_back("edge_points", num_edge_points);
  report.extra.emplace_back("inliers", num_inliers);
  report.extra.emplace_back("rms_px", num_inliers > 0 ? std::sqrt(sum_squares / num_inliers) : 0.0);
  located.value = std::move(value);
  return located;
}

// The mosaic stage's results the measure stage reads (its report section,
// mosaic/scene.json, the mosaic), checked against each other and
// project.yaml; throws InputError where they are missing or an out/ mixes
// runs.
struct MosaicResults {
  SavedScene saved;
  CameraModel camera;  // with the adjusted scene's intrinsics
  GrayImage mosaic;
  OrthoGrid grid;
  double source_px = 1.0;  // raw tile pixels per mosaic pixel: how far its edge noise is correlated
  OrthoGeometry geometry;  // the scene's mosaic grid, the one that made the mosaic
};

MosaicResults ReadMosaicResults(const StageContext& context) {
  const Project& project = context.project;
  if (!context.report.mosaic) {
    throw InputError((context.out_dir / "report.json").string(),
                     std::string(context.StaleInOut(Stage::kMosaic)
                                     ? "its mosaic is from other inputs (tiles/, table.csv, "
                                       "project.yaml's table, mosaic or features, or the "
                                       "calibration changed since)"
                                     : "no mosaic") +
                         ": run `omm mosaic` (or `omm run`) first");
  }
  const MosaicReport& mosaic_report = *context.report.mosaic;
  const fs::path scene_path = context.Input(kSceneName);
  // This run's mosaic is in memory (its file may still be being written).
  const fs::path mosaic_path =
      context.mosaic ? context.staging_dir / mosaic_report.file : context.Input(mosaic_report.file);
  if (scene_path.empty() || mosaic_path.empty()) {
    throw InputError(context.out_dir.string(),
                     fmt::format("{} or {} is missing: run `omm mosaic` (or `omm run`) first",
                                 kSceneName, mosaic_report.file));
  }
  MosaicResults results;
  SavedScene& saved = results.saved;
  saved = ReadSceneJson(scene_path);
  if (saved.lens_model.empty()) {
    throw InputError(scene_path.string(),
                     "no lens_model: written by an older omm; rerun `omm mosaic`");
  }
  results.camera = CameraModel{saved.lens_model, saved.scene.intrinsics, project.image_width_px,
                               project.image_height_px};
  const GrayImage& mosaic = results.mosaic =
      context.mosaic ? ToGrayImage(*context.mosaic) : ReadGrayImage(mosaic_path);
  const OrthoGrid& grid = results.grid =
      OrthoGrid{mosaic_report.gsd_mm, mosaic_report.origin_mm, mosaic_report.size_px};
  if (mosaic.width() != grid.size_px.x() || mosaic.height() != grid.size_px.y()) {
    throw InputError(mosaic_path.string(),
                     fmt::format("{}x{} px, but report.json's mosaic is {}x{} px", mosaic.width(),
                                 mosaic.height(), grid.size_px.x(), grid.size_px.y()));
  }
  if (const ReportObject* ortho = AsObject(Member(mosaic_report.extra, "ortho"))) {
    if (const auto per_px = AsNumber(Member(*ortho, "tile_px_per_mosaic_px"));
        per_px && *per_px > 0.0)
      results.source_px = 1.0 / *per_px;
  }

  // The tiles alone on the mosaic's grid need the scene, the tiles and the
  // grid that made the mosaic.
  std::vector<std::string> project_tiles;
  for (const TilePosition& tile : project.tiles) project_tiles.push_back(tile.image);
  if (project_tiles != saved.tile_images) {
    throw InputError(
        scene_path.string(),
        fmt::format("made from the tiles {}, but table.csv lists {}: rerun `omm "
                    "mosaic`",
                    fmt::join(saved.tile_images, ", "), fmt::join(project_tiles, ", ")));
  }
  OrthoOptions ortho_options;
  ortho_options.gsd_mm = grid.gsd_mm;
  const OrthoGeometry& geometry = results.geometry =
      ComputeOrthoGeometry(results.camera, saved.scene, ortho_options);
  if (geometry.grid.size_px != grid.size_px ||
      !geometry.grid.origin_mm.isApprox(grid.origin_mm, 1e-12)) {
    throw InputError(
        scene_path.string(),
        fmt::format("its scene puts the mosaic at {}x{} px from ({:.3f}, {:.3f}) mm, but {} says "
                    "{}x{} px from ({:.3f}, {:.3f}) mm: rerun `omm mosaic`",
                    geometry.grid.size_px.x(), geometry.grid.size_px.y(),
                    geometry.grid.origin_mm.x(), geometry.grid.origin_mm.y(), "report.json",
                    grid.size_px.x(), grid.size_px.y(), grid.origin_mm.x(), grid.origin_mm.y()));
  }
  return results;
}

// Every feature of project.yaml located and measured (LocateFeature), the
// largest first: a hole's fits take time with its rim (0.006 s for 12 mm,
// 0.04-0.08 s for 50-60 mm on lens-mismatch seed 284). Then the views that
// resolve no bore wall, near a nadir, are measured again with the bore the
// others resolved (inputs->bore_prior, BorePrior; MeasureCircle uses it only
// where a narrow wall covers most of the rim); *bore_prior_report says what
// the pool held.
std::vector<LocatedFeature> LocateFeatures(const StageContext& context, const SavedScene& saved,
                                           HoleViewInputs* inputs,
                                           ReportObject* bore_prior_report) {
  const Project& project = context.project;
  const int num_features = static_cast<int>(project.features.size());
  std::vector<LocatedFeature> located(num_features);
  std::mutex progress_mutex;
  int num_located = 0;
  std::vector<double> diameters_mm;
  for (const FeatureSpec& spec : project.features) diameters_mm.push_back(spec.diameter_mm);
  const std::vector<int> largest_first = CostliestFirst(diameters_mm);
  ParallelFor(num_features, context.num_threads, [&](int n) {
    const int i = largest_first[n];
    const FeatureSpec& spec = project.features[i];
    located[i] = LocateFeature(spec, *inputs, saved);
    const std::lock_guard lock(progress_mutex);
    if (context.progress) context.progress(++num_located, num_features + 1, "located " + spec.name);
  });
  std::vector<BoreEvidence> bores;
  int views_with_k = 0, views_with_wall_level = 0;
  for (const LocatedFeature& feature : located) {
    bores.push_back(feature.bore);
    views_with_k += static_cast<int>(feature.bore.bottom_rim_scales.size());
    views_with_wall_level += static_cast<int>(feature.bore.wall_contrasts.size());
  }
  *bore_prior_report = ReportObject{{"views_with_k", views_with_k},
                                    {"views_with_wall_level", views_with_wall_level}};
  inputs->bore_prior = PoolBorePrior(bores, kMinBorePriorViews);
  if (!inputs->bore_prior) return located;
  bore_prior_report->emplace_back("bottom_rim_scale", inputs->bore_prior->bottom_rim_scale);
  bore_prior_report->emplace_back("wall_contrast", inputs->bore_prior->wall_contrast);
  bore_prior_report->emplace_back("wall_contrast_sigma", inputs->bore_prior->wall_contrast_sigma);
  std::vector<int> unresolved;
  for (int i = 0; i < num_features; ++i) {
    if (located[i].bore.unresolved) unresolved.push_back(i);
  }
  ParallelFor(static_cast<int>(unresolved.size()), context.num_threads, [&](int j) {
    const int i = unresolved[static_cast<size_t>(j)];
    located[i] = LocateFeature(project.features[i], *inputs, saved);
  });
  return located;
}

// One measurement of the located features (`by_name`: their indices), with
// its sigma if the scene has a covariance, and its deviation from cmm.csv's
// value where there is one; *made tells whether a value came out, *flagged
// whether it is beyond kFlagSigmas of the CMM (warned about).
MeasurementReport Measure(const MeasurementSpec& spec, const std::vector<LocatedFeature>& located,
                          const std::map<std::string, int>& by_name,
                          const MeasurementPropagation& propagation, bool have_covariance,
                          const std::vector<CmmValue>& cmm_values, bool* made, bool* flagged) {
  *made = *flagged = false;
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
      m.extra.emplace_back("sigma_note", "mosaic/scene.json has no covariance: sigma not computed");
    }
    *made = true;
  }
  for (const CmmValue& cmm : cmm_values) {
    if (cmm.measurement != spec.name) continue;
    m.cmm_mm = cmm.value_mm;
    m.cmm_sigma_mm = cmm.sigma_mm;
    if (!m.value_mm) continue;
    m.deviation_mm = *m.value_mm - cmm.value_mm;
    if (!m.sigma_mm || !(*m.sigma_mm > 0.0)) continue;
    m.deviation_sigma = *m.deviation_mm / *m.sigma_mm;
    if (cmm.sigma_mm)
      m.deviation_combined_sigma = *m.deviation_mm / std::hypot(*m.sigma_mm, *cmm.sigma_mm);
    const double judged = *JudgedDeviationSigma(m);
    const bool beyond = std::abs(judged) > kFlagSigmas;
    m.extra.emplace_back("beyond_3_sigma", beyond);
    if (beyond) {
      *flagged = true;
      spdlog::warn("measure: {} deviates from the CMM by {:.4f} mm ({:.1f} sigma{})", m.name,
                   *m.deviation_mm, judged, cmm.sigma_mm ? ", the CMM's included" : "");
    }
  }
  return m;
}

}  // namespace

void RunMeasureStage(StageContext& context) {
  const Project& project = context.project;
  const auto stage_start = std::chrono::steady_clock::now();
  const MosaicResults mosaic_stage = ReadMosaicResults(context);
  const SavedScene& saved = mosaic_stage.saved;
  const CameraModel& camera = mosaic_stage.camera;
  const MrcalLensProjection lens(camera);
  const std::shared_ptr<const std::vector<ImageF>> tiles =
      context.tiles ? context.tiles
                    : std::make_shared<const std::vector<ImageF>>(
                          TileImages(project, camera, context.num_threads));
  const std::optional<OrthoGeometry> fine =
      MeasurementGeometry(camera, saved.scene, mosaic_stage.geometry);
  HoleViewInputs inputs{saved.scene,
                        lens,
                        fine ? *fine : mosaic_stage.geometry,
                        camera,
                        *tiles,
                        TileExposures(*context.report.mosaic, saved.tile_images),
                        fine ? 1.0 / TilePxPerMosaicPx(*fine) : mosaic_stage.source_px,
                        &mosaic_stage.mosaic.pixels};
  if (fine) {
    inputs.mosaic_grid = &mosaic_stage.geometry.grid;
    inputs.mosaic_source_px = mosaic_stage.source_px;
  }
  ReportObject bore_prior_report;
  std::vector<LocatedFeature> located = LocateFeatures(context, saved, &inputs, &bore_prior_report);
  const int num_features = static_cast<int>(project.features.size());
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
    if (!feature.views_disagree.empty())
      spdlog::warn("measure: {}: {}", project.features[i].name, feature.views_disagree);
  }

  const int num_tiles = static_cast<int>(saved.scene.table_pos_mm.size());
  const int num_plates = static_cast<int>(saved.scene.plates.size());
  const bool have_covariance = saved.scene.covariance.size() > 0;
  Eigen::MatrixXd scene_covariance = saved.scene.covariance;
  if (!have_covariance) {
    const int size = PlaneSceneCovarianceSize(num_tiles, num_plates, camera.intrinsics.size());
    scene_covariance = Eigen::MatrixXd::Zero(size, size);
  }
  ScenePriors priors;
  priors.num_tiles = num_tiles;
  priors.table_sigma_mm = saved.table_sigma_mm;
  priors.tiles_without_table_prior = saved.tiles_without_table_prior;
  priors.intrinsics_index = PlaneSceneCovarianceIntrinsicsIndex(num_tiles, num_plates);
  priors.intrinsics_information = saved.intrinsics_information;
  const MeasurementPropagation propagation(values, scene_covariance, std::move(priors));

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
    bool made = false, flagged = false;
    measurements.push_back(Measure(spec, located, by_name, propagation, have_covariance,
                                   project.cmm, &made, &flagged));
    num_made += made;
    num_flagged += flagged;
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
                                                 {"bore_prior", std::move(bore_prior_report)},
                                                 // The grid the views' fits (and their notes' px) are on.
                                                 {"views_gsd_mm", inputs.geometry.grid.gsd_mm},
                                                 {"seconds", SecondsSince(stage_start)}});
  if (context.progress) context.progress(num_features + 1, num_features + 1, "measure done");
}

}  // namespace omm
