// Writes the text files of a project directory (project.yaml, table.csv and,
// when there are CMM values, cmm.csv) so that LoadProject reads them back.
#pragma once

#include "pipeline/core/project.h"

namespace omm {

// Writes into project.dir (created if missing). Images are the caller's.
void WriteProjectFiles(const Project& project);

}  // namespace omm
