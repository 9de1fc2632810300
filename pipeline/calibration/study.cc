#include "pipeline/calibration/study.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <random>
#include <sstream>

#include <fmt/format.h>

#include "adapters/mrcal/calibrate.h"

namespace omm {
namespace {

// mrcal's parameter order of the LENSMODEL_OPENCVn models.
constexpr const char* kOpencvNames[] = {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2",   "k3",
                                        "k4", "k5", "k6", "s1", "s2", "s3", "s4", "taux", "tauy"};

double StdDev(const std::vector<double>& values) {
  if (values.size() < 2) return 0.0;
  double mean = 0.0;
  for (double v : values) mean += v;
  mean /= static_cast<double>(values.size());
  double sum_sq = 0.0;
  for (double v : values) sum_sq += (v - mean) * (v - mean);
  return std::sqrt(sum_sq / static_cast<double>(values.size() - 1));
}

}  // namespace

std::string ImageCountStudyOptions::Check() const {
  std::ostringstream what;
  if (min_images < 2) what << "min_images must be >= 2; ";
  if (num_subsets < 2) what << "num_subsets must be >= 2; ";
  if (!(tolerance >= 1.0)) what << "tolerance must be >= 1; ";
  if (max_distortion_terms < 0) what << "max_distortion_terms must be >= 0; ";
  return what.str();
}

ImageCountStudy StudyImageCount(const std::vector<PlateObservation>& observations,
                                const BoardSpec& board, const CameraSpec& nominal,
                                const CameraModel& camera,
                                const Eigen::VectorXd& full_intrinsics_sigma,
                                const ImageCountStudyOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  ImageCountStudy study;
  study.lens_model = camera.lens_model;
  std::vector<PlateObservation> usable;
  for (const PlateObservation& o : observations) {
    if (o.usable) usable.push_back(o);
  }
  const int n = static_cast<int>(usable.size());
  if (n <= options.min_images) {
    study.brief = fmt::format("{} usable image(s): too few for a study from {} images", n,
                              options.min_images);
    return study;
  }

  // Which parameters: fx, cx, cy, and the first distortion terms of a parametric model.
  std::vector<int> indices = {0, 2, 3};
  const bool parametric = camera.lens_model.rfind("LENSMODEL_OPENCV", 0) == 0;
  if (parametric) {
    const int num_distortions =
        std::min<int>(static_cast<int>(camera.intrinsics.size()) - 4, options.max_distortion_terms);
    for (int k = 0; k < num_distortions; ++k) indices.push_back(4 + k);
  }
  for (int index : indices) {
    StudyParameter parameter;
    parameter.index = index;
    parameter.name = index < static_cast<int>(std::size(kOpencvNames)) ? kOpencvNames[index]
                                                                       : fmt::format("p{}", index);
    if (full_intrinsics_sigma.size() > index) parameter.full_sigma = full_intrinsics_sigma(index);
    study.parameters.push_back(parameter);
  }

  CalibrationOptions solve;
  solve.lens_model = camera.lens_model;
  solve.focal_length_mm = nominal.focal_length_mm;
  solve.pixel_pitch_um = nominal.pixel_pitch_um;
  solve.width_px = camera.width_px;
  solve.height_px = camera.height_px;
  solve.min_images = 2;

  std::mt19937 random(options.seed);
  std::vector<int> order(n);
  for (int l = options.min_images; l <= n; ++l) {
    const int num_subsets = l == n ? 1 : options.num_subsets;
    std::vector<std::vector<double>> values(study.parameters.size());
    int solved = 0;
    for (int s = 0; s < num_subsets; ++s) {
      for (int i = 0; i < n; ++i) order[i] = i;
      std::shuffle(order.begin(), order.end(), random);
      std::sort(order.begin(), order.begin() + l);
      std::vector<PlateObservation> subset;
      for (int i = 0; i < l; ++i) subset.push_back(usable[order[i]]);
      const CalibrationResult result = CalibrateCamera(board, subset, solve);
      if (!result.usable) continue;
      ++solved;
      for (size_t p = 0; p < study.parameters.size(); ++p) {
        values[p].push_back(result.camera.intrinsics(study.parameters[p].index));
      }
    }
    study.num_images.push_back(l);
    study.num_solved.push_back(solved);
    for (size_t p = 0; p < study.parameters.size(); ++p) {
      StudyParameter& parameter = study.parameters[p];
      parameter.spread.push_back(StdDev(values[p]));
      parameter.spread_ideal.push_back(parameter.full_sigma *
                                       std::sqrt(std::max(0.0, static_cast<double>(n) / l - 1.0)));
    }
  }

  study.rule = fmt::format(
      "smallest l from which on (up to N - 2 = {}) the spread over {} random l-image subsets of f, "
      "cx and cy is within {:.2f}x sigma_N sqrt(N/l - 1), the spread that noise averaging alone "
      "predicts from the full solve's 1-sigma sigma_N",
      n - 2, options.num_subsets, options.tolerance);
  // The rule looks at the core (f, cx, cy, the first three parameters): the
  // individual distortion terms of the rational models are strongly
  // correlated with each other and shaped by mrcal's regularisation, so their
  // spreads are reported but not judged.
  const bool have_sigma = std::all_of(study.parameters.begin(), study.parameters.begin() + 3,
                                      [](const StudyParameter& p) { return p.full_sigma > 0; });
  if (have_sigma) {
    // Scan down from l = N - 2 while the rule holds. (At l = N - 1 the
    // subsets differ by one image: their spread measures that image's
    // influence, not the count.)
    for (int k = static_cast<int>(study.num_images.size()) - 3; k >= 0; --k) {
      bool within = study.num_solved[k] >= 2;
      for (size_t p = 0; p < 3; ++p) {
        const StudyParameter& parameter = study.parameters[p];
        within = within && parameter.spread[k] <= options.tolerance * parameter.spread_ideal[k];
      }
      if (!within) break;
      study.suffices_from = study.num_images[k];
    }
  } else {
    study.rule += " (not applied: the full solve's uncertainty is not available)";
  }
  study.usable = true;
  study.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  study.brief = study.suffices_from > 0
                    ? fmt::format("{} images suffice ({} usable; {} subsets per size, {:.1f} s)",
                                  study.suffices_from, n, options.num_subsets, study.seconds)
                    : fmt::format("no subset size met the rule ({} usable images, {:.1f} s)", n,
                                  study.seconds);
  return study;
}

}  // namespace omm
