// omm's version, as written into reports and printed by `omm --version`.
#pragma once

namespace omm {

// The CMake project version, e.g. "0.1.0".
const char* SoftwareVersion();

}  // namespace omm
