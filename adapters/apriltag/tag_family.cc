#include "adapters/apriltag/tag_family.h"

#include <cassert>
#include <cstdint>
#include <memory>

#include <apriltag/apriltag.h>
#include <apriltag/tag36h11.h>

namespace omm {
namespace {

using FamilyPtr = std::unique_ptr<apriltag_family_t, void (*)(apriltag_family_t*)>;

// The family tables are static data in libapriltag; creating the family only
// allocates a small header around them, so doing it per call is cheap.
FamilyPtr Family36h11() { return FamilyPtr(tag36h11_create(), tag36h11_destroy); }

}  // namespace

TagFamilyLayout AprilTag36h11Layout() {
  const FamilyPtr family = Family36h11();
  return {static_cast<int>(family->ncodes), family->total_width, family->width_at_border};
}

TagCells AprilTag36h11Cells(int id) {
  const FamilyPtr family = Family36h11();
  assert(id >= 0 && id < static_cast<int>(family->ncodes));
  const int total = family->total_width;
  const int border = family->width_at_border;
  TagCells cells = TagCells::Constant(total, total, false);
  // The ring just outside (normal border) or just inside (reversed border) the
  // black border is white, as in apriltag_to_image().
  const int white_width = border + (family->reversed_border ? 0 : 2);
  const int white_start = (total - white_width) / 2;
  for (int i = 0; i < white_width; ++i) {
    cells(white_start, white_start + i) = true;
    cells(white_start + white_width - 1, white_start + i) = true;
    cells(white_start + i, white_start) = true;
    cells(white_start + i, white_start + white_width - 1) = true;
  }
  const int border_start = (total - border) / 2;
  const std::uint64_t code = family->codes[id];
  for (std::uint32_t i = 0; i < family->nbits; ++i) {
    if (code & (std::uint64_t{1} << (family->nbits - i - 1))) {
      cells(family->bit_y[i] + border_start, family->bit_x[i] + border_start) = true;
    }
  }
  return cells;
}

}  // namespace omm
