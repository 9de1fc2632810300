// The one place mrcal's C headers are included. mrcal 2.2's headers have no
// extern "C" guards, and use a few C-only constructs g++ tolerates with
// warnings silenced. Include this only from adapters/mrcal/*.cc.
#pragma once

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wpedantic"
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
extern "C" {
#include <mrcal/mrcal.h>
}
#pragma GCC diagnostic pop
