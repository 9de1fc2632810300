// What `omm batch` says of the projects' measurements: a brief per project
// and their agreement with the CMM over all projects. Each deviation counts
// in the sigmas it is judged by (JudgedDeviationSigma, report.h): both
// values' where cmm.csv states the CMM's, else omm's.
#pragma once

#include <string>
#include <vector>

#include "adapters/project_io/report_csv.h"
#include "pipeline/core/report.h"

namespace omm {

// "made/listed made, max |dev|/sigma z", or "-" without measurements.
std::string MeasurementBrief(const Report& report);

// Over every measurement with a CMM value: how many, within 2 and beyond 3
// sigmas, the rms deviation in sigmas, and which sigma that is.
std::string CmmAgreement(const std::vector<ProjectMeasurements>& projects);

}  // namespace omm
