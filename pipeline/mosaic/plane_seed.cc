#include "pipeline/mosaic/plane_seed.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <optional>
#include <vector>

#include <Eigen/Dense>

#include "adapters/mrcal/lens.h"
#include "pipeline/core/statistics.h"

namespace omm {
namespace {

constexpr int kMinPairs = 20;

double Deg(double rad) { return rad * 180.0 / std::numbers::pi; }

struct Pair {
  Eigen::Vector3d m_i, m_j;
  Eigen::Vector2d delta_table_mm;  // T_j - T_i, commanded
};

// The two independent rows of [m_j]x (m_j's z is 1) applied to
// m_i + K a: coefficients of vec(K) (column-major) and the right-hand side,
// so that rows * vec(K) = rhs. kTerms 6: the table moved in two directions,
// a = dT (x) m_i and K = [B_1 l^T, B_2 l^T]; 3: along one line u only,
// a = (u . dT) m_i and K = (B u) l^T (`along` is u, read for 3 only).
template <int kTerms>
void PairEquations(const Pair& p, const Eigen::Vector2d& along,
                   Eigen::Matrix<double, 2, 3 * kTerms>* rows, Eigen::Vector2d* rhs) {
  Eigen::Matrix<double, 2, 3> cross;
  cross << 0.0, -1.0, p.m_j.y(), 1.0, 0.0, -p.m_j.x();
  Eigen::Matrix<double, kTerms, 1> a;
  if constexpr (kTerms == 6) {
    a << p.delta_table_mm.x() * p.m_i, p.delta_table_mm.y() * p.m_i;
  } else {
    a = along.dot(p.delta_table_mm) * p.m_i;
  }
  for (int c = 0; c < kTerms; ++c) {
    for (int row = 0; row < 3; ++row) rows->col(3 * c + row) = a[c] * cross.col(row);
  }
  *rhs = -cross * p.m_i;
}

// Least squares for vec(K) over the pairs with keep[n]. Only the normal
// matrix's lower triangle is summed (all that ldlt(), Lower by default,
// reads), element by element: as an 18 x 2 by 2 x 18 product each pair went
// through Eigen's blocked GEMM, half of the seed's time, for the same
// two-term sums.
template <int kTerms>
Eigen::Matrix<double, 3 * kTerms, 1> SolveK(const std::vector<Pair>& pairs,
                                            const std::vector<bool>& keep,
                                            const Eigen::Vector2d& along) {
  constexpr int kN = 3 * kTerms;
  Eigen::Matrix<double, kN, kN> normal = Eigen::Matrix<double, kN, kN>::Zero();
  Eigen::Matrix<double, kN, 1> rhs_sum = Eigen::Matrix<double, kN, 1>::Zero();
  for (size_t n = 0; n < pairs.size(); ++n) {
    if (!keep[n]) continue;
    Eigen::Matrix<double, 2, kN> rows;
    Eigen::Vector2d rhs;
    PairEquations<kTerms>(pairs[n], along, &rows, &rhs);
    for (int j = 0; j < kN; ++j) {
      for (int i = j; i < kN; ++i)
        normal(i, j) += rows(0, i) * rows(0, j) + rows(1, i) * rows(1, j);
    }
    rhs_sum += rows.transpose() * rhs;
  }
  return normal.ldlt().solve(rhs_sum);
}

// K by least squares, once more without the gross outliers (pairs with an
// algebraic residual above 5x the median).
template <int kTerms>
Eigen::Matrix<double, 3 * kTerms, 1> SolveKRobust(const std::vector<Pair>& pairs,
                                                  const Eigen::Vector2d& along) {
  std::vector<bool> keep(pairs.size(), true);
  Eigen::Matrix<double, 3 * kTerms, 1> vec_k = SolveK<kTerms>(pairs, keep, along);
  std::vector<double> errors(pairs.size());
  for (size_t n = 0; n < pairs.size(); ++n) {
    Eigen::Matrix<double, 2, 3 * kTerms> rows;
    Eigen::Vector2d rhs;
    PairEquations<kTerms>(pairs[n], along, &rows, &rhs);
    errors[n] = (rows * vec_k - rhs).norm();
  }
  const double threshold = 5.0 * Median(errors);
  for (size_t n = 0; n < pairs.size(); ++n) keep[n] = errors[n] <= threshold;
  return SolveK<kTerms>(pairs, keep, along);
}

// The unit direction of the line the commanded table motion lies on, when
// it moved along one line only (a strip of tiles: the spread across it under
// 1 % of the spread along it), else nullopt.
std::optional<Eigen::Vector2d> SingleMotionDirection(const std::vector<Pair>& pairs) {
  Eigen::Matrix2d scatter = Eigen::Matrix2d::Zero();
  for (const Pair& p : pairs) scatter += p.delta_table_mm * p.delta_table_mm.transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eigen(scatter);
  if (eigen.eigenvalues()(0) > 1e-4 * eigen.eigenvalues()(1)) return std::nullopt;
  return eigen.eigenvectors().col(1);
}

// The plane's rotation R and l = n / delta from K, with the table moving
// along the one line u (a strip): K = b l^T, b = B u the line's direction in
// the camera frame. The motion cannot tell the part frame's handedness, so
// the normal is taken as Z up, towards the camera (plane_scene.h's part
// frame): n = -l / |l|; then r1 = u_x b - u_y (n x b), r2 = u_y b + u_x
// (n x b). Returns b's angle out of the plane, deg (~0 for consistent
// data); nullopt if the motion is not that of a plane seen from above.
std::optional<double> RotationFromStrip(const std::vector<Pair>& pairs, const Eigen::Vector2d& u,
                                        Eigen::Matrix3d* cam_from_part, Eigen::Vector3d* l) {
  // Each pair oriented to move by s = u . dT > 0. Where every pair moved by
  // the same s, m_j ~ (I + s K) m_i fixes I + s K only up to scale: K is
  // known up to K -> (K - mu I) / (1 + s mu), any mu. The true K = b l^T
  // has the trace b . l = 0 (the motion lies in the plane), so mu is the
  // solution's trace / 3 (~0 where the steps differ). (Not its eigenvalues:
  // b l^T with b . l = 0 is nilpotent, and a nilpotent matrix's eigenvalues
  // move by the square root of a perturbation.) s is the pairs' mean step
  // weighted as the least squares weigh them, by s^2.
  std::vector<Pair> oriented = pairs;
  double sum_s2 = 0.0, sum_s3 = 0.0;
  for (Pair& p : oriented) {
    if (u.dot(p.delta_table_mm) < 0.0) p = {p.m_j, p.m_i, -p.delta_table_mm};
    const double step = u.dot(p.delta_table_mm);
    sum_s2 += step * step;
    sum_s3 += step * step * step;
  }
  const double mean_step = sum_s3 / sum_s2;
  const Eigen::Matrix<double, 9, 1> vec_k = SolveKRobust<3>(oriented, u);
  const Eigen::Map<const Eigen::Matrix3d> k_ls(vec_k.data());
  const double mu = k_ls.trace() / 3.0;
  const Eigen::Matrix3d k_mat = (k_ls - mu * Eigen::Matrix3d::Identity()) / (1.0 + mean_step * mu);
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(k_mat, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Vector3d b = svd.matrixU().col(0);
  *l = svd.singularValues()[0] * svd.matrixV().col(0);
  if (l->z() < 0.0) {
    b = -b;
    *l = -*l;
  }
  const Eigen::Vector3d normal = -l->normalized();
  const double out_of_plane = std::abs(b.dot(normal));
  if (out_of_plane > 0.5 || std::abs(normal.z()) < 0.5) return std::nullopt;
  b = (b - b.dot(normal) * normal).normalized();
  const Eigen::Vector3d b_perp = normal.cross(b);
  *cam_from_part << u.x() * b - u.y() * b_perp, u.y() * b + u.x() * b_perp, normal;
  return Deg(std::asin(out_of_plane));
}

// The same with the table moving in two directions: K = [B_1 l^T, B_2 l^T]
// rearranged is vec(B) l^T, rank 1; its best rank-1 approximation gives B
// (scale |B_1| = |B_2| = 1) and l (sign: l_3 > 0, the points in front); R is
// the rotation nearest [B, B_1 x B_2]. Returns the angle between l and n,
// deg.
std::optional<double> RotationFromGrid(const std::vector<Pair>& pairs,
                                       Eigen::Matrix3d* cam_from_part, Eigen::Vector3d* l) {
  const Eigen::Matrix<double, 18, 1> vec_k = SolveKRobust<6>(pairs, Eigen::Vector2d::Zero());
  Eigen::Matrix<double, 6, 3> rearranged;
  for (int a = 0; a < 2; ++a) {
    for (int b = 0; b < 3; ++b) {
      for (int row = 0; row < 3; ++row) rearranged(3 * a + row, b) = vec_k[3 * (3 * a + b) + row];
    }
  }
  const Eigen::JacobiSVD<Eigen::Matrix<double, 6, 3>> svd(
      rearranged, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix<double, 6, 1> vec_b = std::sqrt(2.0) * svd.matrixU().col(0);
  *l = svd.singularValues()[0] / std::sqrt(2.0) * svd.matrixV().col(0);
  if (l->z() < 0.0) {
    vec_b = -vec_b;
    *l = -*l;
  }
  Eigen::Matrix<double, 3, 2> b_mat;
  b_mat << vec_b.head<3>(), vec_b.tail<3>();
  const Eigen::JacobiSVD<Eigen::MatrixXd> polar(Eigen::MatrixXd(b_mat),
                                                 Eigen::ComputeThinU | Eigen::ComputeThinV);
  const Eigen::Matrix<double, 3, 2> r12 = polar.matrixU() * polar.matrixV().transpose();
  *cam_from_part << r12, r12.col(0).cross(r12.col(1));
  const Eigen::Vector3d normal = cam_from_part->col(2);
  const double n_dot_l = normal.dot(*l);
  if (!(std::abs(n_dot_l) > 0.5 * l->norm()) || std::abs(normal.z()) < 0.5) return std::nullopt;
  return Deg(std::acos(std::min(1.0, std::abs(n_dot_l) / l->norm())));
}

// Pixel residual RMS of the scene over all used observations.
double SceneRms(const CameraModel& camera, const PlaneBundleInput& input, const PlaneScene& scene) {
  const Eigen::Matrix3d rot = RotationFromAngleAxis(scene.cam_from_part_r);
  Eigen::Matrix3Xd p_cam(3, input.observations.size());
  for (size_t n = 0; n < input.observations.size(); ++n) {
    const TrackObservation& obs = input.observations[n];
    const Eigen::Vector2d x = scene.track_xy_mm.col(obs.track) + scene.table_pos_mm[obs.tile];
    p_cam.col(static_cast<Eigen::Index>(n)) =
        rot * Eigen::Vector3d(x.x(), x.y(), 0.0) + scene.cam_from_part_t_mm;
  }
  Eigen::Matrix2Xd q;
  if (!ProjectPoints(camera, p_cam, &q)) return std::numeric_limits<double>::infinity();
  double sum_sq = 0.0;
  int count = 0;
  for (size_t n = 0; n < input.observations.size(); ++n) {
    if (input.observations[n].weight <= 0.0) continue;
    sum_sq += (q.col(static_cast<Eigen::Index>(n)) - input.observations[n].q_px).squaredNorm();
    ++count;
  }
  return count > 0 ? std::sqrt(sum_sq / count) : 0.0;
}

// Pairs of observations of one track in two tiles: their rays (columns of
// `rays`, in the observations' order) and the commanded table move between
// the tiles.
std::vector<Pair> TrackPairs(const PlaneBundleInput& input, const Eigen::Matrix3Xd& rays) {
  std::vector<std::vector<int>> obs_of_track(input.num_tracks);
  for (size_t n = 0; n < input.observations.size(); ++n) {
    if (input.observations[n].weight > 0.0)
      obs_of_track[input.observations[n].track].push_back(static_cast<int>(n));
  }
  std::vector<Pair> pairs;
  for (const std::vector<int>& obs : obs_of_track) {
    for (size_t a = 0; a < obs.size(); ++a) {
      for (size_t b = a + 1; b < obs.size(); ++b) {
        const int i = input.observations[obs[a]].tile, j = input.observations[obs[b]].tile;
        if (i == j) continue;
        pairs.push_back({rays.col(obs[a]), rays.col(obs[b]),
                         input.commanded_table_pos_mm[j] - input.commanded_table_pos_mm[i]});
      }
    }
  }
  return pairs;
}

// The rotation and translation taking the points `from` onto `to` in the
// least-squares sense (2-D: the rotation's angle from the centred points'
// summed cross and dot products). Two points or more.
struct RigidMotion2d {
  double angle_rad = 0.0;
  Eigen::Vector2d translation = Eigen::Vector2d::Zero();
};

RigidMotion2d RigidFit2d(const std::vector<Eigen::Vector2d>& from,
                         const std::vector<Eigen::Vector2d>& to) {
  Eigen::Vector2d mean_from = Eigen::Vector2d::Zero(), mean_to = Eigen::Vector2d::Zero();
  for (size_t k = 0; k < to.size(); ++k) {
    mean_from += from[k] / to.size();
    mean_to += to[k] / to.size();
  }
  double sin_sum = 0.0, cos_sum = 0.0;
  for (size_t k = 0; k < to.size(); ++k) {
    const Eigen::Vector2d w = from[k] - mean_from, p = to[k] - mean_to;
    cos_sum += w.dot(p);
    sin_sum += w.x() * p.y() - w.y() * p.x();
  }
  RigidMotion2d fit;
  fit.angle_rad = std::atan2(sin_sum, cos_sum);
  fit.translation = mean_to - Eigen::Rotation2Dd(fit.angle_rad) * mean_from;
  return fit;
}

}  // namespace

PlaneSeedSummary SeedPlaneScene(const CameraModel& camera, const PlaneBundleInput& input,
                                PlaneScene* scene) {
  PlaneSeedSummary summary;

  // Normalised rays of every observation (tracks, then plate marks).
  const size_t num_track_obs = input.observations.size();
  Eigen::Matrix2Xd q_px(2, num_track_obs + input.plate_observations.size());
  for (size_t n = 0; n < num_track_obs; ++n) q_px.col(n) = input.observations[n].q_px;
  for (size_t n = 0; n < input.plate_observations.size(); ++n) {
    q_px.col(num_track_obs + n) = input.plate_observations[n].q_px;
  }
  Eigen::Matrix3Xd rays;
  if (!UnprojectPixels(camera, q_px, &rays)) {
    summary.why_failed = "the lens model cannot unproject the observations";
    return summary;
  }

  std::vector<Pair> pairs = TrackPairs(input, rays);
  // A tile taken twice at one place: its pairs say nothing of K, and their
  // tiny residuals would lower the outlier threshold.
  const size_t num_all_pairs = pairs.size();
  std::erase_if(pairs, [](const Pair& p) { return p.delta_table_mm.norm() == 0.0; });
  summary.num_pairs = static_cast<int>(pairs.size());
  if (summary.num_pairs == 0 && num_all_pairs > 0) {
    summary.why_failed = "the tiles that overlap were all taken at one table position";
    return summary;
  }
  if (summary.num_pairs < kMinPairs) {
    summary.why_failed = "fewer than " + std::to_string(kMinPairs) + " track pairs";
    return summary;
  }

  Eigen::Matrix3d cam_from_part;
  Eigen::Vector3d l;
  const std::optional<Eigen::Vector2d> strip = SingleMotionDirection(pairs);
  const std::optional<double> disagreement =
      strip ? RotationFromStrip(pairs, *strip, &cam_from_part, &l)
            : RotationFromGrid(pairs, &cam_from_part, &l);
  if (!disagreement) {
    summary.why_failed = "the tile-to-tile motion is not that of a plane seen from above";
    return summary;
  }
  const Eigen::Vector3d normal = cam_from_part.col(2);
  const double n_dot_l = normal.dot(l);
  const double delta = 1.0 / n_dot_l;
  summary.distance_mm = std::abs(delta);
  summary.normal_disagreement_deg = *disagreement;

  const Eigen::AngleAxisd angle_axis(cam_from_part);
  scene->cam_from_part_r = angle_axis.angle() * angle_axis.axis();
  scene->cam_from_part_t_mm = Eigen::Vector3d(0.0, 0.0, delta / normal.z());
  scene->table_pos_mm = input.commanded_table_pos_mm;
  scene->intrinsics = camera.intrinsics;
  summary.tilt_deg = PlaneTiltDeg(scene->cam_from_part_r);

  // A ray's point at height h above the top surface, in the part frame at the
  // tile's commanded table position: P = (R^T (X - t))_xy - T_i.
  auto part_point = [&](size_t ray, int tile, double height_mm) -> Eigen::Vector2d {
    const Eigen::Vector3d m = rays.col(static_cast<Eigen::Index>(ray));
    const Eigen::Vector3d x_cam = m * (delta + height_mm) / normal.dot(m);
    return (cam_from_part.transpose() * (x_cam - scene->cam_from_part_t_mm)).head<2>() -
           input.commanded_table_pos_mm[tile];
  };
  scene->track_xy_mm.setZero(2, input.num_tracks);
  std::vector<int> count(input.num_tracks, 0);
  for (size_t n = 0; n < num_track_obs; ++n) {
    const TrackObservation& obs = input.observations[n];
    if (obs.weight <= 0.0) continue;
    scene->track_xy_mm.col(obs.track) += part_point(n, obs.tile, 0.0);
    ++count[obs.track];
  }
  for (int k = 0; k < input.num_tracks; ++k) {
    if (count[k] > 0) scene->track_xy_mm.col(k) /= count[k];
  }

  // Plates: mean intersection per mark, then P = o + Rot(theta) (u, -v).
  scene->plates.assign(input.plates.size(), PlatePose{});
  for (size_t g = 0; g < input.plates.size(); ++g) {
    const double height = input.plates[g].height_mm.value_or(0.0);
    const Eigen::Index num_marks = input.plates[g].mark_uv_mm.cols();
    Eigen::Matrix2Xd sum = Eigen::Matrix2Xd::Zero(2, num_marks);
    std::vector<int> seen(num_marks, 0);
    for (size_t n = 0; n < input.plate_observations.size(); ++n) {
      const PlateMarkObservation& obs = input.plate_observations[n];
      if (obs.plate != static_cast<int>(g) || obs.weight <= 0.0) continue;
      sum.col(obs.mark) += part_point(num_track_obs + n, obs.tile, height);
      ++seen[obs.mark];
    }
    std::vector<Eigen::Vector2d> mirrored, part;
    for (Eigen::Index k = 0; k < num_marks; ++k) {
      if (seen[k] == 0) continue;
      const Eigen::Vector2d uv = input.plates[g].mark_uv_mm.col(k);
      mirrored.emplace_back(uv.x(), -uv.y());
      part.push_back(sum.col(k) / seen[k]);
    }
    PlatePose& pose = scene->plates[g];
    pose.height_mm = height;
    if (part.size() < 2) continue;  // unobserved: the plate's blocks stay out of the solve
    const RigidMotion2d part_from_mirrored = RigidFit2d(mirrored, part);
    pose.theta_rad = part_from_mirrored.angle_rad;
    pose.x_mm = part_from_mirrored.translation.x();
    pose.y_mm = part_from_mirrored.translation.y();
  }

  summary.rms_px = SceneRms(camera, input, *scene);
  summary.ok = true;
  return summary;
}

}  // namespace omm
