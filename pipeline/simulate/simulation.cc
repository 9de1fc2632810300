#include "pipeline/simulate/simulation.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <utility>
#include <vector>

#include "adapters/apriltag/tag_family.h"
#include "adapters/mrcal/lens.h"
#include "pipeline/simulate/random.h"

namespace omm {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

// Independent random streams: adding an image or a preset feature does not
// change the other draws.
enum Stream : std::uint64_t {
  kCameraStream = 1,
  kCalibStream = 2,
  kPartStream = 3,
  kTableStream = 4,
  kFeatureStream = 5,
  kCmmStream = 6,
  kTextureStream = 7,
  kCalibNoiseStream = 1000,  // + image index
  kTileNoiseStream = 2000,   // + tile index
};

// Nominal values written to project.yaml; the truth differs.
constexpr double kNominalPitchUm = 4.5;
constexpr double kNominalFocalMm = 12.0;
constexpr int kWidthPx = 1600;
constexpr int kHeightPx = 1200;
constexpr double kWorkingDistanceMm = 390.0;
constexpr double kPlateSizeMm = 120.0;  // the plate, white around its board (SimulatedBoard)
constexpr double kMosaicGsdMm = 0.15;
constexpr double kCmmSigmaMm = 0.001;  // the CMM's noise, stated in cmm.csv

const std::vector<PresetSpec>& Presets() {
  static const std::vector<PresetSpec> presets = [] {
    std::vector<PresetSpec> p;
    p.push_back({"demo", "textured part, holes, the caltab lying on the part", false,
                 TextureStyle::kRich, false, true, false});
    p.push_back({"markers", "textured part with paper AprilTag 36h11 markers", false,
                 TextureStyle::kRich, true, false, false});
    p.push_back({"low-texture", "weak, smooth texture: few corners to match", false,
                 TextureStyle::kLow, false, false, false});
    p.push_back({"sparse-texture", "a plain part with sparse specks", false, TextureStyle::kSparse,
                 false, false, false});
    p.push_back({"exposure", "tiles of clearly different brightness and vignetting", false,
                 TextureStyle::kRich, false, false, true});
    p.push_back({"low-texture-exposure",
                 "weak, smooth texture and tiles of clearly different brightness", false,
                 TextureStyle::kLow, false, false, true});
    p.push_back({"lens-mismatch", "a splined truth lens that OPENCV8 cannot represent", true,
                 TextureStyle::kRich, false, false, false});
    return p;
  }();
  return presets;
}

// value rounded to `decimals` decimal places, as the double nearest to that
// decimal (dividing by an exact power of ten rounds correctly), so that files
// show e.g. 371.2 rather than 371.20000000000005.
double RoundDecimals(double value, int decimals) {
  const double scale = std::pow(10.0, decimals);
  return std::round(value * scale) / scale;
}

Eigen::Matrix3d RotZ(double angle) {
  return Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

// Rotation tilting +z by `tilt` towards the azimuth `azimuth` (in the xy plane).
Eigen::Matrix3d Tilt(double tilt, double azimuth) {
  const Eigen::Vector3d axis(-std::sin(azimuth), std::cos(azimuth), 0.0);
  return Eigen::AngleAxisd(tilt, axis).toRotationMatrix();
}

// ---------------------------------------------------------------- camera

// The spline knots of LENSMODEL_SPLINED_STEREOGRAPHIC (mrcal 2.2): uniformly
// spaced in the stereographic u, centred, spacing 2 u_edge / (N - order) with
// u_edge = 2 tan(fov_x / 4) (mrcal's knots_for_splined_models).
double SplineKnotSpacing(int nx, int order, double fov_x_deg) {
  const double u_edge = 2.0 * std::tan(fov_x_deg * kDeg / 4.0);
  return 2.0 * u_edge / (nx - order);
}

CameraTruth DrawCamera(const PresetSpec& preset, SimRandom* random) {
  CameraTruth camera;
  camera.pixel_pitch_um = kNominalPitchUm;  // sensor pitches are exact; the lens is not
  const double sign = random->Bernoulli(0.5) ? 1.0 : -1.0;
  camera.focal_length_mm = kNominalFocalMm * (1.0 + sign * random->Uniform(0.005, 0.015));
  const double fx = camera.focal_length_mm / (camera.pixel_pitch_um * 1e-3);
  const double fy = fx * (1.0 + random->Normal(0.0, 2e-4));
  const double pp_offset = random->Uniform(12.0, 35.0),
               pp_angle = random->Uniform(0, 2 * std::numbers::pi);
  const double cx = 0.5 * (kWidthPx - 1) + pp_offset * std::cos(pp_angle);
  const double cy = 0.5 * (kHeightPx - 1) + pp_offset * std::sin(pp_angle);
  camera.psf_sigma_px = random->Uniform(0.6, 0.85);
  CameraModel& model = camera.model;
  model.width_px = kWidthPx;
  model.height_px = kHeightPx;
  if (!preset.splined_truth) {
    // A 12 mm C-mount lens on a 1/1.8" sensor: ~1 % barrel at the corners.
    model.lens_model = "LENSMODEL_OPENCV8";
    model.intrinsics.resize(12);
    model.intrinsics << fx, fy, cx, cy, random->Uniform(-0.12, -0.05),  // k1
        random->Uniform(0.05, 0.2),                                     // k2
        random->Uniform(-4e-4, 4e-4),                                   // p1
        random->Uniform(-4e-4, 4e-4),                                   // p2
        random->Uniform(-0.15, 0.05),                                   // k3
        random->Uniform(-0.02, 0.02),                                   // k4
        random->Uniform(-0.005, 0.005),                                 // k5
        random->Uniform(-0.005, 0.005);                                 // k6
    return camera;
  }
  // Spline control points are the offsets du of the stereographic u at the
  // knots: q = f (u + du(u)) + c. They encode a strong radial term, a
  // decentring-like term, and a wave no polynomial model of OPENCV8 follows.
  constexpr int kNx = 16, kNy = 12, kOrder = 3;
  constexpr double kFovXDeg = 50.0;
  model.lens_model = "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_fov_x_deg=50";
  const double spacing = SplineKnotSpacing(kNx, kOrder, kFovXDeg);
  const double k1 = random->Uniform(-0.3, -0.2), k2 = random->Uniform(0.0, 0.3);
  const double a = random->Uniform(-0.02, 0.02), b = random->Uniform(-0.02, 0.02);
  const double wave = random->Uniform(4e-4, 8e-4), wave_period = random->Uniform(0.25, 0.4);
  const double wave_phase = random->Uniform(0, 2 * std::numbers::pi);
  model.intrinsics.resize(4 + 2 * kNx * kNy);
  model.intrinsics.head<4>() << fx, fy, cx, cy;
  for (int j = 0; j < kNy; ++j) {
    for (int i = 0; i < kNx; ++i) {
      const double ux = (i - 0.5 * (kNx - 1)) * spacing, uy = (j - 0.5 * (kNy - 1)) * spacing;
      const double r2 = ux * ux + uy * uy;
      const double radial = k1 * r2 + k2 * r2 * r2;
      const double w =
          wave * std::sin(2 * std::numbers::pi * (ux + 0.5 * uy) / wave_period + wave_phase);
      model.intrinsics[4 + 2 * (j * kNx + i)] = radial * ux + a * uy * uy + w;
      model.intrinsics[4 + 2 * (j * kNx + i) + 1] = radial * uy + b * ux * uy - 0.5 * w;
    }
  }
  return camera;
}

// ---------------------------------------------------------------- geometry helpers

// Projects plane points (2 x N, z = 0 of the plane whose pose is
// cam_from_plane); NaN for a point the camera does not see: behind it, or
// folded into the image by the lens (FoldedIntoTheImage: the renders trace
// the pixels' rays, which point elsewhere).
Eigen::Matrix2Xd ProjectPlanePoints(const CameraModel& camera,
                                    const Eigen::Isometry3d& cam_from_plane,
                                    const Eigen::Matrix2Xd& points) {
  Eigen::Matrix3Xd p(3, points.cols());
  for (Eigen::Index i = 0; i < points.cols(); ++i) {
    p.col(i) = cam_from_plane * Eigen::Vector3d(points(0, i), points(1, i), 0.0);
  }
  Eigen::Matrix2Xd q;
  const bool ok = ProjectPoints(camera, p, &q);
  assert(ok);
  (void)ok;
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  const std::vector<bool> folded = FoldedIntoTheImage(camera, p, q, /*near_px=*/100.0);
  for (Eigen::Index i = 0; i < points.cols(); ++i) {
    if (p(2, i) <= 0 || folded[static_cast<size_t>(i)]) q.col(i).setConstant(kNaN);
  }
  return q;
}

// Smallest distance of the projected points to the image border (negative if
// one is outside, -inf if behind the camera).
double ImageMargin(const Eigen::Matrix2Xd& q) {
  double margin = std::numeric_limits<double>::infinity();
  for (Eigen::Index i = 0; i < q.cols(); ++i) {
    if (!q.col(i).allFinite()) return -std::numeric_limits<double>::infinity();
    margin = std::min({margin, q(0, i), q(1, i), kWidthPx - 1 - q(0, i), kHeightPx - 1 - q(1, i)});
  }
  return margin;
}

Eigen::Matrix2Xd CirclePoints(const Eigen::Vector2d& center, double radius, int n) {
  Eigen::Matrix2Xd points(2, n);
  for (int k = 0; k < n; ++k) {
    const double a = 2 * std::numbers::pi * k / n;
    points.col(k) = center + radius * Eigen::Vector2d(std::cos(a), std::sin(a));
  }
  return points;
}

// Points along the outline of a square of side `size` centred at the origin.
Eigen::Matrix2Xd SquareOutline(double size, int per_side) {
  Eigen::Matrix2Xd points(2, 4 * per_side);
  const double h = 0.5 * size;
  for (int k = 0; k < per_side; ++k) {
    const double s = -h + size * k / per_side;
    points.col(4 * k) << s, -h;
    points.col(4 * k + 1) << h, s;
    points.col(4 * k + 2) << -s, h;
    points.col(4 * k + 3) << -h, -s;
  }
  return points;
}

// Camera pose relative to the part at a table position: P + T in the machine
// frame, cam_from_machine = cam_from_part (table 0).
Eigen::Isometry3d CamFromPartAt(const Eigen::Isometry3d& cam_from_part,
                                const Eigen::Vector2d& table_pos_mm) {
  return cam_from_part * Eigen::Translation3d(table_pos_mm.x(), table_pos_mm.y(), 0.0);
}

// Plane point met by the ray of pixel q.
Eigen::Vector2d PixelOnPlane(const CameraModel& camera, const Eigen::Isometry3d& cam_from_plane,
                             const Eigen::Vector2d& q) {
  Eigen::Matrix3Xd v;
  const bool ok = UnprojectPixels(camera, q, &v);
  assert(ok);
  (void)ok;
  Eigen::Vector2d p;
  const bool hit = PlaneView(cam_from_plane).Intersect(v(0, 0), v(1, 0), &p);
  assert(hit);
  (void)hit;
  return p;
}

// ---------------------------------------------------------------- calibration poses

// A plate pose whose projected plate centre is near `target_px`, at depth
// `z_mm`, or false if the plate does not fit the image there.
Eigen::Isometry3d PlatePose(const CameraModel& camera, const Eigen::Vector2d& target_px,
                            double z_mm, const Eigen::Matrix3d& rotation) {
  Eigen::Matrix3Xd v;
  UnprojectPixels(camera, target_px, &v);
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = rotation;
  pose.translation() = z_mm * v.col(0);
  return pose;
}

std::vector<CalibImageTruth> DrawCalibration(const CameraTruth& camera, int num_images,
                                             SimRandom* random) {
  const Eigen::Matrix2Xd outline = SquareOutline(kPlateSizeMm, 12);
  const Eigen::Vector2d centre(0.5 * (kWidthPx - 1), 0.5 * (kHeightPx - 1));
  // Positions of the partial and the plate-absent images in the sequence.
  const int partial_index = random->UniformInt(num_images);
  int absent_index = random->UniformInt(num_images - 1);
  if (absent_index >= partial_index) ++absent_index;

  std::vector<CalibImageTruth> images(num_images);
  int full_count = 0;
  for (int i = 0; i < num_images; ++i) {
    CalibImageTruth& image = images[i];
    char name[32];
    std::snprintf(name, sizeof(name), "calib_%02d.png", i);
    image.image = name;
    image.exposure.gain = random->Uniform(0.92, 1.08);
    double z_mm = kWorkingDistanceMm;
    if (i == absent_index) {
      image.kind = CalibImageTruth::Kind::kPlateAbsent;
    } else if (i == partial_index) {
      // Plate centre 0-150 px inside a random edge: about half the plate is out.
      image.kind = CalibImageTruth::Kind::kPartial;
      const int edge = random->UniformInt(4);
      const double along = random->Uniform(0.3, 0.7), inside = random->Uniform(0.0, 150.0);
      Eigen::Vector2d target;
      switch (edge) {
        case 0: target << inside, along * kHeightPx; break;
        case 1: target << kWidthPx - 1 - inside, along * kHeightPx; break;
        case 2: target << along * kWidthPx, inside; break;
        default: target << along * kWidthPx, kHeightPx - 1 - inside; break;
      }
      z_mm = random->Uniform(370.0, 410.0);
      const Eigen::Matrix3d rotation =
          Tilt(random->Uniform(0, 10 * kDeg), random->Uniform(0, 2 * std::numbers::pi)) *
          RotZ(random->Uniform(0, 2 * std::numbers::pi));
      image.cam_from_plate = PlatePose(camera.model, target, z_mm, rotation);
    } else {
      image.kind = CalibImageTruth::Kind::kFull;
      // Poses cycle over the 3 x 3 cells of the field (a corner, an edge or
      // the centre), so the plate reaches every corner and edge; every fourth
      // pose is nearly flat, the others tilted.
      const int cell = full_count % 9;
      const bool flat = full_count % 4 == 0;
      ++full_count;
      Eigen::Vector2d target((0.15 + 0.35 * (cell % 3) + random->Uniform(-0.05, 0.05)) * kWidthPx,
                             (0.15 + 0.35 * (cell / 3) + random->Uniform(-0.05, 0.05)) * kHeightPx);
      z_mm = random->Uniform(340.0, 440.0);
      const double tilt =
          flat ? random->Uniform(0, 4 * kDeg) : random->Uniform(10 * kDeg, 35 * kDeg);
      // In the field's corners the plate is turned by a multiple of 90 deg
      // (+- 10 deg), so that its own corner, not an edge, fills the image's.
      const bool corner_cell = cell != 4 && cell % 2 == 0;
      const double spin = corner_cell
                              ? random->UniformInt(4) * 90 * kDeg + random->Uniform(-10, 10) * kDeg
                              : random->Uniform(0, 2 * std::numbers::pi);
      const Eigen::Matrix3d rotation =
          Tilt(tilt, random->Uniform(0, 2 * std::numbers::pi)) * RotZ(spin);
      // Slide the plate until it hugs the cell's sides of the image (a few px
      // off them) and all of it shows; back off if it cannot fit.
      const double gap_x = 3.0 + random->Uniform(0, 25), gap_y = 3.0 + random->Uniform(0, 25);
      for (int attempt = 0;; ++attempt) {
        if (attempt == 100) throw std::logic_error("simulate: no calibration pose fits the image");
        image.cam_from_plate = PlatePose(camera.model, target, z_mm, rotation);
        const Eigen::Matrix2Xd q = ProjectPlanePoints(camera.model, image.cam_from_plate, outline);
        if (!q.allFinite()) {
          z_mm += 10.0;
          continue;
        }
        const Eigen::Vector2d lo = q.rowwise().minCoeff(), hi = q.rowwise().maxCoeff();
        const Eigen::Vector2d far(kWidthPx - 1.0, kHeightPx - 1.0);
        if ((hi - lo).x() > far.x() - gap_x - 6 || (hi - lo).y() > far.y() - gap_y - 6) {
          z_mm += 10.0;  // too big for the image at this distance
          continue;
        }
        Eigen::Vector2d shift;
        for (int axis = 0; axis < 2; ++axis) {
          const int side = axis == 0 ? cell % 3 : cell / 3;  // 0: low side, 2: high side
          const double gap = axis == 0 ? gap_x : gap_y;
          if (side == 0) {
            shift[axis] = gap - lo[axis];
          } else if (side == 2) {
            shift[axis] = far[axis] - gap - hi[axis];
          } else {
            shift[axis] = std::max(0.0, 3.0 - lo[axis]) + std::min(0.0, far[axis] - 3.0 - hi[axis]);
          }
        }
        if (shift.norm() < 0.5 && lo.minCoeff() >= 2.5 && (far - hi).minCoeff() >= 2.5) break;
        target += shift;
      }
    }
    // Defocus grows away from the focused working distance.
    image.exposure.psf_sigma_px = camera.psf_sigma_px + 0.004 * std::abs(z_mm - kWorkingDistanceMm);
  }
  return images;
}

// ---------------------------------------------------------------- workpiece

struct Footprint {
  Eigen::Vector2d centre_mm;        // machine point on the optical axis (image centre ray), Z = 0
  double extent_x_mm, extent_y_mm;  // chords through it along machine X and Y
};

Footprint MeasureFootprint(const CameraModel& camera, const Eigen::Isometry3d& cam_from_part) {
  Footprint footprint;
  footprint.centre_mm = PixelOnPlane(camera, cam_from_part,
                                     Eigen::Vector2d(0.5 * (kWidthPx - 1), 0.5 * (kHeightPx - 1)));
  auto reach = [&](const Eigen::Vector2d& direction) {
    double lo = 0.0, hi = 500.0;  // mm; inside at lo, outside at hi
    for (int i = 0; i < 50; ++i) {
      const double mid = 0.5 * (lo + hi);
      Eigen::Matrix2Xd p(2, 1);
      p.col(0) = footprint.centre_mm + mid * direction;
      (ImageMargin(ProjectPlanePoints(camera, cam_from_part, p)) >= 0 ? lo : hi) = mid;
    }
    return lo;
  };
  footprint.extent_x_mm = reach({1, 0}) + reach({-1, 0});
  footprint.extent_y_mm = reach({0, 1}) + reach({0, -1});
  return footprint;
}

// Smallest margin, px, of part points in the tile (table position T).
double TileMargin(const SimulationTruth& truth, int tile, const Eigen::Matrix2Xd& part_points) {
  return ImageMargin(ProjectPlanePoints(
      truth.camera.model, CamFromPartAt(truth.cam_from_part, truth.tiles[tile].actual_mm),
      part_points));
}

// Part-frame point at the centre of a tile's image.
Eigen::Vector2d TileCentreOnPart(const SimulationTruth& truth, const Footprint& footprint,
                                 int tile) {
  return footprint.centre_mm - truth.tiles[tile].actual_mm;
}

// Distance from a point to the plate lying on the part (0 inside).
double DistanceToPlate(const SimulationTruth& truth, const Eigen::Vector2d& p) {
  if (!truth.part_from_plate) return std::numeric_limits<double>::infinity();
  const Eigen::Vector3d q = truth.part_from_plate->inverse() * Eigen::Vector3d(p.x(), p.y(), 0.0);
  const double h = 0.5 * kPlateSizeMm;
  const double dx = std::max(std::abs(q.x()) - h, 0.0), dy = std::max(std::abs(q.y()) - h, 0.0);
  return std::hypot(dx, dy);
}

// Outline of a marker's paper in the part frame.
Eigen::Matrix2Xd MarkerPaperOutline(const MarkerShape& marker) {
  Eigen::Matrix2Xd points = SquareOutline(marker.paper_size_mm, 2);
  const Eigen::Matrix2d rot = Eigen::Rotation2Dd(marker.angle_rad).toRotationMatrix();
  for (Eigen::Index i = 0; i < points.cols(); ++i)
    points.col(i) = marker.center_mm + rot * points.col(i);
  return points;
}

bool InsideOutline(const SimulationTruth& truth, const Eigen::Vector2d& p, double margin_mm) {
  return p.x() >= truth.part_min_mm.x() + margin_mm && p.y() >= truth.part_min_mm.y() + margin_mm &&
         p.x() <= truth.part_max_mm.x() - margin_mm && p.y() <= truth.part_max_mm.y() - margin_mm;
}

void PlacePlateOnPart(const Footprint& footprint, SimulationTruth* truth, SimRandom* random) {
  const Eigen::Matrix2Xd outline = SquareOutline(kPlateSizeMm, 8);
  for (int attempt = 0; attempt < 1000; ++attempt) {
    const int tile = random->UniformInt(static_cast<int>(truth->tiles.size()));
    const Eigen::Vector2d centre =
        TileCentreOnPart(*truth, footprint, tile) +
        Eigen::Vector2d(random->Uniform(-20, 20), random->Uniform(-20, 20));
    const double angle = random->UniformInt(4) * 90 * kDeg + random->Uniform(-15 * kDeg, 15 * kDeg);
    // Face up: plate x along the part's rotated X, plate y (down in print)
    // along the rotated -Y, plate +z into the part (-Z).
    Eigen::Isometry3d part_from_plate = Eigen::Isometry3d::Identity();
    part_from_plate.linear() = RotZ(angle) * Eigen::Vector3d(1, -1, -1).asDiagonal();
    part_from_plate.translation() << centre, 0.0;
    Eigen::Matrix2Xd part_points(2, outline.cols());
    for (Eigen::Index i = 0; i < outline.cols(); ++i) {
      part_points.col(i) =
          (part_from_plate * Eigen::Vector3d(outline(0, i), outline(1, i), 0)).head<2>();
    }
    bool on_part = true;
    for (Eigen::Index i = 0; i < part_points.cols(); ++i)
      on_part = on_part && InsideOutline(*truth, part_points.col(i), 5.0);
    if (on_part && TileMargin(*truth, tile, part_points) >= 15.0) {
      truth->part_from_plate = part_from_plate;
      return;
    }
  }
  assert(false && "no place for the plate on the part");
}

std::vector<MarkerShape> PlaceMarkers(const Footprint& footprint, SimulationTruth* truth,
                                      SimRandom* random) {
  constexpr int kNumMarkers = 16;
  constexpr double kCellMm = 2.5;  // 8 cells across the black border: 20 mm tags
  constexpr double kPaperMm = 30.0;
  const TagFamilyLayout layout = AprilTag36h11Layout();
  // Distinct ids: a partial Fisher-Yates shuffle.
  std::vector<int> ids(layout.num_codes);
  for (int i = 0; i < layout.num_codes; ++i) ids[i] = i;
  std::vector<MarkerShape> markers;
  const int num_tiles = static_cast<int>(truth->tiles.size());
  for (int m = 0; m < kNumMarkers; ++m) {
    const int pick = m + random->UniformInt(layout.num_codes - m);
    std::swap(ids[m], ids[pick]);
    for (int attempt = 0; attempt < 1000; ++attempt) {
      const int tile = (m + attempt) % num_tiles;
      MarkerShape marker;
      marker.center_mm = TileCentreOnPart(*truth, footprint, tile) +
                         Eigen::Vector2d(random->Uniform(-0.45, 0.45) * footprint.extent_x_mm,
                                         random->Uniform(-0.45, 0.45) * footprint.extent_y_mm);
      marker.angle_rad = random->Uniform(0, 2 * std::numbers::pi);
      marker.cell_mm = kCellMm;
      marker.paper_size_mm = kPaperMm;
      const double reach = kPaperMm / std::sqrt(2.0);
      if (!InsideOutline(*truth, marker.center_mm, reach + 3.0)) continue;
      if (DistanceToPlate(*truth, marker.center_mm) < reach + 3.0) continue;
      bool clear = true;
      for (const MarkerShape& other : markers) {
        clear = clear && (other.center_mm - marker.center_mm).norm() > 2 * reach + 3.0;
      }
      if (!clear || TileMargin(*truth, tile, MarkerPaperOutline(marker)) < 10.0) continue;
      marker.cells = AprilTag36h11Cells(ids[m]);
      markers.push_back(marker);

      MarkerTruth marker_truth;
      marker_truth.id = ids[m];
      marker_truth.tag_size_mm = layout.width_at_border * kCellMm;
      marker_truth.paper_size_mm = kPaperMm;
      const double h = 0.5 * marker_truth.tag_size_mm;
      const double c = std::cos(marker.angle_rad), s = std::sin(marker.angle_rad);
      // Print coordinates (u right, w down) of bottom-left, bottom-right,
      // top-right, top-left: libapriltag's corner order.
      const double corners[4][2] = {{-h, h}, {h, h}, {h, -h}, {-h, -h}};
      for (int k = 0; k < 4; ++k) {
        const double u = corners[k][0], w = corners[k][1];
        marker_truth.corners_part_mm.col(k) =
            marker.center_mm + u * Eigen::Vector2d(c, s) + w * Eigen::Vector2d(s, -c);
      }
      truth->markers.push_back(marker_truth);
      break;
    }
  }
  return markers;
}

void PlaceHoles(const Footprint& footprint, const std::vector<MarkerShape>& markers,
                SimulationTruth* truth, SimRandom* random) {
  // Every nominal size once, then four more at random.
  std::vector<double> nominal = {8, 10, 12, 16, 20, 25, 30, 40, 50, 60};
  for (int k = 0; k < 4; ++k) nominal.push_back(nominal[random->UniformInt(10)]);
  for (int i = static_cast<int>(nominal.size()) - 1; i > 0; --i)
    std::swap(nominal[i], nominal[random->UniformInt(i + 1)]);
  const int num_tiles = static_cast<int>(truth->tiles.size());
  for (size_t h = 0; h < nominal.size(); ++h) {
    const double radius = 0.5 * nominal[h];
    for (int attempt = 0; attempt < 2000; ++attempt) {
      const int tile = static_cast<int>((h + attempt) % num_tiles);
      const Eigen::Vector2d centre =
          TileCentreOnPart(*truth, footprint, tile) +
          Eigen::Vector2d(random->Uniform(-0.4, 0.4) * footprint.extent_x_mm,
                          random->Uniform(-0.4, 0.4) * footprint.extent_y_mm);
      if (!InsideOutline(*truth, centre, radius + 10.0)) continue;
      if (DistanceToPlate(*truth, centre) < radius + 8.0) continue;
      bool clear = true;
      for (const HoleTruth& other : truth->holes) {
        clear = clear &&
                (other.center_part_mm - centre).norm() > radius + 0.5 * other.diameter_mm + 8.0;
      }
      for (const MarkerShape& marker : markers) {
        clear = clear && (marker.center_mm - centre).norm() >
                             radius + marker.paper_size_mm / std::sqrt(2.0) + 5.0;
      }
      if (!clear || TileMargin(*truth, tile, CirclePoints(centre, radius, 32)) < 40.0) continue;
      HoleTruth hole;
      hole.center_part_mm = centre;
      hole.nominal_diameter_mm = nominal[h];
      // Machining deviation from the nominal size.
      hole.diameter_mm = nominal[h] + random->Normal(0.0, 0.015);
      truth->holes.push_back(hole);
      break;
    }
  }
  // Names in a stable order (by position) so that they read well.
  std::sort(truth->holes.begin(), truth->holes.end(), [](const HoleTruth& a, const HoleTruth& b) {
    return a.center_part_mm.y() != b.center_part_mm.y()
               ? a.center_part_mm.y() > b.center_part_mm.y()
               : a.center_part_mm.x() < b.center_part_mm.x();
  });
  for (size_t h = 0; h < truth->holes.size(); ++h) {
    char name[32];
    std::snprintf(name, sizeof(name), "hole_%02zu", h + 1);
    truth->holes[h].name = name;
  }
}

// ---------------------------------------------------------------- features and measurements

void DrawFeaturesAndMeasurements(SimulationPlan* plan, SimRandom* random) {
  SimulationTruth& truth = plan->truth;
  std::vector<int> feature_tile;
  for (const HoleTruth& hole : truth.holes) {
    // The tile that sees the hole with the widest margin.
    const Eigen::Matrix2Xd rim = CirclePoints(hole.center_part_mm, 0.5 * hole.diameter_mm, 64);
    int best = 0;
    double best_margin = -std::numeric_limits<double>::infinity();
    for (int t = 0; t < static_cast<int>(truth.tiles.size()); ++t) {
      const double margin = TileMargin(truth, t, rim);
      if (margin > best_margin) best_margin = margin, best = t;
    }
    feature_tile.push_back(best);
    const Eigen::Isometry3d cam_from_part =
        CamFromPartAt(truth.cam_from_part, truth.tiles[best].actual_mm);
    Eigen::Matrix2Xd centre(2, 1);
    centre.col(0) = hole.center_part_mm;
    const Eigen::Vector2d q_centre =
        ProjectPlanePoints(truth.camera.model, cam_from_part, centre).col(0);
    const double diameter_px =
        2.0 * (ProjectPlanePoints(truth.camera.model, cam_from_part, rim).colwise() - q_centre)
                  .colwise()
                  .norm()
                  .mean();
    // A rough position, as a user would click it: up to 0.1 diameter off.
    const double angle = random->Uniform(0, 2 * std::numbers::pi);
    const double offset = random->Uniform(0.0, 0.09) * diameter_px;
    FeatureSpec feature;
    feature.name = hole.name;
    feature.type = FeatureType::kCircle;
    feature.image = truth.tiles[best].image;
    feature.near_px << RoundDecimals(q_centre.x() + offset * std::cos(angle), 1),
        RoundDecimals(q_centre.y() + offset * std::sin(angle), 1);
    feature.diameter_mm = hole.nominal_diameter_mm;
    plan->project.features.push_back(feature);
  }

  const int n = static_cast<int>(truth.holes.size());
  auto distance = [&](int a, int b) {
    return (truth.holes[a].center_part_mm - truth.holes[b].center_part_mm).norm();
  };
  std::vector<std::pair<int, int>> pairs;
  for (int a = 0; a < n; ++a) {
    for (int b = a + 1; b < n; ++b) pairs.emplace_back(a, b);
  }
  for (int i = static_cast<int>(pairs.size()) - 1; i > 0; --i)
    std::swap(pairs[i], pairs[random->UniformInt(i + 1)]);
  std::vector<std::pair<int, int>> chosen;
  auto take = [&](auto predicate, int count) {
    for (const auto& pair : pairs) {
      if (count == 0) break;
      if (std::find(chosen.begin(), chosen.end(), pair) != chosen.end() || !predicate(pair))
        continue;
      chosen.push_back(pair);
      --count;
    }
  };
  // The two farthest holes (across the whole mosaic), three pairs far apart
  // in different tiles, one in neighbouring regions, two within one tile.
  if (!pairs.empty()) {
    chosen.push_back(
        *std::max_element(pairs.begin(), pairs.end(), [&](const auto& x, const auto& y) {
          return distance(x.first, x.second) < distance(y.first, y.second);
        }));
  }
  take(
      [&](const auto& p) {
        return feature_tile[p.first] != feature_tile[p.second] && distance(p.first, p.second) > 200;
      },
      3);
  take(
      [&](const auto& p) {
        return feature_tile[p.first] != feature_tile[p.second] && distance(p.first, p.second) < 150;
      },
      1);
  take([&](const auto& p) { return feature_tile[p.first] == feature_tile[p.second]; }, 2);
  for (const auto& [a, b] : chosen) {
    MeasurementSpec m;
    m.name = "dist_" + truth.holes[a].name + "_" + truth.holes[b].name;
    m.type = MeasurementType::kDistance;
    m.features = {truth.holes[a].name, truth.holes[b].name};
    plan->project.measurements.push_back(m);
    truth.measurements.push_back({m.name, distance(a, b)});
  }
  // Diameters: the smallest, the largest and two others.
  std::vector<int> by_size(n);
  for (int i = 0; i < n; ++i) by_size[i] = i;
  std::sort(by_size.begin(), by_size.end(), [&](int a, int b) {
    return truth.holes[a].nominal_diameter_mm < truth.holes[b].nominal_diameter_mm;
  });
  std::vector<int> diameters;
  if (n > 0) diameters = {by_size.front(), by_size.back()};
  while (n > 3 && diameters.size() < 4) {
    const int pick = by_size[1 + random->UniformInt(n - 2)];
    if (std::find(diameters.begin(), diameters.end(), pick) == diameters.end())
      diameters.push_back(pick);
  }
  for (int h : diameters) {
    MeasurementSpec m;
    m.name = "dia_" + truth.holes[h].name;
    m.type = MeasurementType::kDiameter;
    m.features = {truth.holes[h].name};
    plan->project.measurements.push_back(m);
    truth.measurements.push_back({m.name, truth.holes[h].diameter_mm});
  }
}

}  // namespace

// ---------------------------------------------------------------- public

std::vector<std::string> SimulationPresets() {
  std::vector<std::string> names;
  for (const PresetSpec& preset : Presets()) names.push_back(preset.name);
  return names;
}

PresetSpec GetPreset(const std::string& name) {
  for (const PresetSpec& preset : Presets()) {
    if (preset.name == name) return preset;
  }
  assert(false && "unknown preset");
  return Presets().front();
}

std::string SimulationOptions::Check() const {
  const std::vector<std::string> names = SimulationPresets();
  if (std::find(names.begin(), names.end(), preset) == names.end()) {
    std::string list;
    for (const std::string& name : names) list += (list.empty() ? "" : ", ") + name;
    return "unknown preset '" + preset + "' (expected one of: " + list + ")";
  }
  if (num_calib_images < 3 || num_calib_images > 100) {
    return "num_calib_images must be in 3..100 (one partial, one without the plate, the rest full)";
  }
  if (grid_cols < 1 || grid_cols > 6 || grid_rows < 1 || grid_rows > 6 ||
      grid_cols * grid_rows < 2) {
    return "the grid must be 1..6 tiles per row by 1..6 rows, 2 tiles or more";
  }
  if (!(table_sigma_mm > 0.0 && table_sigma_mm <= 1.0)) return "table_sigma_mm must be in (0, 1]";
  if (supersampling < 2 || supersampling > 16) return "supersampling must be in 2..16";
  if (edge_supersampling < 1 || edge_supersampling > 64)
    return "edge_supersampling must be in 1..64";
  if (num_threads < 1) return "num_threads must be >= 1";
  return "";
}

BoardSpec SimulatedBoard(BoardType type) {
  BoardSpec board;  // the caltab
  board.type = type;
  if (type == BoardType::kChessboard) {
    board.rows = 7;
    board.cols = 9;
    board.pitch_mm = 11.0;
  }
  return board;
}

PlaneScene TruthPlaneScene(const SimulationTruth& truth) {
  PlaneScene scene;
  const Eigen::AngleAxisd r(truth.cam_from_part.linear());
  scene.cam_from_part_r = r.angle() * r.axis();
  scene.cam_from_part_t_mm = truth.cam_from_part.translation();
  for (const TileTruth& tile : truth.tiles) scene.table_pos_mm.push_back(tile.actual_mm);
  scene.intrinsics = truth.camera.model.intrinsics;
  return scene;
}

RayTableOptions RayOptionsFor(const SimulationOptions& options) {
  RayTableOptions ray_options;
  ray_options.supersampling = options.supersampling;
  ray_options.num_threads = options.num_threads;
  return ray_options;
}

SimulationPlan PlanSimulation(const SimulationOptions& options) {
  assert(options.Check().empty());
  SimulationPlan plan;
  plan.options = options;
  plan.preset = GetPreset(options.preset);
  plan.preset.plate_on_part = plan.preset.plate_on_part || options.plate_on_part;
  SimulationTruth& truth = plan.truth;
  truth.preset = options.preset;
  truth.seed = options.seed;
  truth.plate_size_mm = kPlateSizeMm;
  truth.board = SimulatedBoard(options.board);
  truth.table_sigma_mm = options.table_sigma_mm;
  plan.texture_seed = SimRandom(options.seed, kTextureStream).Next();

  SimRandom camera_random(options.seed, kCameraStream);
  truth.camera = DrawCamera(plan.preset, &camera_random);
  const double vignetting = camera_random.Uniform(0.1, 0.2);

  SimRandom calib_random(options.seed, kCalibStream);
  truth.calib_images = DrawCalibration(truth.camera, options.num_calib_images, &calib_random);
  for (CalibImageTruth& image : truth.calib_images) image.exposure.vignetting = vignetting;

  // The camera over the machine: height, tilt, rotation about its axis.
  SimRandom part_random(options.seed, kPartStream);
  const double height_mm = part_random.Uniform(385.0, 395.0);
  const double roll =
      part_random.UniformInt(4) * 90 * kDeg + part_random.Uniform(-8 * kDeg, 8 * kDeg);
  const Eigen::Matrix3d cam_from_machine_r = Tilt(part_random.Uniform(0.5 * kDeg, 2.5 * kDeg),
                                                  part_random.Uniform(0, 2 * std::numbers::pi)) *
                                             RotZ(roll) * Eigen::Vector3d(1, -1, -1).asDiagonal();
  Eigen::Isometry3d cam_from_part = Eigen::Isometry3d::Identity();
  cam_from_part.linear() = cam_from_machine_r;
  cam_from_part.translation() = -cam_from_machine_r * Eigen::Vector3d(0, 0, height_mm);
  const Footprint footprint0 = MeasureFootprint(truth.camera.model, cam_from_part);

  // The part, and the grid of table positions centred on it.
  truth.part_min_mm.setZero();
  truth.part_max_mm << std::round(part_random.Uniform(430, 470)),
      std::round(part_random.Uniform(430, 470));
  truth.part_thickness_mm = std::round(part_random.Uniform(8, 16));
  const Eigen::Vector2d table_centre(std::round(part_random.Uniform(150, 300)),
                                     std::round(part_random.Uniform(80, 200)));
  const double step_x =
      0.5 * std::round(2.0 * (1.0 - part_random.Uniform(0.35, 0.45)) * footprint0.extent_x_mm);
  const double step_y =
      0.5 * std::round(2.0 * (1.0 - part_random.Uniform(0.35, 0.45)) * footprint0.extent_y_mm);
  // Another grid than 3 x 3: the part grows or shrinks with the grid's
  // reach (footprint plus steps), its margin kept.
  const auto scaled_extent = [](double extent_3x3, double footprint, double step, int tiles) {
    return std::round(extent_3x3 * (footprint + (tiles - 1) * step) / (footprint + 2 * step));
  };
  if (options.grid_cols != 3) {
    truth.part_max_mm.x() =
        scaled_extent(truth.part_max_mm.x(), footprint0.extent_x_mm, step_x, options.grid_cols);
  }
  if (options.grid_rows != 3) {
    truth.part_max_mm.y() =
        scaled_extent(truth.part_max_mm.y(), footprint0.extent_y_mm, step_y, options.grid_rows);
  }
  const Eigen::Vector2d part_centre = 0.5 * (truth.part_min_mm + truth.part_max_mm);
  // The grid's middle looks at the part centre (within 8 mm): move the
  // camera so that its axis meets the machine plane at part centre + table
  // centre.
  const Eigen::Vector2d axis_mm =
      part_centre + table_centre +
      Eigen::Vector2d(part_random.Uniform(-8, 8), part_random.Uniform(-8, 8));
  const Eigen::Vector2d shift = axis_mm - footprint0.centre_mm;
  cam_from_part.translation() -= cam_from_machine_r * Eigen::Vector3d(shift.x(), shift.y(), 0.0);
  truth.cam_from_part = cam_from_part;
  Footprint footprint = footprint0;
  footprint.centre_mm += shift;

  SimRandom table_random(options.seed, kTableStream);
  for (int r = 0; r < options.grid_rows; ++r) {
    for (int c = 0; c < options.grid_cols; ++c) {
      TileTruth tile;
      char name[32];
      std::snprintf(name, sizeof(name), "tile_r%dc%d.png", r, c);
      tile.image = name;
      tile.grid_row = r;
      tile.grid_col = c;
      const double col_steps = c - 0.5 * (options.grid_cols - 1);
      const double row_steps = r - 0.5 * (options.grid_rows - 1);
      tile.commanded_mm = table_centre + Eigen::Vector2d(col_steps * step_x, row_steps * step_y);
      tile.actual_mm =
          tile.commanded_mm + Eigen::Vector2d(table_random.Normal(0.0, options.table_sigma_mm),
                                              table_random.Normal(0.0, options.table_sigma_mm));
      tile.exposure.psf_sigma_px = truth.camera.psf_sigma_px;
      tile.exposure.vignetting = vignetting;
      tile.exposure.gain = table_random.Uniform(0.95, 1.05);
      truth.tiles.push_back(tile);
    }
  }
  if (plan.preset.exposure_variation) {
    // Gains spread over 0.6 .. 1.15 in a random order, vignetting 0.1 .. 0.45.
    const int n = static_cast<int>(truth.tiles.size());
    std::vector<double> gains;
    for (int i = 0; i < n; ++i) gains.push_back(0.6 + 0.55 * i / (n - 1));
    for (int i = n - 1; i > 0; --i) std::swap(gains[i], gains[table_random.UniformInt(i + 1)]);
    for (int i = 0; i < n; ++i) {
      truth.tiles[i].exposure.gain = gains[i];
      truth.tiles[i].exposure.vignetting = table_random.Uniform(0.1, 0.45);
    }
  }

  if (plan.preset.plate_on_part) PlacePlateOnPart(footprint, &truth, &part_random);
  const std::vector<MarkerShape> markers = plan.preset.markers
                                               ? PlaceMarkers(footprint, &truth, &part_random)
                                               : std::vector<MarkerShape>();
  PlaceHoles(footprint, markers, &truth, &part_random);

  Project& project = plan.project;
  project.name = "sim-" + options.preset + (options.plate_on_part ? "-plate-" : "-") +
                 std::to_string(options.seed);
  project.camera.pixel_pitch_um = kNominalPitchUm;
  project.camera.focal_length_mm = kNominalFocalMm;
  // The lens type is known for a stock lens; for the mismatch the pipeline
  // has to find out that OPENCV8 is not enough.
  if (!plan.preset.splined_truth) project.camera.lens_model = truth.camera.model.lens_model;
  project.board = truth.board;
  project.table_sigma_mm = options.table_sigma_mm;
  project.mosaic_gsd_mm = kMosaicGsdMm;
  for (const TileTruth& tile : truth.tiles)
    project.tiles.push_back({tile.image, tile.commanded_mm});
  project.image_width_px = kWidthPx;
  project.image_height_px = kHeightPx;

  SimRandom feature_random(options.seed, kFeatureStream);
  DrawFeaturesAndMeasurements(&plan, &feature_random);
  SimRandom cmm_random(options.seed, kCmmStream);
  for (const MeasurementTruth& m : truth.measurements) {
    project.cmm.push_back(
        {m.name, RoundDecimals(m.value_mm + cmm_random.Normal(0.0, kCmmSigmaMm), 4), kCmmSigmaMm});
  }
  return plan;
}

// ---------------------------------------------------------------- rendering

ProjectRenderer::ProjectRenderer(const SimulationPlan& plan)
    : plan_(plan),
      plate_(plan.truth.board, plan.truth.plate_size_mm, plan.materials),
      texture_(std::make_unique<SurfaceTexture>(plan.preset.texture, plan.texture_seed)) {
  const SimulationTruth& truth = plan.truth;
  WorkpieceScene::Layout layout;
  layout.min_mm = truth.part_min_mm;
  layout.max_mm = truth.part_max_mm;
  layout.thickness_mm = truth.part_thickness_mm;
  for (const HoleTruth& hole : truth.holes)
    layout.holes.push_back({hole.center_part_mm, 0.5 * hole.diameter_mm});
  for (const MarkerTruth& marker : truth.markers) {
    MarkerShape shape;
    shape.center_mm = marker.corners_part_mm.rowwise().mean();
    // Corner 1 - corner 0 runs along the print's +x.
    const Eigen::Vector2d along = marker.corners_part_mm.col(1) - marker.corners_part_mm.col(0);
    shape.angle_rad = std::atan2(along.y(), along.x());
    const TagFamilyLayout family = AprilTag36h11Layout();
    shape.cell_mm = marker.tag_size_mm / family.width_at_border;
    shape.paper_size_mm = marker.paper_size_mm;
    shape.cells = AprilTag36h11Cells(marker.id);
    layout.markers.push_back(shape);
  }
  if (truth.part_from_plate) {
    layout.plate = &plate_;
    layout.part_from_plate = *truth.part_from_plate;
  }
  workpiece_ = std::make_unique<WorkpieceScene>(std::move(layout), texture_.get(), plan.materials);
}

ProjectRenderer::~ProjectRenderer() = default;

IntegrationOptions ProjectRenderer::Integration() const {
  IntegrationOptions integration;
  integration.edge_supersampling = plan_.options.edge_supersampling;
  integration.num_threads = plan_.options.num_threads;
  return integration;
}

ImageF ProjectRenderer::CalibReflectance(int index, const RayTable& rays) const {
  const CalibImageTruth& image = plan_.truth.calib_images.at(index);
  if (image.kind == CalibImageTruth::Kind::kPlateAbsent) {
    return IntegratePixels(rays, UniformScene{plan_.materials.calib_background}, Integration());
  }
  return IntegratePixels(
      rays, PlateScene(&plate_, image.cam_from_plate, plan_.materials.calib_background),
      Integration());
}

ImageF ProjectRenderer::TileReflectance(int index, const RayTable& rays) const {
  const TileTruth& tile = plan_.truth.tiles.at(index);
  return IntegratePixels(
      rays,
      TileScene(workpiece_.get(), plan_.truth.cam_from_part, tile.actual_mm, plan_.materials.table),
      Integration());
}

ImageF ProjectRenderer::Expose(const ImageF& reflectance, const RayTable& rays,
                               const ExposureTruth& exposure, std::uint64_t noise_stream) const {
  const CameraModel& camera = plan_.truth.camera.model;
  const Eigen::Vector2d centre(camera.intrinsics[2], camera.intrinsics[3]);
  double corner_radius = 0.0;
  for (const Eigen::Vector2d& corner :
       {Eigen::Vector2d(0, 0), Eigen::Vector2d(camera.width_px - 1, 0),
        Eigen::Vector2d(0, camera.height_px - 1),
        Eigen::Vector2d(camera.width_px - 1, camera.height_px - 1)}) {
    corner_radius = std::max(corner_radius, (corner - centre).norm());
  }
  const NoiseSource noise{plan_.options.sensor_noise, plan_.options.seed, noise_stream};
  return ExposeImage(reflectance, rays.rect, exposure, centre, corner_radius, plan_.sensor, noise,
                     plan_.options.num_threads);
}

ImageF ProjectRenderer::RenderCalibImage(int index, const RayTable& rays) const {
  return Expose(CalibReflectance(index, rays), rays, plan_.truth.calib_images.at(index).exposure,
                kCalibNoiseStream + index);
}

ImageF ProjectRenderer::RenderTile(int index, const RayTable& rays) const {
  return Expose(TileReflectance(index, rays), rays, plan_.truth.tiles.at(index).exposure,
                kTileNoiseStream + index);
}

}  // namespace omm
