#include "adapters/project_io/report_json.h"

#include <cmath>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "pipeline/core/error.h"
#include "tests/test_util.h"

using ::testing::HasSubstr;

namespace omm {
namespace {

Report FullReport() {
  Report report;
  report.project = "die-casting-450";
  report.software_version = "0.1.0";
  report.inputs_sha256 = std::string(64, 'a');
  report.stage_inputs_sha256 = {{"calibrate", std::string(64, 'b')},
                                {"mosaic", std::string(64, 'c')}};
  CalibrationReport calibration;
  calibration.lens_model = "LENSMODEL_OPENCV8";
  calibration.rms_px = 0.0612345678901234;
  calibration.images_used = 17;
  calibration.images_rejected = {{"calib_13.png", "plate not found"}};
  calibration.extra = {{"residuals_px", ReportValue::Array{0.05, 0.07}},
                       {"cross_validation", ReportObject{{"folds", 5}, {"chosen", true}}}};
  report.calibration = calibration;
  MosaicReport mosaic;
  mosaic.file = "mosaic.tif";
  mosaic.rms_px = 0.08;
  mosaic.gsd_mm = 0.1;
  mosaic.size_px = {4800, 4300};
  mosaic.origin_mm = {-120.0, -90.25};
  report.mosaic = mosaic;
  FeatureReport found;
  found.name = "hole_A";
  found.centre_mm = Eigen::Vector2d(12.5, -3.25);
  found.diameter_mm = 40.0012;
  found.centre_sigma_mm = Eigen::Vector2d(0.0011, 0.0012);
  found.diameter_sigma_mm = 0.0009;
  found.extra = {{"edge_points", 240}};
  FeatureReport missing;
  missing.name = "hole_B";
  missing.error = "cut by the mosaic border";
  report.features = std::vector<FeatureReport>{found, missing};
  MeasurementReport made;
  made.name = "A_to_B";
  made.type = MeasurementType::kDistance;
  made.value_mm = 202.6021;
  made.sigma_mm = 0.0031;
  made.cmm_mm = 202.6033;
  made.deviation_mm = 202.6021 - 202.6033;
  made.deviation_sigma = (202.6021 - 202.6033) / 0.0031;
  made.cmm_sigma_mm = 0.0012;
  made.deviation_combined_sigma = (202.6021 - 202.6033) / std::hypot(0.0031, 0.0012);
  made.extra = {{"sigma_breakdown_mm", ReportObject{{"calibration", 0.001}, {"edges", nullptr}}}};
  MeasurementReport failed;
  failed.name = "A_diameter";
  failed.type = MeasurementType::kDiameter;
  failed.error = "hole not found near [812, 400]";
  report.measurements = std::vector<MeasurementReport>{made, failed};
  report.extra = {{"timing_s", ReportObject{{"calibrate", 12.5}}}};
  return report;
}

void ExpectSameMeasurement(const MeasurementReport& a, const MeasurementReport& b) {
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.type, b.type);
  EXPECT_EQ(a.value_mm, b.value_mm);
  EXPECT_EQ(a.sigma_mm, b.sigma_mm);
  EXPECT_EQ(a.cmm_mm, b.cmm_mm);
  EXPECT_EQ(a.deviation_mm, b.deviation_mm);
  EXPECT_EQ(a.deviation_sigma, b.deviation_sigma);
  EXPECT_EQ(a.cmm_sigma_mm, b.cmm_sigma_mm);
  EXPECT_EQ(a.deviation_combined_sigma, b.deviation_combined_sigma);
  EXPECT_EQ(a.error, b.error);
  EXPECT_EQ(a.extra, b.extra);
}

TEST(ReportJson, RoundTripIsExact) {
  const Report report = FullReport();
  testing::TempDir dir;
  const auto path = dir.path() / "report.json";
  WriteReportJson(path, report);
  const Report read = ReadReportJson(path);
  EXPECT_EQ(read.format, "omm-report/1");
  EXPECT_EQ(read.project, report.project);
  EXPECT_EQ(read.software_version, report.software_version);
  EXPECT_EQ(read.inputs_sha256, report.inputs_sha256);
  EXPECT_EQ(read.stage_inputs_sha256, report.stage_inputs_sha256);
  ASSERT_TRUE(read.calibration.has_value());
  EXPECT_EQ(read.calibration->lens_model, "LENSMODEL_OPENCV8");
  EXPECT_EQ(read.calibration->rms_px, report.calibration->rms_px);  // bit-identical
  EXPECT_EQ(read.calibration->images_used, 17);
  ASSERT_EQ(read.calibration->images_rejected.size(), 1u);
  EXPECT_EQ(read.calibration->images_rejected[0].why, "plate not found");
  EXPECT_EQ(read.calibration->extra, report.calibration->extra);
  ASSERT_TRUE(read.mosaic.has_value());
  EXPECT_EQ(read.mosaic->size_px, Eigen::Vector2i(4800, 4300));
  EXPECT_EQ(read.mosaic->origin_mm, Eigen::Vector2d(-120.0, -90.25));
  ASSERT_TRUE(read.features.has_value());
  ASSERT_EQ(read.features->size(), 2u);
  for (size_t i = 0; i < 2; ++i) {
    const FeatureReport& a = (*read.features)[i];
    const FeatureReport& b = (*report.features)[i];
    EXPECT_EQ(a.name, b.name);
    EXPECT_EQ(a.centre_mm, b.centre_mm);
    EXPECT_EQ(a.diameter_mm, b.diameter_mm);
    EXPECT_EQ(a.centre_sigma_mm, b.centre_sigma_mm);
    EXPECT_EQ(a.diameter_sigma_mm, b.diameter_sigma_mm);
    EXPECT_EQ(a.error, b.error);
    EXPECT_EQ(a.extra, b.extra);
  }
  ASSERT_TRUE(read.measurements.has_value());
  ASSERT_EQ(read.measurements->size(), 2u);
  ExpectSameMeasurement((*read.measurements)[0], (*report.measurements)[0]);
  ExpectSameMeasurement((*read.measurements)[1], (*report.measurements)[1]);
  EXPECT_EQ(read.extra, report.extra);
  // Written again, the text is the same.
  EXPECT_EQ(ReportToJson(read), ReportToJson(report));
}

TEST(ReportJson, FollowsTheContract) {
  const std::string text = ReportToJson(FullReport());
  EXPECT_THAT(text, HasSubstr(R"("format": "omm-report/1")"));
  EXPECT_THAT(text, HasSubstr(R"("images_rejected": [)"));
  EXPECT_THAT(text, HasSubstr(R"("size_px": [)"));
  // A measurement that could not be made: value null and an error.
  EXPECT_THAT(text, HasSubstr(R"("value_mm": null)"));
  EXPECT_THAT(text, HasSubstr(R"("error": "hole not found near [812, 400]")"));
  // So is a feature that was not found.
  EXPECT_THAT(text, HasSubstr(R"("centre_mm": null)"));
  // Named fields come before extras.
  EXPECT_LT(text.find("\"deviation_sigma\""), text.find("\"sigma_breakdown_mm\""));
  // The CMM's sigma and the deviation against both sigmas (beyond the
  // contract) only where cmm.csv states it: once, for the measurement made.
  const auto count = [&](const std::string& key) {
    size_t n = 0;
    for (size_t at = text.find(key); at != std::string::npos; at = text.find(key, at + 1)) ++n;
    return n;
  };
  EXPECT_EQ(count("\"cmm_sigma_mm\""), 1u);
  EXPECT_EQ(count("\"deviation_combined_sigma\""), 1u);
  EXPECT_EQ(count("\"deviation_sigma\""), 2u);
}

TEST(ReportJson, SectionsAreOptional) {
  Report report;
  report.project = "p";
  const Report read = ReportFromJson(ReportToJson(report), "test");
  EXPECT_FALSE(read.calibration.has_value());
  EXPECT_FALSE(read.mosaic.has_value());
  EXPECT_FALSE(read.measurements.has_value());
  EXPECT_THAT(ReportToJson(report), ::testing::Not(HasSubstr("mosaic")));
  EXPECT_THAT(ReportToJson(report), ::testing::Not(HasSubstr("stage_inputs_sha256")));
}

TEST(ReportJson, ErrorsNameTheMember) {
  try {
    ReportFromJson(R"({"format": "omm-report/1", "mosaic": {"file": 3}})", "out/report.json");
    FAIL() << "accepted a number for mosaic.file";
  } catch (const InputError& e) {
    EXPECT_THAT(e.what(), HasSubstr("out/report.json"));
    EXPECT_THAT(e.what(), HasSubstr("mosaic.file"));
  }
  EXPECT_THROW(ReportFromJson(R"({"format": "omm-report/9"})", "r"), InputError);
  EXPECT_THROW(
      ReportFromJson(R"({"format": "omm-report/1", "stage_inputs_sha256": {"mosaic": 1}})", "r"),
      InputError);
  EXPECT_THROW(ReportFromJson("{", "r"), InputError);
  EXPECT_THROW(ReadReportJson("/nonexistent/report.json"), InputError);
}

TEST(ReportJson, ExtraMayNotHideANamedField) {
  Report report;
  report.mosaic = MosaicReport{};
  report.mosaic->extra = {{"gsd_mm", 1.0}};
  EXPECT_THROW(ReportToJson(report), std::logic_error);
}

}  // namespace
}  // namespace omm
