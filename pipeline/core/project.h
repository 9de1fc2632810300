// A measurement job as read from a project directory (format omm-project/1,
// ../../../shared/docs/project-format.md). Plain values: no yaml or csv types.
#pragma once

#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/board.h"
#include "pipeline/core/image.h"

namespace omm {

struct CameraSpec {
  double pixel_pitch_um = 0.0;           // nominal sensor pixel pitch
  double focal_length_mm = 0.0;          // nominal lens focal length
  std::optional<std::string> lens_model;  // forced mrcal lens model, if given
  // The camera's response, pixel = linear^gamma (GenICam's Gamma; 1: linear,
  // as metrology wants it). Every image is linearized with it when read.
  double gamma = 1.0;
  // The bits of the camera's samples as project.yaml states them (8-16;
  // GenICam's PixelFormat Mono12: 12); none: told from the images
  // (Project::sample_bits).
  std::optional<int> sample_bits;
};

// `calibration.from`: reuse an earlier calibration instead of calib/.
struct CalibrationSource {
  enum class Kind { kProject, kCameraModel };
  Kind kind = Kind::kProject;
  std::filesystem::path path;  // absolute (resolved against the project directory)
};

enum class FeatureType { kCircle };

struct FeatureSpec {
  std::string name;
  FeatureType type = FeatureType::kCircle;
  std::string image;        // file name of a tile in tiles/ that sees it
  Eigen::Vector2d near_px;  // rough position in that raw tile, px
  double diameter_mm = 0.0;  // nominal diameter
};

enum class MeasurementType { kDistance, kDiameter };

struct MeasurementSpec {
  std::string name;
  MeasurementType type = MeasurementType::kDistance;
  // kDistance: two feature names; kDiameter: one.
  std::vector<std::string> features;
};

// One row of table.csv: the commanded table position a tile was taken at.
struct TilePosition {
  std::string image;            // file name in tiles/
  Eigen::Vector2d table_pos_mm;  // machine X, Y
};

struct CmmValue {
  std::string measurement;  // a name in `measurements`
  double value_mm = 0.0;
  // The value's 1-sigma standard uncertainty (cmm.csv's optional sigma_mm),
  // if stated: the deviation is then also judged against both sigmas.
  std::optional<double> sigma_mm;
};

// An image file as LoadProject read it: read once, its bytes hashed and
// decoded, so that the stages of the same process need not read it again.
struct LoadedImage {
  // Null once the run no longer needs it (WithoutDecodedImages): a stage
  // that asks for it then reads the file again.
  std::shared_ptr<const StoredImage> image;
  std::string sha256;  // of the file's bytes, 64 lower-case hex digits
};

struct LoadedImages {
  std::vector<LoadedImage> calib;  // parallel to Project::calib_images
  std::vector<LoadedImage> tiles;  // parallel to Project::tiles
};

// `loaded` with the decoded calib images, or tiles, dropped (the hashes
// kept); the images themselves are freed with the last copy that holds them.
LoadedImages WithoutDecodedImages(const LoadedImages& loaded, bool calib, bool tiles);

struct Project {
  std::filesystem::path dir;  // the project directory (absolute)
  std::string name;
  CameraSpec camera;
  std::optional<CalibrationSource> calibration_from;
  std::optional<BoardSpec> board;  // required unless calibration_from is set
  double table_sigma_mm = 0.0;
  double mosaic_gsd_mm = 0.0;
  // mosaic.plate_height_mm: height of the marks of the calibration plate lying
  // on the part above its top surface (the plate's thickness), mm; unset:
  // estimated when the plate is seen in >= 2 tiles, else assumed 0.
  std::optional<double> plate_height_mm;
  std::vector<FeatureSpec> features;
  std::vector<MeasurementSpec> measurements;

  std::vector<std::filesystem::path> calib_images;  // absolute, file-name order
  std::vector<TilePosition> tiles;                  // file-name order of tiles/
  std::vector<CmmValue> cmm;                        // empty without cmm.csv
  // project.yaml's top-level sections by key, each re-emitted from its
  // parsed form (comments and layout dropped): what the stages' input
  // hashes see of project.yaml (input_hash.h). Empty for a project not read
  // from a file.
  std::map<std::string, std::string> yaml_sections;

  // Size shared by all images (calib/ and tiles/), px.
  int image_width_px = 0;
  int image_height_px = 0;
  // The bits the images' samples use. Cameras of 10, 12 or 14 bits often
  // store them in 16-bit files unshifted: where every image is such a file
  // and no sample exceeds 2^b - 1 for b in {10, 12, 14}, the smallest such b
  // (2^b - 1 is then full scale); else 16. Those images read 16 to 64 times
  // too dark, and plate detection found no plate. camera.sample_bits, where
  // given, is taken instead (a 16-bit camera whose dim capture stays below
  // 2^14 would otherwise read as 14-bit, its brightest sample as saturated).
  // 16-bit files only: an 8-bit file's full scale is 255.
  int sample_bits = 16;

  // The images as loaded, shared by copies of the project (read only); null:
  // the stages read the files.
  std::shared_ptr<const LoadedImages> images;

  std::filesystem::path TilePath(const std::string& image) const {
    return dir / "tiles" / image;
  }
  std::filesystem::path OutDir() const { return dir / "out"; }
};

const char* FeatureTypeName(FeatureType type);
const char* MeasurementTypeName(MeasurementType type);

}  // namespace omm
