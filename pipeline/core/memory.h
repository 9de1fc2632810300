// What the machine's memory holds.
#pragma once

#include <unistd.h>

#include <cstdint>

namespace omm {

// The machine's physical memory, bytes; 0 if the system does not say.
inline std::int64_t PhysicalMemoryBytes() {
  const long pages = sysconf(_SC_PHYS_PAGES), page_size = sysconf(_SC_PAGESIZE);
  return pages > 0 && page_size > 0 ? std::int64_t{pages} * page_size : 0;
}

}  // namespace omm
