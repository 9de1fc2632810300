#include "pipeline/mosaic/exposure_compensation.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <map>
#include <utility>

#include <Eigen/Dense>

namespace omm {

VignettingFrame VignettingFrame::Of(const CameraModel& camera) {
  VignettingFrame frame;
  frame.centre_px = {camera.intrinsics[2], camera.intrinsics[3]};
  frame.radius_px = 0.5 * std::hypot(camera.width_px, camera.height_px);
  return frame;
}

std::string ExposureOptions::Check() const {
  if (sample_step_px < 1) return "sample_step_px must be >= 1";
  if (smoothing_radius_px < 0) return "smoothing_radius_px must be >= 0";
  if (!(min_border_px >= 0.0)) return "min_border_px must be >= 0";
  if (!(min_value >= 0.0 && min_value < max_value && max_value <= 1.0))
    return "need 0 <= min_value < max_value <= 1";
  if (max_iterations < 1) return "max_iterations must be >= 1";
  if (!(tolerance > 0.0)) return "tolerance must be > 0";
  if (!(cauchy_sigmas > 0.0)) return "cauchy_sigmas must be > 0";
  return "";
}

namespace {

double Median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  const auto mid = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), mid, values.end());
  return *mid;
}

// Consensus radiance of each sample given the exposures (weighted least squares).
void SolveRadiance(const std::vector<ExposureObservation>& obs, const std::vector<int>& start,
                   const std::vector<TileExposure>& exposure, const std::vector<double>& weight,
                   std::vector<double>* radiance) {
  const int num_samples = static_cast<int>(start.size()) - 1;
  radiance->resize(num_samples);
  for (int s = 0; s < num_samples; ++s) {
    double num = 0.0, den = 0.0;
    for (int k = start[s]; k < start[s + 1]; ++k) {
      const double f = exposure[obs[k].tile].Factor(obs[k].rho2);
      num += weight[k] * f * obs[k].value;
      den += weight[k] * f * f;
    }
    (*radiance)[s] = den > 0.0 ? num / den : 0.0;
  }
}

// Relative residual of each observation from its sample's consensus.
std::vector<double> RelativeResiduals(const std::vector<ExposureObservation>& obs,
                                      const std::vector<int>& start,
                                      const std::vector<TileExposure>& exposure,
                                      const std::vector<double>& radiance) {
  std::vector<double> e(obs.size());
  for (size_t s = 0; s + 1 < start.size(); ++s) {
    for (int k = start[s]; k < start[s + 1]; ++k) {
      const double predicted = exposure[obs[k].tile].Factor(obs[k].rho2) * radiance[s];
      e[k] = predicted > 0.0 ? obs[k].value / predicted - 1.0 : 0.0;
    }
  }
  return e;
}

double RobustSigma(const std::vector<double>& e) {
  std::vector<double> a(e.size());
  for (size_t k = 0; k < e.size(); ++k) a[k] = std::abs(e[k]);
  return 1.4826 * Median(std::move(a));
}

// Largest |median log ratio| of compensated intensities over tile pairs.
double MaxPairStep(const std::vector<ExposureObservation>& obs, const std::vector<int>& start,
                   const std::vector<TileExposure>& exposure) {
  std::map<std::pair<int, int>, std::vector<double>> ratios;
  for (size_t s = 0; s + 1 < start.size(); ++s) {
    for (int a = start[s]; a < start[s + 1]; ++a) {
      for (int b = a + 1; b < start[s + 1]; ++b) {
        const ExposureObservation& i = obs[a].tile < obs[b].tile ? obs[a] : obs[b];
        const ExposureObservation& j = obs[a].tile < obs[b].tile ? obs[b] : obs[a];
        ratios[{i.tile, j.tile}].push_back(std::log((i.value / exposure[i.tile].Factor(i.rho2)) /
                                                    (j.value / exposure[j.tile].Factor(j.rho2))));
      }
    }
  }
  double step = 0.0;
  for (auto& [pair, r] : ratios) {
    if (r.size() >= 100) step = std::max(step, std::abs(Median(std::move(r))));
  }
  return step;
}

}  // namespace

ExposureSummary EstimateExposure(const std::vector<ExposureObservation>& obs, int num_tiles,
                                 const ExposureOptions& options) {
  assert(options.Check().empty());
  ExposureSummary summary;
  summary.tiles.assign(num_tiles, TileExposure{});
  std::vector<int> start;
  for (size_t k = 0; k < obs.size(); ++k) {
    assert(obs[k].tile >= 0 && obs[k].tile < num_tiles);
    assert(obs[k].value > 0.0);
    if (k == 0 || obs[k].sample != obs[k - 1].sample) {
      assert(k == 0 || obs[k].sample > obs[k - 1].sample);
      start.push_back(static_cast<int>(k));
    }
  }
  start.push_back(static_cast<int>(obs.size()));
  summary.num_samples = static_cast<int>(start.size()) - 1;
  summary.num_observations = static_cast<int>(obs.size());

  std::vector<int> tile_count(num_tiles, 0);
  for (const ExposureObservation& o : obs) ++tile_count[o.tile];
  for (int i = 0; i < num_tiles; ++i) {
    if (tile_count[i] == 0) summary.tiles_without_samples.push_back(i);
  }
  if (summary.num_samples == 0) {
    summary.brief = "exposure: no tile overlaps to compare; tiles left as recorded";
    return summary;
  }

  std::vector<TileExposure>& exposure = summary.tiles;
  std::vector<double> weight(obs.size(), 1.0), radiance;
  SolveRadiance(obs, start, exposure, weight, &radiance);
  summary.relative_sigma_before = RobustSigma(RelativeResiduals(obs, start, exposure, radiance));
  summary.max_pair_step_before = MaxPairStep(obs, start, exposure);

  for (summary.iterations = 1; summary.iterations <= options.max_iterations; ++summary.iterations) {
    // Per tile: I = a L - b rho^2 L, (a, b) = (g, g v), weighted least squares.
    std::vector<Eigen::Matrix2d> normal(num_tiles, Eigen::Matrix2d::Zero());
    std::vector<Eigen::Vector2d> rhs(num_tiles, Eigen::Vector2d::Zero());
    for (size_t s = 0; s + 1 < start.size(); ++s) {
      for (int k = start[s]; k < start[s + 1]; ++k) {
        const Eigen::Vector2d x(radiance[s], -obs[k].rho2 * radiance[s]);
        normal[obs[k].tile] += weight[k] * x * x.transpose();
        rhs[obs[k].tile] += weight[k] * x * obs[k].value;
      }
    }
    std::vector<TileExposure> next = exposure;
    for (int i = 0; i < num_tiles; ++i) {
      if (tile_count[i] == 0 || !(normal[i](0, 0) > 0.0)) continue;
      if (options.estimate_vignetting) {
        const Eigen::Vector2d ab = normal[i].ldlt().solve(rhs[i]);
        next[i].gain = ab[0];
        next[i].vignetting = ab[1] / ab[0];
      } else {
        next[i].gain = rhs[i][0] / normal[i](0, 0);
      }
    }
    // Gauge: the brightest tile that has samples keeps gain 1.
    int reference = -1;
    for (int i = 0; i < num_tiles; ++i) {
      if (tile_count[i] > 0 && (reference < 0 || next[i].gain > next[reference].gain))
        reference = i;
    }
    const double scale = next[reference].gain;
    for (int i = 0; i < num_tiles; ++i) {
      if (tile_count[i] > 0) next[i].gain /= scale;
    }
    summary.reference_tile = reference;

    double change = 0.0;
    for (int i = 0; i < num_tiles; ++i) {
      change = std::max({change, std::abs(next[i].gain - exposure[i].gain),
                         std::abs(next[i].vignetting - exposure[i].vignetting)});
    }
    exposure = next;
    SolveRadiance(obs, start, exposure, weight, &radiance);
    const std::vector<double> e = RelativeResiduals(obs, start, exposure, radiance);
    const double c = options.cauchy_sigmas * std::max(RobustSigma(e), 1e-6);
    for (size_t k = 0; k < obs.size(); ++k) weight[k] = 1.0 / (1.0 + (e[k] / c) * (e[k] / c));
    if (change < options.tolerance) break;
  }
  summary.iterations = std::min(summary.iterations, options.max_iterations);
  summary.relative_sigma_after = RobustSigma(RelativeResiduals(obs, start, exposure, radiance));
  summary.max_pair_step_after = MaxPairStep(obs, start, exposure);
  summary.usable = summary.tiles_without_samples.empty();
  char line[256];
  std::snprintf(line, sizeof(line),
                "exposure: %d samples, %d iterations; relative sigma %.4f -> %.4f, "
                "largest pair step %.4f -> %.4f%s",
                summary.num_samples, summary.iterations, summary.relative_sigma_before,
                summary.relative_sigma_after, summary.max_pair_step_before,
                summary.max_pair_step_after,
                summary.usable ? "" : "; some tiles share no samples (left as recorded)");
  summary.brief = line;
  return summary;
}

}  // namespace omm
