#include "pipeline/simulate/ray_table.h"

#include <algorithm>
#include <cstdio>

#include <gtest/gtest.h>

#include "adapters/mrcal/lens.h"
#include "pipeline/simulate/simulation.h"

namespace omm {
namespace {

CameraModel TruthCamera(const std::string& preset) {
  SimulationOptions options;
  options.preset = preset;
  options.num_calib_images = 3;
  return PlanSimulation(options).truth.camera.model;
}

// Every stored ray projects (through mrcal, one plain batch projection) to
// the position of its supersample, to far below the 1e-6 px budget.
void ExpectRaysProjectToTheirSamples(const CameraModel& camera, const PixelRect& rect) {
  RayTableOptions options;
  RayTableSummary summary;
  const RayTable table = ComputeRayTable(camera, rect, options, &summary);
  ASSERT_TRUE(summary.ok);
  EXPECT_EQ(summary.num_rays, static_cast<size_t>(rect.width * rect.height * 16));
  EXPECT_LT(summary.max_residual_px, 1e-6);
  const int n = static_cast<int>(summary.num_rays);
  Eigen::Matrix3Xd p(3, n);
  Eigen::Matrix2Xd q_expected(2, n);
  int i = 0;
  for (int r = 0; r < rect.height; ++r) {
    for (int c = 0; c < rect.width; ++c) {
      for (int k = 0; k < 16; ++k, ++i) {
        p.col(i) << table.Ray(r, c, k), 1.0;
        q_expected.col(i) = table.SamplePixel(rect.x0 + c, rect.y0 + r, k % 4, k / 4);
      }
    }
  }
  Eigen::Matrix2Xd q;
  ASSERT_TRUE(ProjectPoints(camera, p, &q));
  EXPECT_LT((q - q_expected).colwise().norm().maxCoeff(), 1e-6);
  // Supersample (sx, sy) of pixel (c, r) sits at (c - 1/2 + (sx + 1/2)/4, ...).
  EXPECT_DOUBLE_EQ(table.SamplePixel(10, 20, 0, 3).x(), 9.625);
  EXPECT_DOUBLE_EQ(table.SamplePixel(10, 20, 0, 3).y(), 20.375);
}

TEST(RayTable, RaysProjectToTheirSamplesOpenCv8Corner) {
  ExpectRaysProjectToTheirSamples(TruthCamera("demo"), {0, 0, 48, 40});
}

TEST(RayTable, RaysProjectToTheirSamplesOpenCv8Centre) {
  ExpectRaysProjectToTheirSamples(TruthCamera("demo"), {780, 580, 48, 40});
}

TEST(RayTable, RaysProjectToTheirSamplesSplinedLensCorner) {
  ExpectRaysProjectToTheirSamples(TruthCamera("lens-mismatch"), {1552, 1160, 48, 40});
}

// The Gauss points' rays are as exact as the supersamples'; the affine map of
// each pixel puts rays anywhere in it to within 1e-4 px (what the renderer's
// edge blocks need: their edges are placed to ~1e-3 px).
void ExpectGaussRaysAndPixelMapsProject(const CameraModel& camera, const PixelRect& rect) {
  RayTableSummary summary;
  const RayTable table = ComputeRayTable(camera, rect, RayTableOptions(), &summary);
  ASSERT_TRUE(summary.ok);
  constexpr int kFine = 8;  // map samples per pixel and axis, to the pixel's border
  const int per_pixel = 4 + kFine * kFine;
  const int n = rect.width * rect.height * per_pixel;
  Eigen::Matrix3Xd p(3, n);
  Eigen::Matrix2Xd q_expected(2, n);
  int i = 0;
  for (int r = 0; r < rect.height; ++r) {
    for (int c = 0; c < rect.width; ++c) {
      for (int k = 0; k < 4; ++k, ++i) {
        p.col(i) << table.GaussRay(r, c, k), 1.0;
        q_expected.col(i) = RayTable::GaussPixel(rect.x0 + c, rect.y0 + r, k);
      }
      const PixelRayMap map = table.PixelMap(r, c);
      for (int j = 0; j < kFine; ++j) {
        for (int k = 0; k < kFine; ++k, ++i) {
          const double u = k / (kFine - 1.0) - 0.5, v = j / (kFine - 1.0) - 0.5;
          p.col(i) << map(u, v), 1.0;
          q_expected.col(i) << rect.x0 + c + u, rect.y0 + r + v;
        }
      }
    }
  }
  Eigen::Matrix2Xd q;
  ASSERT_TRUE(ProjectPoints(camera, p, &q));
  double max_gauss = 0, max_map = 0;
  for (int j = 0; j < n; ++j) {
    const double error = (q.col(j) - q_expected.col(j)).norm();
    double& max = j % per_pixel < 4 ? max_gauss : max_map;
    max = std::max(max, error);
  }
  std::printf("Gauss rays %.1e px, pixel maps %.1e px\n", max_gauss, max_map);
  EXPECT_LT(max_gauss, 1e-6);
  EXPECT_LT(max_map, 1e-4);
}

TEST(RayTable, GaussRaysAndPixelMapsProjectToTheirPointsOpenCv8Corner) {
  ExpectGaussRaysAndPixelMapsProject(TruthCamera("demo"), {0, 0, 48, 40});
}

TEST(RayTable, GaussRaysAndPixelMapsProjectToTheirPointsSplinedLensCorner) {
  ExpectGaussRaysAndPixelMapsProject(TruthCamera("lens-mismatch"), {1552, 1160, 48, 40});
}

TEST(RayTable, DoesNotDependOnThreads) {
  const CameraModel camera = TruthCamera("demo");
  RayTableOptions options;
  RayTableSummary summary;
  options.num_threads = 1;
  const RayTable one = ComputeRayTable(camera, {300, 200, 64, 37}, options, &summary);
  options.num_threads = 3;
  const RayTable three = ComputeRayTable(camera, {300, 200, 64, 37}, options, &summary);
  EXPECT_EQ(one.base_xy, three.base_xy);
  EXPECT_EQ(one.offset_xy, three.offset_xy);
}

TEST(RayTable, OptionsCheck) {
  RayTableOptions options;
  EXPECT_EQ(options.Check(), "");
  options.supersampling = 0;
  EXPECT_NE(options.Check(), "");
}

}  // namespace
}  // namespace omm
