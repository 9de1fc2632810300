#include "pipeline/measure/scene_sensitivity.h"

#include <cassert>
#include <cmath>

#include <Eigen/LU>

#include "pipeline/mosaic/orthorectify.h"

namespace omm {
namespace {

int NumTiles(const PlaneScene& scene) { return static_cast<int>(scene.table_pos_mm.size()); }
int NumPlates(const PlaneScene& scene) { return static_cast<int>(scene.plates.size()); }

}  // namespace

std::optional<Eigen::MatrixXd> SceneSensitivity(const LensProjection& lens, const PlaneScene& scene,
                                                int tile, const Eigen::Vector2d& part_mm) {
  const int num_tiles = NumTiles(scene), num_plates = NumPlates(scene);
  const int num_intrinsics = lens.NumIntrinsics();
  assert(tile >= 0 && tile < num_tiles);
  assert(scene.intrinsics.size() == num_intrinsics);

  const Eigen::Matrix3d rot = RotationFromAngleAxis(scene.cam_from_part_r);
  const Eigen::Vector3d p = CameraPointOfPartPoint(scene.cam_from_part_r, scene, tile, part_mm);
  Eigen::Vector2d q;
  Matrix23d dq_dp;
  RowMajorMatrix2Xd dq_dk(2, num_intrinsics);
  if (!lens.Project(p, scene.intrinsics.data(), &q, &dq_dp, &dq_dk)) return std::nullopt;

  // dq/dtheta in the covariance vector's layout.
  Eigen::MatrixXd dq_dtheta =
      Eigen::MatrixXd::Zero(2, PlaneSceneCovarianceSize(num_tiles, num_plates, num_intrinsics));
  constexpr double kStepRad = 1e-7;
  for (int j = 0; j < 3; ++j) {
    Eigen::Vector3d step = Eigen::Vector3d::Zero();
    step[j] = kStepRad;
    const Eigen::Vector3d dp_drj =
        (CameraPointOfPartPoint(scene.cam_from_part_r + step, scene, tile, part_mm) -
         CameraPointOfPartPoint(scene.cam_from_part_r - step, scene, tile, part_mm)) /
        (2.0 * kStepRad);
    dq_dtheta.col(j) = dq_dp * dp_drj;
  }
  dq_dtheta.block<2, 3>(0, 3) = dq_dp;                                 // t
  dq_dtheta.block<2, 2>(0, 6 + 2 * tile) = dq_dp * rot.leftCols<2>();  // T_i
  dq_dtheta.rightCols(num_intrinsics) = dq_dk;

  const Eigen::Matrix2d dq_dpart = dq_dp * rot.leftCols<2>();
  return Eigen::MatrixXd(-dq_dpart.inverse() * dq_dtheta);
}

std::vector<std::pair<int, double>> MosaicBlendAt(const LensProjection& lens,
                                                  const PlaneScene& scene,
                                                  const Eigen::Vector2d& part_mm, int width_px,
                                                  int height_px, double band_px) {
  std::vector<std::pair<int, double>> seen;  // (tile, border distance)
  double best = 0.0;
  for (int tile = 0; tile < NumTiles(scene); ++tile) {
    const auto q = TilePixelOfPartPoint(lens, scene, tile, part_mm);
    if (!q) continue;
    const double d = TileBorderDistancePx(*q, width_px, height_px);
    if (!(d > 0.0)) continue;
    seen.emplace_back(tile, d);
    best = std::max(best, d);
  }
  double sum = 0.0;
  for (auto& [tile, weight] : seen) {
    weight = TileBlendWeight(weight, best, band_px);
    sum += weight;
  }
  for (auto& entry : seen) entry.second /= sum;
  return seen;
}

std::optional<Eigen::MatrixXd> BlendedSceneSensitivity(const LensProjection& lens,
                                                       const PlaneScene& scene,
                                                       const Eigen::Vector2d& part_mm, int width_px,
                                                       int height_px, double band_px) {
  const auto blend = MosaicBlendAt(lens, scene, part_mm, width_px, height_px, band_px);
  if (blend.empty()) return std::nullopt;
  Eigen::MatrixXd sum;
  for (const auto& [tile, weight] : blend) {
    const auto s = SceneSensitivity(lens, scene, tile, part_mm);
    if (!s) return std::nullopt;
    if (sum.size() == 0) sum = Eigen::MatrixXd::Zero(s->rows(), s->cols());
    sum += weight * *s;
  }
  return sum;
}

}  // namespace omm
