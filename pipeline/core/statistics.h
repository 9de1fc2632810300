// Order statistics shared by the robust fits and the reports.
#pragma once

#include <vector>

namespace omm {

// The middle value of `values` (taken by value: nth_element reorders it).
// For an even count, the upper of the two middle values: a sample value, as
// robust scales (1.4826 x the median absolute residual) and levels use it;
// it differs from the mean of the two by less than their own scatter.
// NaN if `values` is empty.
double Median(std::vector<double> values);

}  // namespace omm
