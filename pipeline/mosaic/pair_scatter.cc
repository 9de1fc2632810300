#include "pipeline/mosaic/pair_scatter.h"

#include <cassert>
#include <cmath>
#include <map>
#include <utility>

#include "pipeline/core/statistics.h"

namespace omm {

std::vector<PairScatter> WeightPairsByScatter(const std::vector<int>& track_anchor_observation,
                                              const Eigen::Matrix2Xd& residual_px,
                                              PlaneBundleInput* input) {
  assert(residual_px.cols() == static_cast<Eigen::Index>(input->observations.size()));
  std::map<std::pair<int, int>, std::vector<int>> pair_observations;
  for (size_t o = 0; o < input->observations.size(); ++o) {
    const TrackObservation& obs = input->observations[o];
    if (obs.track >= static_cast<int>(track_anchor_observation.size())) continue;
    const int anchor = track_anchor_observation[obs.track];
    if (anchor < 0 || anchor == static_cast<int>(o) || obs.weight <= 0.0) continue;
    const Eigen::Vector2d r = residual_px.col(static_cast<Eigen::Index>(o));
    if (!r.allFinite()) continue;
    pair_observations[{input->observations[anchor].tile, obs.tile}].push_back(static_cast<int>(o));
  }
  std::vector<PairScatter> pairs;
  std::vector<double> scatters;
  for (const auto& [tiles, observations] : pair_observations) {
    double sum_squares = 0.0;
    for (const int o : observations) {
      const TrackObservation& obs = input->observations[o];
      sum_squares += (obs.weight * obs.shape * residual_px.col(o)).squaredNorm();
    }
    PairScatter pair;
    pair.tile_a = tiles.first;
    pair.tile_b = tiles.second;
    pair.num_observations = static_cast<int>(observations.size());
    pair.scatter =
        std::sqrt(sum_squares / (2.0 * pair.num_observations)) / input->observation_sigma_px;
    pairs.push_back(pair);
    scatters.push_back(pair.scatter);
  }
  if (pairs.empty()) return pairs;
  const double median = Median(scatters);
  size_t p = 0;
  for (const auto& [tiles, observations] : pair_observations) {
    PairScatter& pair = pairs[p++];
    if (!(pair.scatter > median)) continue;
    pair.weight_scale = median / pair.scatter;
    for (const int o : observations) input->observations[o].weight *= pair.weight_scale;
  }
  return pairs;
}

}  // namespace omm
