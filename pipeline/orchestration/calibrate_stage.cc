// Runner of the calibrate stage (see stage.h): calib/ images -> the stage
// (pipeline/calibration/calibrate_stage.h) -> out/camera.cameramodel,
// out/calibration/{solve.json,residuals.svg,uncertainty.svg[,study.svg]} and
// the report's calibration section. With `calibration.from`, the earlier
// calibration is taken instead and calib/ is not read.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <functional>
#include <future>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include "adapters/mrcal/calibrate.h"
#include "adapters/mrcal/cameramodel_io.h"
#include "adapters/mrcal/solve_record_json.h"
#include "adapters/mrcal/uncertainty.h"
#include "adapters/opencv/plate_detector.h"
#include "adapters/project_io/report_json.h"
#include "adapters/project_io/text_file.h"
#include "pipeline/calibration/calibrate_stage.h"
#include "pipeline/calibration/study.h"
#include "pipeline/core/error.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/core/timing.h"
#include "pipeline/orchestration/calibration_report.h"
#include "pipeline/orchestration/stage.h"
#include "pipeline/orchestration/svg_plots.h"

namespace omm {
namespace {

namespace fs = std::filesystem;

constexpr const char* kResidualsPlotName = "calibration/residuals.svg";
constexpr const char* kStudyPlotName = "calibration/study.svg";
constexpr const char* kUncertaintyPlotName = "calibration/uncertainty.svg";

ReportValue Array(const Eigen::VectorXd& values) {
  ReportValue::Array array;
  for (Eigen::Index i = 0; i < values.size(); ++i) array.emplace_back(values(i));
  return array;
}

ReportValue PerImage(const CalibrationResult& result) {
  ReportValue::Array rows;
  for (const ImageResidual& r : result.per_image) {
    rows.emplace_back(ReportObject{{"image", r.image},
                                   {"rms_px", r.rms_px},
                                   {"inliers", r.num_inliers},
                                   {"outliers", r.num_outliers}});
  }
  return rows;
}

ReportValue Uncertainty(const UncertaintySummary& u) {
  if (!u.available) {
    return ReportObject{{"included", false}, {"why_not", u.why_not}};
  }
  return ReportObject{{"included", true},
                      {"statistic", "worst-direction 1-sigma of the projection (mrcal), px"},
                      {"distance_mm", u.distance_mm},
                      {"typical_px", u.typical_px},
                      {"worst_px", u.worst_px},
                      {"observed_sigma_px", u.observed_sigma_px}};
}

ReportValue StudyReport(const ImageCountStudy& study) {
  ReportValue::Array l_values, parameters;
  for (int l : study.num_images) l_values.emplace_back(l);
  for (const StudyParameter& p : study.parameters) {
    ReportValue::Array spread, ideal;
    for (double v : p.spread) spread.emplace_back(v);
    for (double v : p.spread_ideal) ideal.emplace_back(v);
    parameters.emplace_back(ReportObject{{"name", p.name},
                                         {"full_sigma", p.full_sigma},
                                         {"spread", spread},
                                         {"spread_noise_only", ideal}});
  }
  return ReportObject{{"brief", study.brief},
                      {"lens_model", study.lens_model},
                      {"num_images", l_values},
                      {"parameters", parameters},
                      {"suffices_from", study.suffices_from > 0 ? ReportValue(study.suffices_from)
                                                                : ReportValue(nullptr)},
                      {"rule", study.rule},
                      {"plot", kStudyPlotName},
                      {"seconds", study.seconds}};
}

// The plate in every calib image, num_threads at a time, each image
// converted to gray (from the one LoadProject decoded, taken from `decoded`
// if it is there, else read from its file) where it is detected and dropped
// after: held together, the demo's 20 took 154 MB through the solves.
std::vector<PlateObservation> DetectCalibPlates(
    const Project& project, std::vector<std::shared_ptr<const StoredImage>> decoded,
    const PlateDetectionOptions& options, const ProgressCallback& progress, int num_threads) {
  const int num_images = static_cast<int>(project.calib_images.size());
  decoded.resize(num_images);
  std::vector<PlateObservation> detections(num_images);
  std::mutex progress_mutex;
  int num_done = 0;
  ParallelFor(num_images, num_threads, [&](int i) {
    const GrayImage image = ProjectGrayImage(project, std::exchange(decoded[i], nullptr).get(),
                                             project.calib_images[i]);
    detections[i] = DetectPlate(image, *project.board, options);
    detections[i].image = project.calib_images[i].filename().string();
    const std::lock_guard lock(progress_mutex);
    if (progress) progress(++num_done, num_images, "plate search in " + detections[i].image);
  });
  return detections;
}

// calibration/uncertainty.svg: the map of the projection uncertainty over
// the grid that `uncertainty` summarises. Returns false (and writes nothing)
// when the uncertainty is unavailable.
bool WriteUncertaintyMap(const fs::path& staging_dir, const CalibrationResult& result,
                         const UncertaintySummary& uncertainty) {
  if (!uncertainty.available) return false;
  WriteTextFileAtomically(
      staging_dir / kUncertaintyPlotName,
      UncertaintyMapSvg(uncertainty.grid_q_px, uncertainty.grid_worst_px, uncertainty.grid_nx,
                        uncertainty.grid_ny, result.camera.width_px, result.camera.height_px,
                        uncertainty.distance_mm));
  return true;
}

// The common part of a report from a solve (fresh or reused), and the
// residual plot. rms_px is the plain pixel residual per coordinate; mrcal's
// rms is of WEIGHTED residuals (weight = nominal / estimated mark sigma, up to
// 4 for sharp marks), so it is reported beside it, not as it.
CalibrationReport ReportFromSolve(const fs::path& staging_dir, const CalibrationResult& result,
                                  const UncertaintySummary& uncertainty) {
  Eigen::Matrix2Xd q_px, residual_px;
  ResidualVectors(result, &q_px, &residual_px);
  const double rms_px = residual_px.cols() > 0
                            ? std::sqrt(residual_px.squaredNorm() / (2.0 * residual_px.cols()))
                            : 0.0;
  WriteTextFileAtomically(
      staging_dir / kResidualsPlotName,
      ResidualsSvg(q_px, residual_px, result.camera.width_px, result.camera.height_px, rms_px));
  CalibrationReport report;
  report.lens_model = result.camera.lens_model;
  report.rms_px = rms_px;
  report.extra.emplace_back("weighted_rms", result.rms_px);
  report.images_used = static_cast<int>(result.record.images.size());
  report.extra.emplace_back("intrinsics", Array(result.camera.intrinsics));
  report.extra.emplace_back("image_size_px",
                            ReportValue::Array{result.camera.width_px, result.camera.height_px});
  report.extra.emplace_back("per_image", PerImage(result));
  report.extra.emplace_back("num_outliers", result.num_outliers);
  report.extra.emplace_back("projection_uncertainty", Uncertainty(uncertainty));
  report.extra.emplace_back("residuals_plot", kResidualsPlotName);
  if (WriteUncertaintyMap(staging_dir, result, uncertainty)) {
    report.extra.emplace_back("uncertainty_plot", kUncertaintyPlotName);
  }
  return report;
}

// project.yaml's focal length and pixel pitch only seed the solve. A
// calibrated focal length far from theirs says that one of them is not this
// camera's (copied from another project, a lens changed): warned about, as
// the report of a camera taken for another misleads whoever reads it. A lens's
// nominal focal length is good to a few percent.
constexpr double kFocalLengthTolerance = 0.15;

ReportObject FocalLengthCheck(const CameraSpec& stated, const CameraModel& calibrated) {
  const double pitch_mm = 1e-3 * stated.pixel_pitch_um;
  const double calibrated_mm =
      0.5 * (calibrated.intrinsics(0) + calibrated.intrinsics(1)) * pitch_mm;
  const bool consistent =
      std::abs(calibrated_mm / stated.focal_length_mm - 1.0) <= kFocalLengthTolerance;
  if (!consistent) {
    spdlog::warn(
        "calibrate: the calibrated focal length is {:.2f} mm at camera.pixel_pitch_um {:g}, but "
        "project.yaml's camera.focal_length_mm is {:g} ({:.2f} times): are both this camera's?",
        calibrated_mm, stated.pixel_pitch_um, stated.focal_length_mm,
        calibrated_mm / stated.focal_length_mm);
  }
  return ReportObject{{"stated_mm", stated.focal_length_mm},
                      {"calibrated_mm", calibrated_mm},
                      {"consistent", consistent}};
}

void RunStudy(StageContext& context, const CalibrationStageSummary& summary) {
  const Project& project = context.project;
  Eigen::VectorXd sigma;
  if (const auto uncertainty = CalibrationUncertainty::Compute(summary.result.record)) {
    sigma = uncertainty->IntrinsicsCovariance().diagonal().cwiseMax(0.0).cwiseSqrt();
  }
  spdlog::info("calibrate: image-count study with {}", summary.result.camera.lens_model);
  const ImageCountStudy study =
      StudyImageCount(summary.observations, *project.board, project.camera, summary.result.camera,
                      sigma, ImageCountStudyOptions());
  spdlog::info("calibrate: study: {}", study.brief);
  WriteTextFileAtomically(context.staging_dir / kStudyPlotName, StudySvg(study));
  context.report.calibration->extra.emplace_back("study", StudyReport(study));
}

// The calibration's solves run on one core: the mosaic's camera-free work
// fills the others, at a lower priority (lens-mismatch 284: 0.8 s of solves).
// Started after the plate search, which keeps the cores busy anyway and
// frees the calib images as it goes: side by side, the two took the demo
// with 100 calib images to a peak of 490 MB, one after the other to 375 MB.
void StartMosaicTiles(StageContext& context) {
  if (!context.mosaic_follows || context.num_threads < 2 || context.mosaic_tiles.valid()) return;
  context.mosaic_tiles =
      std::async(std::launch::async,
                 [&project = context.project, options = MosaicRegistrationOptions(context)] {
                   YieldCoresToOtherThreads();
                   return PrepareMosaicTiles(project, options);
                 });
}

void CalibrateFromImages(StageContext& context) {
  const Project& project = context.project;
  if (!project.board) throw InputError((project.dir / "project.yaml").string(), "board: missing");
  if (project.calib_images.empty()) {
    throw InputError((project.dir / "calib").string(),
                     "no calibration images (and no calibration.from)");
  }
  CalibrationStageOptions options;
  options.num_threads = context.num_threads;
  const auto detection_start = std::chrono::steady_clock::now();
  const std::vector<PlateObservation> detections =
      DetectCalibPlates(project, std::move(context.calib_decoded), options.detection,
                        context.progress, context.num_threads);
  const double detection_seconds = SecondsSince(detection_start);
  StartMosaicTiles(context);
  CalibrationStageSummary summary =
      CalibrateFromDetections(detections, *project.board, project.camera, project.image_width_px,
                              project.image_height_px, options);
  summary.detection_seconds = detection_seconds;
  summary.total_seconds = SecondsSince(detection_start);

  std::vector<RejectedImage> rejected;
  for (const PlateObservation& o : summary.detections) {
    if (!o.usable) rejected.push_back({o.image, o.why_rejected});
  }
  for (const RejectedImage& r : rejected)
    spdlog::info("calibrate: rejected {}: {}", r.image, r.why);
  if (!summary.usable) {
    // Grouped by reason: twenty blank images make one line, not twenty.
    std::vector<std::pair<std::string, std::vector<std::string>>> by_reason;
    for (const RejectedImage& r : rejected) {
      auto it = std::find_if(by_reason.begin(), by_reason.end(),
                             [&](const auto& group) { return group.first == r.why; });
      if (it == by_reason.end()) it = by_reason.insert(by_reason.end(), {r.why, {}});
      it->second.push_back(r.image);
    }
    constexpr size_t kNamesShown = 3;
    std::string why = summary.brief;
    for (const auto& [reason, group_images] : by_reason) {
      const size_t shown = std::min(group_images.size(), kNamesShown);
      const std::vector<std::string> names(group_images.begin(), group_images.begin() + shown);
      why += fmt::format("; {}: {}", reason, fmt::join(names, ", "));
      if (group_images.size() > shown)
        why += fmt::format(" and {} more", group_images.size() - shown);
    }
    // In no image at all: the plate may not be the one project.yaml
    // describes (a pitch of 10 mm for 12.5 found 5 of the caltab's 49 marks).
    const bool none_found = std::none_of(summary.detections.begin(), summary.detections.end(),
                                         [](const PlateObservation& o) { return o.usable; });
    if (none_found && !summary.detections.empty()) {
      const BoardSpec& board = *context.project.board;
      why += fmt::format(
          "; is project.yaml's board ({} of {} x {} marks, pitch {:g} mm) the plate in calib/?",
          BoardTypeName(board.type), board.cols, board.rows, board.pitch_mm);
    }
    throw StageFailedError(Stage::kCalibrate, why);
  }
  spdlog::info("calibrate: {}", summary.lens.why);
  if (summary.lens.splined_fov_deg > summary.lens.splined_fov_sized_deg) {
    spdlog::warn(
        "calibrate: the spline's knot field was widened from {} to {} deg so that the lens maps "
        "the whole image: beyond the plate's marks it is extrapolated (calibration images with "
        "the plate near the image's corners would measure it)",
        summary.lens.splined_fov_sized_deg, summary.lens.splined_fov_deg);
  }
  spdlog::info("calibrate: {} ({:.2f} s: detection {:.2f} s, lens-model choice {:.2f} s)",
               summary.brief, summary.total_seconds, summary.detection_seconds,
               summary.lens_choice_seconds);

  fs::create_directories(context.staging_dir / "calibration");
  CameraModel camera = summary.result.camera;
  camera.valid_region_px = CalibratedRegionPx(summary.result.record);
  WriteCameraModel(context.staging_dir / kCameraModelName, camera);
  WriteSolveRecord(context.staging_dir / kSolveRecordName, summary.result.record);
  CalibrationReport report =
      ReportFromSolve(context.staging_dir, summary.result, summary.uncertainty);
  report.images_rejected = rejected;
  report.extra.emplace_back("source", "calib/");
  ReportValue::Array outliers;
  for (const MarkOutlier& o : summary.outliers) {
    outliers.emplace_back(ReportObject{{"image", o.image},
                                       {"row", o.row},
                                       {"col", o.col},
                                       {"q_px", ReportValue::Array{o.q_px.x(), o.q_px.y()}}});
  }
  report.extra.emplace_back("outliers", outliers);
  report.extra.emplace_back("lens_model_choice", LensChoiceReport(summary.lens));
  report.extra.emplace_back("focal_length_check",
                            FocalLengthCheck(context.project.camera, summary.result.camera));
  report.extra.emplace_back("perspective_bias_correction",
                            ReportObject{{"rounds", summary.bias.rounds},
                                         {"rms_px", summary.bias.rms_px},
                                         {"max_px", summary.bias.max_px},
                                         {"last_change_px", summary.bias.last_change_px}});
  report.extra.emplace_back("seconds",
                            ReportObject{{"detection", summary.detection_seconds},
                                         {"lens_model_choice", summary.lens_choice_seconds},
                                         {"total", summary.total_seconds}});
  report.extra.emplace_back("brief", summary.brief);
  context.report.calibration = std::move(report);
  if (context.calibration_study) RunStudy(context, summary);
}

// `calibration.from` an earlier omm project: its camera and solve record,
// copied into this project's out/ so the covariance carries over.
void ReuseProjectCalibration(StageContext& context, const fs::path& from) {
  const fs::path camera_path = from / "out" / kCameraModelName;
  const fs::path record_path = from / "out" / kSolveRecordName;
  for (const fs::path& needed : {camera_path, record_path}) {
    if (!fs::exists(needed)) {
      throw InputError((context.project.dir / "project.yaml").string(),
                       fmt::format("calibration.from: {} has no calibration ({} is missing); run "
                                   "`omm calibrate {}` there first",
                                   from.string(), needed.string(), from.string()));
    }
  }
  const CameraModel camera = ReadCameraModel(camera_path);
  const SolveRecord record = ReadSolveRecord(record_path);
  const CalibrationResult result = SummarizeSolve(record);
  if (!result.usable) {
    throw InputError(record_path.string(), "the solve record cannot be evaluated: " + result.brief);
  }
  fs::create_directories(context.staging_dir / "calibration");
  fs::copy_file(camera_path, context.staging_dir / kCameraModelName,
                fs::copy_options::overwrite_existing);
  fs::copy_file(record_path, context.staging_dir / kSolveRecordName,
                fs::copy_options::overwrite_existing);
  const CalibrationStageOptions options;
  const UncertaintySummary uncertainty = SummarizeUncertainty(
      record, WorkingDistanceMm(result), options.uncertainty_grid_nx, options.uncertainty_grid_ny);
  CalibrationReport report = ReportFromSolve(context.staging_dir, result, uncertainty);
  report.lens_model = camera.lens_model;
  // The earlier run's rejections, if its report is there.
  const fs::path earlier_report = from / "out" / "report.json";
  if (fs::exists(earlier_report)) {
    const Report earlier = ReadReportJson(earlier_report);
    if (earlier.calibration) report.images_rejected = earlier.calibration->images_rejected;
  }
  report.extra.emplace_back("source", "from project " + from.string());
  context.report.calibration = std::move(report);
  spdlog::info("calibrate: reused {}'s calibration ({}, rms {:.3f} px)", from.string(),
               camera.lens_model, result.rms_px);
}

// `calibration.from` a mrcal .cameramodel: the camera only.
void ReuseCameraModel(StageContext& context, const fs::path& from) {
  const CameraModel camera = ReadCameraModel(from);
  const Project& project = context.project;
  if (project.image_width_px > 0 &&
      (camera.width_px != project.image_width_px || camera.height_px != project.image_height_px)) {
    throw InputError(
        from.string(),
        fmt::format("imager {}x{} px, but the project's images are {}x{} px", camera.width_px,
                    camera.height_px, project.image_width_px, project.image_height_px));
  }
  fs::copy_file(from, context.staging_dir / kCameraModelName, fs::copy_options::overwrite_existing);
  CalibrationReport report;
  report.lens_model = camera.lens_model;
  report.extra.emplace_back("source", "from camera model " + from.string());
  report.extra.emplace_back("intrinsics", Array(camera.intrinsics));
  report.extra.emplace_back("image_size_px", ReportValue::Array{camera.width_px, camera.height_px});
  report.extra.emplace_back(
      "projection_uncertainty",
      ReportObject{{"included", false},
                   {"why_not",
                    "calibration taken from a .cameramodel file: the calibration's own uncertainty "
                    "is not included (no solve record)"}});
  report.extra.emplace_back("rms_px_known", false);
  context.report.calibration = std::move(report);
  spdlog::warn("calibrate: camera from {}: its calibration's own uncertainty is not included",
               from.string());
}

}  // namespace

void RunCalibrateStage(StageContext& context) {
  const Project& project = context.project;
  if (!project.calibration_from) return CalibrateFromImages(context);
  StartMosaicTiles(context);
  if (context.calibration_study) {
    throw InputError((project.dir / "project.yaml").string(),
                     "--study needs calib/ images; this project reuses calibration.from");
  }
  const CalibrationSource& source = *project.calibration_from;
  if (source.kind == CalibrationSource::Kind::kProject) {
    ReuseProjectCalibration(context, source.path);
  } else {
    ReuseCameraModel(context, source.path);
  }
}

}  // namespace omm
