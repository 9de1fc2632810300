// Reports as CSV tables, for spreadsheets and scripts (RFC 4180: a field
// with a comma, quote or line break is quoted, quotes doubled; empty fields
// where a value is absent; numbers with 9 significant digits, 0.1 nm at 1 m).
//
// Measurements: every measurement of every project (one project's in its
// out/measurements.csv, the batch's with `omm batch --csv`), its value, sigma
// and deviation from the CMM, one row each. Columns: project, measurement,
// type, value_mm, sigma_mm, cmm_mm, cmm_sigma_mm, deviation_mm,
// deviation_sigma, deviation_combined_sigma, error (report.h's
// MeasurementReport). A project without measurements (it failed before
// writing a report) is one row with only project and error.
//
// Features (out/features.csv): each feature's centre in the part frame and
// its diameter, with their 1-sigma. Columns: project, feature, type, x_mm,
// y_mm, diameter_mm, x_sigma_mm, y_sigma_mm, diameter_sigma_mm, error
// (report.h's FeatureReport).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "pipeline/core/report.h"

namespace omm {

struct ProjectMeasurements {
  std::string project;                          // as the batch names it
  std::vector<MeasurementReport> measurements;  // empty if none were made
  std::string error;                            // why the project has none, if it failed
};

std::string MeasurementsCsv(const std::vector<ProjectMeasurements>& projects);
std::string FeaturesCsv(const std::string& project, const std::vector<FeatureReport>& features);

// `report`'s measurements and features into dir/measurements.csv and
// dir/features.csv, each with its header alone where the report has none (a
// run whose measure stage's results were dropped leaves no stale table).
// Throws InputError if a file cannot be written.
void WriteReportTables(const std::filesystem::path& dir, const Report& report);

}  // namespace omm
