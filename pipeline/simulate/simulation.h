// The ground-truth simulator's scene and images, without files: draws a whole
// project (camera, calibration poses, workpiece, table positions, what to
// measure) from a seed, then renders any of its images.
//
// Physical model (design.md, project-format.md):
// - Camera: a mrcal lens model (LENSMODEL_OPENCV8 with a 12 mm lens's
//   distortion and an off-centre principal point; the lens-mismatch preset uses
//   a LENSMODEL_SPLINED_STEREOGRAPHIC truth with a strong radial plus a
//   non-radial distortion that OPENCV8 cannot represent), 1600 x 1200 px,
//   pitch 4.5 um, focal length within ~1.5 % of the nominal 12 mm. It looks
//   down from ~390 mm with a 0.5-2.5 deg tilt and a rotation about its axis of
//   k * 90 deg +- 8 deg relative to the machine axes.
// - Calibration: the plate (a caltab by default; a circles grid or a
//   chessboard on request, SimulatedBoard) at ~18 poses over the whole field
//   (flat and tilted 10-35 deg, 340-440 mm away, any rotation), one partly
//   outside the image, one image without the plate.
// - Workpiece: a ~450 mm square plate, top surface at Z = 0, textured, with
//   through-holes (8-60 mm), optionally paper AprilTags and the calibration
//   plate lying on it; imaged as a 3 x 3 grid with 35-45 % overlap; actual table
//   positions = commanded + N(0, table sigma). Other grids (a strip of one
//   row, 4 x 3, ...) keep the step and the part's margin: the part is
//   ~450 mm times the grid's reach over the 3 x 3 grid's, per axis.
// - Images: rays from the camera's ray table (RayTable) into exact analytic
//   scenes (scene.h), 2 x 2 Gauss points per pixel and 16 x 16 rays where an
//   edge crosses it (IntegratePixels), then the sensor (render.h): Gaussian
//   PSF, vignetting, gain, shot and read noise, 8-bit quantisation.
// Everything is a deterministic function of (seed, preset, options); noise
// and scene draws come from separate streams (random.h).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "pipeline/core/image.h"
#include "pipeline/core/plane_scene.h"
#include "pipeline/core/project.h"
#include "pipeline/core/truth.h"
#include "pipeline/simulate/ray_table.h"
#include "pipeline/simulate/render.h"
#include "pipeline/simulate/scene.h"
#include "pipeline/simulate/texture.h"

namespace omm {

struct SimulationOptions {
  std::uint64_t seed = 1;       // everything random is drawn from this seed
  std::string preset = "demo";  // one of SimulationPresets()
  // Number of calib/ images, including one with the plate partly outside the
  // image and one without the plate (>= 3).
  int num_calib_images = 20;
  // Also lay the calibration plate on the part (the demo preset always does): a
  // capture in the paper's set-up, with a scale reference on the workpiece.
  bool plate_on_part = false;
  int grid_cols = 3, grid_rows = 3;  // tiles per row, rows (1..6 each, 2 tiles or more)
  BoardType board = BoardType::kCaltab;  // the calibration plate's board (SimulatedBoard)
  double table_sigma_mm = 0.02;      // actual - commanded table position, 1-sigma per axis
  bool sensor_noise = true;     // shot and read noise (images are quantised either way)
  int supersampling = 4;        // S: the ray table's S x S rays per pixel (IntegratePixels)
  int edge_supersampling = 16;  // rays per axis in pixels an edge crosses (IntegrationOptions)
  int num_threads = 2;          // rendering threads; the images do not depend on it

  // Empty if valid, else what is wrong (unknown preset, ...).
  std::string Check() const;
};

// The board of each type on the simulator's 120 mm plate: the caltab of
// project-format.md (7 x 7 dots, pitch 12.5 mm, 100 mm frame); the same 7 x 7
// dots without frame and triangle (circles); 7 x 9 inner corners of 11 mm
// squares (chessboard: 88 x 110 mm of squares, its corners spanning 66 x 88 mm
// as the caltab's dots span 75 x 75; rows and columns of different count so
// that only a half turn is ambiguous).
BoardSpec SimulatedBoard(BoardType type);

// Names of the presets: "demo", "markers", "low-texture", "sparse-texture",
// "exposure", "low-texture-exposure", "lens-mismatch".
std::vector<std::string> SimulationPresets();

// What a preset changes.
struct PresetSpec {
  std::string name;
  std::string description;     // one line, for --help
  bool splined_truth = false;  // lens-mismatch: a truth OPENCV8 cannot represent
  TextureStyle texture = TextureStyle::kRich;
  bool markers = false;             // paper AprilTags on the part
  bool plate_on_part = false;       // the calibration plate lying on the part (a scale check)
  bool exposure_variation = false;  // tiles of clearly different gain and vignetting
};

// The spec of a preset name from SimulationPresets() (asserts otherwise).
PresetSpec GetPreset(const std::string& name);

// A planned project: the truth and the project files' content, no pixels.
struct SimulationPlan {
  SimulationOptions options;
  PresetSpec preset;
  SimulationTruth truth;
  // project.yaml, table.csv and cmm.csv content. dir and calib_images (which
  // are absolute paths) are the writer's; calib image names are in truth.
  Project project;
  Materials materials;
  SensorModel sensor;
  std::uint64_t texture_seed = 0;
};

// Draws everything from options.seed. Fast (no rendering); precondition:
// options.Check() is empty.
SimulationPlan PlanSimulation(const SimulationOptions& options);

// Renders a plan's images. Holds the scene objects shared by all images.
class ProjectRenderer {
 public:
  explicit ProjectRenderer(const SimulationPlan& plan);
  ~ProjectRenderer();

  // Image of rays.rect (the whole image for files), quantised to the sensor's
  // bit depth. `rays` must come from the plan's truth camera.
  ImageF RenderCalibImage(int index, const RayTable& rays) const;
  ImageF RenderTile(int index, const RayTable& rays) const;

  // The noiseless, unblurred mean reflectance of each pixel (tests).
  ImageF CalibReflectance(int index, const RayTable& rays) const;
  ImageF TileReflectance(int index, const RayTable& rays) const;

 private:
  IntegrationOptions Integration() const;
  ImageF Expose(const ImageF& reflectance, const RayTable& rays, const ExposureTruth& exposure,
                std::uint64_t noise_stream) const;

  const SimulationPlan& plan_;
  PlatePattern plate_;
  std::unique_ptr<SurfaceTexture> texture_;
  std::unique_ptr<WorkpieceScene> workpiece_;
};

// The truth as the planar adjustment's scene (pipeline/core/plane_scene.h):
// the plane's pose, the ACTUAL table positions and the true intrinsics (no
// tracks): what the tests compare the adjusted scene and mosaic with.
PlaneScene TruthPlaneScene(const SimulationTruth& truth);

// Ray-table options for a plan (its supersampling and threads).
RayTableOptions RayOptionsFor(const SimulationOptions& options);

}  // namespace omm
