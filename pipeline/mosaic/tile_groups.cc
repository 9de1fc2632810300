#include "pipeline/mosaic/tile_groups.h"

#include <map>
#include <numeric>
#include <utility>

namespace omm {
namespace {

// Union-find over the tiles, each root its group's smallest tile.
class TileUnion {
 public:
  explicit TileUnion(int n) : parent_(static_cast<size_t>(n)) {
    std::iota(parent_.begin(), parent_.end(), 0);
  }
  int Find(int tile) {
    while (parent_[tile] != tile) tile = parent_[tile] = parent_[parent_[tile]];
    return tile;
  }
  void Join(int a, int b) {
    a = Find(a);
    b = Find(b);
    if (a > b) std::swap(a, b);
    parent_[b] = a;
  }

 private:
  std::vector<int> parent_;
};

}  // namespace

std::vector<std::vector<int>> TiedTileGroups(const PlaneBundleInput& input, int num_tiles) {
  TileUnion tiles(num_tiles);
  // The first tile each track (or plate) was seen in; every later one joins it.
  std::map<int, int> first_of_track, first_of_plate;
  for (const TrackObservation& o : input.observations) {
    if (!(o.weight > 0.0)) continue;
    const auto [it, inserted] = first_of_track.emplace(o.track, o.tile);
    if (!inserted) tiles.Join(it->second, o.tile);
  }
  for (const PlateMarkObservation& o : input.plate_observations) {
    if (!(o.weight > 0.0)) continue;
    const auto [it, inserted] = first_of_plate.emplace(o.plate, o.tile);
    if (!inserted) tiles.Join(it->second, o.tile);
  }
  std::vector<std::vector<int>> groups;
  std::vector<int> group_of_root(static_cast<size_t>(num_tiles), -1);
  for (int tile = 0; tile < num_tiles; ++tile) {
    const int root = tiles.Find(tile);
    if (group_of_root[root] < 0) {
      group_of_root[root] = static_cast<int>(groups.size());
      groups.emplace_back();
    }
    groups[group_of_root[root]].push_back(tile);
  }
  return groups;
}

}  // namespace omm
