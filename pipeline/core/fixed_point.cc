#include "pipeline/core/fixed_point.h"

#include <algorithm>
#include <cassert>

namespace omm {

Eigen::VectorXd AndersonStep(const Eigen::VectorXd& x_prev, const Eigen::VectorXd& g_prev,
                             const Eigen::VectorXd& x, const Eigen::VectorXd& g,
                             const AndersonStepOptions& options) {
  assert(x_prev.size() == x.size() && g_prev.size() == x.size() && g.size() == x.size());
  const Eigen::VectorXd f = g - x;
  const Eigen::VectorXd df = f - (g_prev - x_prev);
  const double df2 = df.squaredNorm();
  if (!(df2 > 0.0)) return g;
  const double gamma = std::clamp(df.dot(f) / df2, options.min_gamma, options.max_gamma);
  return g - gamma * (g - g_prev);
}

}  // namespace omm
