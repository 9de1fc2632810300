#include "pipeline/measure/hole_ties.h"

#include <optional>

#include "pipeline/core/error.h"
#include "pipeline/core/parallel_for.h"
#include "pipeline/core/statistics.h"
#include "pipeline/core/tile_pixels.h"

namespace omm {
namespace {

// One view as a tie observation: the fit's centre and covariance carried
// into its tile.
bool TileObservation(const HoleViewInputs& in, const HoleFit& fit, double min_sigma_px,
                     Eigen::Vector2d* q_px, Eigen::Matrix2d* covariance_px2) {
  const OrthoGrid& grid = in.geometry.grid;
  const auto pixel = [&](const Eigen::Vector2d& mosaic_px) {
    return TilePixelOfPartPoint(in.lens, in.scene, *fit.tile, grid.PartFromMosaic(mosaic_px));
  };
  return CarryToTile(pixel, fit.circle.centre_px, fit.circle.covariance_px2.topLeftCorner<2, 2>(),
                     min_sigma_px, q_px, covariance_px2);
}

}  // namespace

std::string HoleTieOptions::Check() const {
  if (min_views < 2) return "min_views must be at least 2";
  if (!(max_cut_uncovered >= 0.0 && max_cut_uncovered < 1.0))
    return "max_cut_uncovered must be in [0, 1)";
  if (!(min_sigma_px > 0.0)) return "min_sigma_px must be > 0";
  if (!(consistency_probability > 0.0 && consistency_probability < 1.0))
    return "consistency_probability must be in (0, 1)";
  if (num_threads < 1) return "num_threads must be at least 1";
  return "";
}

std::vector<HoleTie> FindHoleTies(const HoleViewInputs& in, const std::vector<TieHole>& holes,
                                  const HoleTieOptions& options,
                                  std::vector<std::optional<Eigen::Vector2d>>* located_mm) {
  if (const std::string why = options.Check(); !why.empty())
    throw InputError("HoleTieOptions", why);
  HoleViewInputs tile_inputs = in;
  tile_inputs.mosaic = nullptr;
  const int num_holes = static_cast<int>(holes.size());
  std::vector<HoleViews> views(num_holes);
  const auto fit = [&](int i) {
    views[i] = FitHoleViews(tile_inputs, holes[i].near_part_mm, holes[i].radius_mm);
  };
  // Largest first: a hole's fits take time with its rim.
  std::vector<double> radii_mm;
  for (const TieHole& hole : holes) radii_mm.push_back(hole.radius_mm);
  const std::vector<int> largest_first = CostliestFirst(radii_mm);
  ParallelFor(num_holes, options.num_threads, [&](int n) { fit(largest_first[n]); });
  std::vector<BoreEvidence> bores;
  for (const HoleViews& hole : views) bores.push_back(BoreEvidenceOf(hole.fits));
  tile_inputs.bore_prior = PoolBorePrior(bores, options.min_bore_prior_views);
  if (tile_inputs.bore_prior) {
    std::vector<int> unresolved;
    for (int i = 0; i < num_holes; ++i) {
      if (bores[i].unresolved) unresolved.push_back(i);
    }
    ParallelFor(static_cast<int>(unresolved.size()), options.num_threads,
                [&](int j) { fit(unresolved[static_cast<size_t>(j)]); });
  }

  // The tiles that see part of a hole's rim: views of the tie only.
  std::vector<std::vector<HoleFit>> cut(num_holes);
  ParallelFor(num_holes, options.num_threads, [&](int n) {
    const int i = largest_first[n];
    if (views[i].partial) return;
    cut[i] = FitCutViews(tile_inputs, views[i], holes[i].radius_mm, options.max_cut_uncovered);
  });

  std::vector<HoleTie> ties;
  if (located_mm) located_mm->assign(holes.size(), std::nullopt);
  for (int i = 0; i < num_holes; ++i) {
    HoleTie tie;
    tie.hole = i;
    const auto add = [&](const HoleFit& view) {
      Eigen::Vector2d q;
      Eigen::Matrix2d covariance;
      if (!TileObservation(tile_inputs, view, options.min_sigma_px, &q, &covariance)) return false;
      tie.tiles.push_back(*view.tile);
      tie.q_px.push_back(q);
      tie.covariance_px2.push_back(covariance);
      return true;
    };
    Eigen::Vector2d sum_mm = Eigen::Vector2d::Zero();
    for (const HoleFit& view : views[i].fits) {
      if (add(view)) sum_mm += in.geometry.grid.PartFromMosaic(view.circle.centre_px);
    }
    if (tie.tiles.empty()) continue;
    tie.num_whole = static_cast<int>(tie.tiles.size());
    tie.centre_mm = sum_mm / static_cast<double>(tie.num_whole);
    if (located_mm) (*located_mm)[static_cast<size_t>(i)] = tie.centre_mm;
    for (const HoleFit& view : cut[i]) add(view);
    // Where every tile that sees the hole whole clipped its rim, the views
    // are partial (FitHoleViews): they locate the hole but tie nothing.
    if (static_cast<int>(tie.tiles.size()) >= options.min_views && !views[i].partial)
      ties.push_back(std::move(tie));
  }
  return ties;
}

bool CarryToTile(const std::function<std::optional<Eigen::Vector2d>(const Eigen::Vector2d&)>& pixel,
                 const Eigen::Vector2d& x, const Eigen::Matrix2d& covariance_mosaic_px2,
                 double min_sigma_px, Eigen::Vector2d* q_px, Eigen::Matrix2d* covariance_px2) {
  const std::optional<Eigen::Vector2d> q = pixel(x);
  if (!q) return false;
  Eigen::Matrix2d jacobian;
  for (int k = 0; k < 2; ++k) {
    const Eigen::Vector2d step = 0.5 * Eigen::Vector2d::Unit(k);
    const std::optional<Eigen::Vector2d> plus = pixel(x + step), minus = pixel(x - step);
    if (!plus || !minus) return false;
    jacobian.col(k) = *plus - *minus;
  }
  *q_px = *q;
  *covariance_px2 = jacobian * covariance_mosaic_px2 * jacobian.transpose() +
                    min_sigma_px * min_sigma_px * Eigen::Matrix2d::Identity();
  return true;
}

void AppendTieTrack(const Eigen::Vector2d& point_mm, const std::vector<int>& tiles,
                    const std::vector<Eigen::Vector2d>& q_px,
                    const std::vector<Eigen::Matrix2d>& covariance_px2, PlaneBundleInput* input,
                    PlaneScene* scene) {
  const int track = input->num_tracks++;
  scene->track_xy_mm.conservativeResize(2, track + 1);
  scene->track_xy_mm.col(track) = point_mm;
  for (size_t v = 0; v < tiles.size(); ++v) {
    input->observations.push_back(WhitenedObservation(tiles[v], track, q_px[v], covariance_px2[v],
                                                      input->observation_sigma_px));
  }
}

int AddHoleTieTracks(const std::vector<HoleTie>& ties, PlaneBundleInput* input, PlaneScene* scene) {
  const int first_observation = static_cast<int>(input->observations.size());
  for (const HoleTie& tie : ties)
    AppendTieTrack(tie.centre_mm, tie.tiles, tie.q_px, tie.covariance_px2, input, scene);
  return first_observation;
}

std::vector<int> InconsistentHoleTies(const std::vector<HoleTie>& ties, int first_observation,
                                      const Eigen::Matrix2Xd& residual_px,
                                      const HoleTieOptions& options) {
  std::vector<int> inconsistent;
  int index = first_observation;
  for (size_t t = 0; t < ties.size(); ++t) {
    double chi2 = 0.0;
    for (const Eigen::Matrix2d& covariance : ties[t].covariance_px2) {
      const Eigen::Vector2d r = residual_px.col(index++);
      chi2 += r.dot(covariance.ldlt().solve(r));
    }
    const int dof = 2 * (static_cast<int>(ties[t].tiles.size()) - 1);
    if (!(chi2 <= ChiSquareQuantile(options.consistency_probability, dof)))
      inconsistent.push_back(static_cast<int>(t));
  }
  return inconsistent;
}

TiedAdjustment AdjustWithHoleTies(const CameraModel& camera,
                                  const PlaneBundleInput& registered_input,
                                  const PlaneScene& registered_scene, const PlateOnPart& plate,
                                  const IntrinsicsPrior& prior,
                                  const FinalAdjustmentOptions& options,
                                  const std::vector<HoleTie>& ties,
                                  const HoleTieOptions& tie_options) {
  TiedAdjustment result;
  std::vector<HoleTie> current = ties;  // cut views left out where they disagree
  std::vector<int> kept(ties.size());
  for (size_t t = 0; t < ties.size(); ++t) kept[t] = static_cast<int>(t);
  for (;;) {
    result.kept.clear();
    for (const int t : kept) result.kept.push_back(current[t]);
    PlaneBundleInput input = registered_input;
    PlaneScene scene = registered_scene;
    result.first_tie_observation = AddHoleTieTracks(result.kept, &input, &scene);
    result.adjusted = AdjustWithPlateAndPrior(camera, input, scene, plate, prior, options);
    if (kept.empty()) return result;
    if (!result.adjusted.summary.usable) {
      result.ties_failed = true;
      result.failure = result.adjusted.summary.brief;
      kept.clear();
      continue;
    }
    const std::vector<int> inconsistent = InconsistentHoleTies(
        result.kept, result.first_tie_observation, result.adjusted.scene.residual_px, tie_options);
    if (inconsistent.empty()) return result;
    // Cut views go first, and no tie is dropped in the same round: each
    // cut view sees its rim near a tile's border, where a lens the model
    // cannot represent errs most (lens-mismatch seed 621: 4 of 12 ties with
    // cut views disagreed, and dropping them whole also lost their whole
    // views' ties), and one wrong view can make a good tie disagree until
    // it is gone.
    bool stripped = false;
    for (const int k : inconsistent) {
      HoleTie& tie = current[kept[k]];
      const int num_cut = static_cast<int>(tie.tiles.size()) - tie.num_whole;
      if (num_cut == 0 || tie.num_whole < tie_options.min_views) continue;
      tie.tiles.resize(tie.num_whole);
      tie.q_px.resize(tie.num_whole);
      tie.covariance_px2.resize(tie.num_whole);
      result.num_cut_views_dropped += num_cut;
      stripped = true;
    }
    if (stripped) continue;
    for (auto it = inconsistent.rbegin(); it != inconsistent.rend(); ++it) {
      result.dropped.push_back(kept[*it]);
      kept.erase(kept.begin() + *it);
    }
  }
}

}  // namespace omm
