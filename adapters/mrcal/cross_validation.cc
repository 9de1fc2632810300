#include "adapters/mrcal/cross_validation.h"

#include <algorithm>
#include <limits>
#include <numeric>
#include <random>
#include <sstream>

#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/projection_diff.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

using Split = std::pair<std::vector<PlateObservation>, std::vector<PlateObservation>>;

std::vector<Split> MakeSplits(const std::vector<PlateObservation>& usable, int num_random,
                              uint32_t seed) {
  std::vector<Split> splits;
  Split alternating;
  for (size_t i = 0; i < usable.size(); ++i) {
    (i % 2 == 0 ? alternating.first : alternating.second).push_back(usable[i]);
  }
  splits.push_back(alternating);
  std::mt19937 rng(seed);
  for (int s = 0; s < num_random; ++s) {
    std::vector<size_t> order(usable.size());
    std::iota(order.begin(), order.end(), 0);
    std::shuffle(order.begin(), order.end(), rng);
    Split split;
    for (size_t k = 0; k < order.size(); ++k) {
      (k < order.size() / 2 ? split.first : split.second).push_back(usable[order[k]]);
    }
    splits.push_back(split);
  }
  return splits;
}

}  // namespace

std::string CrossValidationOptions::Check() const {
  std::ostringstream what;
  CalibrationOptions probe = calibration;
  probe.lens_model = "LENSMODEL_OPENCV4";  // candidates are checked one by one
  what << probe.Check();
  if (!(distance_mm > 0.0)) what << "distance_mm must be > 0; ";
  if (num_random_splits < 0) what << "num_random_splits must be >= 0; ";
  if (!(tie_fraction >= 0.0)) what << "tie_fraction must be >= 0; ";
  if (grid_nx < 2 || grid_ny < 2) what << "grid_nx and grid_ny must be >= 2; ";
  return what.str();
}

CrossValidationSummary CrossValidateLensModels(const BoardSpec& board,
                                               const std::vector<PlateObservation>& observations,
                                               const std::vector<std::string>& candidates,
                                               const CrossValidationOptions& options) {
  if (const std::string what = options.Check(); !what.empty()) {
    throw InputError("cross-validation options", what);
  }
  if (candidates.empty()) throw InputError("cross-validation options", "no candidate lens models");
  for (const std::string& candidate : candidates) {
    if (!IsValidLensModel(candidate)) {
      throw InputError("cross-validation options",
                       "candidate '" + candidate + "' is not a configured mrcal lens model");
    }
  }
  std::vector<PlateObservation> usable;
  for (const PlateObservation& observation : observations) {
    if (observation.usable) usable.push_back(observation);
  }
  const std::vector<Split> splits = MakeSplits(usable, options.num_random_splits, options.seed);

  CrossValidationSummary summary;
  for (const std::string& candidate : candidates) {
    LensModelScore score;
    score.lens_model = candidate;
    score.num_params = LensModelNumParams(candidate);
    score.usable = true;
    CalibrationOptions calibration = options.calibration;
    calibration.lens_model = candidate;
    for (const Split& split : splits) {
      const CalibrationResult a = CalibrateCamera(board, split.first, calibration);
      const CalibrationResult b = CalibrateCamera(board, split.second, calibration);
      if (!a.usable || !b.usable) {
        score.usable = false;
        break;
      }
      score.half_rms_px.push_back(a.rms_px);
      score.half_rms_px.push_back(b.rms_px);
      score.diff_rms_px.push_back(ProjectionDiffRms(a.camera, b.camera, options.distance_mm,
                                                    options.grid_nx, options.grid_ny));
    }
    if (score.usable) {
      score.mean_diff_rms_px =
          std::accumulate(score.diff_rms_px.begin(), score.diff_rms_px.end(), 0.0) /
          static_cast<double>(score.diff_rms_px.size());
    }
    summary.scores.push_back(score);
  }

  double best = std::numeric_limits<double>::infinity();
  for (const LensModelScore& score : summary.scores) {
    if (score.usable) best = std::min(best, score.mean_diff_rms_px);
  }
  const LensModelScore* chosen = nullptr;
  const LensModelScore* runner_up = nullptr;
  for (const LensModelScore& score : summary.scores) {
    if (!score.usable || score.mean_diff_rms_px > (1.0 + options.tie_fraction) * best) continue;
    if (chosen == nullptr || score.num_params < chosen->num_params) chosen = &score;
  }
  std::ostringstream brief;
  brief.precision(3);
  if (chosen == nullptr) {
    brief << "no candidate lens model could be calibrated on both halves";
  } else {
    summary.chosen_lens_model = chosen->lens_model;
    for (const LensModelScore& score : summary.scores) {
      if (&score == chosen || !score.usable) continue;
      if (runner_up == nullptr || score.mean_diff_rms_px < runner_up->mean_diff_rms_px) {
        runner_up = &score;
      }
    }
    brief << chosen->lens_model << ": halves differ by " << chosen->mean_diff_rms_px
          << " px rms at " << options.distance_mm << " mm";
    if (runner_up) {
      brief << " (" << runner_up->lens_model << ": " << runner_up->mean_diff_rms_px << " px)";
    }
  }
  summary.brief = brief.str();
  return summary;
}

}  // namespace omm
