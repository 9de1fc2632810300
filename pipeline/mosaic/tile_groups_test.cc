#include "pipeline/mosaic/tile_groups.h"

#include <gtest/gtest.h>

namespace omm {
namespace {

TrackObservation Seen(int tile, int track, double weight = 1.0) {
  TrackObservation o;
  o.tile = tile;
  o.track = track;
  o.weight = weight;
  return o;
}

// Six tiles: tracks tie 0-1 and 1-2 (a chain), a plate seen in 3 and 5 ties
// them; tile 4 sees a track alone, and a dropped observation (weight 0) of
// a track in tiles 2 and 4 ties nothing.
TEST(TiedTileGroups, TracksAndPlatesTieTilesDroppedObservationsDoNot) {
  PlaneBundleInput input;
  input.observations = {Seen(0, 0), Seen(1, 0), Seen(2, 1), Seen(1, 1),
                        Seen(4, 2), Seen(2, 3), Seen(4, 3, 0.0)};
  PlateMarkObservation a, b;
  a.tile = 5;
  b.tile = 3;
  b.mark = 7;
  input.plate_observations = {a, b};
  EXPECT_EQ(TiedTileGroups(input, 6), (std::vector<std::vector<int>>{{0, 1, 2}, {3, 5}, {4}}));

  // The dropped observation kept: 4 joins 0-2.
  input.observations.back().weight = 1.0;
  EXPECT_EQ(TiedTileGroups(input, 6), (std::vector<std::vector<int>>{{0, 1, 2, 4}, {3, 5}}));

  // A track in 2 and 3 ties every tile.
  input.observations.push_back(Seen(3, 9));
  input.observations.push_back(Seen(2, 9));
  EXPECT_EQ(TiedTileGroups(input, 6), (std::vector<std::vector<int>>{{0, 1, 2, 3, 4, 5}}));

  // No observation: each tile alone.
  EXPECT_EQ(TiedTileGroups(PlaneBundleInput{}, 3),
            (std::vector<std::vector<int>>{{0}, {1}, {2}}));
}

}  // namespace
}  // namespace omm
