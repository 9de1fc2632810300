// The stages `omm` runs on a project, and what a stage runner sees.
//
// A stage runner (calibrate_stage.cc, mosaic_stage.cc, measure_stage.cc) is
// the glue between files and a pipeline stage: it reads its inputs through
// adapters, calls the stage's pure functions, writes its outputs into the
// staging directory and fills its section of the report. RunProject
// (run_project.h) moves the staged files into out/ only when every stage
// succeeded.
#pragma once

#include <filesystem>
#include <future>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "pipeline/core/calibration_result.h"
#include "pipeline/core/camera.h"
#include "pipeline/core/image.h"
#include "pipeline/core/progress.h"
#include "pipeline/core/project.h"
#include "pipeline/core/report.h"
#include "pipeline/mosaic/register_tiles.h"

namespace omm {

enum class Stage { kCalibrate, kMosaic, kMeasure };

// "calibrate", "mosaic", "measure".
const char* StageName(Stage stage);
// Their names joined by ", ".
std::string StageNames(const std::vector<Stage>& stages);
// In run order.
std::vector<Stage> AllStages();

// Files in out/ that a stage writes and a later stage reads.
inline constexpr const char* kCameraModelName = "camera.cameramodel";
inline constexpr const char* kSolveRecordName = "calibration/solve.json";
inline constexpr const char* kSceneName = "mosaic/scene.json";

// The files of `stage`'s results in out/ that later stages read, as `report`
// names them: a run keeps a current stage only while they are there
// (RunOptions::reuse_current_stages).
std::vector<std::string> StageOutputFiles(Stage stage, const Report& report);

// A data failure that leaves a stage without a usable result (no plate found
// in any calibration image, tiles that do not overlap, ...): the run stops
// and out/ is left as it was. Failures of single items (one image, one
// measurement) are recorded in the report instead.
class StageFailedError : public std::runtime_error {
 public:
  StageFailedError(Stage stage, const std::string& why)
      : std::runtime_error(std::string("stage '") + StageName(stage) + "' failed: " + why),
        stage_(stage) {}
  Stage stage() const { return stage_; }

 private:
  Stage stage_;
};

struct StageContext {
  const Project& project;
  // Where this run's outputs go, named as they will be in out/.
  std::filesystem::path staging_dir;
  // out/ as earlier runs left it (read only).
  std::filesystem::path out_dir;
  // The report being built; a runner fills its own section.
  Report& report;
  const ProgressCallback& progress;
  // `omm calibrate --study`: also run the image-count study (slow).
  bool calibration_study = false;
  // `omm mosaic --features`: where the registration's anchors come from.
  FeatureSource mosaic_features = FeatureSource::kHarris;
  // Threads for the stage's parallel work (>= 1): RunProject sets it from
  // RunOptions::num_threads.
  int num_threads = 1;
  // This run's mosaic exactly as its file holds it (set by the mosaic stage;
  // null if it did not run): the measure stage and report.html take it from
  // here instead of decoding the file again.
  std::shared_ptr<const StoredImage> mosaic;
  // The calib images LoadProject decoded, parallel to project.calib_images
  // (moved here by RunProject; empty: read from the files). The calibration
  // takes each as it searches it for the plate, so that it is freed then
  // (the demo's 20 are 38 MB).
  std::vector<std::shared_ptr<const StoredImage>> calib_decoded;
  // This run's tiles as gray images, in the project's tile order (set by the
  // mosaic stage; null if it did not run): the measure stage takes them from
  // here instead of converting them again.
  std::shared_ptr<const std::vector<ImageF>> tiles;
  // The mosaic stage runs later in this run (set by RunProject).
  bool mosaic_follows = false;
  // The stages whose results in out/ are from other inputs than this run's,
  // as out/report.json (by this omm) says: a stage run alone must not take
  // their files (set by RunProject).
  std::vector<Stage> stale_in_out;
  bool StaleInOut(Stage stage) const;
  // The registration's camera-independent part (PrepareMosaicTiles),
  // prepared on other threads while the camera is calibrated (started by
  // the calibrate stage when the mosaic follows; invalid otherwise): the
  // mosaic stage takes it from here.
  std::future<PreparedTiles> mosaic_tiles;
  // Output files still being written on other threads (the mosaic's):
  // RunProject waits for them, and rethrows their errors, before it commits
  // out/; destroying the context waits for them too.
  std::vector<std::future<void>> pending_writes;

  // An earlier stage's output file: this run's if it wrote one, else the one
  // in out/ from an earlier run, else an empty path.
  std::filesystem::path Input(const std::string& name) const;
  // Where `path` will be once out/ is committed: a file of the staging
  // directory by its place in out/, any other as it is (for the report).
  std::filesystem::path Published(const std::filesystem::path& path) const;
};

// A project image (calib/ or tiles/) as the stages see it: the one
// LoadProject decoded (`decoded`; null if it kept none), else read from
// `path`, scaled to the full scale of its samples' bits
// (Project::sample_bits), linearized with the camera's gamma
// (LinearizeResponse).
GrayImage ProjectGrayImage(const Project& project, const StoredImage* decoded,
                           const std::filesystem::path& path);

// The project's tile `tile` (index into project.tiles) as a gray image:
// converted from the one LoadProject decoded, else read from its file.
// Throws InputError for a tile that is blank (BlankImageLevel): held by its
// table position alone it would show a uniform square in the mosaic, and its
// holes would fail as poor fits.
ImageF TileImage(const Project& project, int tile);
// All of them, in the project's tile order, num_threads at a time.
std::vector<ImageF> TileImages(const Project& project, int num_threads);
// Throws InputError for a tile whose size is not the camera's: tile `tile`
// of width_px x height_px, or each of `tiles`.
void CheckTileSize(const Project& project, int tile, int width_px, int height_px,
                   const CameraModel& camera);
void CheckTileSizes(const Project& project, const std::vector<ImageF>& tiles,
                    const CameraModel& camera);
// Both.
std::vector<ImageF> TileImages(const Project& project, const CameraModel& camera, int num_threads);

// How the mosaic stage registers the tiles (stage options from the context).
RegisterTilesOptions MosaicRegistrationOptions(const StageContext& context);
// PrepareTiles with `options` on the project's tiles (TileImage), each
// converted where its step 1 starts and dropped after it. Throws as they do.
PreparedTiles PrepareMosaicTiles(const Project& project, const RegisterTilesOptions& options);

// Where a calibration measured the lens: the convex hull of its solve's inlier
// mark centres, px (CameraModel::valid_region_px; empty if they span no area).
Eigen::Matrix2Xd CalibratedRegionPx(const SolveRecord& record);

// The runners, one per stage. Each throws InputError for bad input,
// StageFailedError for a data failure.
void RunCalibrateStage(StageContext& context);
void RunMosaicStage(StageContext& context);
void RunMeasureStage(StageContext& context);

}  // namespace omm
