// The image-count study of the seed paper ("how many images suffice"):
// calibrate on random subsets of l = min_l..N of the usable (bias-corrected)
// observations and watch how the spread of the intrinsics shrinks with l.
//
// For each l, num_subsets seeded random subsets (one for l = N) are solved
// with the stage's lens model; the spread of a parameter at l is the standard
// deviation (ddof 1) of its solved values over the subsets.
//
// Stopping rule. If every image carried the same information, the estimate
// from l images would scatter as sigma_1 / sqrt(l), and l-subsets drawn
// without replacement from N images scatter about their mean as
//     spread_ideal(l) = sigma_N sqrt(N / l - 1),
// with sigma_N the full solve's own 1-sigma (its covariance, uncertainty.h).
// With few images the problem is badly conditioned (focal length against
// distance, distortion against coverage of the field) and the spread is far
// above that. The images "suffice" from the smallest l at which the spread of
// f, cx and cy is within `tolerance` x spread_ideal(l) and stays so for every
// larger l <= N - 2: beyond it more images only average noise at the
// 1/sqrt(l) rate. tolerance absorbs the scatter of a standard deviation
// estimated from num_subsets values: 1.55 is the one-sided 99% point of s/sigma
// for 10 values (sqrt(chi2_9(0.99) / 9)). The distortion terms' spreads are
// reported, not judged (see study.cc).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "pipeline/core/board.h"
#include "pipeline/core/camera.h"
#include "pipeline/core/plate_observation.h"
#include "pipeline/core/project.h"

namespace omm {

struct ImageCountStudyOptions {
  int min_images = 3;    // smallest subset size l (mrcal needs >= 2; 2 is hopeless for OPENCV8)
  int num_subsets = 10;  // random subsets per l
  std::uint32_t seed = 1;
  double tolerance = 1.55;       // spread within this x spread_ideal(l)
  int max_distortion_terms = 8;  // report at most this many (splined models: none)

  std::string Check() const;
};

struct StudyParameter {
  std::string name;                  // "fx", "cx", "cy", "k1", ...
  int index = 0;                     // in the intrinsics vector
  double full_sigma = 0.0;           // the full solve's 1-sigma (px or unitless)
  std::vector<double> spread;        // per l (parallel to ImageCountStudy::num_images)
  std::vector<double> spread_ideal;  // sigma_N sqrt(N / l - 1)
};

struct ImageCountStudy {
  bool usable = false;
  std::string brief;
  std::string lens_model;
  std::vector<int> num_images;  // l
  std::vector<int> num_solved;  // subsets that solved, per l
  std::vector<StudyParameter> parameters;
  int suffices_from = 0;  // the rule's l (0 if never met)
  std::string rule;       // the rule in words, for the report
  double seconds = 0.0;
};

// `observations`: the stage's final (bias-corrected) observations; unusable
// ones are skipped. `camera` is the final camera (lens model and imager size);
// `full_intrinsics_sigma` the full solve's 1-sigma per intrinsic (may be empty:
// then no rule is applied).
ImageCountStudy StudyImageCount(const std::vector<PlateObservation>& observations,
                                const BoardSpec& board, const CameraSpec& nominal,
                                const CameraModel& camera,
                                const Eigen::VectorXd& full_intrinsics_sigma,
                                const ImageCountStudyOptions& options);

}  // namespace omm
