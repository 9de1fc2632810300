#include "adapters/mrcal/synthetic_plates.h"

#include <cmath>
#include <random>
#include <string>

#include <Eigen/Geometry>

#include "adapters/mrcal/lens.h"

namespace omm::testing {

CameraModel TruthCamera() {
  CameraModel camera;
  camera.lens_model = "LENSMODEL_OPENCV8";
  camera.intrinsics.resize(12);
  camera.intrinsics << 2667.0, 2665.5, 815.3, 588.7, -0.12, 0.09, 0.0004, -0.0003, 0.01, 0.002,
      -0.001, 0.003;
  camera.width_px = 1600;
  camera.height_px = 1200;
  return camera;
}

CalibrationOptions SyntheticSolveOptions(const std::string& lens_model) {
  CalibrationOptions options;
  options.lens_model = lens_model;
  options.width_px = 1600;
  options.height_px = 1200;
  return options;
}

CameraModel SplinedCamera() {
  CameraModel camera;
  camera.lens_model = "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=10_Ny=8_fov_x_deg=38";
  camera.intrinsics.resize(4 + 2 * 10 * 8);
  camera.intrinsics.head<4>() << 2670.0, 2668.0, 812.0, 590.0;
  for (int k = 4; k < camera.intrinsics.size(); ++k)
    camera.intrinsics[k] = 1e-3 * std::sin(0.7 * k);
  camera.width_px = 1600;
  camera.height_px = 1200;
  return camera;
}

std::vector<PlateObservation> SyntheticPlates::Observe(double noise_px, uint32_t seed) const {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_px);
  std::vector<PlateObservation> observations;
  for (size_t i = 0; i < q_truth_px.size(); ++i) {
    PlateObservation observation;
    observation.image = "calib_" + std::to_string(i) + ".png";
    observation.usable = true;
    observation.q_px = q_truth_px[i];
    for (int m = 0; m < observation.q_px.cols(); ++m) {
      observation.q_px(0, m) += noise(rng);
      observation.q_px(1, m) += noise(rng);
    }
    observation.weight = Eigen::VectorXd::Ones(observation.q_px.cols());
    observation.sigma_px = Eigen::VectorXd::Constant(observation.q_px.cols(), noise_px);
    observations.push_back(observation);
  }
  return observations;
}

SyntheticPlates MakeSyntheticPlates(const BoardSpec& board, const CameraModel& camera,
                                    int num_images, double distance_mm, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  const Eigen::Matrix3Xd p_plate = BoardPoints(board);
  const double fx = camera.intrinsics[0], fy = camera.intrinsics[1];
  const double margin_px = 20.0;
  SyntheticPlates plates;
  while (static_cast<int>(plates.q_truth_px.size()) < num_images) {
    const int i = static_cast<int>(plates.q_truth_px.size());
    // The plate centre aims at a 3 x 3 pattern reaching the imager's edges
    // (mrcal's advice: cover the whole imager), jittered; if the plate does
    // not fit there it slides toward the centre until it does.
    Eigen::Vector2d target(((i % 3) * 0.5 + 0.04 * (uniform(rng) - 0.5)) * camera.width_px,
                           ((((i / 3) % 3)) * 0.5 + 0.04 * (uniform(rng) - 0.5)) *
                               camera.height_px);
    const Eigen::Vector2d imager_centre(0.5 * camera.width_px, 0.5 * camera.height_px);
    const double z = distance_mm * (0.95 + 0.1 * uniform(rng));
    const double axis_angle = 2.0 * M_PI * uniform(rng);
    const double tilt = (10.0 + 25.0 * uniform(rng)) * M_PI / 180.0;
    const double spin = 2.0 * M_PI * uniform(rng);
    const Eigen::Matrix3d R =
        (Eigen::AngleAxisd(tilt, Eigen::Vector3d(std::cos(axis_angle), std::sin(axis_angle), 0)) *
         Eigen::AngleAxisd(spin, Eigen::Vector3d::UnitZ()))
            .toRotationMatrix();
    Eigen::Vector3d centre;
    Eigen::Matrix2Xd q;
    bool inside = false;
    for (int slide = 0; slide < 100 && !inside; ++slide) {
      centre << (target.x() - camera.intrinsics[2]) / fx * z,
          (target.y() - camera.intrinsics[3]) / fy * z, z;
      const Eigen::Matrix3Xd p_cam = (R * p_plate).colwise() + centre;
      inside = ProjectPoints(camera, p_cam, &q) && q.row(0).minCoeff() >= margin_px &&
               q.row(1).minCoeff() >= margin_px &&
               q.row(0).maxCoeff() <= camera.width_px - 1 - margin_px &&
               q.row(1).maxCoeff() <= camera.height_px - 1 - margin_px;
      target = imager_centre + 0.97 * (target - imager_centre);
    }
    if (!inside) continue;  // redraw this pose
    const Eigen::AngleAxisd angle_axis(R);
    Vector6d rt;
    rt << angle_axis.angle() * angle_axis.axis(), centre;
    plates.rt_cam_from_plate.push_back(rt);
    plates.q_truth_px.push_back(q);
  }
  return plates;
}

}  // namespace omm::testing
