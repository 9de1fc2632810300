#include "app/batch_summary.h"

#include <algorithm>
#include <cmath>
#include <optional>

#include <fmt/format.h>

namespace omm {

std::string MeasurementBrief(const Report& report) {
  if (!report.measurements) return "-";
  int made = 0;
  double worst = 0.0;
  for (const MeasurementReport& m : *report.measurements) {
    made += m.value_mm.has_value();
    if (const auto z = JudgedDeviationSigma(m)) worst = std::max(worst, std::abs(*z));
  }
  return fmt::format("{}/{} made, max |dev|/sigma {:.2f}", made, report.measurements->size(),
                     worst);
}

std::string CmmAgreement(const std::vector<ProjectMeasurements>& projects) {
  int n = 0, within_2 = 0, beyond_3 = 0, combined = 0;
  double sum_z2 = 0.0;
  for (const ProjectMeasurements& project : projects) {
    for (const MeasurementReport& m : project.measurements) {
      const std::optional<double> judged = JudgedDeviationSigma(m);
      if (!judged) continue;
      const double z = std::abs(*judged);
      ++n;
      combined += m.deviation_combined_sigma.has_value();
      within_2 += z <= 2.0;
      beyond_3 += z > 3.0;
      sum_z2 += z * z;
    }
  }
  if (n == 0) return "no measurement has a CMM value";
  const std::string sigma =
      combined == 0   ? ""
      : combined == n ? " (sigma: omm's and the CMM's combined)"
                      : fmt::format(" (sigma: omm's and the CMM's combined for {}, omm's alone for "
                                    "the rest)",
                                    combined);
  return fmt::format(
      "against the CMM: {} measurements, |deviation| <= 2 sigma for {} ({:.1f} %), beyond 3 "
      "sigma {}, rms deviation/sigma {:.2f}{}",
      n, within_2, 100.0 * within_2 / n, beyond_3, std::sqrt(sum_z2 / n), sigma);
}

}  // namespace omm
