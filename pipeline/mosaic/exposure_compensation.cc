#include "pipeline/mosaic/exposure_compensation.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <optional>
#include <utility>
#include <vector>

#include <Eigen/Dense>

#include "pipeline/core/parallel_for.h"
#include "pipeline/core/statistics.h"

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
  if (num_threads < 1) return "num_threads must be >= 1";
  return "";
}

namespace {

// The observations grouped by sample, and how a pass over them is split
// between threads: in fixed blocks of samples, a sum over the samples being
// the blocks' partial sums added in block order, so that the result does not
// depend on the number of threads.
struct Samples {
  static constexpr int kPerBlock = 2048;
  const std::vector<ExposureObservation>& obs;
  std::vector<int> start;  // sample s: obs[start[s]] .. obs[start[s + 1] - 1]
  int max_per_sample = 0;  // observations
  int num_threads = 1;

  int num_samples() const { return static_cast<int>(start.size()) - 1; }
  int num_blocks() const { return (num_samples() + kPerBlock - 1) / kPerBlock; }
  // fn(s0, s1, block) for the samples [s0, s1) of every block.
  template <typename Fn>
  void ForEachBlock(Fn fn) const {
    ParallelFor(num_blocks(), num_threads, [&](int block) {
      fn(block * kPerBlock, std::min(num_samples(), (block + 1) * kPerBlock), block);
    });
  }
};

// Each observation's exposure factor F_i(rho^2) under `exposure`, computed
// once per exposure instead of in every pass over the observations.
void Factors(const Samples& samples, const std::vector<TileExposure>& exposure,
             std::vector<double>* factor) {
  const std::vector<ExposureObservation>& obs = samples.obs;
  factor->resize(obs.size());
  samples.ForEachBlock([&](int s0, int s1, int) {
    for (int k = samples.start[s0]; k < samples.start[s1]; ++k)
      (*factor)[k] = exposure[obs[k].tile].Factor(obs[k].rho2);
  });
}

// Consensus radiance of sample s given the factors (weighted least squares).
double Radiance(const Samples& samples, const std::vector<double>& factor,
                const std::vector<double>& weight, int s) {
  double num = 0.0, den = 0.0;
  for (int k = samples.start[s]; k < samples.start[s + 1]; ++k) {
    const double f = factor[k];
    num += weight[k] * f * samples.obs[k].value;
    den += weight[k] * f * f;
  }
  return den > 0.0 ? num / den : 0.0;
}

// The weighted cost sum w (I - F L)^2 with each sample's radiance re-solved
// for these factors.
double Cost(const Samples& samples, const std::vector<double>& factor,
            const std::vector<double>& weight) {
  std::vector<double> block_cost(samples.num_blocks(), 0.0);
  samples.ForEachBlock([&](int s0, int s1, int block) {
    double cost = 0.0;
    for (int s = s0; s < s1; ++s) {
      const double l = Radiance(samples, factor, weight, s);
      for (int k = samples.start[s]; k < samples.start[s + 1]; ++k) {
        const double r = samples.obs[k].value - factor[k] * l;
        cost += weight[k] * r * r;
      }
    }
    block_cost[block] = cost;
  });
  double cost = 0.0;
  for (const double c : block_cost) cost += c;
  return cost;
}

// The relative residual of each observation from its sample's consensus
// radiance for these factors.
void Residuals(const Samples& samples, const std::vector<double>& factor,
               const std::vector<double>& weight, std::vector<double>* e) {
  e->resize(samples.obs.size());
  samples.ForEachBlock([&](int s0, int s1, int) {
    for (int s = s0; s < s1; ++s) {
      const double l = Radiance(samples, factor, weight, s);
      for (int k = samples.start[s]; k < samples.start[s + 1]; ++k) {
        const double predicted = factor[k] * l;
        (*e)[k] = predicted > 0.0 ? samples.obs[k].value / predicted - 1.0 : 0.0;
      }
    }
  });
}

// The reduced normal equations of one Gauss-Newton step in (a_i, b_i) =
// (g_i, g_i v_i) with the radiances eliminated (variable projection):
// r = I - (a - b rho^2) L, and the radiances are solved here for the current
// exposures and weights (g_L = J_L' W r = 0), so the reduced gradient g is the
// exposures' own. Radiances from before the last re-weighting would leave out
// -H_xL H_LL^-1 g_L: with a few % of gross outliers, whose weights drop 100x,
// the step then went uphill, no halving helped and the fit stopped, 5e-3 off
// in gain. The reduced normal matrix h is H_xx - sum over samples of
// H_xL H_LL^-1 H_Lx (its lower triangle is filled). The alternation this replaces (exposures, then
// radiances) converged linearly at ~0.7 per step: 35 steps on the demo.
void ReducedNormalEquations(const Samples& samples, const std::vector<double>& factor,
                            const std::vector<double>& weight, int num_params, Eigen::MatrixXd* h,
                            Eigen::VectorXd* g) {
  const std::vector<ExposureObservation>& obs = samples.obs;
  std::vector<Eigen::MatrixXd> block_h(samples.num_blocks());
  std::vector<Eigen::VectorXd> block_g(samples.num_blocks());
  samples.ForEachBlock([&](int s0, int s1, int block) {
    Eigen::MatrixXd& hb = block_h[block];
    Eigen::VectorXd& gb = block_g[block];
    hb.setZero(num_params, num_params);
    gb.setZero(num_params);
    // A sample's H_xL entries: parameter index and value, two per observation.
    std::vector<int> xl_index(2 * static_cast<size_t>(samples.max_per_sample));
    std::vector<double> xl_value(xl_index.size());
    for (int s = s0; s < s1; ++s) {
      const double l = Radiance(samples, factor, weight, s);
      double h_ll = 0.0;
      int n = 0;
      for (int k = samples.start[s]; k < samples.start[s + 1]; ++k) {
        const ExposureObservation& o = obs[k];
        const double w = weight[k], f = factor[k];
        const double r = o.value - f * l;
        const int ia = 2 * o.tile, ib = ia + 1;
        const double ja = -l, jb = o.rho2 * l, jl = -f;  // dr/da, dr/db, dr/dL
        hb(ia, ia) += w * ja * ja, hb(ib, ia) += w * jb * ja, hb(ib, ib) += w * jb * jb;
        gb(ia) += w * ja * r, gb(ib) += w * jb * r;
        h_ll += w * jl * jl;
        xl_index[n] = ia, xl_value[n++] = w * ja * jl;
        xl_index[n] = ib, xl_value[n++] = w * jb * jl;
      }
      if (!(h_ll > 0.0)) continue;
      // H_xL H_LL^-1 H_Lx over the lower triangle: each unordered pair of
      // entries once, twice where both are one parameter (a tile seen twice).
      for (int u = 0; u < n; ++u) {
        for (int v = 0; v < u; ++v) {
          const int p = std::max(xl_index[u], xl_index[v]), q = std::min(xl_index[u], xl_index[v]);
          const double term = xl_value[u] * xl_value[v] / h_ll;
          hb(p, q) -= p == q ? term + term : term;
        }
        hb(xl_index[u], xl_index[u]) -= xl_value[u] * xl_value[u] / h_ll;
      }
    }
  });
  h->setZero(num_params, num_params);
  g->setZero(num_params);
  for (int block = 0; block < samples.num_blocks(); ++block) {
    *h += block_h[block];
    *g += block_g[block];
  }
}

// 1.4826 median |e|. With `near_sigma` (the previous iteration's), the
// same value from one counting pass and a selection among the |e| within
// 10 % of it: a selection among all observations on every iteration was half
// of the estimation's time.
double RobustSigma(const std::vector<double>& e, double near_sigma = 0.0) {
  if (e.empty()) return 0.0;
  const size_t rank = e.size() / 2;  // Median's element
  if (near_sigma > 0.0) {
    const double lo = 0.9 * near_sigma / 1.4826, hi = 1.1 * near_sigma / 1.4826;
    size_t below = 0;
    std::vector<double> band;
    for (const double x : e) {
      const double a = std::abs(x);
      below += a < lo;
      if (a >= lo && a <= hi) band.push_back(a);
    }
    if (below <= rank && rank < below + band.size()) {
      const auto mid = band.begin() + static_cast<std::ptrdiff_t>(rank - below);
      std::nth_element(band.begin(), mid, band.end());
      return 1.4826 * *mid;
    }
  }
  std::vector<double> a(e.size());
  for (size_t k = 0; k < e.size(); ++k) a[k] = std::abs(e[k]);
  return 1.4826 * Median(std::move(a));
}

// Largest |median log ratio| of compensated intensities over tile pairs.
double MaxPairStep(const Samples& samples, const std::vector<double>& factor, int num_tiles) {
  const std::vector<ExposureObservation>& obs = samples.obs;
  const std::vector<int>& start = samples.start;
  // ratios[i * num_tiles + j]: the pair (i, j), i < j.
  std::vector<std::vector<double>> ratios(static_cast<size_t>(num_tiles) * num_tiles);
  for (size_t s = 0; s + 1 < start.size(); ++s) {
    for (int a = start[s]; a < start[s + 1]; ++a) {
      for (int b = a + 1; b < start[s + 1]; ++b) {
        const int i = obs[a].tile < obs[b].tile ? a : b;
        const int j = obs[a].tile < obs[b].tile ? b : a;
        ratios[static_cast<size_t>(obs[i].tile) * num_tiles + obs[j].tile].push_back(
            std::log((obs[i].value / factor[i]) / (obs[j].value / factor[j])));
      }
    }
  }
  double step = 0.0;
  for (std::vector<double>& r : ratios) {
    if (r.size() >= 100) step = std::max(step, std::abs(Median(std::move(r))));
  }
  return step;
}

// The observations' samples (runs of one `sample` index, ascending).
Samples GroupSamples(const std::vector<ExposureObservation>& obs, [[maybe_unused]] int num_tiles,
                     int num_threads) {
  Samples samples{obs, {}, 0, num_threads};
  std::vector<int>& start = samples.start;
  for (size_t k = 0; k < obs.size(); ++k) {
    assert(obs[k].tile >= 0 && obs[k].tile < num_tiles);
    assert(obs[k].value > 0.0);
    if (k == 0 || obs[k].sample != obs[k - 1].sample) {
      assert(k == 0 || obs[k].sample > obs[k - 1].sample);
      start.push_back(static_cast<int>(k));
    }
  }
  start.push_back(static_cast<int>(obs.size()));
  for (int s = 0; s < samples.num_samples(); ++s)
    samples.max_per_sample = std::max(samples.max_per_sample, start[s + 1] - start[s]);
  return samples;
}

// The parameters fitted, indices into (a_0, b_0, a_1, b_1, ...): a and b of
// tiles with samples, except the gauge's a (the scale of g L is
// undetermined) and b without vignetting.
std::vector<int> FreeParameters(const std::vector<int>& tile_count, bool estimate_vignetting) {
  std::vector<int> free;
  int gauge = -1;
  for (int i = 0; i < static_cast<int>(tile_count.size()); ++i) {
    if (tile_count[i] == 0) continue;
    if (gauge < 0) {
      gauge = i;
    } else {
      free.push_back(2 * i);
    }
    if (estimate_vignetting) free.push_back(2 * i + 1);
  }
  return free;
}

// The exposures after `step` (over the `free` parameters), halved until the
// weighted cost (radiances re-solved) goes down: far from the solution
// (exposure differences of 2x) a full step can overshoot. nullopt if no
// step down to 1/1000 of it descends.
std::optional<std::vector<TileExposure>> DescendAlong(const Samples& samples,
                                                      const std::vector<TileExposure>& exposure,
                                                      const std::vector<double>& factor,
                                                      const std::vector<double>& weight,
                                                      const std::vector<int>& free,
                                                      const Eigen::VectorXd& step) {
  const double current_cost = Cost(samples, factor, weight);
  std::vector<double> trial_factor;
  for (double scale = 1.0; step.allFinite() && scale > 1e-3; scale *= 0.5) {
    std::vector<TileExposure> trial = exposure;
    bool valid = true;
    for (size_t i = 0; i < exposure.size(); ++i) {
      double a = exposure[i].gain, b = exposure[i].gain * exposure[i].vignetting;
      for (size_t p = 0; p < free.size(); ++p) {
        if (free[p] == 2 * static_cast<int>(i)) a += scale * step(p);
        if (free[p] == 2 * static_cast<int>(i) + 1) b += scale * step(p);
      }
      valid &= a > 0.0;
      trial[i].gain = a;
      trial[i].vignetting = b / a;
    }
    if (!valid) continue;
    Factors(samples, trial, &trial_factor);
    if (Cost(samples, trial_factor, weight) < current_cost) return trial;
  }
  return std::nullopt;
}

// The gauge: the tile of median gain (the lower of two) among those with
// samples keeps gain 1. Its index. The median is a continuous function of
// the gains, so the scale does not jump between iterations.
int NormaliseGains(const std::vector<int>& tile_count, std::vector<TileExposure>* exposure) {
  std::vector<TileExposure>& e = *exposure;
  std::vector<int> with_samples;
  for (size_t i = 0; i < e.size(); ++i) {
    if (tile_count[i] > 0) with_samples.push_back(static_cast<int>(i));
  }
  const auto median = with_samples.begin() + (with_samples.size() - 1) / 2;
  std::nth_element(with_samples.begin(), median, with_samples.end(),
                   [&e](int a, int b) { return e[a].gain < e[b].gain; });
  const int reference = *median;
  const double scale = e[reference].gain;
  for (const int i : with_samples) e[i].gain /= scale;
  return reference;
}

}  // namespace

ExposureSummary EstimateExposure(const std::vector<ExposureObservation>& obs, int num_tiles,
                                 const ExposureOptions& options) {
  assert(options.Check().empty());
  ExposureSummary summary;
  summary.tiles.assign(num_tiles, TileExposure{});
  const Samples samples = GroupSamples(obs, num_tiles, options.num_threads);
  summary.num_samples = samples.num_samples();
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
  std::vector<double> weight(obs.size(), 1.0), factor, e;
  Factors(samples, exposure, &factor);
  Residuals(samples, factor, weight, &e);
  summary.relative_sigma_before = RobustSigma(e);
  summary.max_pair_step_before = MaxPairStep(samples, factor, num_tiles);

  double sigma = 0.0;  // robust sigma of the last iteration's residuals
  const int num_params = 2 * num_tiles;
  const std::vector<int> free = FreeParameters(tile_count, options.estimate_vignetting);
  const int nf = static_cast<int>(free.size());
  for (summary.iterations = 1; summary.iterations <= options.max_iterations; ++summary.iterations) {
    Eigen::MatrixXd h;
    Eigen::VectorXd g;
    ReducedNormalEquations(samples, factor, weight, num_params, &h, &g);
    Eigen::MatrixXd hf(nf, nf);
    Eigen::VectorXd gf(nf);
    for (int p = 0; p < nf; ++p) {
      gf(p) = g(free[p]);
      for (int q = 0; q < nf; ++q) {
        hf(p, q) = free[p] >= free[q] ? h(free[p], free[q]) : h(free[q], free[p]);
      }
    }
    const Eigen::VectorXd step = hf.ldlt().solve(-gf);
    const std::optional<std::vector<TileExposure>> descended =
        DescendAlong(samples, exposure, factor, weight, free, step);
    std::vector<TileExposure> next = descended.value_or(exposure);
    // No descent with a step this small is the optimum (rounding); with a
    // larger one the fit is stuck away from it (a and b are g and g v, so
    // the step compares with the tolerance on g and v).
    const bool stalled = !descended && !(step.cwiseAbs().maxCoeff() < options.tolerance);
    summary.reference_tile = NormaliseGains(tile_count, &next);

    double change = 0.0;
    for (int i = 0; i < num_tiles; ++i) {
      change = std::max({change, std::abs(next[i].gain - exposure[i].gain),
                         std::abs(next[i].vignetting - exposure[i].vignetting)});
    }
    exposure = next;
    Factors(samples, exposure, &factor);
    Residuals(samples, factor, weight, &e);
    sigma = RobustSigma(e, sigma);
    const double c = options.cauchy_sigmas * std::max(sigma, 1e-6);
    for (size_t k = 0; k < obs.size(); ++k) weight[k] = 1.0 / (1.0 + (e[k] / c) * (e[k] / c));
    if (stalled) break;
    if (change < options.tolerance) {
      summary.converged = true;
      break;
    }
  }
  summary.iterations = std::min(summary.iterations, options.max_iterations);
  // e: the residuals of the final exposures and radiances.
  summary.relative_sigma_after = RobustSigma(e);
  summary.max_pair_step_after = MaxPairStep(samples, factor, num_tiles);
  summary.usable = summary.tiles_without_samples.empty();
  char line[320];
  std::snprintf(line, sizeof(line),
                "exposure: %d samples, %d iterations%s; relative sigma %.4f -> %.4f, "
                "largest pair step %.4f -> %.4f%s",
                summary.num_samples, summary.iterations,
                summary.converged ? "" : " (stopped before converging)",
                summary.relative_sigma_before, summary.relative_sigma_after,
                summary.max_pair_step_before, summary.max_pair_step_after,
                summary.usable ? "" : "; some tiles share no samples (left as recorded)");
  summary.brief = line;
  return summary;
}

}  // namespace omm
