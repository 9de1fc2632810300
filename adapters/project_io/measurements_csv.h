// The batch's measurements as one CSV table, for spreadsheets and scripts:
// every measurement of every project, its value, sigma and deviation from the
// CMM, one row each (RFC 4180: a field with a comma, quote or line break is
// quoted, quotes doubled). Empty fields where a value is absent.
//
// Columns: project, measurement, type, value_mm, sigma_mm, cmm_mm,
// cmm_sigma_mm, deviation_mm, deviation_sigma, deviation_combined_sigma,
// error (report.h's MeasurementReport). A project without measurements (it
// failed before writing a report) is one row with only project and error.
// Numbers are written with 9 significant digits (0.1 nm at 1 m).
#pragma once

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

}  // namespace omm
