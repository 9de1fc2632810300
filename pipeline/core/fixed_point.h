// Accelerating a fixed-point iteration x <- G(x) that contracts slowly.
//
// Where G is close to linear about its fixed point x* and one mode dominates
// (G(x) - x* ~ rho (x - x*), 0 < rho < 1), plain iteration shrinks the
// change by rho a round: log(tolerance) / log(rho) rounds. Anderson
// acceleration with one past iterate (Walker & Ni, "Anderson acceleration for
// fixed-point iterations", SIAM J. Numer. Anal. 49, 2011; with depth 1 it is a
// secant step on the residual f(x) = G(x) - x) removes that mode in one
// step:
//   gamma = <f_k - f_(k-1), f_k> / |f_k - f_(k-1)|^2,
//   x_(k+1) = G(x_k) - gamma (G(x_k) - G(x_(k-1))).
// For the single mode gamma = rho / (rho - 1) and x_(k+1) = x*.
#pragma once

#include <Eigen/Core>

namespace omm {

struct AndersonStepOptions {
  // gamma is held to [min_gamma, max_gamma]: -5 extrapolates as far as a
  // contraction of rho = 0.83 asks; beyond, the past pair says too little
  // (nearly equal residuals) to reach further on.
  double min_gamma = -5.0;
  double max_gamma = 0.5;
};

// The next iterate from the last two: x_prev with g_prev = G(x_prev), x with
// g = G(x) (all of one size). g itself (a plain step) when the residuals do
// not differ.
Eigen::VectorXd AndersonStep(const Eigen::VectorXd& x_prev, const Eigen::VectorXd& g_prev,
                             const Eigen::VectorXd& x, const Eigen::VectorXd& g,
                             const AndersonStepOptions& options = {});

}  // namespace omm
