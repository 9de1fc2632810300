#include "pipeline/core/tile_pixels.h"

#include <gtest/gtest.h>

#include <numbers>

#include <Eigen/Geometry>

namespace omm {
namespace {

// Pinhole with one radial term: q = f (1 + k1 |u|^2) u + c, u = p_xy / p_z;
// intrinsics fx, fy, cx, cy, k1 (mrcal's order for the first four).
class RadialLens : public LensProjection {
 public:
  int NumIntrinsics() const override { return 5; }
  bool Project(const Eigen::Vector3d& p, const double* k, Eigen::Vector2d* q, Matrix23d* dq_dp,
               RowMajorMatrix2Xd* dq_dk) const override {
    if (!(p.z() > 0.0)) return false;
    const Eigen::Vector2d u = p.head<2>() / p.z();
    const double s = 1.0 + k[4] * u.squaredNorm();
    *q = Eigen::Vector2d(k[0] * s * u.x() + k[2], k[1] * s * u.y() + k[3]);
    if (dq_dp != nullptr) {
      Eigen::Matrix<double, 2, 3> du_dp;
      du_dp << 1.0 / p.z(), 0.0, -u.x() / p.z(), 0.0, 1.0 / p.z(), -u.y() / p.z();
      const Eigen::RowVector3d ds_dp = 2.0 * k[4] * u.transpose() * du_dp;
      const Eigen::Matrix<double, 2, 3> dsu_dp = s * du_dp + u * ds_dp;
      *dq_dp = Eigen::Vector2d(k[0], k[1]).asDiagonal() * dsu_dp;
    }
    if (dq_dk != nullptr) return false;  // not needed here
    return true;
  }
};

PlaneScene TiltedScene(double k1) {
  PlaneScene scene;
  // The part seen from 400 mm, tilted by ~3.4 deg, turned by ~11 deg.
  scene.cam_from_part_r = Eigen::Vector3d(0.05, -0.03, 0.2);
  scene.cam_from_part_t_mm = Eigen::Vector3d(-100.0, -80.0, 400.0);
  scene.table_pos_mm = {{0.0, 0.0}, {115.0, 0.0}, {0.0, 150.0}};
  scene.intrinsics.resize(5);
  scene.intrinsics << 2700.0, 2702.0, 805.0, 598.0, k1;
  return scene;
}

TEST(TilePixels, PartPointsComeBackFromTheirPixels) {
  const RadialLens lens;
  // A strong radial term: the ray's pinhole start is off by pixels there,
  // and the refinement must close the gap.
  for (const double k1 : {0.0, -0.3}) {
    const PlaneScene scene = TiltedScene(k1);
    for (int tile = 0; tile < 3; ++tile) {
      for (const Eigen::Vector2d& part : {Eigen::Vector2d(90.0, 70.0), Eigen::Vector2d(40.0, 120.0),
                                          Eigen::Vector2d(150.0, 20.0)}) {
        const Eigen::Vector2d on_table = part + scene.table_pos_mm[tile];
        const Eigen::Vector3d p_cam =
            Eigen::AngleAxisd(scene.cam_from_part_r.norm(), scene.cam_from_part_r.normalized()) *
                Eigen::Vector3d(on_table.x(), on_table.y(), 0.0) +
            scene.cam_from_part_t_mm;
        EXPECT_LT((CameraPointOfPartPoint(scene.cam_from_part_r, scene, tile, part) - p_cam).norm(),
                  1e-9);
        Eigen::Vector2d q;
        ASSERT_TRUE(lens.Project(p_cam, scene.intrinsics.data(), &q, nullptr, nullptr));
        const auto pixel = TilePixelOfPartPoint(lens, scene, tile, part);
        ASSERT_TRUE(pixel.has_value());
        EXPECT_LT((*pixel - q).norm(), 1e-9);
        const auto back = PartPointOfTilePixel(lens, scene, tile, q);
        ASSERT_TRUE(back.has_value()) << "k1 " << k1 << ", tile " << tile;
        // 1e-9 px at ~0.15 mm per px.
        EXPECT_LT((*back - part).norm(), 1e-9) << "k1 " << k1 << ", tile " << tile;
      }
    }
  }
}

// Beyond |u| = 1 / sqrt(3 |k1|) the radial term folds the image back: at
// |u| = 1.75 and k1 = -0.3 a point lands at 0.14 f from the principal point,
// inside the image, though the lens's own view of it would be far outside.
// That is no pixel of the point.
TEST(TilePixels, NoPixelWhereTheLensFoldsBack) {
  const RadialLens lens;
  PlaneScene scene = TiltedScene(-0.3);
  scene.cam_from_part_r = Eigen::Vector3d::Zero();
  scene.cam_from_part_t_mm = Eigen::Vector3d(0.0, 0.0, 400.0);
  const Eigen::Vector2d folded(700.0, 0.0), seen(120.0, 0.0);  // |u| 1.75 and 0.3
  Eigen::Vector2d q;
  ASSERT_TRUE(lens.Project(CameraPointOfPartPoint(scene.cam_from_part_r, scene, 0, folded),
                           scene.intrinsics.data(), &q, nullptr, nullptr));
  EXPECT_GT(q.x(), 0.0);
  EXPECT_LT(q.x(), 1600.0);  // inside the image
  EXPECT_FALSE(TilePixelOfPartPoint(lens, scene, 0, folded).has_value());
  EXPECT_TRUE(TilePixelOfPartPoint(lens, scene, 0, seen).has_value());
}

TEST(TilePixels, NoPartPointWhereTheRayMissesThePlane) {
  const RadialLens lens;
  PlaneScene behind = TiltedScene(0.0);
  behind.cam_from_part_t_mm.z() = -400.0;  // the plane behind the camera
  EXPECT_FALSE(PartPointOfTilePixel(lens, behind, 0, {800.0, 600.0}).has_value());
  EXPECT_FALSE(TilePixelOfPartPoint(lens, behind, 0, {90.0, 70.0}).has_value());

  PlaneScene edge_on = TiltedScene(0.0);
  // The plane turned by 90 deg about its X axis: it contains the optical
  // axis, whose pixel's ray runs along it.
  edge_on.cam_from_part_r = Eigen::Vector3d(std::numbers::pi / 2, 0.0, 0.0);
  edge_on.cam_from_part_t_mm = Eigen::Vector3d(0.0, 0.0, 0.0);
  EXPECT_FALSE(PartPointOfTilePixel(lens, edge_on, 0, {805.0, 598.0}).has_value());
}

}  // namespace
}  // namespace omm
