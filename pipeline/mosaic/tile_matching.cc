#include "pipeline/mosaic/tile_matching.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <sstream>
#include <vector>

#include <Eigen/Dense>

#include "pipeline/core/parallel_for.h"
#include "pipeline/core/statistics.h"
#include "pipeline/mosaic/cross_correlation.h"
#include "pipeline/mosaic/tile_features.h"

namespace omm {

std::string ImageMotionOptions::Check() const {
  if (coarse_max_size_px < 16) return "motion.coarse_max_size_px must be >= 16";
  if (!(min_overlap_fraction > 0 && min_overlap_fraction < 1))
    return "motion.min_overlap_fraction must be in (0, 1)";
  if (finest_factor < 1) return "motion.finest_factor must be >= 1";
  if (peaks_per_pair < 1) return "motion.peaks_per_pair must be >= 1";
  if (!(tolerance_fraction >= 0)) return "motion.tolerance_fraction must be >= 0";
  if (!(tolerance_px > 0)) return "motion.tolerance_px must be > 0";
  if (!(min_margin >= 1)) return "motion.min_margin must be >= 1";
  if (num_threads < 1) return "motion.num_threads must be >= 1";
  return {};
}

std::string PatchMatchOptions::Check() const {
  if (half_size_px < 3) return "patch.half_size_px must be >= 3";
  if (!(min_ncc > 0 && min_ncc < 1)) return "patch.min_ncc must be in (0, 1)";
  if (!(min_template_std >= 0)) return "patch.min_template_std must be >= 0";
  if (max_iterations < 1) return "patch.max_iterations must be >= 1";
  if (!(convergence_px > 0)) return "patch.convergence_px must be > 0";
  if (!(max_refinement_px > 0)) return "patch.max_refinement_px must be > 0";
  if (!(robust_tukey_c >= 0)) return "patch.robust_tukey_c must be >= 0";
  if (max_robust_iterations < 1) return "patch.max_robust_iterations must be >= 1";
  return {};
}

namespace {

// Tukey's biweight w = (1 - (e / (c s))^2)^2 for |e| < c s, else 0, with the
// robust scale s = 1.4826 median |e| (the residuals of a fit with an offset
// centre on 0). All ones when s is 0 (an exact fit).
Eigen::VectorXd TukeyWeights(const Eigen::VectorXd& residual, double c) {
  std::vector<double> magnitude(residual.size());
  for (Eigen::Index i = 0; i < residual.size(); ++i) magnitude[i] = std::abs(residual(i));
  const double cut = c * 1.4826 * Median(std::move(magnitude));
  if (!(cut > 0)) return Eigen::VectorXd::Ones(residual.size());
  return (1 - (residual.array() / cut).square()).max(0.0).square();
}

// Whether TukeyWeights(residual, c) is positive everywhere, by counting
// instead of a median (most templates end their robust phase here):
// max |e| < c 1.4826 median |e| when at most n / 2 of the |e| lie at or below
// max |e| / (c 1.4826) (Median takes the element n / 2); or the median is 0.
bool TukeyKeepsAll(const Eigen::VectorXd& residual, double c) {
  const Eigen::ArrayXd magnitude = residual.array().abs();
  const double level = magnitude.maxCoeff() / (c * 1.4826);
  const Eigen::Index half = residual.size() / 2;
  return (magnitude <= level).count() <= half || (magnitude == 0.0).count() > half;
}

// Summed-area tables of an image's values and squares (double): the sum and
// the sum of squares over any rectangle in O(1).
class WindowMoments {
 public:
  explicit WindowMoments(const ImageF& image);
  // Over rows [r0, r1), columns [c0, c1).
  double Sum(int r0, int r1, int c0, int c1) const { return Box(sum_, r0, r1, c0, c1); }
  double SumSq(int r0, int r1, int c0, int c1) const { return Box(sum_sq_, r0, r1, c0, c1); }

 private:
  double Box(const std::vector<double>& t, int r0, int r1, int c0, int c1) const {
    return t[r1 * stride_ + c1] - t[r0 * stride_ + c1] - t[r1 * stride_ + c0] +
           t[r0 * stride_ + c0];
  }
  int stride_;
  std::vector<double> sum_, sum_sq_;
};

WindowMoments::WindowMoments(const ImageF& image)
    : stride_(static_cast<int>(image.cols()) + 1),
      sum_(static_cast<size_t>(stride_) * (image.rows() + 1), 0.0),
      sum_sq_(sum_.size(), 0.0) {
  for (int r = 0; r < image.rows(); ++r) {
    double acc = 0, acc_sq = 0;
    for (int c = 0; c < image.cols(); ++c) {
      const double v = image(r, c);
      acc += v, acc_sq += v * v;
      sum_[(r + 1) * stride_ + c + 1] = sum_[r * stride_ + c + 1] + acc;
      sum_sq_[(r + 1) * stride_ + c + 1] = sum_sq_[r * stride_ + c + 1] + acc_sq;
    }
  }
}

// NCC of a and b over their overlap when b is shifted by (dx, dy): a(r, c)
// against b(r + dy, c + dx), from the cross sum sab over that overlap (null:
// summed here). -2 if the overlap is smaller than min_pixels.
double OverlapNcc(const ImageF& a, const ImageF& b, const WindowMoments& ma,
                  const WindowMoments& mb, int dx, int dy, Eigen::Index min_pixels,
                  double* overlap_fraction = nullptr, const double* cross_sum = nullptr) {
  const int c0 = std::max(0, -dx), c1 = std::min<int>(a.cols(), b.cols() - dx);
  const int r0 = std::max(0, -dy), r1 = std::min<int>(a.rows(), b.rows() - dy);
  if (c1 <= c0 || r1 <= r0) return -2.0;
  const Eigen::Index n = static_cast<Eigen::Index>(c1 - c0) * (r1 - r0);
  if (n < min_pixels) return -2.0;
  double sab = 0;
  if (cross_sum != nullptr) {
    sab = *cross_sum;
  } else {
    for (int r = r0; r < r1; ++r) {
      const float* pa = a.data() + static_cast<size_t>(r) * a.cols();
      const float* pb = b.data() + static_cast<size_t>(r + dy) * b.cols() + dx;
      // Eigen's dot product vectorises the float sum (a plain loop cannot be
      // reordered without -ffast-math).
      sab += Eigen::Map<const Eigen::VectorXf>(pa + c0, c1 - c0)
                 .dot(Eigen::Map<const Eigen::VectorXf>(pb + c0, c1 - c0));
    }
  }
  const double sa = ma.Sum(r0, r1, c0, c1), saa = ma.SumSq(r0, r1, c0, c1);
  const double sb = mb.Sum(r0 + dy, r1 + dy, c0 + dx, c1 + dx);
  const double sbb = mb.SumSq(r0 + dy, r1 + dy, c0 + dx, c1 + dx);
  const double inv_n = 1.0 / static_cast<double>(n);
  const double var_a = saa - sa * sa * inv_n, var_b = sbb - sb * sb * inv_n;
  if (overlap_fraction != nullptr) *overlap_fraction = static_cast<double>(n) / a.size();
  if (var_a <= 0 || var_b <= 0) return -2.0;
  return (sab - sa * sb * inv_n) / std::sqrt(var_a * var_b);
}

// One level of a tile's pyramid: box-downsampled by `factor`, with moments.
struct Level {
  Level(ImageF downsampled, int f) : factor(f), image(std::move(downsampled)), moments(image) {}
  int factor;
  ImageF image;
  WindowMoments moments;
};

// Levels from the coarsest (larger side <= coarse_max_size_px) down to
// finest_factor, each factor half the previous (rounded down).
std::vector<Level> Pyramid(const ImageF& tile, const ImageMotionOptions& options) {
  const int largest = static_cast<int>(std::max(tile.rows(), tile.cols()));
  const int coarse_factor =
      std::max(1, (largest + options.coarse_max_size_px - 1) / options.coarse_max_size_px);
  // Every level high-passed by the coarsest level's blur (bilinearly
  // upsampled to the finer ones, which is cheap): vignetting and shading
  // would otherwise correlate at any shift that overlaps two bright centres,
  // and pull the refined shifts.
  const ImageF coarsest = DownsampleBox(tile, coarse_factor);
  const ImageF low = options.coarse_highpass_sigma_px > 0
                         ? GaussianBlur(coarsest, options.coarse_highpass_sigma_px)
                         : ImageF::Zero(coarsest.rows(), coarsest.cols());
  std::vector<Level> levels;
  for (int factor = coarse_factor;; factor = std::max(options.finest_factor, factor / 2)) {
    ImageF image = DownsampleBox(tile, factor);
    // A level pixel's centre in coarsest pixels (centres at integers),
    // clamped: the two neighbours and the weight of the second.
    const auto locate = [&](int i, Eigen::Index n, int* i0, int* i1, double* w) {
      const double v =
          std::clamp((factor * i + 0.5 * (factor - 1) - 0.5 * (coarse_factor - 1)) / coarse_factor,
                     0.0, static_cast<double>(n - 1));
      *i0 = static_cast<int>(v);
      *i1 = std::min<int>(*i0 + 1, static_cast<int>(n) - 1);
      *w = v - *i0;
    };
    for (int r = 0; r < image.rows(); ++r) {
      int y0, y1;
      double fy;
      locate(r, low.rows(), &y0, &y1, &fy);
      for (int c = 0; c < image.cols(); ++c) {
        int x0, x1;
        double fx;
        locate(c, low.cols(), &x0, &x1, &fx);
        image(r, c) -= static_cast<float>((1 - fy) * ((1 - fx) * low(y0, x0) + fx * low(y0, x1)) +
                                          fy * ((1 - fx) * low(y1, x0) + fx * low(y1, x1)));
      }
    }
    levels.emplace_back(std::move(image), factor);
    if (factor <= options.finest_factor) break;
  }
  return levels;
}

// The best NCC of two levels over the integer shifts within +-radius of
// `center` (level px); ncc -2 if no shift overlaps enough.
struct LocalBest {
  Eigen::Vector2i shift = Eigen::Vector2i::Zero();
  double ncc = -2.0;
};
LocalBest SearchShift(const Level& a, const Level& b, const Eigen::Vector2i& center, int radius,
                      double min_overlap_fraction) {
  const auto min_pixels = static_cast<Eigen::Index>(min_overlap_fraction * a.image.size());
  LocalBest best;
  for (int dy = center.y() - radius; dy <= center.y() + radius; ++dy) {
    for (int dx = center.x() - radius; dx <= center.x() + radius; ++dx) {
      const double ncc = OverlapNcc(a.image, b.image, a.moments, b.moments, dx, dy, min_pixels);
      if (ncc > best.ncc) best.ncc = ncc, best.shift << dx, dy;
    }
  }
  return best;
}

// A similarity with handedness m (+-1) taking the table displacement dt_mm
// to the image shift shift_px: A = [[a, -b], [b, a]] diag(1, m).
Eigen::Matrix2d SimilarityThrough(const Eigen::Vector2d& dt_mm, const Eigen::Vector2d& shift_px,
                                  int m) {
  const std::complex<double> z = std::complex<double>(shift_px.x(), shift_px.y()) /
                                 std::complex<double>(dt_mm.x(), m * dt_mm.y());
  Eigen::Matrix2d a;
  a << z.real(), -m * z.imag(), z.imag(), m * z.real();
  return a;
}

// The similarity with handedness m fitted (least squares) to shift_px[k] ~ A dt_mm[k]
// over the pairs ks: shift = [[a, -b], [b, a]] v, v = diag(1, m) dt, linear in (a, b).
Eigen::Matrix2d FitSimilarity(const std::vector<Eigen::Vector2d>& dt_mm,
                              const std::vector<Eigen::Vector2d>& shift_px,
                              const std::vector<int>& ks, int m) {
  Eigen::Matrix2d n = Eigen::Matrix2d::Zero();
  Eigen::Vector2d rhs = Eigen::Vector2d::Zero();
  for (int k : ks) {
    const Eigen::Vector2d v(dt_mm[k].x(), m * dt_mm[k].y());
    Eigen::Matrix2d j;
    j << v.x(), -v.y(), v.y(), v.x();
    n += j.transpose() * j;
    rhs += j.transpose() * shift_px[k];
  }
  const Eigen::Vector2d ab = n.ldlt().solve(rhs);
  Eigen::Matrix2d a;
  a << ab(0), -m * ab(1), ab(1), m * ab(0);
  return a;
}

// A pair's evidence for a motion from its NCC there: Fisher's z = atanh(ncc)
// (correlations add as z, not as r: 0.99 against 0.9 is a large difference),
// 0 for negative NCC, capped at atanh(0.99) so that a near-perfect match of
// a dark region does not outweigh the other pairs.
double Evidence(double ncc) { return std::atanh(std::clamp(ncc, 0.0, 0.99)); }

// How far from its predicted shift a pair still agrees with a motion, px.
double Tolerance(const ImageMotionOptions& options, const Eigen::Vector2d& predicted_px) {
  return options.tolerance_fraction * predicted_px.norm() + options.tolerance_px;
}

// Step 1 for a pair: the NCC of its coarsest levels at every shift (-2
// where they overlap too little), and the strongest local maxima.
struct CoarseSurface {
  int rows = 0, cols = 0;   // the coarsest level's size: shifts within +-(rows - 1, cols - 1)
  std::vector<double> ncc;  // at (dx, dy): [(dy + rows - 1) (2 cols - 1) + dx + cols - 1]
  std::vector<std::pair<double, Eigen::Vector2i>> peaks;  // (ncc, shift), best first

  double At(int dx, int dy) const {
    return ncc[static_cast<size_t>((dy + rows - 1) * (2 * cols - 1) + dx + cols - 1)];
  }
};

// `sa`, `sb`: the levels' spectra, zero-padded to fft_rows x fft_cols.
CoarseSurface CoarseNccSurface(const Level& a, const Level& b, const Spectrum& sa,
                               const Spectrum& sb, int fft_rows, int fft_cols,
                               const ImageMotionOptions& options) {
  CoarseSurface surface;
  const int rows = surface.rows = static_cast<int>(a.image.rows());
  const int cols = surface.cols = static_cast<int>(a.image.cols());
  const int grid_w = 2 * cols - 1, grid_h = 2 * rows - 1;
  const auto min_pixels = static_cast<Eigen::Index>(options.min_overlap_fraction * a.image.size());
  const std::vector<double> cross = CrossSums(sa, sb, fft_rows, fft_cols);
  surface.ncc.assign(static_cast<size_t>(grid_w) * grid_h, -2.0);
  for (int dy = -rows + 1; dy < rows; ++dy) {
    for (int dx = -cols + 1; dx < cols; ++dx) {
      const double sab = cross[static_cast<size_t>((dy + fft_rows) % fft_rows) * fft_cols +
                               (dx + fft_cols) % fft_cols];
      surface.ncc[(dy + rows - 1) * grid_w + dx + cols - 1] =
          OverlapNcc(a.image, b.image, a.moments, b.moments, dx, dy, min_pixels, nullptr, &sab);
    }
  }
  std::vector<std::pair<double, Eigen::Vector2i>>& maxima = surface.peaks;
  for (int y = 0; y < grid_h; ++y) {
    for (int x = 0; x < grid_w; ++x) {
      const double v = surface.ncc[y * grid_w + x];
      if (v <= -1.0) continue;
      bool is_max = true;
      for (int ny = std::max(0, y - 1); ny <= std::min(grid_h - 1, y + 1) && is_max; ++ny)
        for (int nx = std::max(0, x - 1); nx <= std::min(grid_w - 1, x + 1); ++nx)
          if (surface.ncc[ny * grid_w + nx] > v) is_max = false;
      if (is_max) maxima.emplace_back(v, Eigen::Vector2i(x - cols + 1, y - rows + 1));
    }
  }
  const size_t keep = std::min<size_t>(options.peaks_per_pair, maxima.size());
  std::partial_sort(maxima.begin(), maxima.begin() + keep, maxima.end(),
                    [](const auto& x, const auto& y) { return x.first > y.first; });
  maxima.resize(keep);
  return surface;
}

// Step 2's candidate motion and, per pair, the best coarse shift near what
// it predicts.
struct Candidate {
  Eigen::Matrix2d a;
  int mirror;
  double score = 0.0;
  std::vector<LocalBest> at;
};

// Every pair's peaks, with either handedness, as candidates.
std::vector<Candidate> CandidateMotions(const std::vector<Eigen::Vector2d>& dt_mm,
                                        const std::vector<CoarseSurface>& surfaces,
                                        int coarse_factor) {
  std::vector<Candidate> candidates;
  for (size_t k = 0; k < surfaces.size(); ++k) {
    if (!(dt_mm[k].norm() > 0)) continue;
    for (const auto& peak : surfaces[k].peaks) {
      for (const int m : {1, -1}) {
        Candidate c;
        c.a = SimilarityThrough(dt_mm[k], coarse_factor * peak.second.cast<double>(), m);
        c.mirror = m;
        candidates.push_back(c);
      }
    }
  }
  return candidates;
}

// A candidate scored over all pairs: the best of each pair's surface within
// the tolerance of its prediction.
void ScoreCandidate(const std::vector<CoarseSurface>& surfaces,
                    const std::vector<Eigen::Vector2d>& dt_mm, int coarse_factor,
                    const ImageMotionOptions& options, Candidate* c) {
  c->at.resize(surfaces.size());
  for (size_t k = 0; k < surfaces.size(); ++k) {
    const CoarseSurface& s = surfaces[k];
    const Eigen::Vector2d predicted = c->a * dt_mm[k];
    const int cx = static_cast<int>(std::lround(predicted.x() / coarse_factor));
    const int cy = static_cast<int>(std::lround(predicted.y() / coarse_factor));
    const int radius = static_cast<int>(std::ceil(Tolerance(options, predicted) / coarse_factor));
    LocalBest& best = c->at[k];
    for (int dy = std::max(cy - radius, -s.rows + 1); dy <= std::min(cy + radius, s.rows - 1);
         ++dy) {
      for (int dx = std::max(cx - radius, -s.cols + 1); dx <= std::min(cx + radius, s.cols - 1);
           ++dx) {
        const double v = s.At(dx, dy);
        if (v > best.ncc) best.ncc = v, best.shift << dx, dy;
      }
    }
    c->score += Evidence(best.ncc);
  }
}

// A pair's shift under a motion, for step 3's comparison: found or not,
// where (px), and its NCC there.
struct PairShift {
  bool found = false;
  Eigen::Vector2d px = Eigen::Vector2d::Zero();
  double ncc = 0.0;
};

// A candidate's pairs at the coarsest level.
std::vector<PairShift> CoarseShifts(const Candidate& c, int coarse_factor) {
  std::vector<PairShift> shifts(c.at.size());
  for (size_t k = 0; k < c.at.size(); ++k) {
    if (c.at[k].ncc <= -1.0) continue;
    shifts[k] = {true, coarse_factor * c.at[k].shift.cast<double>(), c.at[k].ncc};
  }
  return shifts;
}

// x's evidence over y's on the pairs where their shifts differ (by more
// than tolerance_px[k], or one found and not the other); nothing where they
// differ on fewer than half the pairs: then y is x's motion with a spurious
// peak or two, not a competing one.
std::optional<double> EvidenceRatio(const std::vector<PairShift>& x,
                                    const std::vector<PairShift>& y,
                                    const std::vector<double>& tolerance_px) {
  const int num_pairs = static_cast<int>(x.size());
  double x_sum = 0, y_sum = 0;
  int num_different = 0;
  for (int k = 0; k < num_pairs; ++k) {
    const bool same =
        x[k].found == y[k].found && (!x[k].found || (x[k].px - y[k].px).norm() <= tolerance_px[k]);
    if (same) continue;
    ++num_different;
    if (x[k].found) x_sum += Evidence(x[k].ncc);
    if (y[k].found) y_sum += Evidence(y[k].ncc);
  }
  if (2 * num_different < num_pairs || !(y_sum > 0)) return std::nullopt;
  return x_sum / y_sum;
}

// Step 3: the first candidate's evidence ratio over each other one (as
// EvidenceRatio, within the tolerance of the first's predictions), in the
// candidates' order; nothing for the first.
std::vector<std::optional<double>> RatiosOverOthers(const std::vector<Candidate>& candidates,
                                                    const std::vector<Eigen::Vector2d>& dt_mm,
                                                    int coarse_factor,
                                                    const ImageMotionOptions& options) {
  const Candidate& best = candidates.front();
  const std::vector<PairShift> best_shifts = CoarseShifts(best, coarse_factor);
  std::vector<double> tolerance_px(dt_mm.size());
  for (size_t k = 0; k < dt_mm.size(); ++k) tolerance_px[k] = Tolerance(options, best.a * dt_mm[k]);
  std::vector<std::optional<double>> ratios(candidates.size());
  for (size_t i = 1; i < candidates.size(); ++i)
    ratios[i] =
        EvidenceRatio(best_shifts, CoarseShifts(candidates[i], coarse_factor), tolerance_px);
  return ratios;
}

// Step 4 for a pair: its coarse shift followed down the pyramids to the
// finest level (not ok where a level finds no overlap).
TranslationEstimate RefineShift(const std::vector<Level>& pa, const std::vector<Level>& pb,
                                const LocalBest& coarse, double min_overlap_fraction) {
  TranslationEstimate t;
  LocalBest level_best = coarse;
  for (size_t l = 1; l < pa.size() && level_best.ncc > -1.0; ++l) {
    const int ratio = pa[l - 1].factor / pa[l].factor;
    level_best = SearchShift(pa[l], pb[l], level_best.shift * pa[l - 1].factor / pa[l].factor,
                             ratio + 1, min_overlap_fraction);
  }
  if (level_best.ncc <= -1.0) return t;
  const Level& la = pa.back();
  const Level& lb = pb.back();
  t.ok = true;
  t.shift_px = level_best.shift.cast<double>() * la.factor;
  t.ncc = OverlapNcc(la.image, lb.image, la.moments, lb.moments, level_best.shift.x(),
                     level_best.shift.y(), 1, &t.overlap_fraction);
  return t;
}

// The motion per table mm by least squares over the agreeing pairs: affine
// where their displacements span the plane, else a similarity of handedness
// `mirror`.
Eigen::Matrix2d FitMotion(const std::vector<Eigen::Vector2d>& dt_mm,
                          const std::vector<TranslationEstimate>& shifts,
                          const std::vector<int>& agreeing, int mirror) {
  Eigen::Matrix2d tt = Eigen::Matrix2d::Zero(), st = Eigen::Matrix2d::Zero();
  for (int k : agreeing) {
    tt += dt_mm[k] * dt_mm[k].transpose();
    st += shifts[k].shift_px * dt_mm[k].transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> spread(tt);
  if (spread.eigenvalues()(0) > 0.05 * spread.eigenvalues()(1)) return st * tt.inverse();
  std::vector<Eigen::Vector2d> refined_px(dt_mm.size());
  for (int k : agreeing) refined_px[k] = shifts[k].shift_px;
  return FitSimilarity(dt_mm, refined_px, agreeing, mirror);
}

// Step 3b: the contenders (the first candidate and the others whose ratio
// is below min_margin, one of each set of coarse shifts) followed to the
// finest level, where the fine texture decides. The index of the contender
// with the most evidence there, and its least ratio over the others that
// differ from it there (EvidenceRatio within the tolerance of its shifts;
// infinity if none differs).
struct FinestLevelVerdict {
  size_t index = 0;
  double margin = 0.0;
};
FinestLevelVerdict SettleAtFinestLevel(const std::vector<Candidate>& candidates,
                                       const std::vector<std::optional<double>>& ratios,
                                       const std::vector<std::vector<Level>>& pyramids,
                                       const std::vector<std::pair<int, int>>& pairs,
                                       const ImageMotionOptions& options) {
  const auto same_shifts = [](const Candidate& x, const Candidate& y) {
    for (size_t k = 0; k < x.at.size(); ++k) {
      if ((x.at[k].ncc > -1.0) != (y.at[k].ncc > -1.0) || x.at[k].shift != y.at[k].shift)
        return false;
    }
    return true;
  };
  std::vector<size_t> contenders = {0};
  for (size_t i = 1; i < candidates.size(); ++i) {
    if (!ratios[i] || *ratios[i] >= options.min_margin) continue;
    if (std::none_of(contenders.begin(), contenders.end(),
                     [&](size_t c) { return same_shifts(candidates[c], candidates[i]); }))
      contenders.push_back(i);
  }
  const int num_pairs = static_cast<int>(pairs.size());
  std::vector<std::vector<PairShift>> refined(contenders.size(),
                                              std::vector<PairShift>(pairs.size()));
  ParallelFor(static_cast<int>(contenders.size()) * num_pairs, options.num_threads, [&](int n) {
    const size_t c = static_cast<size_t>(n / num_pairs);
    const int k = n % num_pairs;
    const LocalBest& coarse = candidates[contenders[c]].at[k];
    if (coarse.ncc <= -1.0) return;
    const TranslationEstimate t = RefineShift(pyramids[pairs[k].first], pyramids[pairs[k].second],
                                              coarse, options.min_overlap_fraction);
    if (t.ok) refined[c][k] = {true, t.shift_px, t.ncc};
  });
  std::vector<double> totals(contenders.size(), 0.0);
  for (size_t c = 0; c < contenders.size(); ++c)
    for (const PairShift& shift : refined[c])
      if (shift.found) totals[c] += Evidence(shift.ncc);
  const size_t w =
      static_cast<size_t>(std::max_element(totals.begin(), totals.end()) - totals.begin());
  std::vector<double> tolerance_px(pairs.size());
  for (size_t k = 0; k < pairs.size(); ++k) tolerance_px[k] = Tolerance(options, refined[w][k].px);
  FinestLevelVerdict verdict{contenders[w], std::numeric_limits<double>::infinity()};
  for (size_t c = 0; c < contenders.size(); ++c) {
    if (c == w) continue;
    if (const std::optional<double> ratio = EvidenceRatio(refined[w], refined[c], tolerance_px))
      verdict.margin = std::min(verdict.margin, *ratio);
  }
  return verdict;
}

}  // namespace

ImageMotionEstimate EstimateImageMotion(const std::vector<ImageF>& tiles,
                                        const std::vector<Eigen::Vector2d>& table_mm,
                                        const std::vector<std::pair<int, int>>& pairs,
                                        const ImageMotionOptions& options) {
  ImageMotionEstimate estimate;
  const int num_pairs = static_cast<int>(pairs.size());
  estimate.pair_shifts.resize(num_pairs);
  estimate.pair_agrees.assign(num_pairs, false);
  if (num_pairs == 0) {
    estimate.brief = "no neighbouring tiles";
    return estimate;
  }
  // The tiles' pyramids in parallel too: on one thread they were two thirds
  // of the motion's 0.1 s (demo). With them the coarsest levels' spectra:
  // step 1's cross sums at every shift by FFT (zero-padded against
  // wrap-around), summed directly they were 8 % of the registration.
  std::vector<std::vector<Level>> pyramids(tiles.size());
  std::vector<Spectrum> spectra(tiles.size());
  const auto padded = [](Eigen::Index n) { return FftSize(2 * static_cast<int>(n) - 1); };
  ParallelFor(static_cast<int>(tiles.size()), options.num_threads, [&](int i) {
    pyramids[i] = Pyramid(tiles[i], options);
    const ImageF& coarsest = pyramids[i][0].image;
    spectra[i] = Fft2(coarsest, padded(coarsest.rows()), padded(coarsest.cols()));
  });
  const int fft_rows = padded(pyramids[0][0].image.rows());
  const int fft_cols = padded(pyramids[0][0].image.cols());
  const int coarse_factor = pyramids[0][0].factor;
  std::vector<Eigen::Vector2d> dt_mm(num_pairs);
  for (int k = 0; k < num_pairs; ++k)
    dt_mm[k] = table_mm[pairs[k].second] - table_mm[pairs[k].first];

  // 1. Every pair's coarse NCC surface and its strongest local maxima.
  std::vector<CoarseSurface> surfaces(num_pairs);
  ParallelFor(num_pairs, options.num_threads, [&](int k) {
    const auto [i, j] = pairs[k];
    surfaces[k] = CoarseNccSurface(pyramids[i][0], pyramids[j][0], spectra[i], spectra[j], fft_rows,
                                   fft_cols, options);
  });
  std::vector<Candidate> candidates = CandidateMotions(dt_mm, surfaces, coarse_factor);
  if (candidates.empty()) {
    estimate.brief = "no pair of neighbouring tiles overlaps by more than " +
                     std::to_string(options.min_overlap_fraction) + " of the image";
    return estimate;
  }

  // 2. Each candidate scored over all pairs.
  for (Candidate& c : candidates) ScoreCandidate(surfaces, dt_mm, coarse_factor, options, &c);
  std::sort(candidates.begin(), candidates.end(),
            [](const Candidate& x, const Candidate& y) { return x.score > y.score; });
  const Candidate& best = candidates.front();
  // 3. The margin over every clearly different candidate.
  estimate.score = best.score;
  estimate.mirrored = best.mirror < 0;
  const std::vector<std::optional<double>> ratios =
      RatiosOverOthers(candidates, dt_mm, coarse_factor, options);
  estimate.margin = std::numeric_limits<double>::infinity();
  for (const std::optional<double>& ratio : ratios)
    if (ratio) estimate.margin = std::min(estimate.margin, *ratio);
  // 3b. An ambiguity of the coarsest level settled at the finest.
  if (best.score > 0 && estimate.margin < options.min_margin) {
    const FinestLevelVerdict verdict =
        SettleAtFinestLevel(candidates, ratios, pyramids, pairs, options);
    estimate.finest_margin = verdict.margin;
    if (verdict.margin >= options.min_margin) {
      std::swap(candidates.front(), candidates[verdict.index]);
      estimate.score = best.score;
      estimate.mirrored = best.mirror < 0;
    }
  }
  if (!(best.score > 0) ||
      (estimate.margin < options.min_margin && estimate.finest_margin < options.min_margin)) {
    std::ostringstream brief;
    brief << "the image motion per table mm is ambiguous: the best consensus of the " << num_pairs
          << " neighbour pairs (evidence " << best.score
          << ") beats a different one only by a factor " << estimate.margin
          << " on the pairs where they differ, and by " << estimate.finest_margin
          << " at the finest level";
    estimate.brief = brief.str();
    return estimate;
  }

  // 4. Each pair refined from its best coarse shift near the prediction,
  // which agrees when within the tolerance of the similarity fitted to the
  // best candidate's coarse shifts on all pairs: the candidate itself goes
  // through one pair's peak (+-coarse_factor / 2 px), and every candidate near
  // the true motion scores alike (demo seed 2: one through a neighbouring
  // peak predicted 68 px off).
  std::vector<int> found;
  std::vector<Eigen::Vector2d> coarse_px(num_pairs, Eigen::Vector2d::Zero());
  for (int k = 0; k < num_pairs; ++k) {
    if (best.at[k].ncc <= -1.0) continue;
    found.push_back(k);
    coarse_px[k] = coarse_factor * best.at[k].shift.cast<double>();
  }
  const Eigen::Matrix2d coarse_a = FitSimilarity(dt_mm, coarse_px, found, best.mirror);
  std::vector<int> agreeing;
  for (int k : found) {
    TranslationEstimate& t = estimate.pair_shifts[k];
    t = RefineShift(pyramids[pairs[k].first], pyramids[pairs[k].second], best.at[k],
                    options.min_overlap_fraction);
    if (!t.ok) continue;
    const Eigen::Vector2d predicted = coarse_a * dt_mm[k];
    if ((t.shift_px - predicted).norm() <= Tolerance(options, predicted)) {
      estimate.pair_agrees[k] = true;
      agreeing.push_back(k);
    }
  }
  estimate.num_agreeing = static_cast<int>(agreeing.size());
  if (agreeing.empty()) {
    estimate.brief = "no neighbour pair's refined shift agrees with the consensus motion";
    return estimate;
  }
  estimate.px_per_table_mm = FitMotion(dt_mm, estimate.pair_shifts, agreeing, best.mirror);
  estimate.ok = true;
  std::ostringstream brief;
  brief << estimate.num_agreeing << " of " << num_pairs
        << " neighbour pairs agree on the image motion (evidence " << best.score << ", margin "
        << estimate.margin;
  if (estimate.finest_margin > 0) brief << ", at the finest level " << estimate.finest_margin;
  brief << ")";
  estimate.brief = brief.str();
  return estimate;
}

namespace {

// A (2 h + 1)^2 window at `centre` less its least-squares plane, as a
// vector; empty where that leaves only the samples' rounding (a plane). The
// grid's coordinates are centred, so 1, x and y are orthogonal and each
// coefficient a projection.
Eigen::VectorXd DetrendedWindow(const ImageF& image, const Eigen::Vector2i& centre, int h) {
  const int side = 2 * h + 1;
  Eigen::VectorXd w(side * side);
  double sum = 0, sum_x = 0, sum_y = 0;
  for (int r = 0; r < side; ++r) {
    for (int c = 0; c < side; ++c) {
      const double v = image(centre.y() - h + r, centre.x() - h + c);
      w(r * side + c) = v;
      sum += v, sum_x += (c - h) * v, sum_y += (r - h) * v;
    }
  }
  const double magnitude = w.norm();
  // sum over the grid of x^2 (or y^2): side * sum_{i=-h..h} i^2.
  const double sxx = side * h * (h + 1) * (2.0 * h + 1) / 3.0;
  const double mean = sum / w.size(), b = sum_x / sxx, c = sum_y / sxx;
  for (int r = 0; r < side; ++r)
    for (int col = 0; col < side; ++col) w(r * side + col) -= mean + b * (col - h) + c * (r - h);
  // float samples: relative rounding ~6e-8 each.
  if (!(w.norm() > 1e-5 * magnitude)) return {};
  return w;
}

bool WindowInside(const ImageF& image, const Eigen::Vector2i& centre, int h) {
  return centre.x() - h >= 0 && centre.y() - h >= 0 && centre.x() + h < image.cols() &&
         centre.y() + h < image.rows();
}

}  // namespace

double BestDetrendedNcc(const ImageF& reference, const Eigen::Vector2i& anchor_px, int half_size_px,
                        const ImageF& target, const Eigen::Vector2i& center_px, int radius_px) {
  const int h = half_size_px;
  if (!WindowInside(reference, anchor_px, h)) return -2.0;
  const Eigen::VectorXd t = DetrendedWindow(reference, anchor_px, h);
  if (t.size() == 0) return -2.0;
  const double t_norm = t.norm();
  double best = -2.0;
  for (int dy = -radius_px; dy <= radius_px; ++dy) {
    for (int dx = -radius_px; dx <= radius_px; ++dx) {
      const Eigen::Vector2i at = center_px + Eigen::Vector2i(dx, dy);
      if (!WindowInside(target, at, h)) return -2.0;
      const Eigen::VectorXd w = DetrendedWindow(target, at, h);
      if (w.size() > 0) best = std::max(best, t.dot(w) / (t_norm * w.norm()));
    }
  }
  return best;
}

NccPeak SearchNcc(const ImageF& reference, const Eigen::Vector2i& anchor_px, int half_size_px,
                  const ImageF& target, const Eigen::Vector2i& center_px, int radius_px) {
  NccPeak peak;
  const int h = half_size_px, side = 2 * h + 1, n = side * side;
  const int ax = anchor_px.x(), ay = anchor_px.y();
  const int cx = center_px.x(), cy = center_px.y(), rad = radius_px;
  if (ax - h < 0 || ay - h < 0 || ax + h >= reference.cols() || ay + h >= reference.rows() ||
      cx - rad - h < 0 || cy - rad - h < 0 || cx + rad + h >= target.cols() ||
      cy + rad + h >= target.rows())
    return peak;
  // The zero-mean template, so that the cross term needs no target mean.
  std::vector<float> t0(static_cast<size_t>(n));
  double t_sum = 0;
  for (int r = 0; r < side; ++r)
    for (int c = 0; c < side; ++c) t_sum += reference(ay - h + r, ax - h + c);
  const double t_mean = t_sum / n;
  double t_ss = 0;
  for (int r = 0; r < side; ++r) {
    for (int c = 0; c < side; ++c) {
      const double v = reference(ay - h + r, ax - h + c) - t_mean;
      t0[r * side + c] = static_cast<float>(v);
      t_ss += v * v;
    }
  }
  if (!(t_ss > 0)) return peak;
  const double t_norm = std::sqrt(t_ss);
  const int grid = 2 * rad + 1;
  // Summed-area tables of the searched region (value and square, double), so
  // that each position's window moments cost O(1) and only the cross term
  // is summed per pixel.
  const int region = grid + 2 * h, x0 = cx - rad - h, y0 = cy - rad - h;
  const int stride = region + 1;
  // Only the tables' first row and column need zeros: the loop writes the
  // rest (zeroing them all was a fifth of this function's time).
  const size_t table_size = static_cast<size_t>(stride) * stride;
  const auto sum = std::make_unique_for_overwrite<double[]>(table_size);
  const auto sum_sq = std::make_unique_for_overwrite<double[]>(table_size);
  for (int k = 0; k < stride; ++k) {
    sum[k] = sum_sq[k] = 0.0;
    sum[static_cast<size_t>(k) * stride] = sum_sq[static_cast<size_t>(k) * stride] = 0.0;
  }
  for (int r = 0; r < region; ++r) {
    const float* row = target.data() + static_cast<size_t>(y0 + r) * target.cols() + x0;
    double acc = 0, acc_sq = 0;
    for (int c = 0; c < region; ++c) {
      acc += row[c], acc_sq += static_cast<double>(row[c]) * row[c];
      sum[(r + 1) * stride + c + 1] = sum[r * stride + c + 1] + acc;
      sum_sq[(r + 1) * stride + c + 1] = sum_sq[r * stride + c + 1] + acc_sq;
    }
  }
  const auto box = [&](const std::unique_ptr<double[]>& table, int r, int c) {
    return table[(r + side) * stride + c + side] - table[r * stride + c + side] -
           table[(r + side) * stride + c] + table[r * stride + c];
  };
  std::vector<double> scores(static_cast<size_t>(grid) * grid, -2.0);
  double best = -2.0, best_s = 0, best_ss = 0;
  int best_index = -1;
  for (int dy = -rad; dy <= rad; ++dy) {
    for (int dx = -rad; dx <= rad; ++dx) {
      // The cross term against the zero-mean template: float sums per row
      // (<= a few hundred terms of normalised intensities; Eigen's dot
      // product vectorises them), double across rows.
      double st = 0;
      for (int r = 0; r < side; ++r) {
        const float* row =
            target.data() + static_cast<size_t>(cy + dy - h + r) * target.cols() + (cx + dx - h);
        st += Eigen::Map<const Eigen::VectorXf>(row, side).dot(
            Eigen::Map<const Eigen::VectorXf>(t0.data() + r * side, side));
      }
      const double s = box(sum, dy + rad, dx + rad), ss = box(sum_sq, dy + rad, dx + rad);
      const double var = ss - s * s / n;
      const int index = (dy + rad) * grid + (dx + rad);
      scores[index] = var > 0 ? st / (t_norm * std::sqrt(var)) : -2.0;
      if (scores[index] > best) best = scores[index], best_index = index, best_s = s, best_ss = ss;
    }
  }
  if (best_index < 0) return peak;
  const int bx = best_index % grid, by = best_index / grid;
  peak.ok = true;
  peak.ncc = best;
  peak.pixel << cx + bx - rad, cy + by - rad;
  peak.q_px = peak.pixel.cast<double>();
  peak.target_mean = best_s / n;
  peak.target_std = std::sqrt(std::max(best_ss / n - peak.target_mean * peak.target_mean, 0.0));
  if (bx > 0 && bx + 1 < grid) {
    const double l = scores[by * grid + bx - 1], r = scores[by * grid + bx + 1];
    const double d = l - 2 * best + r;
    if (d < 0) peak.q_px.x() += std::clamp(0.5 * (l - r) / d, -0.5, 0.5);
  }
  if (by > 0 && by + 1 < grid) {
    const double u = scores[(by - 1) * grid + bx], d2 = scores[(by + 1) * grid + bx];
    const double d = u - 2 * best + d2;
    if (d < 0) peak.q_px.y() += std::clamp(0.5 * (u - d2) / d, -0.5, 0.5);
  }
  return peak;
}

PatchWarp PatchWarp::FromJacobians(const Eigen::Matrix2d& j, const Eigen::Matrix2d& j_px,
                                   const Eigen::Matrix2d& j_mx, const Eigen::Matrix2d& j_py,
                                   const Eigen::Matrix2d& j_my, double step_px) {
  PatchWarp warp;
  warp.jacobian = j;
  // d J(k, i) / d q_m = H_k(i, m).
  const Eigen::Matrix2d dj_dx = (j_px - j_mx) / (2 * step_px);
  const Eigen::Matrix2d dj_dy = (j_py - j_my) / (2 * step_px);
  for (int k = 0; k < 2; ++k) {
    Eigen::Matrix2d h;
    h.col(0) = dj_dx.row(k).transpose();
    h.col(1) = dj_dy.row(k).transpose();
    warp.hessian[k] = 0.5 * (h + h.transpose());
  }
  return warp;
}

namespace {

// The normal equations of a patch's least-squares step in (dq_x, dq_y,
// dgain, doffset): J' W J and -J' W r, r = gain b(q + offset_i) + offset - t
// (residual), J its derivatives (gain times b's gradient, b, 1).
// The upper triangle is summed with pixel pairs in the two lanes of packed
// doubles (SSE2 does two per instruction; the scalar sums could not be
// reordered without -ffast-math). An odd last pixel pairs with weight 0.
void PatchNormalEquations(const Eigen::VectorXd& weight, const Eigen::VectorXd& sampled,
                          const Eigen::VectorXd& residual, const Eigen::VectorXd& gradient_x,
                          const Eigen::VectorXd& gradient_y, double gain, Eigen::Matrix4d* normal,
                          Eigen::Vector4d* rhs) {
  using Pair = Eigen::Array2d;
  Pair n00 = Pair::Zero(), n01 = n00, n02 = n00, n03 = n00, n11 = n00, n12 = n00, n13 = n00,
       n22 = n00, n23 = n00, n33 = n00, b0 = n00, b1 = n00, b2 = n00, b3 = n00;
  const auto add = [&](const Pair& w, const Pair& v, const Pair& r, const Pair& gx,
                       const Pair& gy) {
    const Pair e = w * r, j0 = gain * gx, j1 = gain * gy;
    const Pair wj0 = w * j0, wj1 = w * j1, wv = w * v;
    n00 += wj0 * j0, n01 += wj0 * j1, n02 += wj0 * v, n03 += wj0;
    n11 += wj1 * j1, n12 += wj1 * v, n13 += wj1;
    n22 += wv * v, n23 += wv, n33 += w;
    b0 -= j0 * e, b1 -= j1 * e, b2 -= v * e, b3 -= e;
  };
  const auto n = static_cast<int>(weight.size());
  int i = 0;
  for (; i + 1 < n; i += 2) {
    add(weight.segment<2>(i), sampled.segment<2>(i), residual.segment<2>(i),
        gradient_x.segment<2>(i), gradient_y.segment<2>(i));
  }
  if (i < n) {
    add(Pair(weight(i), 0), Pair(sampled(i), 0), Pair(residual(i), 0), Pair(gradient_x(i), 0),
        Pair(gradient_y(i), 0));
  }
  const double s01 = n01.sum(), s02 = n02.sum(), s03 = n03.sum(), s12 = n12.sum(), s13 = n13.sum(),
               s23 = n23.sum();
  *normal << n00.sum(), s01, s02, s03, s01, n11.sum(), s12, s13, s02, s12, n22.sum(), s23, s03, s13,
      s23, n33.sum();
  *rhs = Eigen::Vector4d(b0.sum(), b1.sum(), b2.sum(), b3.sum());
}

}  // namespace

PatchMatch MatchPatch(const ImageF& reference, const Eigen::Vector2i& anchor_px,
                      const ImageF& target, const ImageF& target_spline,
                      const Eigen::Vector2d& predicted_q_px, const PatchWarp& warp,
                      int search_radius_px, const PatchMatchOptions& options) {
  PatchMatch match;
  const int h = options.half_size_px, side = 2 * h + 1, n = side * side;
  const int ax = anchor_px.x(), ay = anchor_px.y();
  if (ax - h < 0 || ay - h < 0 || ax + h >= reference.cols() || ay + h >= reference.rows())
    return match;
  Eigen::VectorXd templ(n);
  for (int r = 0; r < side; ++r)
    for (int c = 0; c < side; ++c) templ(r * side + c) = reference(ay - h + r, ax - h + c);
  const double t_mean = templ.mean();
  const Eigen::VectorXd t0 = templ.array() - t_mean;
  const double t_norm = t0.norm();
  const double t_std = t_norm / std::sqrt(static_cast<double>(n));
  if (t_std < options.min_template_std) return match;

  // 1. Integer NCC search around the prediction (translation of the template).
  const int px = static_cast<int>(std::lround(predicted_q_px.x()));
  const int py = static_cast<int>(std::lround(predicted_q_px.y()));
  const int rad = search_radius_px;
  // The search window plus the B-spline's support around any refined position.
  if (px - rad - h - 2 < 0 || py - rad - h - 2 < 0 || px + rad + h + 3 >= target.cols() ||
      py + rad + h + 3 >= target.rows())
    return match;
  const NccPeak peak = SearchNcc(reference, anchor_px, h, target, {px, py}, rad);
  if (!peak.ok || peak.ncc < options.min_ncc - 0.1) return match;
  // Radius 0: the prediction is already sub-pixel (a relocation); start there.
  const Eigen::Vector2d start = rad == 0 ? predicted_q_px : peak.q_px;

  // 2. Least-squares template matching: position, gain and offset, starting
  // from the moments of the best integer window.
  std::vector<Eigen::Vector2d> offsets(static_cast<size_t>(n));
  for (int r = -h, i = 0; r <= h; ++r)
    for (int c = -h; c <= h; ++c, ++i) offsets[i] = warp.Offset(Eigen::Vector2d(c, r));
  Eigen::Vector2d q = start;
  double gain = t_std / std::max(peak.target_std, 1e-6);
  double offset = t_mean - gain * peak.target_mean;
  bool converged = false;
  bool samples_at_q = false;  // the samples are those of q, gain and offset
  Eigen::VectorXd sampled(n), gradient_x(n), gradient_y(n), residual(n);
  Eigen::VectorXd weight = Eigen::VectorXd::Ones(n);
  Eigen::Matrix4d normal;
  // Phase 0: plain least squares; phase 1 (robust_tukey_c > 0) from its
  // solution: iteratively reweighted least squares with Tukey's biweight of
  // every pixel's current residual, to its fixed point (the M-estimate).
  const int num_phases = options.robust_tukey_c > 0 ? 2 : 1;
  for (int phase = 0; phase < num_phases; ++phase) {
    converged = false;
    double last_step_px = 0.0;  // of the previous iteration (0: none yet)
    const int max_iterations = phase == 0 ? options.max_iterations : options.max_robust_iterations;
    for (int it = 0; it < max_iterations && !converged; ++it) {
      // Phase 1 starts where phase 0 converged: when phase 0 stopped before
      // applying its last step, the samples and residuals are those of q.
      if (!samples_at_q) {
        if (!SampleBSplinePatch(target_spline, q, offsets, &sampled, &gradient_x, &gradient_y))
          return match;
        residual = (gain * sampled.array() + offset - templ.array()).matrix();
      }
      samples_at_q = false;
      if (phase > 0) {
        // No pixel beyond the cut at the plain solution: its content agrees
        // with the warp and that solution stands, its weights all ones (half
        // the matching time on the demo, whose templates rarely have one).
        if (it == 0 && TukeyKeepsAll(residual, options.robust_tukey_c)) {
          converged = true;
          break;
        }
        weight = TukeyWeights(residual, options.robust_tukey_c);
      }
      Eigen::Vector4d rhs;
      PatchNormalEquations(weight, sampled, residual, gradient_x, gradient_y, gain, &normal, &rhs);
      const Eigen::Vector4d step = normal.ldlt().solve(rhs);
      if (!step.allFinite()) return match;
      ++match.iterations;
      const double step_px = step.head<2>().norm();
      converged = step_px < options.convergence_px;
      if (converged) {  // the samples stay those of q (within convergence_px of q + step)
        samples_at_q = true;
        break;
      }
      q += step.head<2>();
      gain += step(2);
      offset += step(3);
      if ((q - start).norm() > options.max_refinement_px) return match;
      // The steps contract by ~rho = step / last step: the remaining ones sum
      // to ~rho / (1 - rho) step. Below convergence_px this step is the last
      // (Gauss-Newton contracts fast: one resampling of the patch fewer for
      // two thirds of the demo's matches); the samples stay those before it,
      // within 10 convergence_px. Only small, fast-contracting steps: a
      // looser test accepted the slow, erratic matches of a bore's wall
      // (plain least squares, low-texture seed 104: 371 -> 386 matches).
      const double rho = last_step_px > 0 ? step_px / last_step_px : 1.0;
      converged = step_px < 10 * options.convergence_px && rho < 0.5 &&
                  rho / (1 - rho) * step_px < options.convergence_px;
      if (converged) break;
      last_step_px = step_px;
    }
    if (!converged) break;
  }
  // Quality at the final position (the last iteration's samples).
  const Eigen::VectorXd s0 = sampled.array() - sampled.mean();
  match.ncc = s0.dot(t0) / (s0.norm() * t_norm);
  match.residual_rms = residual.norm() / std::sqrt(static_cast<double>(n));
  // The weighted residual variance over the pixels that count.
  const double w_sum = weight.sum();
  const double variance = weight.dot(residual.cwiseAbs2()) / std::max(1.0, w_sum - 4);
  match.covariance_px2 = variance * normal.inverse().topLeftCorner<2, 2>();
  match.q_px = q;
  match.ok = converged && match.ncc >= options.min_ncc;
  return match;
}

}  // namespace omm
