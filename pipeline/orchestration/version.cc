#include "pipeline/orchestration/version.h"

#include "source_revision.h"  // generated: OMM_SOURCE_REVISION

namespace omm {

const char* SoftwareVersion() { return OMM_VERSION "+" OMM_SOURCE_REVISION; }

}  // namespace omm
