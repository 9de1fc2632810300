#include "pipeline/orchestration/version.h"

namespace omm {

const char* SoftwareVersion() { return OMM_VERSION; }

}  // namespace omm
