#include "adapters/project_io/measurements_csv.h"

#include <optional>

#include <fmt/format.h>

#include "pipeline/core/project.h"

namespace omm {
namespace {

std::string Field(const std::string& text) {
  if (text.find_first_of(",\"\r\n") == std::string::npos) return text;
  std::string quoted = "\"";
  for (const char c : text) {
    if (c == '"') quoted += '"';
    quoted += c;
  }
  return quoted + "\"";
}

std::string Field(const std::optional<double>& value) {
  return value ? fmt::format("{:.9g}", *value) : "";
}

}  // namespace

std::string MeasurementsCsv(const std::vector<ProjectMeasurements>& projects) {
  std::string csv =
      "project,measurement,type,value_mm,sigma_mm,cmm_mm,cmm_sigma_mm,deviation_mm,"
      "deviation_sigma,deviation_combined_sigma,error\n";
  for (const ProjectMeasurements& project : projects) {
    if (project.measurements.empty()) {
      csv += fmt::format("{},,,,,,,,,,{}\n", Field(project.project), Field(project.error));
      continue;
    }
    for (const MeasurementReport& m : project.measurements) {
      csv +=
          fmt::format("{},{},{},{},{},{},{},{},{},{},{}\n", Field(project.project), Field(m.name),
                      MeasurementTypeName(m.type), Field(m.value_mm), Field(m.sigma_mm),
                      Field(m.cmm_mm), Field(m.cmm_sigma_mm), Field(m.deviation_mm),
                      Field(m.deviation_sigma), Field(m.deviation_combined_sigma), Field(m.error));
    }
  }
  return csv;
}

}  // namespace omm
