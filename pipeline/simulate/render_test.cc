// The renderer proved against geometry alone: images of the caltab's dots
// have their intensity centroids where the truth lens model puts the centroid
// of each dot's exact image, and the pattern and the sensor do what their
// headers say.
#include "pipeline/simulate/render.h"

#include <cmath>
#include <cstdio>
#include <numbers>
#include <set>

#include <gtest/gtest.h>

#include "adapters/mrcal/lens.h"
#include "pipeline/simulate/scene.h"
#include "pipeline/simulate/simulation.h"

namespace omm {
namespace {

CameraModel TruthCamera(const std::string& preset) {
  SimulationOptions options;
  options.preset = preset;
  options.num_calib_images = 3;
  return PlanSimulation(options).truth.camera.model;
}

// Area centroid of the image of the plate circle (centre, radius): the dense
// boundary projected through the model, then the polygon's centroid.
// Also returns the largest distance of the boundary from that centroid.
Eigen::Vector2d ExactImageCentroid(const CameraModel& camera,
                                   const Eigen::Isometry3d& cam_from_plate,
                                   const Eigen::Vector2d& centre, double radius, double* reach_px) {
  constexpr int kN = 4096;
  Eigen::Matrix3Xd p(3, kN);
  for (int k = 0; k < kN; ++k) {
    const double a = 2 * std::numbers::pi * k / kN;
    p.col(k) = cam_from_plate * Eigen::Vector3d(centre.x() + radius * std::cos(a),
                                                centre.y() + radius * std::sin(a), 0);
  }
  Eigen::Matrix2Xd q;
  EXPECT_TRUE(ProjectPoints(camera, p, &q));
  double area = 0;
  Eigen::Vector2d moment = Eigen::Vector2d::Zero();
  for (int k = 0; k < kN; ++k) {
    const Eigen::Vector2d a = q.col(k), b = q.col((k + 1) % kN);
    const double cross = a.x() * b.y() - b.x() * a.y();
    area += cross;
    moment += cross * (a + b);
  }
  const Eigen::Vector2d centroid = moment / (3.0 * area);
  *reach_px = (q.colwise() - centroid).colwise().norm().maxCoeff();
  return centroid;
}

struct CentroidStats {
  int num_dots = 0;
  double max_error_px = 0;
};

// Renders the plate at cam_from_plate (noise, vignetting and quantisation
// off, gain 1) over `rect`, and compares each dot fully inside it with the
// exact centroid of its image. The intensity centroid weights each pixel by
// white - I: zero on the white ground, proportional to the dot's coverage.
CentroidStats CompareDotCentroids(const CameraModel& camera,
                                  const Eigen::Isometry3d& cam_from_plate, const PixelRect& rect,
                                  double psf_sigma_px) {
  const BoardSpec board;
  const Materials materials;
  const PlatePattern pattern(board, 120.0, materials);
  RayTableOptions ray_options;
  RayTableSummary ray_summary;
  const RayTable rays = ComputeRayTable(camera, rect, ray_options, &ray_summary);
  EXPECT_TRUE(ray_summary.ok);
  const ImageF reflectance =
      IntegratePixels(rays, PlateScene(&pattern, cam_from_plate, 0.2f), IntegrationOptions());
  ExposureTruth exposure;
  exposure.psf_sigma_px = psf_sigma_px;
  SensorModel sensor;
  sensor.bit_depth = 0;
  const ImageF image = ExposeImage(reflectance, rect, exposure, Eigen::Vector2d(800, 600), 1000.0,
                                   sensor, NoiseSource(), 2);

  CentroidStats stats;
  const Eigen::Matrix3Xd marks = BoardPoints(board);
  const double radius = 0.5 * board.dot_diameter_mm;
  for (int m = 0; m < marks.cols(); ++m) {
    double reach_px = 0;
    const Eigen::Vector2d exact =
        ExactImageCentroid(camera, cam_from_plate, marks.col(m).head<2>(), radius, &reach_px);
    // Window: the dot's image and 4 px for the blur (sigma <= 0.8 px); the
    // corner triangle next to mark (0, 0) is ~9 px beyond its edge.
    const double window = reach_px + 4.0;
    if (exact.x() - window < rect.x0 || exact.y() - window < rect.y0 ||
        exact.x() + window > rect.x0 + rect.width - 1 ||
        exact.y() + window > rect.y0 + rect.height - 1) {
      continue;
    }
    double sum = 0;
    Eigen::Vector2d moment = Eigen::Vector2d::Zero();
    for (int r = 0; r < rect.height; ++r) {
      for (int c = 0; c < rect.width; ++c) {
        const Eigen::Vector2d q(rect.x0 + c, rect.y0 + r);
        if ((q - exact).norm() > window) continue;
        const double w = materials.plate_white - image(r, c);
        sum += w;
        moment += w * q;
      }
    }
    const double error = (moment / sum - exact).norm();
    stats.max_error_px = std::max(stats.max_error_px, error);
    ++stats.num_dots;
  }
  return stats;
}

Eigen::Isometry3d PlateAt(const CameraModel& camera, const Eigen::Vector2d& centre_px, double z_mm,
                          const Eigen::Matrix3d& rotation) {
  Eigen::Matrix3Xd v;
  EXPECT_TRUE(UnprojectPixels(camera, centre_px, &v));
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = rotation;
  pose.translation() = z_mm * v.col(0);
  return pose;
}

// Dots near the image corner see the strongest distortion. The bound, 0.003
// px, leaves room for what a 16 x 16 sampling of edge pixels and the
// pixel-centre moment sum can do (~0.0015 px measured), and is far below the
// 0.007 px calibration accuracy the images must support. With 4 x 4 rays
// everywhere (no edge refinement) the error is ~0.01 px, and with the
// refinement but without the neighbour rule ~0.006 px.
TEST(RenderedDots, CentroidsMatchTheExactImageNearTheCorner) {
  const CameraModel camera = TruthCamera("demo");
  const Eigen::Isometry3d pose = PlateAt(camera, {430, 420}, 390.0, Eigen::Matrix3d::Identity());
  const CentroidStats stats = CompareDotCentroids(camera, pose, {20, 20, 420, 420}, 0.75);
  std::printf("corner: %d dots, max centroid error %.4f px\n", stats.num_dots, stats.max_error_px);
  EXPECT_GE(stats.num_dots, 9);
  EXPECT_LT(stats.max_error_px, 0.003);
}

TEST(RenderedDots, CentroidsMatchTheExactImageOfATiltedPlate) {
  const CameraModel camera = TruthCamera("demo");
  const Eigen::Matrix3d tilt =
      Eigen::AngleAxisd(30 * std::numbers::pi / 180, Eigen::Vector3d(1, 1, 0).normalized())
          .toRotationMatrix();
  const Eigen::Isometry3d pose = PlateAt(camera, {800, 600}, 400.0, tilt);
  const CentroidStats stats = CompareDotCentroids(camera, pose, {600, 400, 400, 400}, 0.0);
  std::printf("tilted, no blur: %d dots, max centroid error %.4f px\n", stats.num_dots,
              stats.max_error_px);
  EXPECT_GE(stats.num_dots, 4);
  EXPECT_LT(stats.max_error_px, 0.003);
}

TEST(RenderedDots, CentroidsMatchThroughTheSplinedLens) {
  const CameraModel camera = TruthCamera("lens-mismatch");
  const Eigen::Isometry3d pose = PlateAt(camera, {1170, 180}, 390.0, Eigen::Matrix3d::Identity());
  const CentroidStats stats = CompareDotCentroids(camera, pose, {1180, 0, 420, 300}, 0.8);
  std::printf("splined lens: %d dots, max centroid error %.4f px\n", stats.num_dots,
              stats.max_error_px);
  EXPECT_GE(stats.num_dots, 4);
  EXPECT_LT(stats.max_error_px, 0.003);
}

// The rich texture with a through-hole, seen from 390 mm, integrated by
// IntegratePixels and by the plain mean of 16 x 16 rays per pixel (the
// midpoint rule that the renderer's edge blocks use, here everywhere).
// Returns max and rms of the difference and the number of pixels that
// straddle a rim.
struct DenseComparison {
  double max_abs = 0, rms = 0;
  int rim_pixels = 0;
};

DenseComparison CompareWithDenseMean(const IntegrationOptions& options) {
  const CameraModel camera = TruthCamera("demo");
  Eigen::Isometry3d cam_from_part = Eigen::Isometry3d::Identity();
  cam_from_part.linear() = Eigen::Vector3d(1, -1, -1).asDiagonal();
  cam_from_part.translation() << 0, 0, 390;
  const PixelRect rect{700, 500, 96, 96};
  Eigen::Matrix3Xd v;
  EXPECT_TRUE(UnprojectPixels(camera, Eigen::Vector2d(748, 548), &v));
  const SurfaceTexture texture(TextureStyle::kRich, 7);
  WorkpieceScene::Layout layout;
  layout.min_mm = {-300, -300};
  layout.max_mm = {300, 300};
  layout.thickness_mm = 12;
  layout.holes.push_back({Eigen::Vector2d(390 * v(0, 0), -390 * v(1, 0)), 5.0});  // ~68 px
  const Materials materials;
  const WorkpieceScene workpiece(layout, &texture, materials);
  const TileScene scene(&workpiece, cam_from_part, Eigen::Vector2d::Zero(), materials.table);

  RayTableSummary summary;
  const ImageF image =
      IntegratePixels(ComputeRayTable(camera, rect, RayTableOptions(), &summary), scene, options);
  RayTableOptions dense_options;
  dense_options.supersampling = 16;
  const RayTable dense = ComputeRayTable(camera, rect, dense_options, &summary);
  DenseComparison result;
  double sum2 = 0;
  for (int r = 0; r < rect.height; ++r) {
    for (int c = 0; c < rect.width; ++c) {
      double sum = 0;
      std::set<Region> regions;
      for (int k = 0; k < dense.SamplesPerPixel(); ++k) {
        const Eigen::Vector2d ray = dense.Ray(r, c, k);
        const SceneSample sample = scene(ray.x(), ray.y());
        sum += sample.reflectance;
        regions.insert(sample.region);
      }
      const double error = image(r, c) - sum / dense.SamplesPerPixel();
      result.max_abs = std::max(result.max_abs, std::abs(error));
      sum2 += error * error;
      result.rim_pixels += regions.size() > 1;
    }
  }
  result.rms = std::sqrt(sum2 / (rect.width * rect.height));
  return result;
}

// Over the texture (finest wavelength ~5 px) both rules are exact to far
// below a digital number, and at the rims the renderer must sample the same
// 16 x 16 grid in every block that an edge crosses: a block it missed would
// be off by up to its area times the rim's contrast, ~0.01. Bounds: 0.1 DN
// max and 0.01 DN rms at 8 bits (4e-4, 4e-5; measured 1.6e-4, 1.7e-5); with
// 8 x 8 rays in edge blocks the difference is 0.036, without refinement 0.14.
TEST(IntegratePixels, TextureAndHoleRimsMatchADenseMeanOfRays) {
  const DenseComparison result = CompareWithDenseMean(IntegrationOptions());
  std::printf("%d rim pixels; max %.2e, rms %.2e\n", result.rim_pixels, result.max_abs, result.rms);
  EXPECT_GE(result.rim_pixels, 300);
  EXPECT_LT(result.max_abs, 4e-4);
  EXPECT_LT(result.rms, 4e-5);
}

TEST(PlatePattern, FollowsTheFormatDocument) {
  const BoardSpec board;
  const Materials m;
  const PlatePattern pattern(board, 120.0, m);
  EXPECT_TRUE(pattern.Contains(59.9, -59.9));
  EXPECT_FALSE(pattern.Contains(60.1, 0));
  EXPECT_EQ(pattern.Sample(55, 0).reflectance, m.plate_white);      // margin
  EXPECT_EQ(pattern.Sample(48.4, 0).reflectance, m.plate_black);    // frame bar
  EXPECT_EQ(pattern.Sample(-20, 49.0).reflectance, m.plate_black);  // frame bar
  EXPECT_EQ(pattern.Sample(46.5, 10).reflectance, m.plate_white);   // inside the frame
  const Eigen::Matrix3Xd marks = BoardPoints(board);
  for (int i = 0; i < marks.cols(); ++i) {
    EXPECT_EQ(pattern.Sample(marks(0, i) + 3.1, marks(1, i)).region, Region::kPlateBlack) << i;
    EXPECT_EQ(pattern.Sample(marks(0, i) + 3.15, marks(1, i)).region, Region::kPlateWhite) << i;
  }
  // The triangle fills the inner corner next to mark (0, 0) at (-x, -y) only.
  EXPECT_EQ(pattern.Sample(-46.0, -40.0).reflectance, m.plate_black);
  EXPECT_EQ(pattern.Sample(-40.0, -46.0).reflectance, m.plate_black);
  EXPECT_EQ(pattern.Sample(-40.0, -40.0).reflectance, m.plate_white);
  EXPECT_EQ(pattern.Sample(46.0, -40.0).reflectance, m.plate_white);
  EXPECT_EQ(pattern.Sample(-46.0, 40.0).reflectance, m.plate_white);
  EXPECT_EQ(pattern.Sample(46.0, 40.0).reflectance, m.plate_white);
}

TEST(PlatePattern, CirclesAreTheCaltabsDotsAlone) {
  const BoardSpec board = SimulatedBoard(BoardType::kCircles);
  const Materials m;
  const PlatePattern pattern(board, 120.0, m);
  const Eigen::Matrix3Xd marks = BoardPoints(board);
  for (int i = 0; i < marks.cols(); ++i) {
    EXPECT_EQ(pattern.Sample(marks(0, i) + 3.1, marks(1, i)).region, Region::kPlateBlack) << i;
    EXPECT_EQ(pattern.Sample(marks(0, i) + 3.15, marks(1, i)).region, Region::kPlateWhite) << i;
  }
  // No frame bar, no corner triangle.
  EXPECT_EQ(pattern.Sample(48.4, 0).region, Region::kPlateWhite);
  EXPECT_EQ(pattern.Sample(-46.0, -40.0).region, Region::kPlateWhite);
}

TEST(PlatePattern, ChessboardCornersSitAtTheMarks) {
  const BoardSpec board = SimulatedBoard(BoardType::kChessboard);
  const Materials m;
  const PlatePattern pattern(board, 120.0, m);
  const Eigen::Matrix3Xd marks = BoardPoints(board);
  const double d = 0.3 * board.pitch_mm;
  for (int i = 0; i < marks.cols(); ++i) {
    const double x = marks(0, i), y = marks(1, i);
    const Region at_minus_xy = pattern.Sample(x - d, y - d).region;
    // Diagonal squares alike, neighbouring squares different: an X-junction.
    EXPECT_EQ(pattern.Sample(x + d, y + d).region, at_minus_xy) << i;
    EXPECT_NE(pattern.Sample(x + d, y - d).region, at_minus_xy) << i;
    EXPECT_EQ(pattern.Sample(x - d, y + d).region, pattern.Sample(x + d, y - d).region) << i;
  }
  // The square at the (-x, -y) corner is black; beyond the squares, white.
  const double half_x = 0.5 * (board.cols + 1) * board.pitch_mm;
  const double half_y = 0.5 * (board.rows + 1) * board.pitch_mm;
  EXPECT_EQ(pattern.Sample(-half_x + 1, -half_y + 1).region, Region::kPlateBlack);
  EXPECT_EQ(pattern.Sample(-half_x - 1, 0).region, Region::kPlateWhite);
  EXPECT_EQ(pattern.Sample(0, half_y + 1).region, Region::kPlateWhite);
  EXPECT_TRUE(pattern.Contains(half_x + 4, half_y + 4));
}

TEST(GaussianBlur, PreservesSumAndCentroid) {
  ImageF image = ImageF::Zero(41, 41);
  image(20, 17) = 1.0f;
  image(22, 25) = 2.0f;
  const ImageF blurred = GaussianBlur(image, 0.8, 2);
  double sum = 0, mx = 0, my = 0;
  for (int r = 0; r < 41; ++r) {
    for (int c = 0; c < 41; ++c)
      sum += blurred(r, c), mx += c * blurred(r, c), my += r * blurred(r, c);
  }
  EXPECT_NEAR(sum, 3.0, 1e-5);
  EXPECT_NEAR(mx / sum, (17 + 2 * 25) / 3.0, 1e-5);
  EXPECT_NEAR(my / sum, (20 + 2 * 22) / 3.0, 1e-5);
  EXPECT_LT(blurred(20, 17), 0.3f);
}

// Shot plus read noise has the variance the header states.
TEST(ExposeImage, NoiseHasTheModelledVariance) {
  const PixelRect rect{0, 0, 200, 200};
  const ImageF flat = ImageF::Constant(200, 200, 0.5f);
  ExposureTruth exposure;
  SensorModel sensor;
  sensor.bit_depth = 0;
  const ImageF image = ExposeImage(flat, rect, exposure, Eigen::Vector2d(100, 100), 141.0, sensor,
                                   NoiseSource{true, 7, 1}, 2);
  const double mean = image.cast<double>().mean();
  const double var = (image.cast<double>().array() - mean).square().sum() / (image.size() - 1);
  const double expected = (0.5 * sensor.full_well_e + sensor.read_noise_e * sensor.read_noise_e) /
                          (sensor.full_well_e * sensor.full_well_e);
  EXPECT_NEAR(mean, 0.5, 5 * std::sqrt(expected / image.size()));
  // 40000 samples: the variance's relative sigma is sqrt(2 / n) = 0.7 %.
  EXPECT_NEAR(var / expected, 1.0, 0.035);
}

// A crop is exposed with the same noise as the same pixels of the whole image.
TEST(ExposeImage, CropNoiseMatchesTheWholeImage) {
  const ImageF flat = ImageF::Constant(60, 80, 0.4f);
  ExposureTruth exposure;
  const SensorModel sensor;
  const NoiseSource noise{true, 3, 1001};
  const ImageF whole =
      ExposeImage(flat, {0, 0, 80, 60}, exposure, Eigen::Vector2d(40, 30), 50.0, sensor, noise, 2);
  const ImageF crop = ExposeImage(flat.block(10, 20, 30, 40), {20, 10, 40, 30}, exposure,
                                  Eigen::Vector2d(40, 30), 50.0, sensor, noise, 1);
  EXPECT_EQ(crop, whole.block(10, 20, 30, 40));
}

TEST(ExposeImage, VignettingAndGainFollowTheModel) {
  const PixelRect rect{100, 50, 300, 200};
  const ImageF flat = ImageF::Constant(200, 300, 0.8f);
  ExposureTruth exposure;
  exposure.gain = 0.9;
  exposure.vignetting = 0.3;
  SensorModel sensor;
  sensor.bit_depth = 0;
  const Eigen::Vector2d centre(200, 150);
  const ImageF image = ExposeImage(flat, rect, exposure, centre, 250.0, sensor, NoiseSource(), 2);
  for (const auto& [col, row] : {std::pair{200, 150}, std::pair{399, 249}, std::pair{100, 50}}) {
    const double r2 = (Eigen::Vector2d(col, row) - centre).squaredNorm() / (250.0 * 250.0);
    EXPECT_NEAR(image(row - rect.y0, col - rect.x0), 0.9 * 0.8 * (1 - 0.3 * r2), 1e-6);
  }
  sensor.bit_depth = 8;
  const ImageF quantised =
      ExposeImage(flat, rect, exposure, centre, 250.0, sensor, NoiseSource(), 2);
  for (int i = 0; i < quantised.size(); ++i) {
    const double dn = quantised.data()[i] * 255.0;
    ASSERT_NEAR(dn, std::round(dn), 1e-3);
  }
}

}  // namespace
}  // namespace omm
