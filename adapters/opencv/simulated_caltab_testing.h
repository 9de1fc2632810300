// Test support: caltab images from the simulator (pipeline/simulate) and the
// truth to score plate detection against. Header-only, for the tests here.
#pragma once

#include <cmath>
#include <cstdint>
#include <memory>
#include <numbers>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "adapters/mrcal/lens.h"
#include "pipeline/core/board.h"
#include "pipeline/core/image.h"
#include "pipeline/core/plate_observation.h"
#include "pipeline/core/truth.h"
#include "pipeline/simulate/simulation.h"

namespace omm::testing {

// A planned demo project with its ray table and renderer. The renderer reads
// the plate poses from `plan` at render time, so a test may set its own poses
// in plan.truth.calib_images before rendering.
struct SimulatedCalibration {
  explicit SimulatedCalibration(std::uint64_t seed, const std::string& preset = "demo") {
    SimulationOptions options;
    options.seed = seed;
    options.preset = preset;
    plan = PlanSimulation(options);
    const CameraModel& camera = plan.truth.camera.model;
    RayTableSummary summary;
    rays = ComputeRayTable(camera, PixelRect{0, 0, camera.width_px, camera.height_px},
                           RayOptionsFor(plan.options), &summary);
    EXPECT_TRUE(summary.ok);
    renderer = std::make_unique<ProjectRenderer>(plan);
  }

  const SimulationTruth& truth() const { return plan.truth; }
  const CalibImageTruth& image_truth(int index) const { return plan.truth.calib_images[static_cast<size_t>(index)]; }
  int num_images() const { return static_cast<int>(plan.truth.calib_images.size()); }

  GrayImage Render(int index) const {
    GrayImage image;
    image.pixels = renderer->RenderCalibImage(index, rays);
    image.bit_depth = plan.sensor.bit_depth;
    return image;
  }

  // Image `index` exposed from a given reflectance with the noise stream
  // `noise_stream` of seed `noise_seed`: independent noise draws of one view.
  GrayImage Expose(const ImageF& reflectance, int index, std::uint64_t noise_seed, std::uint64_t noise_stream) const {
    const CameraModel& camera = plan.truth.camera.model;
    const Eigen::Vector2d centre(camera.intrinsics[2], camera.intrinsics[3]);
    double corner_radius = 0.0;
    for (const Eigen::Vector2d& corner : {Eigen::Vector2d(0, 0), Eigen::Vector2d(camera.width_px - 1, 0),
                                          Eigen::Vector2d(0, camera.height_px - 1),
                                          Eigen::Vector2d(camera.width_px - 1, camera.height_px - 1)}) {
      corner_radius = std::max(corner_radius, (corner - centre).norm());
    }
    GrayImage image;
    image.pixels = ExposeImage(reflectance, rays.rect, image_truth(index).exposure, centre, corner_radius, plan.sensor,
                               NoiseSource{true, noise_seed, noise_stream}, plan.options.num_threads);
    image.bit_depth = plan.sensor.bit_depth;
    return image;
  }

  // The truth projection of the mark centres in image `index` (2 x rows*cols).
  Eigen::Matrix2Xd TrueMarks(int index) const {
    Eigen::Matrix2Xd q_px;
    EXPECT_TRUE(ProjectPoints(plan.truth.camera.model, image_truth(index).cam_from_plate * BoardPoints(plan.truth.board),
                              &q_px));
    return q_px;
  }

  // Angle between the plate normal and the optical axis, degrees.
  double TiltDeg(int index) const {
    const double cos_tilt = std::abs(image_truth(index).cam_from_plate.linear()(2, 2));
    return std::acos(std::min(1.0, cos_tilt)) * 180.0 / std::numbers::pi;
  }

  SimulationPlan plan;
  RayTable rays;
  std::unique_ptr<ProjectRenderer> renderer;
};

// Per-mark distance between an observation's centres and the truth, px.
inline Eigen::VectorXd MarkErrors(const PlateObservation& o, const Eigen::Matrix2Xd& truth_px) {
  return (o.q_px - truth_px).colwise().norm().transpose();
}

}  // namespace omm::testing
