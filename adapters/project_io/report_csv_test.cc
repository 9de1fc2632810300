#include "adapters/project_io/report_csv.h"

#include <algorithm>

#include <gtest/gtest.h>

#include "tests/test_util.h"

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

TEST(FeaturesCsv, CentreDiameterAndSigmasOrWhyNot) {
  FeatureReport found;
  found.name = "hole_A";
  found.centre_mm = Eigen::Vector2d(-195.351008123, -5.8438634712);
  found.diameter_mm = 8.0014257512;
  found.centre_sigma_mm = Eigen::Vector2d(0.0187, 0.0150);
  found.diameter_sigma_mm = 0.0022;
  FeatureReport missing;
  missing.name = "hole_B";
  missing.error = "cut by the mosaic border (72% of the rim not covered)";
  EXPECT_EQ(FeaturesCsv("part, 1", {found, missing}),
            "project,feature,type,x_mm,y_mm,diameter_mm,x_sigma_mm,y_sigma_mm,diameter_sigma_mm,"
            "error\n"
            "\"part, 1\",hole_A,circle,-195.351008,-5.84386347,8.00142575,0.0187,0.015,0.0022,\n"
            "\"part, 1\",hole_B,circle,,,,,,,cut by the mosaic border (72% of the rim not "
            "covered)\n");
}

// A report without the measure stage's results (a mosaic rerun alone) gives
// the tables' headers alone: none of an earlier run's rows stays in out/.
TEST(ReportTables, HeadersAloneWithoutMeasurements) {
  testing::TempDir dir;
  Report report;
  report.project = "p";
  WriteReportTables(dir.path(), report);
  const std::string measurements = testing::ReadTextFile(dir.path() / "measurements.csv");
  EXPECT_EQ(std::count(measurements.begin(), measurements.end(), '\n'), 1) << measurements;
  EXPECT_EQ(measurements, MeasurementsCsv({}));
  EXPECT_EQ(testing::ReadTextFile(dir.path() / "features.csv"), FeaturesCsv("p", {}));

  MeasurementReport made;
  made.name = "A_to_B";
  made.value_mm = 202.6;
  report.measurements = std::vector<MeasurementReport>{made};
  WriteReportTables(dir.path(), report);
  EXPECT_EQ(testing::ReadTextFile(dir.path() / "measurements.csv"),
            MeasurementsCsv({{"p", {made}, ""}}));
}

}  // namespace
}  // namespace omm
