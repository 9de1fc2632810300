#include "pipeline/core/plane_scene.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

namespace omm {

Eigen::Matrix3d RotationFromAngleAxis(const Eigen::Vector3d& r) {
  const double angle = r.norm();
  // First order where r / angle loses its digits (exact to rounding there).
  if (angle < 1e-12) {
    Eigen::Matrix3d m = Eigen::Matrix3d::Identity();
    m(0, 1) = -r.z(), m(0, 2) = r.y(), m(1, 0) = r.z(), m(1, 2) = -r.x(), m(2, 0) = -r.y(),
    m(2, 1) = r.x();
    return m;
  }
  return Eigen::AngleAxisd(angle, r / angle).toRotationMatrix();
}

std::string PlaneBundleConfig::Check() const {
  if (gauge == PlaneGauge::kFixedTrack && gauge_track < 0) {
    return "gauge kFixedTrack needs gauge_track >= 0";
  }
  if (gauge == PlaneGauge::kFixedTrack && !refine_plane_pose) {
    return "gauge kFixedTrack with the plane pose held: the origin is then fixed twice";
  }
  return "";
}

std::string PlaneBundleOptions::Check() const {
  if (!(loss_scale_px > 0.0)) return "loss_scale_px must be > 0";
  if (max_iterations < 1) return "max_iterations must be >= 1";
  if (!(initial_trust_region_radius > 0.0)) return "initial_trust_region_radius must be > 0";
  if (!(function_tolerance >= 0.0) || !(gradient_tolerance >= 0.0) ||
      !(parameter_tolerance >= 0.0)) {
    return "tolerances must be >= 0";
  }
  if (num_threads < 1) return "num_threads must be >= 1";
  if (!(max_usable_rms_px > 0.0)) return "max_usable_rms_px must be > 0";
  if (!(intrinsics_block_margin_px >= 0.0)) return "intrinsics_block_margin_px must be >= 0";
  return "";
}

std::vector<int> FreeIntrinsics(int num_intrinsics, const std::vector<int>& held) {
  std::vector<int> free;
  for (int k = 0; k < num_intrinsics; ++k) {
    if (!std::binary_search(held.begin(), held.end(), k)) free.push_back(k);
  }
  return free;
}

std::string CheckPlaneBundleInput(const PlaneBundleInput& input,
                                  const PlaneBundleConfig& config, int num_intrinsics) {
  const int num_tiles = static_cast<int>(input.commanded_table_pos_mm.size());
  if (num_tiles < 2) return "need at least 2 tiles";
  if (!(input.table_sigma_mm > 0.0)) return "table_sigma_mm must be > 0";
  if (!(input.observation_sigma_px > 0.0)) return "observation_sigma_px must be > 0";
  if (input.num_tracks < 0) return "num_tracks must be >= 0";
  const std::vector<int>& unprior = input.tiles_without_table_prior;
  for (size_t k = 0; k < unprior.size(); ++k) {
    if (unprior[k] < 0 || unprior[k] >= num_tiles || (k > 0 && unprior[k] <= unprior[k - 1]))
      return "tiles_without_table_prior must be ascending tile indices";
  }
  if (static_cast<int>(unprior.size()) > num_tiles - 2)
    return "at least 2 tiles need their table prior (the scale and the axes' rotation)";
  std::vector<int> seen(input.num_tracks, 0);
  for (const TrackObservation& obs : input.observations) {
    if (obs.tile < 0 || obs.tile >= num_tiles) return "an observation's tile is out of range";
    if (obs.track < 0 || obs.track >= input.num_tracks) {
      return "an observation's track is out of range";
    }
    if (!(obs.weight >= 0.0) || !obs.q_px.allFinite() || !obs.shape.allFinite()) {
      return "an observation has a negative weight or a non-finite pixel or shape";
    }
    if (obs.weight > 0.0) ++seen[obs.track];
  }
  for (int k = 0; k < input.num_tracks; ++k) {
    if (seen[k] == 0) return "track " + std::to_string(k) + " has no observation";
  }
  for (const PlateMarkObservation& obs : input.plate_observations) {
    if (obs.tile < 0 || obs.tile >= num_tiles) return "a plate observation's tile is out of range";
    if (obs.plate < 0 || obs.plate >= static_cast<int>(input.plates.size())) {
      return "a plate observation's plate is out of range";
    }
    if (obs.mark < 0 || obs.mark >= input.plates[obs.plate].mark_uv_mm.cols()) {
      return "a plate observation's mark is out of range";
    }
    if (!(obs.weight >= 0.0) || !obs.q_px.allFinite()) {
      return "a plate observation has a negative weight or a non-finite pixel";
    }
  }
  if (config.gauge == PlaneGauge::kFixedTrack && config.gauge_track >= input.num_tracks) {
    return "gauge_track is out of range";
  }
  for (int k : config.covariance_tracks) {
    if (k < 0 || k >= input.num_tracks) return "a covariance_tracks entry is out of range";
  }
  if (config.refine_intrinsics) {
    const Eigen::MatrixXd& info = input.intrinsics_information;
    if (info.rows() != num_intrinsics || info.cols() != num_intrinsics) {
      return "refine_intrinsics needs an intrinsics_information of " +
             std::to_string(num_intrinsics) + " x " + std::to_string(num_intrinsics);
    }
    const std::vector<int>& held = input.intrinsics_held;
    for (size_t i = 0; i < held.size(); ++i) {
      if (held[i] < 0 || held[i] >= num_intrinsics || (i > 0 && held[i] <= held[i - 1]))
        return "intrinsics_held must be ascending indices of intrinsics";
      if (!info.row(held[i]).isZero() || !info.col(held[i]).isZero())
        return "intrinsics_information must be 0 in the rows and columns of held intrinsics";
    }
    const std::vector<int> free = FreeIntrinsics(num_intrinsics, held);
    if (free.empty()) return "refine_intrinsics with every intrinsic held";
    if (Eigen::LLT<Eigen::MatrixXd>(info(free, free)).info() != Eigen::Success) {
      return "intrinsics_information is not positive definite over the free intrinsics";
    }
    if (input.intrinsics_prior_mean.size() != 0 &&
        input.intrinsics_prior_mean.size() != num_intrinsics) {
      return "intrinsics_prior_mean must be empty or have " + std::to_string(num_intrinsics) +
             " entries";
    }
  }
  return "";
}

double PlaneTiltDeg(const Eigen::Vector3d& cam_from_part_r) {
  const double angle = cam_from_part_r.norm();
  const Eigen::Matrix3d cam_from_part =
      angle > 0.0 ? Eigen::AngleAxisd(angle, cam_from_part_r / angle).toRotationMatrix()
                  : Eigen::Matrix3d::Identity();
  // The part's -Z in the camera frame against the camera's z axis.
  const double cos_tilt = std::clamp(-cam_from_part(2, 2), -1.0, 1.0);
  return std::acos(cos_tilt) * 180.0 / std::numbers::pi;
}

TrackObservation WhitenedObservation(int tile, int track, const Eigen::Vector2d& q_px,
                                     const Eigen::Matrix2d& covariance_px2,
                                     double observation_sigma_px) {
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eigen(covariance_px2);
  const Eigen::Vector2d sigma_px = eigen.eigenvalues().cwiseSqrt();  // ascending
  TrackObservation observation;
  observation.tile = tile;
  observation.track = track;
  observation.q_px = q_px;
  observation.weight = observation_sigma_px / sigma_px(0);
  observation.shape = eigen.eigenvectors() *
                      Eigen::Vector2d(1.0, sigma_px(0) / sigma_px(1)).asDiagonal() *
                      eigen.eigenvectors().transpose();
  return observation;
}

}  // namespace omm
