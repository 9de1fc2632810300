// omm's version, as written into reports and printed by `omm --version`.
#pragma once

namespace omm {

// The CMake project version and the source revision it was built from
// (`git describe --always --dirty`, "unknown" outside a git checkout), e.g.
// "0.1.0+ec9f4b3a1b2c" or "0.1.0+ec9f4b3a1b2c-dirty". Results differ between
// revisions, so reports carry it and `omm batch` reruns what another one made.
const char* SoftwareVersion();

}  // namespace omm
