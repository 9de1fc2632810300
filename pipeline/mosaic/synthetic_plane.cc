#include "pipeline/mosaic/synthetic_plane.h"

#include <cmath>
#include <numbers>
#include <random>

#include <Eigen/Geometry>

#include "adapters/mrcal/lens.h"
#include "pipeline/core/board.h"

namespace omm {
namespace {

double Rad(double deg) { return deg * std::numbers::pi / 180.0; }

bool Inside(const CameraModel& camera, const Eigen::Vector2d& q) {
  const double margin = 10.0;
  return q.x() > margin && q.y() > margin && q.x() < camera.width_px - 1 - margin &&
         q.y() < camera.height_px - 1 - margin;
}

}  // namespace

Eigen::Vector2d ProjectPartPoint(const CameraModel& camera, const PlaneScene& scene,
                                 const Eigen::Vector3d& part_mm,
                                 const Eigen::Vector2d& table_pos_mm) {
  const Eigen::Matrix3d rot = RotationFromAngleAxis(scene.cam_from_part_r);
  const Eigen::Vector3d moved = part_mm + Eigen::Vector3d(table_pos_mm.x(), table_pos_mm.y(), 0.0);
  Eigen::Matrix2Xd q;
  ProjectPoints(camera, rot * moved + scene.cam_from_part_t_mm, &q);
  return q.col(0);
}

SyntheticPlane MakeSyntheticPlane(const SyntheticPlaneOptions& options) {
  SyntheticPlane s;
  s.camera.lens_model = "LENSMODEL_OPENCV8";
  s.camera.intrinsics.resize(12);
  s.camera.intrinsics << 2667.0, 2669.0, 805.3, 594.1, -0.11, 0.08, 0.0004, -0.0003, 0.01,
      0.002, -0.001, 0.003;
  s.camera.width_px = 1600;
  s.camera.height_px = 1200;

  // cam_from_part: part -Z along the camera's z (Rx(pi)), tilted, rotated
  // about the camera's axis.
  const Eigen::Vector3d tilt_axis(std::cos(Rad(options.tilt_azimuth_deg)),
                                  std::sin(Rad(options.tilt_azimuth_deg)), 0.0);
  const Eigen::Matrix3d rot =
      (Eigen::AngleAxisd(Rad(options.rotation_about_axis_deg), Eigen::Vector3d::UnitZ()) *
       Eigen::AngleAxisd(Rad(options.tilt_deg), tilt_axis) *
       Eigen::AngleAxisd(std::numbers::pi, Eigen::Vector3d::UnitX()))
          .toRotationMatrix();
  const Eigen::AngleAxisd aa(rot);
  s.truth.cam_from_part_r = aa.angle() * aa.axis();
  // The part origin on the camera's axis at distance_mm: t_x = t_y = 0.
  s.truth.cam_from_part_t_mm = Eigen::Vector3d(0.0, 0.0, options.distance_mm);
  s.truth.intrinsics = s.camera.intrinsics;

  std::mt19937_64 noise_rng(options.noise_seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  s.input.table_sigma_mm = options.table_sigma_mm;
  s.input.observation_sigma_px = options.observation_sigma_px;
  const Eigen::Rotation2Dd grid_turn(Rad(options.grid_angle_deg));
  for (int row = 0; row < options.num_rows; ++row) {
    for (int col = 0; col < options.num_cols; ++col) {
      const Eigen::Vector2d commanded =
          grid_turn * Eigen::Vector2d((col - 0.5 * (options.num_cols - 1)) * options.step_x_mm,
                                      (row - 0.5 * (options.num_rows - 1)) * options.step_y_mm);
      s.input.commanded_table_pos_mm.push_back(commanded);
      const Eigen::Vector2d error(normal(noise_rng), normal(noise_rng));
      s.truth.table_pos_mm.push_back(commanded / (1.0 + options.table_scale_error) +
                                     options.table_sigma_mm * error);
    }
  }
  if (options.repeated_tile >= 0) {
    const Eigen::Vector2d commanded = s.input.commanded_table_pos_mm[options.repeated_tile];
    s.input.commanded_table_pos_mm.push_back(commanded);
    const Eigen::Vector2d error(normal(noise_rng), normal(noise_rng));
    s.truth.table_pos_mm.push_back(commanded / (1.0 + options.table_scale_error) +
                                   options.table_sigma_mm * error);
  }
  const int num_tiles = static_cast<int>(s.truth.table_pos_mm.size());

  // Tracks: uniform part points kept if seen in >= 2 tiles.
  std::mt19937_64 scene_rng(options.scene_seed);
  const double half_x =
      0.5 * (options.num_cols - 1) * options.step_x_mm + 0.6 * options.distance_mm * 1600 / 2667.0;
  const double half_y =
      0.5 * (options.num_rows - 1) * options.step_y_mm + 0.6 * options.distance_mm * 1200 / 2667.0;
  std::uniform_real_distribution<double> ux(-half_x, half_x), uy(-half_y, half_y);
  std::vector<Eigen::Vector2d> points;
  while (static_cast<int>(points.size()) < options.num_tracks) {
    const Eigen::Vector2d xy = grid_turn * Eigen::Vector2d(ux(scene_rng), uy(scene_rng));
    const Eigen::Vector3d p(xy.x(), xy.y(), 0.0);
    std::vector<TrackObservation> seen;
    for (int i = 0; i < num_tiles; ++i) {
      const Eigen::Vector2d q = ProjectPartPoint(s.camera, s.truth, p, s.truth.table_pos_mm[i]);
      if (Inside(s.camera, q)) seen.push_back({i, static_cast<int>(points.size()), q, 1.0});
    }
    if (seen.size() < 2) continue;
    points.push_back(p.head<2>());
    for (TrackObservation& obs : seen) {
      obs.q_px += options.observation_sigma_px * Eigen::Vector2d(normal(noise_rng), normal(noise_rng));
      if (obs.tile != options.empty_tile) s.input.observations.push_back(obs);
    }
  }
  s.input.num_tracks = static_cast<int>(points.size());
  s.truth.track_xy_mm.resize(2, s.input.num_tracks);
  for (int k = 0; k < s.input.num_tracks; ++k) s.truth.track_xy_mm.col(k) = points[k];

  if (options.with_plate) {
    // Near the middle of the four upper-right tiles, so several tiles see it.
    const PlatePose pose{-60.0, -45.0, 0.4, options.plate_height_mm, 1.0};
    s.truth.plates.push_back(pose);
    const Eigen::Matrix3Xd board = BoardPoints(BoardSpec{});
    PlateMarks plate;
    plate.mark_uv_mm = board.topRows<2>();
    plate.height_mm = std::nullopt;
    s.input.plates.push_back(plate);
    const double c = std::cos(pose.theta_rad), sn = std::sin(pose.theta_rad);
    for (int m = 0; m < board.cols(); ++m) {
      const double u = board(0, m), v = board(1, m);
      const Eigen::Vector3d p(pose.x_mm + pose.scale * (c * u + sn * v),
                              pose.y_mm + pose.scale * (sn * u - c * v), pose.height_mm);
      for (int i = 0; i < num_tiles; ++i) {
        const Eigen::Vector2d q = ProjectPartPoint(s.camera, s.truth, p, s.truth.table_pos_mm[i]);
        if (!Inside(s.camera, q) || i == options.empty_tile) continue;
        s.input.plate_observations.push_back(
            {i, 0, m, q + options.observation_sigma_px * Eigen::Vector2d(normal(noise_rng), normal(noise_rng)),
             1.0});
      }
    }
  }
  return s;
}

double ScaleErrorPpm(const std::vector<Eigen::Vector2d>& adjusted,
                     const std::vector<Eigen::Vector2d>& actual) {
  const int n = static_cast<int>(actual.size());
  Eigen::Vector2d mean_a = Eigen::Vector2d::Zero(), mean_t = Eigen::Vector2d::Zero();
  for (int i = 0; i < n; ++i) mean_a += adjusted[i] / n, mean_t += actual[i] / n;
  // Similarity adjusted ~ s Rot actual + d: s = |sum conj(t) a| / sum |t|^2 in complex form.
  double dot = 0, cross = 0, norm = 0;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d a = adjusted[i] - mean_a, t = actual[i] - mean_t;
    dot += t.dot(a);
    cross += t.x() * a.y() - t.y() * a.x();
    norm += t.squaredNorm();
  }
  return (std::hypot(dot, cross) / norm - 1) * 1e6;
}

}  // namespace omm
