#include "adapters/ceres/plane_bundle.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <ceres/ceres.h>

#include <Eigen/QR>

#include "adapters/ceres/plane_costs.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/core/timing.h"

namespace omm {
namespace {

using Clock = std::chrono::steady_clock;

// The Ceres parameter blocks: copies of the scene's values in the layout the
// cost functions expect (track points alias scene->track_xy_mm's columns).
struct Blocks {
  std::array<double, 3> r{};
  std::array<double, 3> t{};
  std::vector<std::array<double, 2>> table_pos;
  std::vector<std::array<double, 3>> plate_pose;  // x, y, theta
  std::vector<double> plate_height;
  std::vector<double> plate_scale;
  Eigen::VectorXd intrinsics;
  double* point(PlaneScene* scene, int track) const { return scene->track_xy_mm.col(track).data(); }
};

Blocks BlocksFromScene(const PlaneScene& scene) {
  Blocks b;
  for (int k = 0; k < 3; ++k) {
    b.r[k] = scene.cam_from_part_r[k];
    b.t[k] = scene.cam_from_part_t_mm[k];
  }
  for (const Eigen::Vector2d& pos : scene.table_pos_mm) b.table_pos.push_back({pos.x(), pos.y()});
  for (const PlatePose& plate : scene.plates) {
    b.plate_pose.push_back({plate.x_mm, plate.y_mm, plate.theta_rad});
    b.plate_height.push_back(plate.height_mm);
    b.plate_scale.push_back(plate.scale);
  }
  b.intrinsics = scene.intrinsics;
  return b;
}

void BlocksToScene(const Blocks& b, PlaneScene* scene) {
  scene->cam_from_part_r = Eigen::Vector3d(b.r.data());
  scene->cam_from_part_t_mm = Eigen::Vector3d(b.t.data());
  for (size_t i = 0; i < b.table_pos.size(); ++i) {
    scene->table_pos_mm[i] = Eigen::Vector2d(b.table_pos[i][0], b.table_pos[i][1]);
  }
  for (size_t g = 0; g < b.plate_pose.size(); ++g) {
    scene->plates[g] = {b.plate_pose[g][0], b.plate_pose[g][1], b.plate_pose[g][2],
                        b.plate_height[g], b.plate_scale[g]};
  }
  scene->intrinsics = b.intrinsics;
}

// Model minus observed pixel of every observation (weight-0 ones too), px;
// NaN where the lens cannot project.
void ComputeResiduals(const LensProjection& lens, const PlaneBundleInput& input, Blocks* b,
                      PlaneScene* scene) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  scene->residual_px.resize(2, static_cast<Eigen::Index>(input.observations.size()));
  for (size_t n = 0; n < input.observations.size(); ++n) {
    const TrackObservation& obs = input.observations[n];
    const TrackReprojectionCost cost(lens, obs.q_px, 1.0);
    const double* params[] = {b->r.data(), b->t.data(), b->table_pos[obs.tile].data(),
                              b->point(scene, obs.track), b->intrinsics.data()};
    Eigen::Vector2d res;
    if (!cost.Evaluate(params, res.data(), nullptr)) res.setConstant(nan);
    scene->residual_px.col(static_cast<Eigen::Index>(n)) = res;
  }
  scene->plate_residual_px.resize(2,
                                  static_cast<Eigen::Index>(input.plate_observations.size()));
  for (size_t n = 0; n < input.plate_observations.size(); ++n) {
    const PlateMarkObservation& obs = input.plate_observations[n];
    const PlateMarkReprojectionCost cost(lens, input.plates[obs.plate].mark_uv_mm.col(obs.mark),
                                         obs.q_px, 1.0);
    const double* params[] = {b->r.data(),
                              b->t.data(),
                              b->table_pos[obs.tile].data(),
                              b->plate_pose[obs.plate].data(),
                              &b->plate_height[obs.plate],
                              &b->plate_scale[obs.plate],
                              b->intrinsics.data()};
    Eigen::Vector2d res;
    if (!cost.Evaluate(params, res.data(), nullptr)) res.setConstant(nan);
    scene->plate_residual_px.col(static_cast<Eigen::Index>(n)) = res;
  }
}

struct ResidualStats {
  double rms_px = 0.0;  // over the used observations
  double chi2 = 0.0;    // their weighted sum of squares, in sigmas
  int num_outliers = 0;  // |residual| > outlier_px
  double inlier_rms_px = 0.0;
};

ResidualStats Stats(const PlaneBundleInput& input, const PlaneScene& scene, double outlier_px) {
  ResidualStats stats;
  double sum_sq = 0.0, inlier_sum_sq = 0.0;
  int count = 0;
  const double inv_sigma = 1.0 / input.observation_sigma_px;
  auto add = [&](double weight, const Eigen::Matrix2d& shape, const Eigen::Vector2d& res) {
    if (weight <= 0.0) return;
    sum_sq += res.squaredNorm();
    stats.chi2 += (weight * inv_sigma * shape * res).squaredNorm();
    ++count;
    if (res.norm() > outlier_px) {
      ++stats.num_outliers;
    } else {
      inlier_sum_sq += res.squaredNorm();
    }
  };
  for (size_t n = 0; n < input.observations.size(); ++n) {
    add(input.observations[n].weight, input.observations[n].shape,
        scene.residual_px.col(static_cast<Eigen::Index>(n)));
  }
  for (size_t n = 0; n < input.plate_observations.size(); ++n) {
    add(input.plate_observations[n].weight, Eigen::Matrix2d::Identity(),
        scene.plate_residual_px.col(static_cast<Eigen::Index>(n)));
  }
  const int inliers = count - stats.num_outliers;
  stats.rms_px = count > 0 ? std::sqrt(sum_sq / count) : 0.0;
  stats.inlier_rms_px = inliers > 0 ? std::sqrt(inlier_sum_sq / inliers) : 0.0;
  return stats;
}

ceres::LossFunction* MakeLoss(const PlaneBundleOptions& options, double sigma_px) {
  // The residual is in sigmas; the loss scale is given in px.
  const double scale = options.loss_scale_px / sigma_px;
  switch (options.loss) {
    case RobustLoss::kTrivial: return nullptr;
    case RobustLoss::kHuber: return new ceres::HuberLoss(scale);
    case RobustLoss::kCauchy: return new ceres::CauchyLoss(scale);
  }
  return nullptr;
}

// The problem's Jacobian over its variable blocks (loss applied, manifolds'
// tangent spaces): the tracks' points first, 2 columns each, then the
// scene's tangent columns.
struct SchurJacobian {
  ceres::CRSMatrix jacobian;
  std::vector<int> point_of_track;  // its point's index, -1 if not variable
  int num_points = 0;
  std::vector<int> tangent_offset;  // per scene block, in the scene columns; -1 if constant
  int num_scene_columns = 0;
  int PointColumns() const { return 2 * num_points; }
};

std::optional<SchurJacobian> EvaluateSchurJacobian(
    ceres::Problem* problem, const std::vector<std::pair<double*, int>>& scene_blocks,
    const Blocks& b, PlaneScene* scene, int num_threads) {
  SchurJacobian j;
  ceres::Problem::EvaluateOptions evaluate;
  // The Jacobian alone: each block has its own place in it, so its bits do
  // not depend on the threads (a cost or gradient, summed per thread, would).
  evaluate.num_threads = num_threads;
  j.point_of_track.assign(scene->track_xy_mm.cols(), -1);
  for (Eigen::Index k = 0; k < scene->track_xy_mm.cols(); ++k) {
    double* point = b.point(scene, static_cast<int>(k));
    if (!problem->HasParameterBlock(point) || problem->IsParameterBlockConstant(point)) continue;
    j.point_of_track[k] = static_cast<int>(evaluate.parameter_blocks.size());
    evaluate.parameter_blocks.push_back(point);
  }
  j.num_points = static_cast<int>(evaluate.parameter_blocks.size());
  for (const auto& [block, offset] : scene_blocks) {
    if (problem->IsParameterBlockConstant(block)) {
      j.tangent_offset.push_back(-1);
      continue;
    }
    j.tangent_offset.push_back(j.num_scene_columns);
    j.num_scene_columns += problem->ParameterBlockTangentSize(block);
    evaluate.parameter_blocks.push_back(block);
  }
  if (!problem->Evaluate(evaluate, nullptr, nullptr, nullptr, &j.jacobian)) return std::nullopt;
  return j;
}

// The Jacobian's rows by point: a point is seen by a few tiles and, through
// a splined lens, depends on the knots near its pixels.
struct RowsByPoint {
  std::vector<std::vector<int>> rows;     // per point
  std::vector<std::vector<int>> columns;  // per point: the scene columns its rows touch, ascending
  std::vector<int> other_rows;            // rows of priors, which no point enters
};

RowsByPoint SortRowsByPoint(const SchurJacobian& j) {
  const ceres::CRSMatrix& jacobian = j.jacobian;
  const int point_columns = j.PointColumns();
  RowsByPoint by;
  by.rows.resize(j.num_points);
  by.columns.resize(j.num_points);
  for (int row = 0; row < jacobian.num_rows; ++row) {
    int point = -1;
    for (int e = jacobian.rows[row]; e < jacobian.rows[row + 1] && point < 0; ++e)
      if (jacobian.cols[e] < point_columns) point = jacobian.cols[e] / 2;
    if (point < 0) {
      by.other_rows.push_back(row);
      continue;
    }
    by.rows[point].push_back(row);
    for (int e = jacobian.rows[row]; e < jacobian.rows[row + 1]; ++e) {
      if (jacobian.cols[e] >= point_columns)
        by.columns[point].push_back(jacobian.cols[e] - point_columns);
    }
  }
  for (std::vector<int>& c : by.columns) {
    std::sort(c.begin(), c.end());
    c.erase(std::unique(c.begin(), c.end()), c.end());
  }
  return by;
}

// J^T J = [V W; W^T U] reduced to the scene columns: S = U - W^T V^-1 W,
// with each point's V_k^-1 and W_k (2 x its columns) kept for its own
// covariance.
struct ReducedSystem {
  Eigen::MatrixXd s;
  std::vector<Eigen::Matrix2d> v_inverse;
  std::vector<Eigen::MatrixXd> w;
};

// Each point's share of S, J_k' J_k - W_k' V_k^-1 W_k (J_k its rows' scene
// columns, W_k = P_k' J_k, V_k = P_k' P_k, P_k their point columns), is
// formed densely over its columns, as a product of rank num_rows - 2, and
// added to S once. nullopt where a point's V_k is singular.
std::optional<ReducedSystem> ReduceToScene(const SchurJacobian& j, const RowsByPoint& by,
                                           int num_threads) {
  const ceres::CRSMatrix& jacobian = j.jacobian;
  const int point_columns = j.PointColumns(), m = j.num_scene_columns;
  ReducedSystem reduced;
  reduced.v_inverse.resize(j.num_points);
  reduced.w.resize(j.num_points);
  // S's upper triangle, summed per chunk of points and the chunks then in
  // order: a fixed number of chunks, so that the bits do not depend on the
  // threads.
  constexpr int kNumChunks = 8;
  std::vector<Eigen::MatrixXd> chunk_s(kNumChunks);
  std::atomic<bool> singular{false};
  ParallelFor(kNumChunks, num_threads, [&](int chunk) {
    Eigen::MatrixXd& sum = chunk_s[chunk];
    sum = Eigen::MatrixXd::Zero(m, m);
    const int end = static_cast<int>(static_cast<long>(j.num_points) * (chunk + 1) / kNumChunks);
    for (int k = static_cast<int>(static_cast<long>(j.num_points) * chunk / kNumChunks); k < end;
         ++k) {
      const std::vector<int>& cols = by.columns[k];
      const int num_rows = static_cast<int>(by.rows[k].size());
      Eigen::MatrixXd j_scene =
          Eigen::MatrixXd::Zero(num_rows, static_cast<Eigen::Index>(cols.size()));
      Eigen::Matrix<double, Eigen::Dynamic, 2> j_point =
          Eigen::Matrix<double, Eigen::Dynamic, 2>::Zero(num_rows, 2);
      for (int i = 0; i < num_rows; ++i) {
        const int row = by.rows[k][i];
        for (int e = jacobian.rows[row]; e < jacobian.rows[row + 1]; ++e) {
          const int col = jacobian.cols[e];
          if (col < point_columns) {
            j_point(i, col % 2) = jacobian.values[e];
          } else {
            const auto at = std::lower_bound(cols.begin(), cols.end(), col - point_columns);
            j_scene(i, at - cols.begin()) = jacobian.values[e];
          }
        }
      }
      const Eigen::Matrix2d v = j_point.transpose() * j_point;
      if (!(v.determinant() > 0)) {
        singular = true;
        return;
      }
      reduced.v_inverse[k] = v.inverse();
      reduced.w[k] = j_point.transpose() * j_scene;
      if (num_rows <= 2) continue;  // one view: its point absorbs it, no share of S
      // J_k' J_k - W_k' V_k^-1 W_k = (Z' J_k)' (Z' J_k), Z an orthonormal
      // basis of the rows' space orthogonal to P_k: the last num_rows - 2
      // rows of Q' J_k, P_k = Q R.
      const Eigen::HouseholderQR<Eigen::Matrix<double, Eigen::Dynamic, 2>> qr(j_point);
      const Eigen::MatrixXd projected =
          (qr.householderQ().adjoint() * j_scene).bottomRows(num_rows - 2);
      for (Eigen::Index c2 = 0; c2 < projected.cols(); ++c2) {
        double* column = &sum(0, cols[c2]);  // its upper part: rows up to cols[c2]
        for (Eigen::Index c1 = 0; c1 <= c2; ++c1)
          column[cols[c1]] += projected.col(c1).dot(projected.col(c2));
      }
    }
  });
  if (singular) return std::nullopt;
  Eigen::MatrixXd& s = reduced.s;
  s = Eigen::MatrixXd::Zero(m, m);
  std::vector<std::pair<int, double>> entries;  // of a row: (scene column, value)
  for (const int row : by.other_rows) {
    entries.clear();
    for (int e = jacobian.rows[row]; e < jacobian.rows[row + 1]; ++e)
      entries.emplace_back(jacobian.cols[e] - point_columns, jacobian.values[e]);
    for (size_t e1 = 0; e1 < entries.size(); ++e1) {
      const auto [i, x] = entries[e1];
      for (size_t e2 = e1; e2 < entries.size(); ++e2) {
        const auto [jj, y] = entries[e2];
        s(std::min(i, jj), std::max(i, jj)) += x * y;
      }
    }
  }
  for (const Eigen::MatrixXd& sum : chunk_s) s += sum;
  s.triangularView<Eigen::StrictlyLower>() = s.transpose();
  return reduced;
}

// S^-1, nullopt when S is rank-deficient: its Jacobi-scaled eigenvalues
// spread beyond 1e14.
std::optional<Eigen::MatrixXd> InverseOfFullRank(const Eigen::MatrixXd& s) {
  const Eigen::VectorXd d = s.diagonal();
  if (!(d.minCoeff() > 0)) return std::nullopt;
  const Eigen::VectorXd inv_sqrt_d = d.cwiseSqrt().cwiseInverse();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(
      inv_sqrt_d.asDiagonal() * s * inv_sqrt_d.asDiagonal());
  const Eigen::VectorXd& lambda = eigen.eigenvalues();
  if (!(lambda(0) > 1e-14 * lambda(lambda.size() - 1))) return std::nullopt;
  return inv_sqrt_d.asDiagonal() * eigen.eigenvectors() * lambda.cwiseInverse().asDiagonal() *
         eigen.eigenvectors().transpose() * inv_sqrt_d.asDiagonal();
}

// P, the plus Jacobian from the scene's tangent columns to its blocks'
// ambient values (zero rows for constant blocks): C = P C_tangent P^T.
Eigen::MatrixXd AmbientFromTangent(const ceres::Problem& problem,
                                   const std::vector<std::pair<double*, int>>& scene_blocks,
                                   const SchurJacobian& j) {
  int ambient_size = 0;
  for (const auto& [block, offset] : scene_blocks)
    ambient_size += problem.ParameterBlockSize(block);
  Eigen::MatrixXd lift = Eigen::MatrixXd::Zero(ambient_size, j.num_scene_columns);
  for (size_t n = 0, row = 0; n < scene_blocks.size(); ++n) {
    double* block = scene_blocks[n].first;
    const int ambient = problem.ParameterBlockSize(block);
    if (j.tangent_offset[n] >= 0) {
      const int tangent_size = problem.ParameterBlockTangentSize(block);
      if (const ceres::Manifold* manifold = problem.GetManifold(block)) {
        Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> plus(ambient,
                                                                                   tangent_size);
        manifold->PlusJacobian(block, plus.data());
        lift.block(row, j.tangent_offset[n], ambient, tangent_size) = plus;
      } else {
        lift.block(row, j.tangent_offset[n], ambient, tangent_size).setIdentity();
      }
    }
    row += ambient;
  }
  return lift;
}

// The covariance of the scene blocks (ambient, in their order and sizes;
// zero rows and columns for constant ones) and of the chosen tracks' points,
// as ceres::Covariance gives them, from the Schur complement: the Jacobian
// of the problem (loss applied, manifolds' tangent spaces) gives J^T J =
// [V W; W^T U] with V the tracks' 2 x 2 blocks; the scene's tangent
// covariance is S^-1, S = U - W^T V^-1 W (the solver's reduced system), a
// track's is V_k^-1 + V_k^-1 W_k S^-1 W_k^T V_k^-1. A QR of the whole
// Jacobian (ceres::Covariance, SPARSE_QR) took ~4x as long on the demo. False
// when S is rank-deficient (its Jacobi-scaled condition beyond 1e14).
bool SchurCovariance(ceres::Problem* problem,
                     const std::vector<std::pair<double*, int>>& scene_blocks, const Blocks& b,
                     PlaneScene* scene, const std::vector<int>& tracks, int num_threads,
                     Eigen::MatrixXd* scene_covariance,
                     std::vector<Eigen::Matrix2d>* track_covariance) {
  const std::optional<SchurJacobian> j =
      EvaluateSchurJacobian(problem, scene_blocks, b, scene, num_threads);
  if (!j) return false;
  const RowsByPoint by = SortRowsByPoint(*j);
  const std::optional<ReducedSystem> reduced = ReduceToScene(*j, by, num_threads);
  if (!reduced) return false;
  const std::optional<Eigen::MatrixXd> tangent = InverseOfFullRank(reduced->s);
  if (!tangent) return false;
  const Eigen::MatrixXd lift = AmbientFromTangent(*problem, scene_blocks, *j);
  *scene_covariance = lift * *tangent * lift.transpose();
  track_covariance->clear();
  for (int k : tracks) {
    const int point = j->point_of_track[k];
    if (point < 0) {
      track_covariance->push_back(Eigen::Matrix2d::Zero());
      continue;
    }
    Eigen::Matrix2d c = reduced->v_inverse[point];
    if (reduced->w[point].size() > 0) {
      const Eigen::MatrixXd g = reduced->v_inverse[point] * reduced->w[point];
      c += g * (*tangent)(by.columns[point], by.columns[point]) * g.transpose();
    }
    track_covariance->push_back(c);
  }
  return true;
}

// What every build of a solve's Ceres problem reads.
struct ProblemInputs {
  const LensProjection& lens;
  const PlaneBundleInput& input;
  const PlaneBundleConfig& config;
  const PlaneBundleOptions& options;
  ceres::LossFunction* loss;                     // the robust observations'
  const Eigen::VectorXd& calibrated_intrinsics;  // the intrinsics prior's mean
  // Read for the intrinsics outside an observation's blocks (IntrinsicsBlocks).
  const Eigen::VectorXd& initial_intrinsics;
  bool has_observations;
  std::atomic<int>* num_outside;  // steps that needed intrinsics outside an observation's blocks
};

// A solve's Ceres problem, on the parameter blocks of BlocksFromScene and
// the scene's track points.
struct BuiltProblem {
  std::unique_ptr<ceres::Problem> problem;
  std::vector<int> block_starts;  // the intrinsics' blocks: starts, {0, N} for one block
  // Held intrinsics in blocks held constant: Ceres counts them in
  // num_effective_parameters (a SubsetManifold's held values it does not).
  int held_in_constant_blocks = 0;
};

// The problem with the intrinsics in the lens's blocks (split) or in one.
// Each tile's table prior (none for input.tiles_without_table_prior, whose
// positions the observations alone place); positions held where the config
// does not refine them.
void AddTablePriors(const PlaneBundleInput& input, const PlaneBundleConfig& config, Blocks* b,
                    ceres::Problem* problem) {
  for (size_t i = 0; i < input.commanded_table_pos_mm.size(); ++i) {
    double* table_pos = b->table_pos[i].data();
    if (std::binary_search(input.tiles_without_table_prior.begin(),
                           input.tiles_without_table_prior.end(), static_cast<int>(i))) {
      problem->AddParameterBlock(table_pos, 2);
    } else {
      problem->AddResidualBlock(
          new TablePriorCost(input.commanded_table_pos_mm[i], input.table_sigma_mm), nullptr,
          table_pos);
    }
    if (!config.refine_table_positions) problem->SetParameterBlockConstant(table_pos);
  }
}

// What the config holds of a problem with observations: the plane pose or
// the gauge, the intrinsics (with their prior where refined, and the held
// ones in each block: the number held in constant blocks is returned).
int HoldAsConfigured(const ProblemInputs& in, const std::vector<int>& block_starts, Blocks* b,
                     PlaneScene* scene, ceres::Problem* problem) {
  const PlaneBundleConfig& config = in.config;
  const PlaneBundleInput& input = in.input;
  int held_in_constant_blocks = 0;
  if (!config.refine_plane_pose) {
    problem->SetParameterBlockConstant(b->r.data());
    problem->SetParameterBlockConstant(b->t.data());
  } else if (config.gauge == PlaneGauge::kOriginOnOpticalAxis) {
    problem->SetManifold(b->t.data(), new ceres::SubsetManifold(3, {0, 1}));
  }
  if (config.refine_intrinsics) {
    const size_t num_blocks = block_starts.size() - 1;
    std::vector<double*> all_blocks;
    for (size_t k = 0; k < num_blocks; ++k)
      all_blocks.push_back(b->intrinsics.data() + block_starts[k]);
    problem->AddResidualBlock(
        new IntrinsicsPriorCost(in.calibrated_intrinsics, input.intrinsics_information,
                                input.intrinsics_held, block_starts),
        nullptr, all_blocks);
    // The held intrinsics: each block's, in its own indices.
    for (size_t k = 0; k < num_blocks; ++k) {
      const int first = block_starts[k], size = block_starts[k + 1] - first;
      std::vector<int> held;
      for (int j : input.intrinsics_held)
        if (j >= first && j < first + size) held.push_back(j - first);
      if (static_cast<int>(held.size()) == size) {
        problem->SetParameterBlockConstant(all_blocks[k]);
        held_in_constant_blocks += size;
      } else if (!held.empty()) {
        problem->SetManifold(all_blocks[k], new ceres::SubsetManifold(size, held));
      }
    }
  } else {
    problem->SetParameterBlockConstant(b->intrinsics.data());
  }
  if (config.gauge == PlaneGauge::kFixedTrack) {
    problem->SetParameterBlockConstant(b->point(scene, config.gauge_track));
  }
  return held_in_constant_blocks;
}

// A plate's height where the input gives it, and its scale unless refined,
// held.
void HoldPlateBlocks(const PlaneBundleInput& input, const PlaneBundleConfig& config, Blocks* b,
                     ceres::Problem* problem) {
  for (size_t g = 0; g < input.plates.size(); ++g) {
    if (!problem->HasParameterBlock(b->plate_pose[g].data())) continue;
    if (input.plates[g].height_mm.has_value()) {
      b->plate_height[g] = *input.plates[g].height_mm;
      problem->SetParameterBlockConstant(&b->plate_height[g]);
    }
    if (!config.refine_plate_scale) problem->SetParameterBlockConstant(&b->plate_scale[g]);
  }
}

BuiltProblem BuildProblem(const ProblemInputs& in, bool split, Blocks* scene_blocks,
                          PlaneScene* scene) {
  const LensProjection& lens = in.lens;
  const PlaneBundleInput& input = in.input;
  const PlaneBundleConfig& config = in.config;
  const PlaneBundleOptions& options = in.options;
  Blocks& b = *scene_blocks;
  BuiltProblem built;
  std::vector<int>& block_starts = built.block_starts;
  block_starts = split ? lens.IntrinsicsBlockStarts() : std::vector<int>{0, lens.NumIntrinsics()};
  const auto intrinsics_block = [&](size_t k) { return b.intrinsics.data() + block_starts[k]; };
  // A track of exactly two observations (two tiles): the first has no loss.
  // With both robust, a pair that disagreed by more than twice the loss scale
  // had a segment of minima (both residuals on Huber's linear branch pulling
  // opposite ways: the cost is flat between the ends where one of them is at
  // the scale), and Ceres' model (it drops the loss's negative curvature)
  // crawled along it: lens-mismatch's first solve hit 100 iterations. Without
  // the first loss the minimum is the end where the first residual is at the
  // scale, with the same cost and the same pull on the scene; a consistent
  // pair is on the quadratic branch either way.
  std::vector<int> num_used(input.num_tracks, 0), first_used(input.num_tracks, -1);
  for (size_t n = 0; n < input.observations.size(); ++n) {
    const TrackObservation& obs = input.observations[n];
    if (obs.weight <= 0.0) continue;
    if (num_used[obs.track]++ == 0) first_used[obs.track] = static_cast<int>(n);
  }
  const double inv_sigma = 1.0 / input.observation_sigma_px;
  const Eigen::Matrix3d cam_from_part = RotationFromAngleAxis(Eigen::Vector3d(b.r.data()));
  const Eigen::Vector3d t(b.t.data());
  // An observation's intrinsics blocks, given its part-frame point.
  std::vector<double*> blocks;
  const auto intrinsics_of = [&](const Eigen::Vector3d& x_part) {
    blocks.clear();
    if (!split) {
      blocks.push_back(b.intrinsics.data());
      return IntrinsicsBlocks{};
    }
    IntrinsicsBlocks of{{}, in.initial_intrinsics.data(), in.num_outside};
    for (int k : lens.IntrinsicsBlocksNear(cam_from_part * x_part + t, b.intrinsics.data(),
                                           options.intrinsics_block_margin_px)) {
      of.ranges.emplace_back(block_starts[k], block_starts[k + 1] - block_starts[k]);
      blocks.push_back(intrinsics_block(k));
    }
    return of;
  };
  ceres::Problem::Options problem_options;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  auto problem = std::make_unique<ceres::Problem>(problem_options);
  for (size_t n = 0; n < input.observations.size(); ++n) {
    const TrackObservation& obs = input.observations[n];
    if (obs.weight <= 0.0) continue;
    const bool robust = num_used[obs.track] != 2 || first_used[obs.track] != static_cast<int>(n);
    double* table_pos = b.table_pos[obs.tile].data();
    double* point = b.point(scene, obs.track);
    IntrinsicsBlocks of = intrinsics_of(MovedTrackPoint(table_pos, point));
    std::vector<double*> parameters = {b.r.data(), b.t.data(), table_pos, point};
    parameters.insert(parameters.end(), blocks.begin(), blocks.end());
    problem->AddResidualBlock(
        new TrackReprojectionCost(lens, obs.q_px, obs.weight * inv_sigma * obs.shape,
                                  std::move(of)),
        robust ? in.loss : nullptr, parameters);
  }
  for (const PlateMarkObservation& obs : input.plate_observations) {
    if (obs.weight <= 0.0) continue;
    const Eigen::Vector2d mark_uv = input.plates[obs.plate].mark_uv_mm.col(obs.mark);
    double* table_pos = b.table_pos[obs.tile].data();
    double* pose = b.plate_pose[obs.plate].data();
    IntrinsicsBlocks of = intrinsics_of(MovedPlateMark(table_pos, pose, b.plate_height[obs.plate],
                                                       b.plate_scale[obs.plate], mark_uv));
    std::vector<double*> parameters = {b.r.data(),
                                       b.t.data(),
                                       table_pos,
                                       pose,
                                       &b.plate_height[obs.plate],
                                       &b.plate_scale[obs.plate]};
    parameters.insert(parameters.end(), blocks.begin(), blocks.end());
    problem->AddResidualBlock(new PlateMarkReprojectionCost(lens, mark_uv, obs.q_px,
                                                            obs.weight * inv_sigma, std::move(of)),
                              in.loss, parameters);
  }
  AddTablePriors(input, config, &b, problem.get());
  if (in.has_observations) {
    built.held_in_constant_blocks = HoldAsConfigured(in, block_starts, &b, scene, problem.get());
  }
  HoldPlateBlocks(input, config, &b, problem.get());
  built.problem = std::move(problem);
  return built;
}

// The covariance of the scene vector (plane_scene.h's layout) and of
// `tracks`' points into *scene (both left empty if it cannot be computed:
// false), from the solved problem on b.
bool CovarianceIntoScene(const BuiltProblem& built, Blocks* blocks, const std::vector<int>& tracks,
                         int num_threads, PlaneScene* scene) {
  Blocks& b = *blocks;
  const int num_tiles = static_cast<int>(scene->table_pos_mm.size());
  const int num_plates = static_cast<int>(scene->plates.size());
  std::vector<std::pair<double*, int>> scene_blocks;  // block, offset in the scene vector
  auto add_block = [&](double* block, int offset) {
    if (built.problem->HasParameterBlock(block)) scene_blocks.push_back({block, offset});
  };
  add_block(b.r.data(), 0);
  add_block(b.t.data(), 3);
  for (int i = 0; i < num_tiles; ++i) add_block(b.table_pos[i].data(), 6 + 2 * i);
  for (int g = 0; g < num_plates; ++g) {
    const int offset = PlaneSceneCovariancePlateIndex(num_tiles, g);
    add_block(b.plate_pose[g].data(), offset);
    add_block(&b.plate_height[g], offset + 3);
    add_block(&b.plate_scale[g], offset + 4);
  }
  for (size_t k = 0; k + 1 < built.block_starts.size(); ++k) {
    add_block(b.intrinsics.data() + built.block_starts[k],
              PlaneSceneCovarianceIntrinsicsIndex(num_tiles, num_plates) + built.block_starts[k]);
  }
  const int size = PlaneSceneCovarianceSize(num_tiles, num_plates, b.intrinsics.size());
  scene->covariance.resize(0, 0);
  scene->track_covariance_mm2.clear();
  Eigen::MatrixXd scene_covariance;
  std::vector<Eigen::Matrix2d> track_covariance;
  if (!SchurCovariance(built.problem.get(), scene_blocks, b, scene, tracks, num_threads,
                       &scene_covariance, &track_covariance))
    return false;
  scene->covariance = Eigen::MatrixXd::Zero(size, size);
  for (size_t m = 0, row = 0; m < scene_blocks.size(); ++m) {
    const int size_m = built.problem->ParameterBlockSize(scene_blocks[m].first);
    for (size_t n = 0, col = 0; n < scene_blocks.size(); ++n) {
      const int size_n = built.problem->ParameterBlockSize(scene_blocks[n].first);
      scene->covariance.block(scene_blocks[m].second, scene_blocks[n].second, size_m, size_n) =
          scene_covariance.block(row, col, size_m, size_n);
      col += size_n;
    }
    row += size_m;
  }
  scene->track_covariance_mm2 = track_covariance;
  return true;
}

// Why the solve cannot run on these inputs ("" when it can).
std::string WhyNotRun(const LensProjection& lens, const PlaneBundleInput& input,
                      const PlaneBundleConfig& config, const PlaneBundleOptions& options,
                      const PlaneScene& scene) {
  std::string error = config.Check();
  if (error.empty()) error = options.Check();
  if (error.empty()) error = CheckPlaneBundleInput(input, config, lens.NumIntrinsics());
  if (error.empty() &&
      (scene.table_pos_mm.size() != input.commanded_table_pos_mm.size() ||
       scene.track_xy_mm.cols() != input.num_tracks || scene.plates.size() != input.plates.size() ||
       scene.intrinsics.size() != lens.NumIntrinsics())) {
    error = "the initial scene's sizes do not match the input";
  }
  return error;
}

// The observations of weight > 0, per tile into summary's counts; "" or why
// the solve cannot run (a tile with neither a prior nor an observation).
std::string CountObservations(const PlaneBundleInput& input, PlaneBundleSummary* summary) {
  const int num_tiles = static_cast<int>(input.commanded_table_pos_mm.size());
  std::vector<int> tile_observations(num_tiles, 0);
  for (const TrackObservation& obs : input.observations) {
    if (obs.weight <= 0.0) continue;
    ++tile_observations[obs.tile];
    ++summary->num_observations;
  }
  for (const PlateMarkObservation& obs : input.plate_observations) {
    if (obs.weight <= 0.0) continue;
    ++tile_observations[obs.tile];
    ++summary->num_observations;
  }
  for (int i = 0; i < num_tiles; ++i)
    if (tile_observations[i] == 0) summary->tiles_without_observations.push_back(i);
  for (const int i : input.tiles_without_table_prior) {
    if (tile_observations[i] > 0) continue;
    return "tile " + std::to_string(i) + " has neither a table prior nor an observation";
  }
  return {};
}

ceres::Solver::Options SolverOptions(const PlaneBundleOptions& options, bool has_observations) {
  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = options.linear_solver == LinearSolver::kSparseSchur
                                          ? ceres::SPARSE_SCHUR
                                          : ceres::DENSE_SCHUR;
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.initial_trust_region_radius = options.initial_trust_region_radius;
  solver_options.function_tolerance = options.function_tolerance;
  solver_options.gradient_tolerance = options.gradient_tolerance;
  solver_options.parameter_tolerance = options.parameter_tolerance;
  // One thread: Ceres sums the cost and gradient per thread and adds into
  // the reduced system under locks, in the threads' order, so the last bits
  // of every solve differed between runs. Two threads were slower in every
  // solve of the demo and lens-mismatch here (2 shared cores).
  solver_options.num_threads = 1;
  solver_options.logging_type = ceres::SILENT;
  if (!has_observations) solver_options.linear_solver_type = ceres::DENSE_QR;  // priors alone
  return solver_options;
}

// The elimination ordering. Ceres orders a group's blocks by address (a
// std::set<double*>), and that order lays out the reduced system and orders
// its sums: with the heap's layout, which differs between runs, the
// solution's last bits did. So every scene block has a group of its own, in
// the scene vector's order. The points share group 0: columns of one
// matrix, they are in track order.
std::shared_ptr<ceres::ParameterBlockOrdering> DeterministicOrdering(const BuiltProblem& built,
                                                                     int num_tracks, Blocks* b,
                                                                     PlaneScene* scene) {
  const ceres::Problem& problem = *built.problem;
  auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
  for (int k = 0; k < num_tracks; ++k) ordering->AddElementToGroup(b->point(scene, k), 0);
  int group = 1;
  const auto add_group = [&](double* block) {
    if (problem.HasParameterBlock(block)) ordering->AddElementToGroup(block, group++);
  };
  add_group(b->r.data());
  add_group(b->t.data());
  for (std::array<double, 2>& pos : b->table_pos) add_group(pos.data());
  for (size_t g = 0; g < b->plate_pose.size(); ++g) {
    add_group(b->plate_pose[g].data());
    add_group(&b->plate_height[g]);
    add_group(&b->plate_scale[g]);
  }
  for (size_t k = 0; k + 1 < built.block_starts.size(); ++k)
    add_group(b->intrinsics.data() + built.block_starts[k]);
  return ordering;
}

// Why the solution cannot be used ("" when it can).
std::string WhyUnusable(const ceres::Solver::Summary& solver_summary,
                        const PlaneBundleSummary& summary, int num_tiles,
                        const PlaneBundleConfig& config, const PlaneBundleOptions& options) {
  const int observed_tiles =
      num_tiles - static_cast<int>(summary.tiles_without_observations.size());
  if (!solver_summary.IsSolutionUsable()) return "the solver failed: " + solver_summary.message;
  if (solver_summary.termination_type == ceres::NO_CONVERGENCE)
    return "no convergence in " + std::to_string(options.max_iterations) + " iterations";
  if (observed_tiles < 2) return "fewer than 2 tiles observed";
  if (!(summary.inlier_rms_px <= options.max_usable_rms_px))
    return "inlier RMS above max_usable_rms_px";
  if (config.compute_covariance && !summary.covariance_ok)
    return "covariance not computable (rank-deficient: too few observations?)";
  return {};
}

std::string Brief(const PlaneBundleSummary& summary, const std::string& why_unusable, int num_tiles,
                  int num_tracks) {
  double max_adjustment_mm = 0.0;
  for (const Eigen::Vector2d& a : summary.table_adjustment_mm) {
    max_adjustment_mm = std::max(max_adjustment_mm, a.norm());
  }
  std::ostringstream brief;
  brief.precision(3);
  brief << "plane BA " << (summary.usable ? "ok" : "UNUSABLE (" + why_unusable + ")") << ": "
        << num_tiles << " tiles (" << summary.tiles_without_observations.size()
        << " by prior only), " << num_tracks << " tracks, " << summary.num_observations
        << " obs, rms " << summary.initial_rms_px << " -> " << summary.final_rms_px
        << " px (inliers " << summary.inlier_rms_px << ", " << summary.num_outliers
        << " outliers) in " << summary.iterations << " it, tilt " << summary.plane_tilt_deg
        << " deg, max |T adj| " << max_adjustment_mm << " mm";
  return brief.str();
}

}  // namespace

PlaneBundleSummary SolvePlaneBundle(const LensProjection& lens, const PlaneBundleInput& input,
                                    const PlaneBundleConfig& config,
                                    const PlaneBundleOptions& options, PlaneScene* scene) {
  PlaneBundleSummary summary;
  const int num_tiles = static_cast<int>(input.commanded_table_pos_mm.size());
  if (const std::string error = WhyNotRun(lens, input, config, options, *scene); !error.empty()) {
    summary.brief = "plane bundle adjustment not run: " + error;
    return summary;
  }
  const Clock::time_point start = Clock::now();

  Blocks b = BlocksFromScene(*scene);
  const Eigen::VectorXd calibrated_intrinsics =  // the prior's mean
      input.intrinsics_prior_mean.size() > 0 ? input.intrinsics_prior_mean : scene->intrinsics;
  ComputeResiduals(lens, input, &b, scene);
  const double outlier_px = 3.0 * options.loss_scale_px;
  summary.initial_rms_px = Stats(input, *scene, outlier_px).rms_px;
  if (const std::string error = CountObservations(input, &summary); !error.empty()) {
    summary.brief = "plane bundle adjustment not run: " + error;
    return summary;
  }
  const bool has_observations = summary.num_observations > 0;

  // Refined intrinsics in the lens's blocks (IntrinsicsBlockStarts): each
  // observation lists only the blocks its projection depends on (within
  // options.intrinsics_block_margin_px), so that the reduced system sees the
  // sparsity: a splined model's 2 x 164 Jacobian rows have 2 x 36 nonzeros,
  // and Ceres formed 164 x 164 products per observation. The intrinsics
  // outside an observation's blocks are read from `initial_intrinsics`; a
  // step that needs them fails (IntrinsicsBlocks), and then the solve runs
  // again with one block.
  const Eigen::VectorXd initial_intrinsics = b.intrinsics;
  std::atomic<int> num_outside{0};
  const std::unique_ptr<ceres::LossFunction> loss(MakeLoss(options, input.observation_sigma_px));
  const ProblemInputs problem_inputs{lens,
                                     input,
                                     config,
                                     options,
                                     loss.get(),
                                     calibrated_intrinsics,
                                     initial_intrinsics,
                                     has_observations,
                                     &num_outside};
  ceres::Solver::Options solver_options = SolverOptions(options, has_observations);
  const bool split =
      has_observations && config.refine_intrinsics && lens.IntrinsicsBlockStarts().size() > 2;
  BuiltProblem built = BuildProblem(problem_inputs, split, &b, scene);
  if (has_observations) {
    solver_options.linear_solver_ordering =
        DeterministicOrdering(built, input.num_tracks, &b, scene);
  }
  ceres::Solver::Summary solver_summary;
  ceres::Solve(solver_options, built.problem.get(), &solver_summary);
  int iterations = static_cast<int>(solver_summary.iterations.size()) - 1;
  summary.intrinsics_block_exits = num_outside;
  if (num_outside > 0) {  // from where it stopped, with the intrinsics in one block
    built = BuildProblem(problem_inputs, false, &b, scene);
    solver_options.linear_solver_ordering =
        DeterministicOrdering(built, input.num_tracks, &b, scene);
    ceres::Solve(solver_options, built.problem.get(), &solver_summary);
    iterations += static_cast<int>(solver_summary.iterations.size()) - 1;
  }
  summary.iterations = iterations;
  summary.num_residuals = solver_summary.num_residuals;
  summary.num_parameters = solver_summary.num_effective_parameters - built.held_in_constant_blocks;
  summary.solve_seconds = SecondsSince(start);

  BlocksToScene(b, scene);
  ComputeResiduals(lens, input, &b, scene);
  const ResidualStats stats = Stats(input, *scene, outlier_px);
  summary.final_rms_px = stats.rms_px;
  summary.num_outliers = stats.num_outliers;
  summary.inlier_rms_px = stats.inlier_rms_px;
  double chi2 = stats.chi2;
  for (int i = 0; i < num_tiles; ++i) {
    const Eigen::Vector2d adjustment = scene->table_pos_mm[i] - input.commanded_table_pos_mm[i];
    summary.table_adjustment_mm.push_back(adjustment);
    chi2 += adjustment.squaredNorm() / (input.table_sigma_mm * input.table_sigma_mm);
  }
  if (config.refine_intrinsics) {
    const Eigen::VectorXd change = scene->intrinsics - calibrated_intrinsics;
    chi2 += change.dot(input.intrinsics_information * change);
  }
  const int dof = summary.num_residuals - summary.num_parameters;
  summary.unit_weight_sigma = dof > 0 ? std::sqrt(chi2 / dof) : 0.0;
  summary.plane_tilt_deg = PlaneTiltDeg(scene->cam_from_part_r);

  if (config.compute_covariance) {
    const Clock::time_point covariance_start = Clock::now();
    summary.covariance_ok =
        CovarianceIntoScene(built, &b, config.covariance_tracks, options.num_threads, scene);
    summary.covariance_seconds = SecondsSince(covariance_start);
  }
  const std::string why_unusable = WhyUnusable(solver_summary, summary, num_tiles, config, options);
  summary.usable = why_unusable.empty();
  summary.brief = Brief(summary, why_unusable, num_tiles, input.num_tracks);
  return summary;
}

PlateScaleRelease ReleasePlateScale(const LensProjection& lens, const PlaneBundleInput& input,
                                    const PlaneBundleOptions& options, const PlaneScene& scene,
                                    int plate) {
  PlateScaleRelease result;
  const int num_tiles = static_cast<int>(scene.table_pos_mm.size());
  const int num_plates = static_cast<int>(scene.plates.size());
  const int size = PlaneSceneCovarianceSize(num_tiles, num_plates, lens.NumIntrinsics());
  if (plate < 0 || plate >= num_plates || scene.covariance.rows() != size) return result;
  // The blocks as the solve had them; none constant, so that every column is
  // ambient (a block the solve held has zero rows in C).
  Blocks b = BlocksFromScene(scene);
  ceres::Problem::Options problem_options;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  std::unique_ptr<ceres::LossFunction> loss(MakeLoss(options, input.observation_sigma_px));
  const double inv_sigma = 1.0 / input.observation_sigma_px;
  for (const PlateMarkObservation& obs : input.plate_observations) {
    if (obs.plate != plate || obs.weight <= 0.0) continue;
    problem.AddResidualBlock(
        new PlateMarkReprojectionCost(lens, input.plates[plate].mark_uv_mm.col(obs.mark), obs.q_px,
                                      obs.weight * inv_sigma),
        loss.get(),
        {b.r.data(), b.t.data(), b.table_pos[obs.tile].data(), b.plate_pose[plate].data(),
         &b.plate_height[plate], &b.plate_scale[plate], b.intrinsics.data()});
  }
  if (problem.NumResidualBlocks() == 0) return result;
  // The evaluated blocks and their offsets in the scene vector; s last.
  ceres::Problem::EvaluateOptions evaluate;
  std::vector<int> offset;
  const auto add = [&](double* block, int at) {
    if (!problem.HasParameterBlock(block)) return;
    evaluate.parameter_blocks.push_back(block);
    offset.push_back(at);
  };
  const int plate_offset = PlaneSceneCovariancePlateIndex(num_tiles, plate);
  add(b.r.data(), 0);
  add(b.t.data(), 3);
  for (int i = 0; i < num_tiles; ++i) add(b.table_pos[i].data(), 6 + 2 * i);
  add(b.plate_pose[plate].data(), plate_offset);
  add(&b.plate_height[plate], plate_offset + 3);
  add(b.intrinsics.data(), PlaneSceneCovarianceIntrinsicsIndex(num_tiles, num_plates));
  std::vector<int> scene_index;  // per Jacobian column but s's: its index in the scene vector
  for (size_t k = 0; k < offset.size(); ++k) {
    for (int j = 0; j < problem.ParameterBlockSize(evaluate.parameter_blocks[k]); ++j)
      scene_index.push_back(offset[k] + j);
  }
  const int s_column = static_cast<int>(scene_index.size());
  evaluate.parameter_blocks.push_back(&b.plate_scale[plate]);
  std::vector<double> residuals;
  ceres::CRSMatrix jacobian;
  if (!problem.Evaluate(evaluate, nullptr, &residuals, nullptr, &jacobian)) return result;
  double h_ss = 0.0, g_s = 0.0;
  Eigen::VectorXd h = Eigen::VectorXd::Zero(size);
  for (int row = 0; row < jacobian.num_rows; ++row) {
    double j_s = 0.0;
    for (int e = jacobian.rows[row]; e < jacobian.rows[row + 1]; ++e)
      if (jacobian.cols[e] == s_column) j_s = jacobian.values[e];
    h_ss += j_s * j_s;
    g_s += j_s * residuals[row];
    for (int e = jacobian.rows[row]; e < jacobian.rows[row + 1]; ++e)
      if (jacobian.cols[e] != s_column)
        h(scene_index[jacobian.cols[e]]) += j_s * jacobian.values[e];
  }
  const double s = h_ss - h.dot(scene.covariance * h);
  if (!(s > 0)) return result;
  result.ok = true;
  result.scale_minus_1 = scene.plates[plate].scale - 1.0 - g_s / s;
  result.sigma = 1.0 / std::sqrt(s);
  return result;
}

}  // namespace omm
