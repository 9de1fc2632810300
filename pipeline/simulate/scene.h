// The analytic scenes the simulator images: reflectance as an exact function
// of position on a plane, so edges are exact at any sampling density.
//
// Two planes are imaged: the calibration plate (plate frame, project-format.md) and
// the workpiece's top surface (part frame, Z = 0). A view of a plane maps a
// camera ray (x/z, y/z) to the plane point it meets:
//   X(lambda) = R^T (lambda d - t),  d = (x/z, y/z, 1),  lambda = (R^T t)_z / (R^T d)_z
// for cam_from_plane = (R, t), and the scene gives that point's reflectance.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "adapters/apriltag/tag_family.h"
#include "pipeline/core/board.h"
#include "pipeline/simulate/texture.h"

namespace omm {

// What a ray sees: a reflectance and the region it belongs to. Reflectance is
// continuous inside a region and may jump between regions; the renderer
// integrates pixels that straddle a region boundary more finely (render.h).
enum class Region : std::uint8_t {
  kTexture,     // the workpiece's (continuous) surface texture
  kPlateWhite,  // caltab ground and margin
  kPlateBlack,  // caltab frame, dots, triangle
  kBackground,  // behind the plate in calib/ images
  kTable,       // machine table: beyond the part and through holes
  kHoleWall,
  kPaper,
  kInk,
};

struct SceneSample {
  float reflectance = 0.0f;
  Region region = Region::kBackground;
};

// Reflectances of the simulated materials (fraction of a perfect white).
struct Materials {
  float plate_white = 0.85f;
  float plate_black = 0.06f;
  float calib_background = 0.22f;  // what is behind the plate in calib/ images
  float table = 0.04f;             // machine table: beyond the part and through holes
  float hole_wall = 0.16f;         // the bore of a through-hole, seen obliquely
  float paper = 0.9f;              // marker paper
  float ink = 0.05f;               // marker print
};

// The calibration plate: a square white plate of `plate_size_mm` carrying
// the board of project-format.md: a caltab (black frame, rows x cols dots,
// corner triangle), a circles grid (the dots alone) or a chessboard (rows x
// cols inner corners at the marks of BoardPoints, squares of pitch_mm, the
// square at its (-x, -y) corner black).
class PlatePattern {
 public:
  PlatePattern(const BoardSpec& board, double plate_size_mm, const Materials& materials);
  bool Contains(double x_mm, double y_mm) const {
    return std::abs(x_mm) <= half_plate_ && std::abs(y_mm) <= half_plate_;
  }
  // What plate point (x, y) looks like; the point must be on the plate
  // (Contains). Inline: the renderer calls it for every ray of a calib image.
  SceneSample Sample(double x, double y) const {
    const SceneSample white{white_, Region::kPlateWhite}, black{black_, Region::kPlateBlack};
    if (board_.type == BoardType::kChessboard) {
      // Squares k = 0 .. cols (x) and 0 .. rows (y); corner c sits between
      // squares c and c + 1.
      const double sx = x * inv_pitch_ + 0.5 * (board_.cols + 1);
      const double sy = y * inv_pitch_ + 0.5 * (board_.rows + 1);
      if (sx < 0 || sy < 0 || sx >= board_.cols + 1 || sy >= board_.rows + 1) return white;
      return (static_cast<int>(sx) + static_cast<int>(sy)) % 2 == 0 ? black : white;
    }
    const double ax = std::abs(x), ay = std::abs(y);
    if (board_.type == BoardType::kCaltab) {
      if (ax > half_frame_ || ay > half_frame_) return white;    // margin
      if (ax >= half_inner_ || ay >= half_inner_) return black;  // frame bar
      // Corner triangle in the inner corner next to mark (0, 0), i.e. at -x, -y.
      const double tx = x + half_inner_, ty = y + half_inner_;
      if (tx + ty <= board_.triangle_mm) return black;
    }
    // Nearest mark (+ 1/2 and truncation round every index that survives the
    // clamp; at a tie the point is far from both dots).
    const double fc = x * inv_pitch_ + 0.5 * (board_.cols - 1);
    const double fr = y * inv_pitch_ + 0.5 * (board_.rows - 1);
    const int c = std::clamp(static_cast<int>(fc + 0.5), 0, board_.cols - 1);
    const int r = std::clamp(static_cast<int>(fr + 0.5), 0, board_.rows - 1);
    const double dx = x - (c - 0.5 * (board_.cols - 1)) * board_.pitch_mm;
    const double dy = y - (r - 0.5 * (board_.rows - 1)) * board_.pitch_mm;
    return dx * dx + dy * dy <= dot_r2_ ? black : white;
  }

 private:
  BoardSpec board_;
  double half_plate_, half_frame_, half_inner_, dot_r2_, inv_pitch_;
  float white_, black_;
};

// A plane's pose seen along camera rays: precomputes R^T and R^T t.
class PlaneView {
 public:
  explicit PlaneView(const Eigen::Isometry3d& cam_from_plane)
      : rt_(cam_from_plane.linear().transpose()), rtt_(rt_ * cam_from_plane.translation()) {}
  // Plane point (X, Y) met by the ray (x, y, 1); false if the plane is behind
  // the camera along this ray or parallel to it.
  bool Intersect(double x, double y, Eigen::Vector2d* point) const {
    const Eigen::Vector3d d = rt_ * Eigen::Vector3d(x, y, 1.0);
    if (std::abs(d.z()) < 1e-12) return false;
    const double lambda = rtt_.z() / d.z();
    if (lambda <= 0) return false;
    *point = lambda * d.head<2>() - rtt_.head<2>();
    return true;
  }
  // The ray direction in plane coordinates (not normalised).
  Eigen::Vector3d Direction(double x, double y) const { return rt_ * Eigen::Vector3d(x, y, 1.0); }

 private:
  Eigen::Matrix3d rt_;
  Eigen::Vector3d rtt_;
};

// The plate in a calib/ image: the pattern on the plate, background beyond.
class PlateScene {
 public:
  PlateScene(const PlatePattern* pattern, const Eigen::Isometry3d& cam_from_plate, float background)
      : pattern_(pattern), view_(cam_from_plate), background_(background) {}
  SceneSample operator()(double x, double y) const {
    Eigen::Vector2d p;
    if (!view_.Intersect(x, y, &p) || !pattern_->Contains(p.x(), p.y())) {
      return {background_, Region::kBackground};
    }
    return pattern_->Sample(p.x(), p.y());
  }

 private:
  const PlatePattern* pattern_;
  PlaneView view_;
  float background_;
};

// A uniform scene (the calib/ image without a plate).
struct UniformScene {
  float value = 0.0f;
  SceneSample operator()(double, double) const { return {value, Region::kBackground}; }
};

struct HoleShape {
  Eigen::Vector2d center_mm;
  double radius_mm = 0.0;
};

// A paper AprilTag: paper square centred at center_mm, rotated by angle_rad
// (the printed tag's +x along (cos, sin) in the part frame, its +y, down in
// the print, along (sin, -cos)), tag cells of cell_mm.
struct MarkerShape {
  Eigen::Vector2d center_mm;
  double angle_rad = 0.0;
  double cell_mm = 0.0;
  double paper_size_mm = 0.0;
  TagCells cells;
};

// The workpiece: its top surface (rectangle outline, textured), through-holes
// of thickness_mm (inside: the bore where the ray meets it, else the table),
// paper markers and optionally the caltab plate lying on it. Zero-thickness
// paper and plate; the part's outer walls face away from the camera and are
// not modelled.
class WorkpieceScene {
 public:
  struct Layout {
    Eigen::Vector2d min_mm, max_mm;
    double thickness_mm = 0.0;
    std::vector<HoleShape> holes;
    std::vector<MarkerShape> markers;
    const PlatePattern* plate = nullptr;  // may be null
    Eigen::Isometry3d part_from_plate = Eigen::Isometry3d::Identity();
  };
  WorkpieceScene(Layout layout, const SurfaceTexture* texture, const Materials& materials);

  // What a ray sees that meets the top surface at part point p, travelling
  // along d_part (d_part.z < 0: downwards).
  SceneSample Sample(const Eigen::Vector2d& p, const Eigen::Vector3d& d_part) const;

 private:
  Layout layout_;
  const SurfaceTexture* texture_;
  Materials materials_;
  // plate (x, y) = plate_from_part_2d_ * (p - plate_origin_)
  Eigen::Matrix2d plate_from_part_2d_;
  Eigen::Vector2d plate_origin_;
  std::vector<Eigen::Vector2d> marker_axes_;  // (cos, sin) of each marker's angle
  // A uniform grid of kCellMm cells over the outline listing the holes and
  // markers that reach into each cell: one lookup instead of a loop over all
  // shapes for every ray.
  static constexpr double kCellMm = 20.0;
  struct Cell {
    std::vector<int> holes, markers;
  };
  int grid_cols_ = 0, grid_rows_ = 0;
  std::vector<Cell> grid_;
};

// The workpiece in a tile: the part moved by the table, seen from the camera.
class TileScene {
 public:
  TileScene(const WorkpieceScene* scene, const Eigen::Isometry3d& cam_from_part,
            const Eigen::Vector2d& table_pos_mm, float table_reflectance)
      : scene_(scene),
        view_(cam_from_part),
        table_pos_mm_(table_pos_mm),
        table_(table_reflectance) {}
  SceneSample operator()(double x, double y) const {
    // The plane is fixed in the machine frame (= part frame at table 0); the
    // part point under machine point M is M - T.
    Eigen::Vector2d m;
    if (!view_.Intersect(x, y, &m)) return {table_, Region::kTable};
    return scene_->Sample(m - table_pos_mm_, view_.Direction(x, y));
  }

 private:
  const WorkpieceScene* scene_;
  PlaneView view_;
  Eigen::Vector2d table_pos_mm_;
  float table_;
};

}  // namespace omm
