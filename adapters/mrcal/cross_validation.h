// Choosing a lens model by cross-validation (mrcal's recommended check of a
// model's fit, http://mrcal.secretsauce.net/tour-cross-validation.html).
//
// The usable images are split into two halves (the alternating split, then
// num_random_splits seeded random ones). For each candidate model, each half
// is calibrated on its own and the halves' projections are compared over the
// imager at the working distance with the best rigid transform fitted
// (projection_diff.h). A model that fits the lens leaves only the noise in
// that difference; a model too simple leaves its systematic error, which
// differs between halves that see the plate in different places. The winner
// has the lowest mean difference; candidates within tie_fraction of the
// lowest count as tied and the one with the fewest parameters wins.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "adapters/mrcal/calibrate.h"
#include "pipeline/core/board.h"
#include "pipeline/core/plate_observation.h"

namespace omm {

struct CrossValidationOptions {
  CalibrationOptions calibration;  // lens_model is replaced by each candidate
  double distance_mm = 390.0;      // working distance, range along the ray
  int num_random_splits = 2;       // random half-splits besides the alternating one
  uint32_t seed = 1;               // for the random splits
  double tie_fraction = 0.1;       // within (1 + tie_fraction) * best: a tie
  int grid_nx = 40;                // comparison grid over the imager
  int grid_ny = 30;

  std::string Check() const;
};

struct LensModelScore {
  std::string lens_model;
  int num_params = 0;
  bool usable = false;                // every half calibrated
  std::vector<double> diff_rms_px;    // per split, halves compared
  double mean_diff_rms_px = 0.0;
  std::vector<double> half_rms_px;    // reprojection rms of each half's solve
};

struct CrossValidationSummary {
  std::string chosen_lens_model;  // empty if no candidate was usable
  std::vector<LensModelScore> scores;  // in the order of the candidates
  std::string brief;  // one line: the winner, its diff, the runner-up's
};

// Throws InputError on bad options or an empty candidate list.
CrossValidationSummary CrossValidateLensModels(const BoardSpec& board,
                                               const std::vector<PlateObservation>& observations,
                                               const std::vector<std::string>& candidates,
                                               const CrossValidationOptions& options);

}  // namespace omm
