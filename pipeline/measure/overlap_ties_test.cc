#include "pipeline/measure/overlap_ties.h"

#include <utility>
#include <vector>

#include <gtest/gtest.h>

namespace omm {
namespace {

using Pairs = std::vector<std::pair<int, int>>;

// A 3 x 3 grid of tiles (index 3 row + col) on the mosaic's grid, each
// footprint 100 px square at a 60 px step: neighbours overlap, diagonals too,
// tiles two apart do not.
OrthoGeometry ThreeByThree() {
  OrthoGeometry geometry;
  for (int row = 0; row < 3; ++row) {
    for (int col = 0; col < 3; ++col) {
      TileOrthoMap map;
      map.min_px = Eigen::Vector2i(60 * col, 60 * row);
      map.max_px = map.min_px + Eigen::Vector2i(99, 99);
      geometry.tiles.push_back(map);
    }
  }
  return geometry;
}

// Every overlapping pair of the grid but those with `except`, as links.
Pairs AllLinksBut(const std::vector<int>& except) {
  Pairs links;
  for (int a = 0; a < 9; ++a) {
    for (int b = a + 1; b < 9; ++b) {
      const bool overlap = std::abs(a % 3 - b % 3) <= 1 && std::abs(a / 3 - b / 3) <= 1;
      const bool excepted = std::find(except.begin(), except.end(), a) != except.end() ||
                            std::find(except.begin(), except.end(), b) != except.end();
      if (overlap && !excepted) links.emplace_back(a, b);
    }
  }
  return links;
}

TEST(OverlapsToAlign, AHeldTileWithEveryPlacedTileItOverlaps) {
  // Corner tile 0 held: its neighbours 1, 3 and the diagonal 4.
  EXPECT_EQ(OverlapsToAlign(ThreeByThree(), {0}, AllLinksBut({0})),
            (Pairs{{1, 0}, {3, 0}, {4, 0}}));
  // Two held tiles are not aligned to each other.
  EXPECT_EQ(OverlapsToAlign(ThreeByThree(), {0, 1}, AllLinksBut({0, 1})),
            (Pairs{{3, 0}, {4, 0}, {2, 1}, {3, 1}, {4, 1}, {5, 1}}));
}

TEST(OverlapsToAlign, ATileLinkedToOneNeighbourWithItsOtherOverlaps) {
  // Tile 8 (a corner) linked to 5 alone: aligned to 4 and 7, not to 5.
  Pairs links = AllLinksBut({8});
  links.emplace_back(5, 8);
  EXPECT_EQ(OverlapsToAlign(ThreeByThree(), {}, links), (Pairs{{4, 8}, {7, 8}}));
  // Linked to two: well placed, nothing to align.
  links.emplace_back(7, 8);
  EXPECT_TRUE(OverlapsToAlign(ThreeByThree(), {}, links).empty());
}

TEST(OverlapsToAlign, TwoWeakTilesOverlapOnce) {
  // Tiles 7 and 8 each linked to one tile (4 and 5): 7 aligned to 3, 5
  // and 6, 8 to 4 and 7; their own overlap once.
  Pairs links = AllLinksBut({7, 8});
  links.emplace_back(4, 7);
  links.emplace_back(5, 8);
  EXPECT_EQ(OverlapsToAlign(ThreeByThree(), {}, links),
            (Pairs{{3, 7}, {5, 7}, {6, 7}, {4, 8}, {7, 8}}));
}

}  // namespace
}  // namespace omm
