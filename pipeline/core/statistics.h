// Order statistics and test quantiles shared by the robust fits, the
// consistency checks and the reports.
#pragma once

#include <vector>

namespace omm {

// The middle value of `values` (taken by value: nth_element reorders it).
// For an even count, the upper of the two middle values: a sample value, as
// robust scales (1.4826 x the median absolute residual) and levels use it;
// it differs from the mean of the two by less than their own scatter.
// NaN if `values` is empty.
double Median(std::vector<double> values);

// The p-quantile of the chi-square distribution with `dof` degrees of
// freedom: exact in closed form for 1 and 2 dof (through the normal
// quantile, Acklam's approximation, relative error < 1.2e-9), the
// Wilson-Hilferty cube-root normal approximation above (at p = 0.999 within
// 2 %, high: 16.55 vs 16.27 for 3 dof, 22.68 vs 22.46 for 6). p in
// (0.97575, 1).
double ChiSquareQuantile(double p, int dof);

}  // namespace omm
