// Runner of the mosaic stage (see stage.h): the calibrated camera and the
// tiles in, RegisterTiles, each pair's matches weighted by their own scatter
// (pair_scatter.h), the final adjustment with the plate lying on the part,
// the calibration's intrinsics prior (plate_on_part.h) and the project's
// holes that several tiles see whole as tie points
// (pipeline/measure/hole_ties.h), Orthorectify (pipeline/mosaic), and out
// mosaic.png (16 bit) with its world file mosaic.pgw, mosaic/scene.json (the
// adjusted scene and its joint covariance for the measure stage), colmap/
// (the scene as a COLMAP sparse model) and report.mosaic.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <future>
#include <memory>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <Eigen/Eigenvalues>

#include "adapters/colmap/colmap_model.h"
#include "adapters/colmap/colmap_sift.h"
#include "adapters/mrcal/cameramodel_io.h"
#include "adapters/mrcal/mrcal_lens_projection.h"
#include "adapters/mrcal/solve_record_json.h"
#include "adapters/mrcal/uncertainty.h"
#include "adapters/opencv/image_io.h"
#include "adapters/project_io/scene_json.h"
#include "pipeline/core/error.h"
#include "pipeline/core/memory.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/core/statistics.h"
#include "pipeline/core/tile_pixels.h"
#include "pipeline/core/timing.h"
#include "pipeline/measure/hole_ties.h"
#include "pipeline/measure/overlap_ties.h"
#include "pipeline/mosaic/exposure_compensation.h"
#include "pipeline/mosaic/ortho_file.h"
#include "pipeline/mosaic/orthorectify.h"
#include "pipeline/mosaic/pair_scatter.h"
#include "pipeline/mosaic/plate_on_part.h"
#include "pipeline/mosaic/register_tiles.h"
#include "pipeline/mosaic/table_prior_check.h"
#include "pipeline/mosaic/tile_features.h"
#include "pipeline/mosaic/tile_groups.h"
#include "pipeline/mosaic/working_distance.h"
#include "pipeline/orchestration/stage.h"

namespace omm {
namespace {

namespace fs = std::filesystem;

// The median of every 7th pixel of a tile, [0, 1].
double MedianOfImage(const ImageF& image) {
  std::vector<double> values;
  values.reserve(static_cast<size_t>(image.size() / 7 + 1));
  for (Eigen::Index k = 0; k < image.size(); k += 7) values.push_back(image.data()[k]);
  return Median(std::move(values));
}
constexpr const char* kMosaicName = "mosaic.png";
constexpr const char* kColmapDirName = "colmap";
constexpr int kMosaicBitDepth = 16;
// Bytes a mosaic pixel takes while the mosaic is made, written and measured
// (its float samples, their 16-bit copy, the file's encoding): ~9 at the
// peak of `omm run` on the demo at a gsd of 0.03 mm (242 Mpx, 2.5 GB).
constexpr double kBytesPerMosaicPixel = 12.0;

// The largest mosaic this machine makes: what its memory holds, and what
// omm's image readers read back (kMaxImagePixels).
std::int64_t MosaicPixelLimit() {
  const std::int64_t memory = PhysicalMemoryBytes();
  if (memory == 0) return kMaxImagePixels;
  return std::min(kMaxImagePixels,
                  static_cast<std::int64_t>(static_cast<double>(memory) / kBytesPerMosaicPixel));
}

// The mosaic's geometry on `scene`; a gsd out of range is project.yaml's
// error.
OrthoGeometry MosaicGeometry(const Project& project, const CameraModel& camera,
                             const PlaneScene& scene, const OrthoOptions& options) {
  try {
    return ComputeOrthoGeometry(camera, scene, options);
  } catch (const GsdError& e) {
    const double memory = static_cast<double>(PhysicalMemoryBytes());
    throw InputError(
        (project.dir / "project.yaml").string(),
        "key 'mosaic.gsd_mm': " + std::string(e.what()) +
            (e.too_fine ? fmt::format(" (omm's image readers take {:.0f} Mpx; this machine's "
                                      "{:.1f} GB of memory hold {:.0f} Mpx at {:g} bytes each)",
                                      1e-6 * static_cast<double>(kMaxImagePixels), 1e-9 * memory,
                                      1e-6 * memory / kBytesPerMosaicPixel, kBytesPerMosaicPixel)
                        : ""));
  }
}

ReportValue Pair(const Eigen::Vector2d& v) { return ReportValue::Array{v.x(), v.y()}; }

// Whether out/'s calibration is from other inputs than this run's (and this
// run has none of its own).
bool StaleCalibration(const StageContext& context) {
  return !context.report.calibration && context.StaleInOut(Stage::kCalibrate);
}

// The calibrated camera: this run's or an earlier one's
// out/camera.cameramodel unless that is stale, else the one calibration.from
// names.
fs::path CameraModelPath(const StageContext& context) {
  fs::path staged = context.Input(kCameraModelName);
  if (!staged.empty() && !StaleCalibration(context)) return staged;
  const Project& project = context.project;
  if (project.calibration_from) {
    const CalibrationSource& source = *project.calibration_from;
    fs::path from = source.kind == CalibrationSource::Kind::kCameraModel
                        ? source.path
                        : source.path / "out" / kCameraModelName;
    if (fs::exists(from)) return from;
  }
  throw InputError((context.out_dir / kCameraModelName).string(),
                   std::string(staged.empty() ? "no calibrated camera"
                                              : "calibrated from other calib/ images or settings "
                                                "(changed since)") +
                       ": run `omm calibrate` (or `omm run`) first, or set calibration.from in "
                       "project.yaml");
}

// Where the calibration measured a splined lens: the convex hull of its inlier
// mark centres (plate_on_part.h, IntrinsicsPrior). Empty for the other
// models: their form extrapolates (OPENCV8 on the demo seeds is within
// 0.07 px of the truth up to the corners), and on the demo seeds 101-105,
// 201-205 widening the 14-30 plate marks outside the hull would cost
// precision for nothing: scale sigma 4.6-5.9 -> 5.6-45 ppm, distances RMS
// 0.0145 -> 0.0346 raw px.
// A .cameramodel's valid_intrinsics_region stands in for the marks (mrcal's
// own polygon may be concave: its hull).
bool Splined(const CameraModel& camera) {
  return camera.lens_model.rfind("LENSMODEL_SPLINED", 0) == 0;
}
Eigen::Matrix2Xd MeasuredRegion(const SolveRecord& record) {
  return Splined(record.camera) ? CalibratedRegionPx(record) : Eigen::Matrix2Xd();
}
Eigen::Matrix2Xd MeasuredRegion(const CameraModel& camera) {
  return Splined(camera) ? ConvexHull(camera.valid_region_px) : Eigen::Matrix2Xd();
}

// An intrinsics prior and the seconds its covariance took (0 if none was computed).
struct TimedPrior {
  IntrinsicsPrior prior;
  double seconds = 0.0;
};

std::future<TimedPrior> Ready(IntrinsicsPrior prior) {
  std::promise<TimedPrior> ready;
  ready.set_value({std::move(prior), 0.0});
  return ready.get_future();
}

// The calibration's intrinsics prior: from the calibrate stage's solve record
// (this run's, out/'s unless stale, or calibration.from's project), if it belongs to
// *camera; then *camera takes the record's exact intrinsics (mrcal writes the
// .cameramodel with 6 decimals), and *rt_cam_from_plates the record's plate
// poses. The covariance is computed on another thread (0.06 s on
// lens-mismatch 284), beside the registration's single-threaded solves.
std::future<TimedPrior> CalibrationPrior(const StageContext& context, CameraModel* camera,
                                         std::vector<Vector6d>* rt_cam_from_plates) {
  const Project& project = context.project;
  IntrinsicsPrior prior;
  fs::path record_path = StaleCalibration(context) ? fs::path() : context.Input(kSolveRecordName);
  if (record_path.empty() && project.calibration_from &&
      project.calibration_from->kind == CalibrationSource::Kind::kProject) {
    record_path = project.calibration_from->path / "out" / kSolveRecordName;
  }
  if (project.calibration_from &&
      project.calibration_from->kind == CalibrationSource::Kind::kCameraModel) {
    prior.why_held = "calibration from a .cameramodel without covariance";
    prior.measured_region_px = MeasuredRegion(*camera);
    return Ready(std::move(prior));
  }
  if (record_path.empty() || !fs::exists(record_path)) {
    prior.why_held = "no calibration solve record (" + std::string(kSolveRecordName) + ")";
    return Ready(std::move(prior));
  }
  SolveRecord record = ReadSolveRecord(record_path);
  const Eigen::VectorXd& k = camera->intrinsics;
  if (record.camera.lens_model != camera->lens_model ||
      record.camera.intrinsics.size() != k.size() ||
      !((record.camera.intrinsics - k).cwiseAbs().array() <= 1e-6).all()) {
    prior.why_held = record_path.string() + " is not the solve of the camera used";
    return Ready(std::move(prior));
  }
  for (const SolveImage& image : record.images)
    rt_cam_from_plates->push_back(image.rt_cam_from_plate);
  camera->intrinsics = record.camera.intrinsics;
  return std::async(std::launch::async, [record = std::move(record)] {
    const auto start = std::chrono::steady_clock::now();
    TimedPrior timed;
    std::string why_not;
    const std::optional<CalibrationUncertainty> uncertainty =
        CalibrationUncertainty::Compute(record, 0.0, &why_not);
    if (uncertainty) {
      timed.prior = IntrinsicsPriorFromCovariance(uncertainty->IntrinsicsCovariance());
    } else {
      timed.prior.why_held = "the calibration's covariance could not be computed: " + why_not;
    }
    timed.prior.measured_region_px = MeasuredRegion(record);
    timed.seconds = SecondsSince(start);
    return timed;
  });
}

// The calibration plate on the part off by more than this from the table's
// scale: beyond any height the plate may stand at (its unknown height moves
// the scale by h / d: 5 mm at 400 mm is 12 500 ppm), a units error.
constexpr double kPlateScaleUnitsPpm = 1e5;
// The largest move of a refined intrinsic, in its calibration sigmas, that
// a calibration covariance which holds leaves likely: a normal's |z| passes
// 5 with probability 6e-7, so even over a spline's ~120 free intrinsics one
// run in ~15000. Lens-mismatch projects with 18 calibration images moved
// theirs by 1.1-4.0; with 4 (circles, seeds 1201-1219) by 7.8-18.7.
constexpr double kMaxIntrinsicsChangeSigmas = 5.0;
// The table's variance component (FinalAdjustmentWithHoles): priors this
// many times looser show a scatter that stiff ones hide; the estimate is
// repeated until it moves by less than kTableSigmaSettled.
constexpr double kLooseTableSigmaFactor = 100.0;
constexpr double kTableSigmaSettled = 0.02;
constexpr int kMaxTableSigmaPasses = 8;

// report.mosaic.working_distance_check (working_distance.h), and a warning
// when the part is far from where the calibration saw its plate.
ReportValue WorkingDistanceReport(const PlaneScene& scene,
                                  const std::vector<Vector6d>& rt_cam_from_plates,
                                  const Project& project) {
  const WorkingDistanceOptions options;
  const WorkingDistanceCheck check = CheckWorkingDistance(
      scene.cam_from_part_r, scene.cam_from_part_t_mm, rt_cam_from_plates, options);
  if (rt_cam_from_plates.empty()) {
    return "not checked: no calibration plate poses (a .cameramodel, or another camera's solve)";
  }
  if (!check.ok)
    return "not checked: the part plane does not cross the optical axis before the camera";
  if (!check.consistent) {
    spdlog::warn(
        "mosaic: the table positions put the part {:.0f} mm from the camera, the calibration "
        "saw its plate at {:.0f}-{:.0f} mm: every size on the part scales with that distance; "
        "are {}'s positions in mm?",
        check.part_mm, check.calibration_min_mm, check.calibration_max_mm,
        (project.dir / "table.csv").string());
  }
  return ReportObject{{"part_mm", check.part_mm},
                      {"calibration_min_mm", check.calibration_min_mm},
                      {"calibration_max_mm", check.calibration_max_mm},
                      {"max_ratio", options.max_ratio},
                      {"consistent", check.consistent}};
}

// Why a tile kept no feature: its pairs' fates.
std::string WhyHeld(const TileRegistration& registration, int tile) {
  int num_pairs = 0, num_usable = 0;
  for (const PairRegistration& pair : registration.pairs) {
    if (pair.tile_a != tile && pair.tile_b != tile) continue;
    ++num_pairs;
    if (pair.usable) ++num_usable;
  }
  if (num_pairs == 0)
    return "no other tile is predicted to overlap it: held by its table position alone";
  if (num_usable == 0) {
    return fmt::format(
        "none of its {} overlapping pairs had enough good matches: held by its "
        "table position alone",
        num_pairs);
  }
  return "its matches were all dropped as outliers: held by its table position alone";
}

ReportValue PairsReport(const Project& project, const TileRegistration& registration,
                        const std::vector<PairScatter>& scatter) {
  ReportValue::Array rows;
  for (const PairRegistration& pair : registration.pairs) {
    const auto it = std::find_if(scatter.begin(), scatter.end(), [&](const PairScatter& s) {
      return s.tile_a == pair.tile_a && s.tile_b == pair.tile_b;
    });
    const PairScatter pair_scatter = it == scatter.end() ? PairScatter{} : *it;
    rows.emplace_back(ReportObject{{"images", ReportValue::Array{project.tiles[pair.tile_a].image,
                                                                 project.tiles[pair.tile_b].image}},
                                   {"predicted_overlap", pair.predicted_overlap},
                                   {"candidates", pair.num_candidates},
                                   {"matched", pair.num_matched},
                                   {"inliers", pair.num_inliers},
                                   {"tag_corners", pair.num_tag_corners},
                                   {"used", pair.num_used},
                                   {"rms_px", pair.rms_px},
                                   {"usable", pair.usable},
                                   {"matched_on_adjusted_scene", pair.rescued},
                                   {"scatter", pair_scatter.scatter},
                                   {"weight_scale", pair_scatter.weight_scale}});
  }
  return rows;
}

ReportValue TilesReport(const Project& project, const TileRegistration& registration,
                        const OrthoSummary& ortho, const std::vector<double>& saturated_fraction) {
  ReportValue::Array rows;
  for (size_t i = 0; i < project.tiles.size(); ++i) {
    const bool held =
        std::find(registration.tiles_held_by_prior.begin(), registration.tiles_held_by_prior.end(),
                  static_cast<int>(i)) != registration.tiles_held_by_prior.end();
    const std::vector<int>& unprior = registration.input.tiles_without_table_prior;
    ReportObject row{{"image", project.tiles[i].image},
                     {"commanded_mm", Pair(project.tiles[i].table_pos_mm)},
                     {"adjusted_minus_commanded_mm", Pair(registration.table_adjustment_mm[i])},
                     {"held_by_prior", held},
                     {"table_prior_used",
                      !std::binary_search(unprior.begin(), unprior.end(), static_cast<int>(i))},
                     {"saturated_fraction", saturated_fraction[i]}};
    if (i < ortho.exposure.tiles.size()) {
      row.emplace_back("exposure_gain", ortho.exposure.tiles[i].gain);
      row.emplace_back("vignetting", ortho.exposure.tiles[i].vignetting);
    }
    rows.emplace_back(std::move(row));
  }
  return rows;
}

// Largest |refined - calibrated| / calibration sigma over the intrinsics the
// calibration refined (0 if held).
double IntrinsicsChangeSigmas(const CameraModel& camera, const FinalAdjustment& adjusted,
                              const IntrinsicsPrior& prior) {
  if (!adjusted.intrinsics_refined) return 0.0;
  const std::vector<int> free =
      FreeIntrinsics(static_cast<int>(camera.intrinsics.size()), prior.held);
  const Eigen::VectorXd sigma = prior.information(free, free).inverse().diagonal().cwiseSqrt();
  return ((adjusted.scene.intrinsics - camera.intrinsics)(free).cwiseQuotient(sigma))
      .cwiseAbs()
      .maxCoeff();
}

// report.mosaic's intrinsics: how the adjustment treated them.
std::string IntrinsicsTreatment(const FinalAdjustment& adjusted, const IntrinsicsPrior& prior) {
  if (!adjusted.intrinsics_refined) {
    return "held: " +
           (adjusted.intrinsics_held_why.empty() ? prior.why_held : adjusted.intrinsics_held_why);
  }
  std::string text = "refined with the calibration covariance as prior";
  if (!prior.held.empty()) {
    text += fmt::format(" (the {} the calibration held kept)", prior.held.size());
  }
  return text;
}

// report.mosaic's plate_scale_check: the table's scale against the plate, or
// why there is none.
ReportValue PlateReport(const Project& project, const PlateOnPart& plate,
                        const FinalAdjustment& adjusted) {
  if (!plate.found || !adjusted.plate_not_used.empty()) {
    const std::string why =
        plate.found ? "plate on the part not used (" + adjusted.plate_not_used + ")" : plate.brief;
    return fmt::format("{}: scale from the table positions alone (sigma {:.0f} ppm)", why,
                       adjusted.scale_sigma_ppm);
  }
  const auto names = [&](const std::vector<int>& tiles) {
    ReportValue::Array out;
    for (int i : tiles) out.emplace_back(project.tiles[i].image);
    return out;
  };
  std::string brief = plate.brief;
  if (adjusted.plate_outside_region > 0) {
    brief += fmt::format(
        "; {} marks outside the image region the calibration measured, weighted down (the "
        "lens is extrapolated there)",
        adjusted.plate_outside_region);
  }
  if (adjusted.mark_sigma_px > 0) {
    brief +=
        fmt::format("; marks weighed by their scatter, sigma {:.4f} px", adjusted.mark_sigma_px);
  }
  ReportObject report{{"brief", brief},
                      {"scale_reference", plate.scale_reference},
                      {"whole_in_tiles", names(plate.whole_in_tiles)},
                      {"seen_in_tiles", names(plate.seen_in_tiles)},
                      {"marks", static_cast<int>(adjusted.input.plate_observations.size())},
                      {"outliers", adjusted.plate_outliers},
                      {"outside_calibrated_region", adjusted.plate_outside_region},
                      {"rms_px", adjusted.plate_rms_px},
                      {"max_perspective_bias_px", plate.max_bias_correction_px},
                      {"height", plate.height_source},
                      {"height_mm", adjusted.plate_height_mm},
                      {"height_sigma_mm", adjusted.plate_height_sigma_mm}};
  if (adjusted.mark_sigma_px > 0) report.emplace_back("mark_sigma_px", adjusted.mark_sigma_px);
  if (adjusted.scale_check.ok) {
    report.emplace_back("scale_minus_1_ppm", adjusted.scale_check.scale_minus_1_ppm);
    report.emplace_back("sigma_ppm", adjusted.scale_check.sigma_ppm);
  } else {
    report.emplace_back("scale_check",
                        "not computed (the solve with the plate's scale free failed)");
  }
  return report;
}

// report.mosaic.overlap_ties: the overlap alignments (OverlapsToAlign), with
// the final solve's residual RMS of the used ones' observations (their
// tracks follow in `ties`' order from first_observation on).
ReportValue OverlapTiesReport(const Project& project, const std::vector<OverlapTie>& ties,
                              int first_observation, const Eigen::Matrix2Xd& residual_px,
                              std::string* brief) {
  ReportValue::Array rows;
  int index = first_observation;
  int num_used = 0;
  for (const OverlapTie& tie : ties) {
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eigen(tie.alignment.covariance_px2);
    ReportObject row{
        {"images",
         ReportValue::Array{project.tiles[tie.tile_a].image, project.tiles[tie.tile_b].image}},
        {"used", tie.used},
        {"pixels", tie.alignment.num_pixels},
        {"shift_px", ReportValue::Array{tie.alignment.shift_px.x(), tie.alignment.shift_px.y()}},
        {"sigma_px", ReportValue::Array{std::sqrt(std::max(0.0, eigen.eigenvalues()(1))),
                                        std::sqrt(std::max(0.0, eigen.eigenvalues()(0)))}},
        {"covariance_px2",
         ReportValue::Array{ReportValue::Array{tie.alignment.covariance_px2(0, 0),
                                               tie.alignment.covariance_px2(0, 1)},
                            ReportValue::Array{tie.alignment.covariance_px2(1, 0),
                                               tie.alignment.covariance_px2(1, 1)}}}};
    if (tie.alignment.usable) row.emplace_back("prior_chi2", tie.prior_chi2);
    if (tie.used) {
      ++num_used;
      const double sum_squares =
          residual_px.col(index).squaredNorm() + residual_px.col(index + 1).squaredNorm();
      index += 2;
      row.emplace_back("rms_px", std::sqrt(sum_squares / 2.0));
    } else {
      row.emplace_back("why", tie.why);
    }
    rows.emplace_back(std::move(row));
  }
  *brief = ties.empty()
               ? "no overlap of a tile held by its table prior alone, or tied to one "
                 "neighbour only, with another tile to align"
               : fmt::format("{} of {} overlaps of held or weakly tied tiles aligned directly",
                             num_used, ties.size());
  return ReportObject{{"brief", *brief}, {"ties", std::move(rows)}};
}

// The holes of project.yaml's features where their near_px puts them on
// `scene`, and the features' names.
struct HolesToTie {
  std::vector<TieHole> holes;
  std::vector<std::string> names;
};

HolesToTie LocateHolesToTie(const Project& project, const LensProjection& lens,
                            const PlaneScene& scene) {
  HolesToTie located;
  for (const FeatureSpec& feature : project.features) {
    const auto it = std::find_if(project.tiles.begin(), project.tiles.end(),
                                 [&](const TilePosition& t) { return t.image == feature.image; });
    if (it == project.tiles.end()) continue;
    const auto near_mm = PartPointOfTilePixel(
        lens, scene, static_cast<int>(it - project.tiles.begin()), feature.near_px);
    if (!near_mm) continue;
    located.holes.push_back({*near_mm, 0.5 * feature.diameter_mm});
    located.names.push_back(feature.name);
  }
  return located;
}

// The pairs of tiles (lower index first) that usable matches or hole ties
// link.
std::vector<std::pair<int, int>> LinkedTiles(const TileRegistration& registration,
                                             const std::vector<HoleTie>& ties) {
  std::vector<std::pair<int, int>> links;
  for (const PairRegistration& pair : registration.pairs) {
    if (pair.usable) links.emplace_back(pair.tile_a, pair.tile_b);
  }
  for (const HoleTie& tie : ties) {
    for (size_t u = 0; u < tie.tiles.size(); ++u) {
      for (size_t v = u + 1; v < tie.tiles.size(); ++v) {
        links.emplace_back(std::min(tie.tiles[u], tie.tiles[v]),
                           std::max(tie.tiles[u], tie.tiles[v]));
      }
    }
  }
  return links;
}

// The final adjustment with the hole ties (AdjustWithHoleTies), of the
// registered scene and any variant of its input.
struct TiedSolver {
  const CameraModel& camera;
  const PlaneScene& registered;
  const PlateOnPart& plate;
  const IntrinsicsPrior& prior;
  const FinalAdjustmentOptions& options;
  const std::vector<HoleTie>& ties;
  const HoleTieOptions& tie_options;

  TiedAdjustment operator()(const PlaneBundleInput& input) const {
    return AdjustWithHoleTies(camera, input, registered, plate, prior, options, ties, tie_options);
  }
};

// Table positions the features contradict (table_prior_check.h): left out
// of *input, *tied the solve without them; each as found, with the bound it
// exceeded.
std::vector<std::pair<TablePriorTest, double>> LeaveOutWrongTablePriors(const TiedSolver& solve,
                                                                        PlaneBundleInput* input,
                                                                        TiedAdjustment* tied) {
  // Every solve without some priors is kept for the one the search settles on.
  std::vector<TiedAdjustment> solves;
  const auto as_solve = [](const TiedAdjustment& t) {
    return TablePriorSolve{t.adjusted.summary.usable, t.adjusted.scene.table_pos_mm,
                           t.adjusted.scene.covariance};
  };
  const WrongTablePriors wrong = FindWrongTablePriors(
      input->commanded_table_pos_mm, input->table_sigma_mm, as_solve(*tied),
      [&](const std::vector<int>& without) {
        PlaneBundleInput trial = *input;
        trial.tiles_without_table_prior = without;
        solves.push_back(solve(trial));
        return as_solve(solves.back());
      },
      TablePriorCheckOptions());
  if (wrong.solve > 0) {
    input->tiles_without_table_prior = wrong.tiles;
    *tied = std::move(solves[wrong.solve - 1]);
  }
  return wrong.found;
}

// A table that scatters more than table.sigma_mm says, and no wrong
// position explains it: its priors are weighed by the scatter estimated
// (their variance component) into input->table_sigma_mm, *tied solved so,
// so that the covariance, and so every sigma's table part, rests on what
// the data show. Never narrower than stated: the test is one-sided.
void WeighTablePriorsByScatter(const TiedSolver& solve, PlaneBundleInput* input,
                               TiedAdjustment* tied) {
  const auto solve_weighed_by = [&](double sigma_mm) {
    PlaneBundleInput weighed = *input;
    weighed.table_sigma_mm = sigma_mm;
    return solve(weighed);
  };
  const auto scatter_of = [&](const TiedAdjustment& t, double sigma_mm) {
    return EstimateTableSigma(input->commanded_table_pos_mm, t.adjusted.scene.table_pos_mm,
                              t.adjusted.scene.covariance, sigma_mm,
                              input->tiles_without_table_prior);
  };
  const double stated_mm = input->table_sigma_mm;
  TableSigmaEstimate scatter = scatter_of(*tied, stated_mm);
  // Looser priors can check positions only beyond the gauge's 4 dof (shift,
  // turn, scale): 3 tiles with priors or more.
  const size_t num_with_prior =
      input->commanded_table_pos_mm.size() - input->tiles_without_table_prior.size();
  if (!scatter.ok && num_with_prior >= 3) {
    // Priors so stiff that the features check no position (redundancy < 1):
    // a table stated to 0.1 um that scatters 20 um was held to its
    // positions, and on markers seed 101 the measurements were off by up to
    // 25 of their sigmas.
    // Seen with priors 100x looser, the scatter has its full redundancy.
    const TiedAdjustment loose = solve_weighed_by(kLooseTableSigmaFactor * stated_mm);
    if (loose.adjusted.summary.usable)
      scatter = scatter_of(loose, kLooseTableSigmaFactor * stated_mm);
  }
  if (!scatter.ok || TableSigmaConsistent(scatter, stated_mm)) return;
  // Each estimate rests on the weights it was solved with: too stiff ones
  // squeeze the positions' scatter, so the estimate is repeated until it
  // stands (stated 0.0005 mm on markers seed 283, which scatters 0.017,
  // the first pass weighed it 0.009, the second 0.0168, and the third
  // estimate moved by less than 2 %).
  double used_mm = stated_mm;
  for (int pass = 0; pass < kMaxTableSigmaPasses && scatter.ok &&
                     scatter.sigma_mm > (1.0 + kTableSigmaSettled) * used_mm;
       ++pass) {
    TiedAdjustment retried = solve_weighed_by(scatter.sigma_mm);
    if (!retried.adjusted.summary.usable) break;
    used_mm = scatter.sigma_mm;
    *tied = std::move(retried);
    scatter = scatter_of(*tied, used_mm);
    spdlog::info("mosaic: table priors weighed by {:.4f} mm (pass {}): they scatter {:.4f} mm",
                 used_mm, pass + 1, scatter.sigma_mm);
  }
  input->table_sigma_mm = used_mm;
}

// The report of the hole ties (`names`: the holes' features) in the final
// adjustment `tied` (its residuals: residual_px): each kept tie's tiles and
// residual, the dropped ones, and *brief.
ReportValue HoleTiesReport(const Project& project, const TiedAdjustment& tied,
                           const Eigen::Matrix2Xd& residual_px, const std::vector<HoleTie>& ties,
                           const std::vector<std::string>& names, bool no_holes,
                           std::string* brief) {
  ReportValue::Array rows;
  int index = tied.first_tie_observation;
  size_t num_cut = 0;
  for (const HoleTie& tie : tied.kept) num_cut += tie.tiles.size() - tie.num_whole;
  for (const HoleTie& tie : tied.kept) {
    ReportValue::Array images, cut;
    double sum_squares = 0.0;
    for (size_t v = 0; v < tie.tiles.size(); ++v) {
      images.emplace_back(project.tiles[tie.tiles[v]].image);
      if (static_cast<int>(v) >= tie.num_whole) cut.emplace_back(project.tiles[tie.tiles[v]].image);
      sum_squares += residual_px.col(index++).squaredNorm();
    }
    rows.emplace_back(
        ReportObject{{"feature", names[tie.hole]},
                     {"images", std::move(images)},
                     {"cut_in", std::move(cut)},
                     {"rms_px", std::sqrt(sum_squares / static_cast<double>(tie.tiles.size()))}});
  }
  ReportValue::Array dropped;
  for (const int t : tied.dropped) dropped.emplace_back(names[ties[t].hole]);
  if (tied.ties_failed) {
    *brief = "the adjustment with them failed (" + tied.failure + "): not used";
  } else if (no_holes) {
    *brief = "no feature to tie with";
  } else if (ties.empty()) {
    *brief = "no hole ties tiles: none is seen whole by one tile and by another too";
  } else {
    const bool one = tied.kept.size() == 1;
    *brief = fmt::format("{} {} the tiles that see {} (whole in one at least; {} cut view{})",
                         tied.kept.size(), one ? "hole ties" : "holes tie", one ? "it" : "them",
                         num_cut, num_cut == 1 ? "" : "s");
  }
  if (!dropped.empty()) {
    *brief += fmt::format("; {} dropped: their views disagree beyond their sigma", dropped.size());
  }
  if (tied.num_cut_views_dropped > 0) {
    *brief += fmt::format("; {} cut view{} left out: {} disagreed with the whole views",
                          tied.num_cut_views_dropped, tied.num_cut_views_dropped == 1 ? "" : "s",
                          tied.num_cut_views_dropped == 1 ? "it" : "they");
  }
  return ReportObject{
      {"brief", *brief}, {"ties", std::move(rows)}, {"dropped", std::move(dropped)}};
}

// The final adjustment (the plate on the part, the intrinsics prior) with
// the holes of project.yaml's features that several tiles see whole as tie
// points (pipeline/measure/hole_ties.h), fitted on the registered scene
// (`geometry`: the mosaic's grid on it, ComputeOrthoGeometry): a
// view's centre is an image position, which the final adjustment's small
// changes of the scene leave as it is. A tie the solve finds inconsistent is
// dropped and the solve run again; the kept ties' tracks join
// registration->input, and its tiles held by the prior are the final
// solve's.
struct FinalOutcome {
  FinalAdjustment adjusted;
  std::string ties_brief;
  ReportValue ties_report;  // report.mosaic's hole_ties
  std::string overlap_brief;
  ReportValue overlap_report;  // report.mosaic's overlap_ties
  // Table priors left out (registration->input.tiles_without_table_prior),
  // each as it was found, and the bound it exceeded.
  std::vector<std::pair<TablePriorTest, double>> table_priors_left_out;
  // The features' holes for the mosaic to keep whole (orthorectify.h): where
  // their views put them, else where near_px does, within a quarter of the
  // diameter (project-format.md).
  std::vector<OrthoDisc> holes_to_keep_whole;
  // What the mosaic's interpolator samples of the tiles (InterpolatorSamples),
  // computed during the solves, whose single thread leaves a core free.
  std::vector<ImageF> samples;
  double fit_seconds = 0.0;      // the ties' hole fits
  double overlap_seconds = 0.0;  // the held tiles' overlap alignments
  double solve_seconds = 0.0;    // the final adjustment's solves
};

FinalOutcome FinalAdjustmentWithHoles(const Project& project, const std::vector<ImageF>& tiles,
                                      const CameraModel& camera, const OrthoGeometry& geometry,
                                      const PlateOnPart& plate, const IntrinsicsPrior& prior,
                                      const FinalAdjustmentOptions& options, int num_threads,
                                      TileRegistration* registration) {
  const auto start = std::chrono::steady_clock::now();
  // The registered scene; the overlap ties add their tracks to it.
  const PlaneScene& registered = registration->scene;
  const MrcalLensProjection lens(camera);
  const HolesToTie to_tie = LocateHolesToTie(project, lens, registered);
  const std::vector<TieHole>& holes = to_tie.holes;
  const std::optional<OrthoGeometry> fine = MeasurementGeometry(camera, registered, geometry);
  const OrthoGeometry& views_geometry = fine ? *fine : geometry;
  const double tile_px_per_mosaic_px = TilePxPerMosaicPx(views_geometry);
  const HoleViewInputs in{registered, lens, views_geometry, camera, tiles,
                          // Not compensated yet (Orthorectify estimates it): each
                          // rim's step fit takes its own levels and ramp.
                          std::vector<TileExposure>(tiles.size()),
                          tile_px_per_mosaic_px > 0.0 ? 1.0 / tile_px_per_mosaic_px : 1.0};
  HoleTieOptions tie_options;
  tie_options.num_threads = num_threads;
  std::vector<std::optional<Eigen::Vector2d>> located_mm;
  const std::vector<HoleTie> ties = FindHoleTies(in, holes, tie_options, &located_mm);
  FinalOutcome result;
  for (size_t i = 0; i < holes.size(); ++i) {
    result.holes_to_keep_whole.push_back(
        located_mm[i] ? OrthoDisc{*located_mm[i], holes[i].radius_mm}
                      : OrthoDisc{holes[i].near_part_mm, 1.5 * holes[i].radius_mm});
  }
  result.fit_seconds = SecondsSince(start);

  // Tiles that no match placed, or that matches and holes tie to one
  // neighbour only: their other overlaps, aligned directly, as tracks.
  const auto overlap_start = std::chrono::steady_clock::now();
  OverlapTieOptions overlap_options;
  overlap_options.num_threads = num_threads;
  const std::vector<OverlapTie> overlap_ties =
      FindOverlapTies(views_geometry, tiles,
                      OverlapsToAlign(views_geometry, registration->tiles_held_by_prior,
                                      LinkedTiles(*registration, ties)),
                      holes, registration->input.table_sigma_mm, overlap_options);
  const int first_overlap_observation = static_cast<int>(registration->input.observations.size());
  AddOverlapTieTracks(overlap_ties, &registration->input, &registration->scene);
  result.overlap_seconds = SecondsSince(overlap_start);

  // On every thread: the core the solves leave while they run, both after.
  OrthoOptions samples_options;
  samples_options.num_threads = num_threads;
  std::future<std::vector<ImageF>> samples_beside =
      std::async(std::launch::async,
                 [&tiles, samples_options] { return InterpolatorSamples(tiles, samples_options); });
  const TiedSolver solve{camera, registered, plate, prior, options, ties, tie_options};
  PlaneBundleInput& input = registration->input;
  TiedAdjustment tied = solve(input);
  result.table_priors_left_out = LeaveOutWrongTablePriors(solve, &input, &tied);
  WeighTablePriorsByScatter(solve, &input, &tied);
  result.adjusted = std::move(tied.adjusted);
  result.samples = samples_beside.get();
  result.solve_seconds = SecondsSince(start) - result.fit_seconds - result.overlap_seconds;
  result.overlap_report =
      OverlapTiesReport(project, overlap_ties, first_overlap_observation,
                        result.adjusted.scene.residual_px, &result.overlap_brief);

  result.ties_report = HoleTiesReport(project, tied, result.adjusted.scene.residual_px, ties,
                                      to_tie.names, holes.empty(), &result.ties_brief);
  // The tracks (the plate's observations stay the final adjustment's).
  registration->input.observations = result.adjusted.input.observations;
  registration->input.num_tracks = result.adjusted.input.num_tracks;
  // Held by the table prior alone: what the final solve saw no observation
  // of (no match, tie or plate mark).
  registration->tiles_held_by_prior = result.adjusted.summary.tiles_without_observations;
  return result;
}

// COLMAP's verified SIFT matches between the tiles of `pairs` (those the
// table prior makes overlap), where the features use them (none for Harris
// alone); throws StageFailedError if COLMAP fails.
std::vector<ColmapPairMatches> SiftMatches(const StageContext& context,
                                           const std::vector<PairRegistration>& pairs) {
  if (context.mosaic_features == FeatureSource::kHarris) return {};
  std::vector<fs::path> tile_paths;
  for (const TilePosition& tile : context.project.tiles)
    tile_paths.push_back(context.project.TilePath(tile.image));
  ColmapSiftOptions sift_options;
  sift_options.num_threads = context.num_threads;
  sift_options.sample_bits = context.project.sample_bits;
  std::vector<std::pair<int, int>> tile_pairs;
  for (const PairRegistration& pair : pairs) tile_pairs.emplace_back(pair.tile_a, pair.tile_b);
  const ColmapSiftResult sift = ColmapSiftMatches(tile_paths, sift_options, tile_pairs);
  spdlog::info("mosaic: {}", sift.brief);
  if (!sift.usable) throw StageFailedError(Stage::kMosaic, sift.brief);
  return sift.matches.pairs;
}

// The table's scatter about the features against table.sigma_mm (a check,
// warned about where it fails), and the sigma the priors were weighed by
// (FinalAdjustmentWithHoles).
ReportValue TableSigmaCheck(const Project& project, const PlaneBundleInput& input,
                            const PlaneScene& adjusted) {
  const double used_sigma_mm = input.table_sigma_mm;
  const TableSigmaEstimate table_sigma =
      EstimateTableSigma(input.commanded_table_pos_mm, adjusted.table_pos_mm, adjusted.covariance,
                         used_sigma_mm, input.tiles_without_table_prior);
  if (!table_sigma.ok) return "no estimate: no covariance or too few table positions checked";
  const bool consistent = TableSigmaConsistent(table_sigma, project.table_sigma_mm);
  if (!consistent) {
    spdlog::warn(
        "mosaic: the table positions scatter {:.4f} mm about where the features put the tiles, "
        "{:.1f} times table.sigma_mm {} ({:.1f} dof), which no wrong position explains: the "
        "adjustment weighs them, and every sigma's table part assumes, {:.4f} mm; check "
        "table.sigma_mm and table.csv",
        table_sigma.sigma_mm, table_sigma.sigma_mm / project.table_sigma_mm, project.table_sigma_mm,
        table_sigma.redundancy, used_sigma_mm);
  }
  return ReportObject{{"stated_mm", project.table_sigma_mm},
                      {"estimated_mm", table_sigma.sigma_mm},
                      {"redundancy", table_sigma.redundancy},
                      {"consistent", consistent},
                      {"used_mm", used_sigma_mm}};
}

// The table positions the features contradicted, left out of the
// adjustment: warned about and reported.
ReportValue::Array PriorsLeftOut(const Project& project, const TileRegistration& registration,
                                 const std::vector<std::pair<TablePriorTest, double>>& left_out) {
  ReportValue::Array rows;
  for (const auto& [test, bound] : left_out) {
    const Eigen::Vector2d off = registration.table_adjustment_mm[test.tile];
    spdlog::warn(
        "mosaic: {}: the features place it {:.3f} mm ({:+.3f}, {:+.3f}) from its table.csv "
        "position, beyond table.sigma_mm {} (w^2 {:.1f}, bound {:.1f}): that position is left out "
        "of the adjustment; check table.csv",
        project.tiles[test.tile].image, off.norm(), off.x(), off.y(), project.table_sigma_mm,
        test.w2, bound);
    rows.emplace_back(ReportObject{{"image", project.tiles[test.tile].image},
                                   {"adjusted_minus_commanded_mm", Pair(off)},
                                   {"w2", test.w2},
                                   {"bound", bound}});
  }
  return rows;
}

// report.mosaic.tile_groups: the groups of tiles that what the final
// adjustment saw ties (TiedTileGroups), by image; warned about where there
// are two or more.
ReportValue::Array TileGroupsReport(const Project& project, const PlaneBundleInput& input) {
  const std::vector<std::vector<int>> groups =
      TiedTileGroups(input, static_cast<int>(project.tiles.size()));
  ReportValue::Array rows;
  std::string listed;
  for (const std::vector<int>& group : groups) {
    ReportValue::Array images;
    std::string names;
    for (const int tile : group) {
      images.emplace_back(project.tiles[tile].image);
      names += (names.empty() ? "" : " ") + project.tiles[tile].image;
    }
    rows.emplace_back(std::move(images));
    listed += (listed.empty() ? "[" : " [") + names + "]";
  }
  if (groups.size() > 1) {
    spdlog::warn(
        "mosaic: the tiles fall into {} groups that no match, hole or plate seen in two of them "
        "ties together: {}; table.csv alone places the groups against each other, and every "
        "measurement between two of them carries its sigma (the table part): tiles that overlap "
        "by 30-50 %, with texture, holes or markers there, would tie them",
        groups.size(), listed);
  }
  return rows;
}

ReportValue::Array HeldTilesReport(const Project& project, const TileRegistration& registration) {
  ReportValue::Array held;
  for (int tile : registration.tiles_held_by_prior) {
    held.emplace_back(
        ReportObject{{"image", project.tiles[tile].image}, {"why", WhyHeld(registration, tile)}});
  }
  return held;
}

// Each tile's fraction of pixels at full scale; a warning for each tile
// with more than kOverexposedFraction of them. The rims beside them are left
// out, so an overexposed tile loses holes (circle_measure.h).
constexpr double kOverexposedFraction = 0.02;
std::vector<double> WarnOfOverexposedTiles(const Project& project,
                                           const std::vector<ImageF>& tiles) {
  std::vector<double> fractions;
  for (size_t i = 0; i < tiles.size(); ++i) {
    fractions.push_back(SaturatedFraction(tiles[i]));
    if (fractions.back() > kOverexposedFraction) {
      spdlog::warn(
          "mosaic: {}: {:.1f} % of its pixels at full scale (overexposed): the rims beside them "
          "are left out, or the holes refused; lower the exposure",
          project.tiles[i].image, 100.0 * fractions.back());
    }
  }
  return fractions;
}

// Why the orthorectification failed: its brief, and the tiles the exposure
// fit found nothing in with the likely cause.
std::string WhyOrthoFailed(const Project& project, const std::vector<ImageF>& tiles,
                           const OrthoSummary& summary) {
  std::string why = summary.brief;
  const ExposureOptions exposure_options;
  for (const int i : summary.exposure.tiles_without_samples) {
    const double median = MedianOfImage(tiles[i]);
    const char* cause = median < exposure_options.min_value ? "a black or underexposed image?"
                        : median > exposure_options.max_value
                            ? "a white or saturated image?"
                            : "where it overlaps the others it is all black or saturated";
    why += fmt::format(
        "; {} has no pixel between {:.0f} % and {:.0f} % of full scale where it overlaps "
        "another tile (median {:.1f} %): {}",
        project.tiles[i].image, 100.0 * exposure_options.min_value,
        100.0 * exposure_options.max_value, 100.0 * median, cause);
  }
  return why;
}

// mosaic/scene.json's content: the adjusted scene without its tracks (they
// go to colmap/), and what the measure stage checks it against.
SavedScene SceneToSave(const Project& project, const CameraModel& camera,
                       const TileRegistration& registration, const FinalAdjustment& adjusted) {
  SavedScene saved;
  saved.scene = registration.scene;
  saved.scene.track_xy_mm.resize(2, 0);
  for (const TilePosition& tile : project.tiles) {
    saved.tile_images.push_back(tile.image);
    saved.commanded_table_pos_mm.push_back(tile.table_pos_mm);
  }
  saved.tiles_held_by_prior = registration.tiles_held_by_prior;
  saved.tiles_without_table_prior = registration.input.tiles_without_table_prior;
  saved.table_sigma_mm = registration.input.table_sigma_mm;  // as weighed
  saved.rms_px = registration.rms_px;
  saved.lens_model = camera.lens_model;
  saved.intrinsics_refined = adjusted.intrinsics_refined;
  if (adjusted.intrinsics_refined)
    saved.intrinsics_information = adjusted.input.intrinsics_information;
  return saved;
}

ReportValue ExposureReport(const ExposureSummary& exposure) {
  return ReportObject{{"brief", exposure.brief},
                      {"converged", exposure.converged},
                      {"relative_sigma_before", exposure.relative_sigma_before},
                      {"relative_sigma_after", exposure.relative_sigma_after},
                      {"max_pair_step_before", exposure.max_pair_step_before},
                      {"max_pair_step_after", exposure.max_pair_step_after}};
}

ReportValue OrthoReport(const OrthoSummary& summary) {
  return ReportObject{{"brief", summary.brief},
                      {"covered_fraction", summary.covered_fraction},
                      {"clipped_fraction", summary.clipped_fraction},
                      {"tile_px_per_mosaic_px", summary.tile_px_per_mosaic_px},
                      {"lens_table_max_error_px", summary.lens_table_max_error_px},
                      {"features_kept_whole", summary.features_kept_whole},
                      {"features_blended", summary.features_blended}};
}

ReportValue ColmapReport(const ColmapExportSummary& colmap) {
  return ReportObject{{"dir", kColmapDirName},
                      {"camera_model", colmap.camera_model},
                      {"undistorted", colmap.undistorted},
                      {"images", colmap.num_images},
                      {"points", colmap.num_points},
                      {"observations", colmap.num_observations},
                      {"mean_point_error_px", colmap.mean_point_error_px}};
}

}  // namespace

RegisterTilesOptions MosaicRegistrationOptions(const StageContext& context) {
  RegisterTilesOptions options;
  options.compute_covariance = false;  // the final adjustment's
  options.num_threads = context.num_threads;
  options.bundle.num_threads = context.num_threads;
  options.features = context.mosaic_features;
  return options;
}

PreparedTiles PrepareMosaicTiles(const Project& project, const RegisterTilesOptions& options) {
  std::vector<Eigen::Vector2d> commanded_mm;
  for (const TilePosition& tile : project.tiles) commanded_mm.push_back(tile.table_pos_mm);
  return PrepareTiles(
      static_cast<int>(project.tiles.size()), project.image_width_px, project.image_height_px,
      [&project](int i) { return TileImage(project, i); }, commanded_mm, options);
}

// The final adjustment's outcome in the log: its ties, and warnings of
// what it found.
void LogFinalAdjustment(const FinalOutcome& outcome) {
  const FinalAdjustment& adjusted = outcome.adjusted;
  spdlog::info("mosaic: holes: {}", outcome.ties_brief);
  spdlog::info("mosaic: overlaps: {}", outcome.overlap_brief);
  spdlog::info("mosaic: final {}", adjusted.summary.brief);
  if (adjusted.observation_sigma_scale > 1.0) {
    spdlog::info(
        "mosaic: the matches scatter {:.2f}x their declared sigma: the covariance is widened "
        "accordingly",
        adjusted.observation_sigma_scale);
  }
  if (adjusted.summary.usable && adjusted.scale_check.ok &&
      std::abs(adjusted.scale_check.scale_minus_1_ppm) > kPlateScaleUnitsPpm) {
    spdlog::warn(
        "mosaic: the calibration plate on the part measures {:.4f} times its size at the scale "
        "of table.csv's positions: are they in mm, and is project.yaml's board the plate used?",
        1.0 + 1e-6 * adjusted.scale_check.scale_minus_1_ppm);
  }
}

// What the stage writes into the staging directory: the mosaic (on a thread
// of its own, which RunProject waits for before it commits out/), the
// scene, the COLMAP model.
struct MosaicFiles {
  MosaicReport report;  // its file, grid and RMS; `extra` empty
  ColmapExportSummary colmap;
  double seconds = 0.0;  // scene.json, colmap/ (mosaic.png: in the background)
};

MosaicFiles WriteMosaicFiles(StageContext& context, const OrthoMosaic& mosaic,
                             const CameraModel& camera, const CameraModel& scene_camera,
                             const TileRegistration& registration,
                             const FinalAdjustment& adjusted) {
  const auto start = std::chrono::steady_clock::now();
  // The samples the file will hold, for the measure stage and report.html,
  // while the file is written on another thread (0.05 s of CPU on the demo,
  // WriteOrthoMosaic).
  context.mosaic =
      std::make_shared<const StoredImage>(QuantizeImage(mosaic.pixels, kMosaicBitDepth));
  const fs::path mosaic_path = context.staging_dir / kMosaicName;
  const OrthoGrid grid = mosaic.grid;
  context.pending_writes.push_back(
      std::async(std::launch::async, [mosaic_path, grid, samples = context.mosaic] {
        const auto write_start = std::chrono::steady_clock::now();
        WriteOrthoMosaic(mosaic_path, grid, *samples);
        spdlog::debug("mosaic: {} written in {:.2f} s (in the background)", mosaic_path.string(),
                      SecondsSince(write_start));
      }));
  MosaicFiles files;
  files.report = OrthoMosaicReport(mosaic_path, grid);
  files.report.rms_px = registration.rms_px;
  fs::create_directories(context.staging_dir / "mosaic");
  const SavedScene saved = SceneToSave(context.project, camera, registration, adjusted);
  WriteSceneJson(saved, context.staging_dir / kSceneName);
  files.colmap =
      WriteColmapModel(context.staging_dir / kColmapDirName, scene_camera, registration.scene,
                       registration.input.observations, saved.tile_images);
  files.seconds = SecondsSince(start);
  return files;
}

void RunMosaicStage(StageContext& context) {
  const Project& project = context.project;
  const auto stage_start = std::chrono::steady_clock::now();
  if (project.tiles.size() < 2) {
    throw InputError((project.dir / "table.csv").string(),
                     fmt::format("{} tile(s): a mosaic needs at least 2", project.tiles.size()));
  }
  const fs::path camera_path = CameraModelPath(context);
  CameraModel camera = ReadCameraModel(camera_path);
  std::vector<Vector6d> rt_cam_from_plates;
  std::future<TimedPrior> pending_prior = CalibrationPrior(context, &camera, &rt_cam_from_plates);
  const RegisterTilesOptions register_options = MosaicRegistrationOptions(context);
  PreparedTiles prepared = context.mosaic_tiles.valid()
                               ? context.mosaic_tiles.get()
                               : PrepareMosaicTiles(project, register_options);
  // All tiles have one size (LoadProject, PrepareTiles): the first's is theirs.
  CheckTileSize(project, 0, prepared.width_px, prepared.height_px, camera);
  double read_seconds = SecondsSince(stage_start);

  const int num_tiles = static_cast<int>(project.tiles.size());
  if (context.progress) context.progress(num_tiles, num_tiles + 4, "register tiles");
  TileRegistration registration =
      RegisterTiles(prepared, project.table_sigma_mm, camera, SiftMatches(context, prepared.pairs));
  prepared = {};  // its matching images (the demo's: 143 MB) serve no later step
  spdlog::info("mosaic: {}", registration.brief);

  // The tiles themselves, converted again: not held beside the matching
  // images. Their overexposure is told even where the registration failed
  // (it may be why).
  const auto read_start = std::chrono::steady_clock::now();
  const auto tile_images =
      std::make_shared<const std::vector<ImageF>>(TileImages(project, context.num_threads));
  const std::vector<ImageF>& tiles = *tile_images;
  const std::vector<double> saturated_fraction = WarnOfOverexposedTiles(project, tiles);
  read_seconds += SecondsSince(read_start);
  if (!registration.usable) throw StageFailedError(Stage::kMosaic, registration.brief);

  // Each pair's matches weighted by their own scatter.
  const std::vector<PairScatter> pair_scatter = WeightPairsByScatter(
      registration.track_anchor_observation, registration.scene.residual_px, &registration.input);

  // The tiles' exposure for the mosaic, on the registered scene (gains and
  // vignetting do not move with the final adjustment's hundredths of a
  // pixel), on a thread of its own: it takes what the plate search and the
  // hole ties leave of the cores.
  // The mosaic's grid on the registered scene serves it and the hole ties.
  OrthoOptions exposure_ortho;
  exposure_ortho.gsd_mm = project.mosaic_gsd_mm;
  exposure_ortho.num_threads = 1;
  exposure_ortho.max_pixels = MosaicPixelLimit();
  const OrthoGeometry registered_geometry =
      MosaicGeometry(project, camera, registration.scene, exposure_ortho);
  std::future<ExposureSummary> exposure_beside =
      std::async(std::launch::async, [&registered_geometry, &tiles, exposure_ortho] {
        return EstimateTileExposure(registered_geometry, tiles, exposure_ortho);
      });

  // The final adjustment: the plate on the part, the intrinsics prior.
  PlateOnPart plate;
  if (project.board) {
    PlateOnPartOptions plate_options;
    plate_options.height_mm = project.plate_height_mm;
    plate_options.num_threads = context.num_threads;
    plate = FindPlateOnPart(tiles, *project.board, camera, registration.input, registration.scene,
                            plate_options);
  } else {
    plate.brief = "no plate on the part: project.yaml has no board";
  }
  spdlog::info("mosaic: {}", plate.brief);
  const TimedPrior timed_prior = pending_prior.get();
  const IntrinsicsPrior& prior = timed_prior.prior;
  FinalAdjustmentOptions final_options;
  final_options.bundle = register_options.bundle;
  if (context.progress)
    context.progress(num_tiles + 1, num_tiles + 4, "tie holes, final adjustment");
  FinalOutcome final_outcome =
      FinalAdjustmentWithHoles(project, tiles, camera, registered_geometry, plate, prior,
                               final_options, context.num_threads, &registration);
  FinalAdjustment& adjusted = final_outcome.adjusted;
  LogFinalAdjustment(final_outcome);
  if (!adjusted.summary.usable) throw StageFailedError(Stage::kMosaic, adjusted.summary.brief);
  if (!adjusted.intrinsics_held_why.empty()) {
    spdlog::warn(
        "mosaic: the calibration's intrinsics are kept as they are: {}. Their uncertainty is "
        "then left out of every sigma (its calibration part is 0). The lens is known only near "
        "the calibration plate's marks; calibration images with the plate near the image's "
        "corners and edges would measure it there",
        adjusted.intrinsics_held_why);
  }
  const double intrinsics_change_sigmas = IntrinsicsChangeSigmas(camera, adjusted, prior);
  if (intrinsics_change_sigmas > kMaxIntrinsicsChangeSigmas) {
    spdlog::warn(
        "mosaic: the tiles moved the calibrated intrinsics by up to {:.1f} of their calibration "
        "sigmas: the calibration's uncertainty is understated, and with it the calibration part "
        "of every sigma. More calibration images, with the plate near the image's corners and "
        "edges too, would measure the lens better",
        intrinsics_change_sigmas);
  }
  registration.scene = adjusted.scene;
  registration.bundle = adjusted.summary;
  registration.rms_px = adjusted.summary.final_rms_px;
  registration.table_adjustment_mm = adjusted.summary.table_adjustment_mm;
  ReportValue table_sigma_check = TableSigmaCheck(project, registration.input, adjusted.scene);
  ReportValue::Array priors_left_out =
      PriorsLeftOut(project, registration, final_outcome.table_priors_left_out);
  registration.plane_tilt_deg = adjusted.summary.plane_tilt_deg;
  const ReportValue working_distance =
      WorkingDistanceReport(adjusted.scene, rt_cam_from_plates, project);
  // The camera of the adjusted scene: its (refined or held) intrinsics.
  CameraModel scene_camera = camera;
  scene_camera.intrinsics = adjusted.scene.intrinsics;

  if (context.progress) context.progress(num_tiles + 2, num_tiles + 4, "orthorectify");
  OrthoOptions ortho_options;
  ortho_options.gsd_mm = project.mosaic_gsd_mm;
  ortho_options.num_threads = context.num_threads;
  ortho_options.max_pixels = exposure_ortho.max_pixels;
  const ExposureSummary exposure = exposure_beside.get();
  OrthoResult ortho =
      Orthorectify(scene_camera, registration.scene, tiles, ortho_options,
                   final_outcome.holes_to_keep_whole, {&exposure, &final_outcome.samples});
  final_outcome.samples = {};  // the tiles' coefficients (the demo's: 69 MB) serve no later step
  spdlog::info("mosaic: {}", ortho.summary.brief);
  if (!ortho.summary.usable)
    throw StageFailedError(Stage::kMosaic, WhyOrthoFailed(project, tiles, ortho.summary));

  if (context.progress) context.progress(num_tiles + 3, num_tiles + 4, "write mosaic");
  context.tiles = tile_images;
  MosaicFiles files =
      WriteMosaicFiles(context, ortho.mosaic, camera, scene_camera, registration, adjusted);
  MosaicReport& report = files.report;

  const Eigen::Matrix2d& a = registration.image_px_per_table_mm;
  report.extra = ReportObject{
      {"brief", registration.brief},
      {"camera", context.Published(camera_path).string()},
      {"num_tracks", registration.input.num_tracks},
      {"num_observations", static_cast<int>(registration.input.observations.size())},
      {"num_dropped_observations", registration.num_dropped_observations},
      {"num_tags_detected", registration.num_tags_detected},
      {"unit_weight_sigma", registration.bundle.unit_weight_sigma},
      // > 1: the matches scattered more than declared; their sigma (and so
      // the covariance) was widened by this factor (FinalAdjustmentOptions).
      {"observation_sigma_scale", adjusted.observation_sigma_scale},
      {"plane_tilt_deg", registration.plane_tilt_deg},
      {"image_px_per_table_mm", ReportValue::Array{ReportValue::Array{a(0, 0), a(0, 1)},
                                                   ReportValue::Array{a(1, 0), a(1, 1)}}},
      {"image_motion", registration.motion_brief},
      {"covariance_computed", registration.scene.covariance.size() > 0},
      {"intrinsics", IntrinsicsTreatment(adjusted, prior)},
      {"intrinsics_max_change_sigmas", intrinsics_change_sigmas},
      {"scale_sigma_ppm", adjusted.scale_sigma_ppm},
      {"plate_scale_check", PlateReport(project, plate, adjusted)},
      {"hole_ties", std::move(final_outcome.ties_report)},
      {"overlap_ties", std::move(final_outcome.overlap_report)},
      {"pairs", PairsReport(project, registration, pair_scatter)},
      {"tiles", TilesReport(project, registration, ortho.summary, saturated_fraction)},
      {"tiles_held_by_prior", HeldTilesReport(project, registration)},
      {"tile_groups", TileGroupsReport(project, adjusted.input)},
      {"table_priors_left_out", std::move(priors_left_out)},
      {"table_sigma_check", std::move(table_sigma_check)},
      {"working_distance_check", working_distance},
      {"exposure", ExposureReport(ortho.summary.exposure)},
      {"ortho", OrthoReport(ortho.summary)},
      {"world_file", WorldFilePath(kMosaicName).string()},
      {"scene_file", kSceneName},
      {"colmap", ColmapReport(files.colmap)},
      {"timings_s", ReportObject{{"read", read_seconds},
                                 {"features", registration.features_seconds},
                                 {"matching", registration.matching_seconds},
                                 {"adjustment", registration.adjustment_seconds},
                                 {"plate_detection", plate.seconds},
                                 {"intrinsics_prior", timed_prior.seconds},
                                 {"hole_ties", final_outcome.fit_seconds},
                                 {"overlap_ties", final_outcome.overlap_seconds},
                                 {"final_adjustment", final_outcome.solve_seconds},
                                 {"ortho_geometry", ortho.summary.geometry_seconds},
                                 {"ortho_exposure", ortho.summary.exposure_seconds},
                                 {"ortho_resample", ortho.summary.resample_seconds},
                                 // scene.json, colmap/ (mosaic.png: in the background)
                                 {"write", files.seconds},
                                 {"total", SecondsSince(stage_start)}}}};
  context.report.mosaic = std::move(report);
  if (context.progress) context.progress(num_tiles + 4, num_tiles + 4, "mosaic done");
}

}  // namespace omm
