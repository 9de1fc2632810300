#include "pipeline/core/gauss_newton.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <Eigen/Cholesky>

#include "pipeline/core/error.h"

namespace omm {

std::string GaussNewtonOptions::Check() const {
  std::ostringstream what;
  if (max_iterations < 1) what << "max_iterations must be >= 1; ";
  if (!(step_tolerance > 0.0)) what << "step_tolerance must be > 0; ";
  if (!(min_scale_change > 0.0)) what << "min_scale_change must be > 0; ";
  if (!(max_scale > 1.0)) what << "max_scale must be > 1; ";
  return what.str();
}

Eigen::MatrixXd DenseNormalMatrix(const Eigen::SparseMatrix<double, Eigen::RowMajor>& J) {
  using Entry = Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator;
  Eigen::MatrixXd normal = Eigen::MatrixXd::Zero(J.cols(), J.cols());
  for (Eigen::Index row = 0; row < J.outerSize(); ++row) {
    for (Entry a(J, row); a; ++a) {
      // Columns ascend within a row: b from a on falls on or below the diagonal.
      double* lower = normal.col(a.col()).data();
      for (Entry b = a; b; ++b) lower[b.col()] += a.value() * b.value();
    }
  }
  normal.triangularView<Eigen::StrictlyUpper>() = normal.transpose();
  return normal;
}

GaussNewtonSummary MinimizeByGaussNewton(const ResidualsAndJacobian& residuals,
                                         const GaussNewtonOptions& options,
                                         Eigen::VectorXd* state) {
  if (const std::string what = options.Check(); !what.empty()) {
    throw InputError("Gauss-Newton options", what);
  }
  GaussNewtonSummary summary;
  Eigen::VectorXd r;
  Eigen::SparseMatrix<double, Eigen::RowMajor> J;
  if (!residuals(*state, &r, &J)) return summary;
  double cost = r.squaredNorm();
  summary.initial_cost = summary.final_cost = cost;

  struct Trial {
    Eigen::VectorXd step;
    Eigen::VectorXd r;
    Eigen::SparseMatrix<double, Eigen::RowMajor> J;
    double cost = INFINITY;  // infinite where r cannot be evaluated
  };
  const auto try_step = [&](const Eigen::VectorXd& step) {
    Trial trial;
    trial.step = step;
    if (residuals(*state + step, &trial.r, &trial.J)) trial.cost = trial.r.squaredNorm();
    return trial;
  };

  while (summary.iterations < options.max_iterations) {
    const Eigen::VectorXd gradient = J.transpose() * r;  // half the cost's
    const Eigen::LDLT<Eigen::MatrixXd> ldlt(DenseNormalMatrix(J));
    if (ldlt.info() != Eigen::Success) break;
    const Eigen::VectorXd step = -ldlt.solve(gradient);
    if (!step.allFinite()) break;
    const bool within_tolerance = step.cwiseAbs().maxCoeff() <= options.step_tolerance;

    Trial taken = try_step(step);
    bool scaled = false;
    if (options.line_search && std::isfinite(taken.cost)) {
      // cost(a step) ~ cost + slope a + curvature a^2.
      const double slope = 2.0 * gradient.dot(step);
      const double curvature = taken.cost - cost - slope;
      if (slope < 0.0 && curvature > 0.0) {
        const double scale =
            std::clamp(-slope / (2.0 * curvature), 1.0 / options.max_scale, options.max_scale);
        if (std::abs(scale - 1.0) >= options.min_scale_change) {
          Trial at_scale = try_step(scale * step);
          if (at_scale.cost < taken.cost) {
            taken = std::move(at_scale);
            scaled = true;
          }
        }
      }
    }
    if (!(taken.cost < cost)) {
      summary.converged = within_tolerance;  // else: at the precision's floor
      break;
    }
    *state += taken.step;
    r = std::move(taken.r);
    J = std::move(taken.J);
    cost = taken.cost;
    ++summary.iterations;
    summary.scaled += scaled ? 1 : 0;
    if (within_tolerance) {
      summary.converged = true;
      break;
    }
  }
  summary.final_cost = cost;
  return summary;
}

}  // namespace omm
