// Gauss-Newton with a line search along each step, for least-squares
// problems on which plain Gauss-Newton converges slowly. Where the residuals
// do not vanish at the optimum and a direction is weakly determined,
// Gauss-Newton's J'J neglects a curvature that is large against it there:
// its steps along that direction are too short (they shrink by a steady
// ratio rho, needing log(tolerance) / log(rho) of them: a splined lens's
// calibration, rho ~ 0.85, 50-120 iterations with the cost falling in its
// sixth digit) or too long (they overshoot and fail). The cost along a step,
// a parabola through its value and slope at the start and its value at the
// step's end, puts the minimum along it at a scale alpha of the step
// (1 / (1 - rho) for the short ones); the scaled step is tried beside the
// plain one, and the lower taken. No damping: where neither lowers the cost
// it stops.
#pragma once

#include <functional>
#include <string>

#include <Eigen/Core>
#include <Eigen/SparseCore>

namespace omm {

struct GaussNewtonOptions {
  int max_iterations = 50;
  // Converged when no component of a step exceeds this (in the state's
  // units).
  double step_tolerance = 1e-6;
  bool line_search = true;
  // The line search's scale is tried when it differs from 1 by at least
  // min_scale_change, and is held to [1 / max_scale, max_scale].
  double min_scale_change = 0.1;
  double max_scale = 100.0;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct GaussNewtonSummary {
  int iterations = 0;         // steps taken (each lowered the cost)
  int scaled = 0;             // of them, scaled by the line search
  double initial_cost = 0.0;  // |r|^2
  double final_cost = 0.0;
  // The last step was within step_tolerance. Otherwise it stopped at
  // max_iterations, where neither the step nor the searched one lowered the
  // cost (at the precision's floor along it, or where Gauss-Newton's model
  // fails: a caller's robust solver finishes from there), or where the
  // problem could not be evaluated or solved.
  bool converged = false;
};

// The residuals r(state) and their Jacobian; false where they cannot be
// evaluated.
using ResidualsAndJacobian = std::function<bool(const Eigen::VectorXd& state, Eigen::VectorXd* r,
                                                Eigen::SparseMatrix<double, Eigen::RowMajor>* J)>;

// J'J, dense, of a sparse row-major J, summed row by row into its lower
// triangle: Eigen's sparse product goes through a sparse accumulator, 3x
// slower on a splined calibration's J (1924 x 268, 39k non-zeros: 1.0 ms
// against 0.36), and the normal matrix is dense there anyway.
Eigen::MatrixXd DenseNormalMatrix(const Eigen::SparseMatrix<double, Eigen::RowMajor>& J);

// Minimises |r(state)|^2 from *state, in place.
GaussNewtonSummary MinimizeByGaussNewton(const ResidualsAndJacobian& residuals,
                                         const GaussNewtonOptions& options, Eigen::VectorXd* state);

}  // namespace omm
