#include "app/batch_summary.h"

#include <cmath>

#include <gtest/gtest.h>

namespace omm {
namespace {

// A measurement deviating from its CMM value by `deviation_mm`, omm's sigma
// `sigma_mm`, and the CMM's `cmm_sigma_mm` if stated (as the measure stage
// sets them).
MeasurementReport Compared(double deviation_mm, double sigma_mm,
                           std::optional<double> cmm_sigma_mm = std::nullopt) {
  MeasurementReport m;
  m.value_mm = 100.0 + deviation_mm;
  m.sigma_mm = sigma_mm;
  m.cmm_mm = 100.0;
  m.cmm_sigma_mm = cmm_sigma_mm;
  m.deviation_mm = deviation_mm;
  m.deviation_sigma = deviation_mm / sigma_mm;
  if (cmm_sigma_mm) m.deviation_combined_sigma = deviation_mm / std::hypot(sigma_mm, *cmm_sigma_mm);
  return m;
}

// 0.010 mm off at omm's 0.003 is 3.33 sigma; with the CMM's 0.004 stated,
// 2 sigma of both: within 2 and not beyond 3.
TEST(BatchSummary, DeviationsCountInBothSigmasWhereTheCmmsIsStated) {
  const std::vector<ProjectMeasurements> alone = {{"p", {Compared(0.010, 0.003)}, ""}};
  EXPECT_EQ(CmmAgreement(alone),
            "against the CMM: 1 measurements, |deviation| <= 2 sigma for 0 (0.0 %), beyond 3 "
            "sigma 1, rms deviation/sigma 3.33");
  const std::vector<ProjectMeasurements> both = {{"p", {Compared(0.010, 0.003, 0.004)}, ""}};
  EXPECT_EQ(CmmAgreement(both),
            "against the CMM: 1 measurements, |deviation| <= 2 sigma for 1 (100.0 %), beyond 3 "
            "sigma 0, rms deviation/sigma 2.00 (sigma: omm's and the CMM's combined)");
  const std::vector<ProjectMeasurements> mixed = {
      {"p", {Compared(0.010, 0.003, 0.004), Compared(-0.003, 0.003)}, ""},
      {"q", {}, "stage 'calibrate' failed"}};
  EXPECT_EQ(CmmAgreement(mixed),
            "against the CMM: 2 measurements, |deviation| <= 2 sigma for 2 (100.0 %), beyond 3 "
            "sigma 0, rms deviation/sigma 1.58 (sigma: omm's and the CMM's combined for 1, "
            "omm's alone for the rest)");
  EXPECT_EQ(CmmAgreement({{"q", {}, "failed"}}), "no measurement has a CMM value");

  Report report;
  report.measurements = {Compared(0.010, 0.003, 0.004), Compared(-0.006, 0.003), {}};
  EXPECT_EQ(MeasurementBrief(report), "2/3 made, max |dev|/sigma 2.00");
}

}  // namespace
}  // namespace omm
