// Internal to adapters/mrcal: a SolveRecord as mrcal 2.2's optimisation
// problem (the arrays mrcal_optimize and mrcal_optimizer_callback take), and
// back. Not installed for other folders: it exposes mrcal types.
//
// Board coordinates: mrcal puts calibration-object point (row i, col j) at
// (j, i, 0) * spacing, origin at the first mark; BoardPoints (board.h) centres
// the plate. With o = ((cols-1)/2, (rows-1)/2, 0) * pitch,
//   p_mrcal = p_ours + o,  so  t_mrcal = t_ours - R o  for the same R.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "adapters/mrcal/mrcal_c.h"
#include "pipeline/core/calibration_result.h"
#include "pipeline/core/gauss_newton.h"

namespace omm::mrcal_internal {

struct Problem {
  mrcal_lensmodel_t lensmodel;
  std::vector<double> intrinsics;
  std::vector<mrcal_pose_t> frames_toref;  // mrcal board coordinates
  mrcal_calobject_warp_t calobject_warp;
  std::vector<mrcal_observation_board_t> observations;
  // (x, y, weight) per mark, weight < 0 = outlier (mrcal's convention).
  std::vector<mrcal_point3_t> pool;
  int imagersize[2];
  mrcal_problem_selections_t selections;
  mrcal_problem_constants_t constants;
  double spacing_mm;
  int width_n;   // board cols
  int height_n;  // board rows

  int NumStates() const;
  int NumMeasurements() const;
  int NumMeasurementsBoards() const;
};

// Builds the problem. Precondition: the record is consistent (valid lens
// model, sizes match); violations are bugs (assert).
Problem ToProblem(const SolveRecord& record);

// Copies the state (intrinsics, frames, warp) and the outlier flags back.
void UpdateRecord(const Problem& problem, SolveRecord* record);

// mrcal_optimize on the problem, in place. Returns the stats; x (weighted
// residuals, mrcal's measurement vector) if asked.
mrcal_stats_t Optimize(Problem* problem, Eigen::VectorXd* x = nullptr);

// mrcal_optimizer_callback at the problem's state: the measurement vector and
// the Jacobian in mrcal's packed (unitless) state, J* = J D with D the state
// scaling. Returns false if mrcal fails.
bool EvaluateCallback(const Problem& problem, Eigen::VectorXd* x,
                      Eigen::SparseMatrix<double, Eigen::RowMajor>* J_packed);

// D: the factors mrcal_unpack_solver_state_vector multiplies a packed state by
// (b = D b*), size NumStates().
Eigen::VectorXd UnpackScale(const Problem& problem);

// The optimised values (intrinsics, frames, board warp, as the selections
// say) in mrcal's packed state vector b*, and back.
Eigen::VectorXd PackedState(const Problem& problem);
void SetPackedState(const Eigen::VectorXd& packed, Problem* problem);

// mrcal_optimize's convergence test: it stops when no component of a step in
// the packed state exceeds this (libdogleg's update threshold, as mrcal 2.2
// sets it; not settable through its API).
constexpr double kMrcalUpdateThreshold = 1e-6;

// The problem brought to mrcal_optimize's convergence, in place, by
// Gauss-Newton with a line search (gauss_newton.h) on
// mrcal_optimizer_callback: the same measurements, weights, regularization
// and outliers, so the same optimum. Used ahead of mrcal_optimize where its
// steps converge slowly; outlier rejection stays mrcal_optimize's.
GaussNewtonSummary ConvergeByGaussNewton(Problem* problem);

Vector6d RtMrcalFromOurs(const Vector6d& rt_cam_from_plate, const BoardSpec& board);
Vector6d RtOursFromMrcal(const Vector6d& rt_cam_from_board, const BoardSpec& board);

}  // namespace omm::mrcal_internal
