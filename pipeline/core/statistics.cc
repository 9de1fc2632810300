#include "pipeline/core/statistics.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstddef>
#include <limits>

namespace omm {
namespace {

// The normal distribution's p-quantile for p > 0.97575: Acklam's rational
// approximation of its upper tail (relative error < 1.2e-9).
double NormalUpperQuantile(double p) {
  const double t = std::sqrt(-2.0 * std::log(1.0 - p));
  return -(((((-7.784894002430293e-03 * t - 3.223964580411365e-01) * t - 2.400758277161838e+00) *
                 t -
             2.549732539343734e+00) *
                t +
            4.374664141464968e+00) *
               t +
           2.938163982698783e+00) /
         ((((7.784695709041462e-03 * t + 3.224671290700398e-01) * t + 2.445134137142996e+00) * t +
           3.754408661907416e+00) *
              t +
          1.0);
}

}  // namespace

double Median(std::vector<double> values) {
  if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
  const auto mid = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), mid, values.end());
  return *mid;
}

double ChiSquareQuantile(double p, int dof) {
  assert(p > 0.97575 && p < 1.0 && dof >= 1);
  if (dof == 1) return std::pow(NormalUpperQuantile(0.5 * (1.0 + p)), 2);
  if (dof == 2) return -2.0 * std::log(1.0 - p);
  const double a = 2.0 / (9.0 * dof);
  return dof * std::pow(1.0 - a + NormalUpperQuantile(p) * std::sqrt(a), 3);
}

}  // namespace omm
