#include "adapters/project_io/report_csv.h"

#include <gtest/gtest.h>

namespace omm {
namespace {

TEST(MeasurementsCsv, OneRowPerMeasurementQuotedWhereNeeded) {
  MeasurementReport made;
  made.name = "A_to_B";
  made.type = MeasurementType::kDistance;
  made.value_mm = 202.60214567891;
  made.sigma_mm = 0.0031;
  made.cmm_mm = 202.6;
  made.deviation_mm = 0.00214567891;
  made.deviation_sigma = 0.692154;
  made.cmm_sigma_mm = 0.001;
  made.deviation_combined_sigma = 0.658651;
  MeasurementReport missing;
  missing.name = "A_diameter";
  missing.type = MeasurementType::kDiameter;
  missing.error = "cut by the mosaic border (\"hole_A\", 12 of 96 wedges)";
  const std::vector<ProjectMeasurements> projects = {
      {"jobs/part 1", {made, missing}, ""},
      {"jobs/part,2", {}, "stage 'calibrate' failed: plate not found"}};
  EXPECT_EQ(MeasurementsCsv(projects),
            "project,measurement,type,value_mm,sigma_mm,cmm_mm,cmm_sigma_mm,deviation_mm,"
            "deviation_sigma,deviation_combined_sigma,error\n"
            "jobs/part 1,A_to_B,distance,202.602146,0.0031,202.6,0.001,0.00214567891,0.692154,"
            "0.658651,\n"
            "jobs/part 1,A_diameter,diameter,,,,,,,,"
            "\"cut by the mosaic border (\"\"hole_A\"\", 12 of 96 wedges)\"\n"
            "\"jobs/part,2\",,,,,,,,,,stage 'calibrate' failed: plate not found\n");
}

}  // namespace
}  // namespace omm
