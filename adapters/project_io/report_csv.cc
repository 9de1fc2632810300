#include "adapters/project_io/report_csv.h"

#include <optional>

#include <fmt/format.h>

#include "adapters/project_io/text_file.h"
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

std::string FeaturesCsv(const std::string& project, const std::vector<FeatureReport>& features) {
  std::string csv =
      "project,feature,type,x_mm,y_mm,diameter_mm,x_sigma_mm,y_sigma_mm,diameter_sigma_mm,"
      "error\n";
  const auto x = [](const std::optional<Eigen::Vector2d>& v) {
    return v ? std::optional<double>(v->x()) : std::nullopt;
  };
  const auto y = [](const std::optional<Eigen::Vector2d>& v) {
    return v ? std::optional<double>(v->y()) : std::nullopt;
  };
  for (const FeatureReport& f : features) {
    csv += fmt::format("{},{},{},{},{},{},{},{},{},{}\n", Field(project), Field(f.name),
                       FeatureTypeName(f.type), Field(x(f.centre_mm)), Field(y(f.centre_mm)),
                       Field(f.diameter_mm), Field(x(f.centre_sigma_mm)),
                       Field(y(f.centre_sigma_mm)), Field(f.diameter_sigma_mm), Field(f.error));
  }
  return csv;
}

void WriteReportTables(const std::filesystem::path& dir, const Report& report) {
  // One project's table: no row where it has no measurement.
  const std::string measurements =
      report.measurements && !report.measurements->empty()
          ? MeasurementsCsv({{report.project, *report.measurements, ""}})
          : MeasurementsCsv({});
  WriteTextFileAtomically(dir / "measurements.csv", measurements);
  WriteTextFileAtomically(
      dir / "features.csv",
      FeaturesCsv(report.project, report.features.value_or(std::vector<FeatureReport>{})));
}

}  // namespace omm
