// The ground truth of a simulated project (`omm simulate`): everything the
// renderer used, so that every stage can be scored against it.
//
// Frames (pipeline/README.md): camera x right, y down, z forward; part frame =
// machine X, Y with the table at (0, 0), Z up, Z = 0 on the part's top
// surface; plate frame = the caltab's plate coordinates (x right along a row,
// y down along a column, origin at the plate centre, z = 0 on the printed
// face, +z into the plate). All lengths mm, angles radians.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "pipeline/core/board.h"
#include "pipeline/core/camera.h"

namespace omm {

// The true camera: its lens model and parameters, and the physical values the
// nominal project.yaml entries approximate.
struct CameraTruth {
  CameraModel model;             // the exact model every image was rendered with
  double pixel_pitch_um = 0.0;   // true pitch (project.yaml has the nominal one)
  double focal_length_mm = 0.0;  // true focal length
  double psf_sigma_px = 0.0;     // Gaussian blur at the working distance
};

// Sensor effects applied to one image: value = gain * V(q) * (PSF * reflectance)
// + noise, V(q) = 1 - vignetting * (|q - c| / |corner - c|)^2 with c the
// principal point.
struct ExposureTruth {
  double gain = 1.0;
  double vignetting = 0.0;  // relative fall-off at the image corners
  double psf_sigma_px = 0.0;
};

struct CalibImageTruth {
  std::string image;  // file name in calib/
  enum class Kind { kFull, kPartial, kPlateAbsent };
  Kind kind = Kind::kFull;
  // Plate pose in this image (identity and meaningless for kPlateAbsent).
  Eigen::Isometry3d cam_from_plate = Eigen::Isometry3d::Identity();
  ExposureTruth exposure;
};

struct TileTruth {
  std::string image;                   // file name in tiles/
  int grid_row = 0, grid_col = 0;      // place in the capture grid
  Eigen::Vector2d commanded_mm{0, 0};  // what table.csv says
  Eigen::Vector2d actual_mm{0, 0};     // where the table really was
  ExposureTruth exposure;
};

// A through-hole: a circle on the top surface (Z = 0) of the part.
struct HoleTruth {
  std::string name;  // the feature name in project.yaml
  Eigen::Vector2d center_part_mm{0, 0};
  double diameter_mm = 0.0;          // true diameter
  double nominal_diameter_mm = 0.0;  // project.yaml's diameter_mm
};

// A paper AprilTag (family tag36h11) lying on the part.
struct MarkerTruth {
  int id = 0;
  // Outer corners of the tag's black border in the part frame (Z = 0), in
  // libapriltag's detection order: bottom-left, bottom-right, top-right,
  // top-left of the printed tag (counter-clockwise as seen in the image).
  Eigen::Matrix<double, 2, 4> corners_part_mm;
  double tag_size_mm = 0.0;    // edge of the black border square
  double paper_size_mm = 0.0;  // edge of the white paper square around it
};

struct MeasurementTruth {
  std::string name;  // the measurement name in project.yaml
  double value_mm = 0.0;
};

struct SimulationTruth {
  std::string preset;
  std::uint64_t seed = 0;

  CameraTruth camera;

  // Calibration: the plate (board.h) and its pose in each calib/ image.
  BoardSpec board;
  double plate_size_mm = 0.0;  // edge of the square plate (white margin outside the frame)
  std::vector<CalibImageTruth> calib_images;

  // Workpiece: the plane pose with the table at (0, 0) (the camera never
  // moves; a part point P is at P + T_i for table position T_i).
  Eigen::Isometry3d cam_from_part = Eigen::Isometry3d::Identity();
  Eigen::Vector2d part_min_mm{0, 0}, part_max_mm{0, 0};  // outline (a rectangle)
  double part_thickness_mm = 0.0;  // through-holes show their wall, then the table
  double table_sigma_mm = 0.0;     // sigma of actual - commanded, each axis
  std::vector<TileTruth> tiles;
  std::vector<HoleTruth> holes;
  std::vector<MarkerTruth> markers;
  // The caltab plate lying printed face up on the part (zero thickness), if
  // the preset has one: part_from_plate maps plate coordinates to the part frame.
  std::optional<Eigen::Isometry3d> part_from_plate;

  // True values of project.yaml's measurements (cmm.csv adds ~1 um noise).
  std::vector<MeasurementTruth> measurements;
};

inline const char* CalibImageKindName(CalibImageTruth::Kind kind) {
  switch (kind) {
    case CalibImageTruth::Kind::kFull: return "full";
    case CalibImageTruth::Kind::kPartial: return "partial";
    case CalibImageTruth::Kind::kPlateAbsent: return "plate-absent";
  }
  return "?";
}

}  // namespace omm
