// out/report.json (format omm-report/1) written and read with nlohmann-json.
//
// Layout: the named fields of pipeline/core/report.h in their order, then each
// section's `extra` members. A measurement always has value_mm, sigma_mm,
// cmm_mm, deviation_mm and deviation_sigma (null when absent) and "error" only
// when it failed. Sections not yet computed are left out. Unknown members of
// a section are kept in its `extra`, so reading and writing a report from a
// newer omm loses nothing.
#pragma once

#include <filesystem>
#include <string>

#include "pipeline/core/report.h"

namespace omm {

// Pretty-printed JSON text (2-space indent, trailing newline).
std::string ReportToJson(const Report& report);

// Parses report JSON; `where` names its origin in errors. Throws InputError
// for bad JSON, another format or a member of the wrong type.
Report ReportFromJson(const std::string& text, const std::string& where);

// Writes to a temporary file beside `path`, then renames it into place, so
// `path` is always either the old or the complete new report.
void WriteReportJson(const std::filesystem::path& path, const Report& report);

// Throws InputError if the file is missing or not a valid report.
Report ReadReportJson(const std::filesystem::path& path);

}  // namespace omm
