#include "adapters/colmap/colmap_model.h"

#include <cmath>
#include <cstdio>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "adapters/mrcal/lens.h"
#include "adapters/project_io/text_file.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

// omm pixel (centre of the top-left pixel at 0) -> COLMAP's (corner at 0).
constexpr double kColmapPixelShift = 0.5;

std::string Format(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

std::string Num(double value) { return Format("%.17g", value); }

// cameras.txt: the one camera as the COLMAP model nearest to its lens model
// (PINHOLE, with the observations undistorted, for the models COLMAP lacks);
// the model and whether it undistorts go into *summary.
std::string CamerasTxt(const CameraModel& camera, ColmapExportSummary* summary) {
  const Eigen::VectorXd& k = camera.intrinsics;
  const auto n_intrinsics = static_cast<int>(k.size());
  std::ostringstream cam;
  cam << "# Camera list with one line of data per camera:\n"
      << "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n# Number of cameras: 1\n";
  std::vector<double> params = {k[0], k[1], k[2] + kColmapPixelShift, k[3] + kColmapPixelShift};
  if (camera.lens_model == "LENSMODEL_PINHOLE") {
    summary->camera_model = "PINHOLE";
  } else if (camera.lens_model == "LENSMODEL_OPENCV4") {
    summary->camera_model = "OPENCV";
    for (int i = 4; i < 8; ++i) params.push_back(k[i]);
  } else if (camera.lens_model == "LENSMODEL_OPENCV5" || camera.lens_model == "LENSMODEL_OPENCV8") {
    summary->camera_model = "FULL_OPENCV";
    for (int i = 4; i < 12; ++i) params.push_back(i < n_intrinsics ? k[i] : 0.0);
  } else {
    summary->camera_model = "PINHOLE";
    summary->undistorted = true;
  }
  cam << "1 " << summary->camera_model << " " << camera.width_px << " " << camera.height_px;
  for (double p : params) cam << " " << Num(p);
  cam << "\n";
  return cam.str();
}

// The used observations (weight > 0) by track; a track of two or more is a
// COLMAP point, numbered from 1 in track order.
struct ColmapPoints {
  std::vector<std::vector<int>> track_obs;  // per track: indices into the observations
  std::vector<int> point_id;                // per track: -1 if not a point
  int num_points = 0;
};

ColmapPoints PointsOf(const std::vector<TrackObservation>& observations, int num_tracks) {
  ColmapPoints points;
  points.track_obs.resize(num_tracks);
  for (size_t i = 0; i < observations.size(); ++i) {
    if (observations[i].weight > 0.0)
      points.track_obs[observations[i].track].push_back(static_cast<int>(i));
  }
  points.point_id.assign(num_tracks, -1);
  for (int tr = 0; tr < num_tracks; ++tr) {
    if (points.track_obs[tr].size() >= 2) points.point_id[tr] = ++points.num_points;
  }
  return points;
}

// images.txt: each tile's pose (camera from its part position) and its
// points2D, its used observations of points at `q_written`; *point2d_index
// gets each observation's index among its tile's points2D.
std::string ImagesTxt(const PlaneScene& scene, const Eigen::Matrix3d& r,
                      const std::vector<std::string>& image_names,
                      const std::vector<TrackObservation>& observations,
                      const Eigen::Matrix2Xd& q_written, const ColmapPoints& points,
                      std::vector<int>* point2d_index) {
  const int num_tiles = static_cast<int>(image_names.size());
  std::vector<std::vector<int>> tile_obs(num_tiles);
  point2d_index->assign(observations.size(), -1);
  for (size_t tr = 0; tr < points.track_obs.size(); ++tr) {
    if (points.point_id[tr] < 0) continue;
    for (int i : points.track_obs[tr]) {
      (*point2d_index)[i] = static_cast<int>(tile_obs[observations[i].tile].size());
      tile_obs[observations[i].tile].push_back(i);
    }
  }
  const Eigen::Quaterniond quat(r);
  std::ostringstream img;
  img << "# Image list with two lines of data per image:\n"
      << "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
      << "#   POINTS2D[] as (X, Y, POINT3D_ID)\n# Number of images: " << num_tiles << "\n";
  for (int i = 0; i < num_tiles; ++i) {
    const Eigen::Vector3d t =
        r * Eigen::Vector3d(scene.table_pos_mm[i].x(), scene.table_pos_mm[i].y(), 0.0) +
        scene.cam_from_part_t_mm;
    img << i + 1 << " " << Num(quat.w()) << " " << Num(quat.x()) << " " << Num(quat.y()) << " "
        << Num(quat.z()) << " " << Num(t.x()) << " " << Num(t.y()) << " " << Num(t.z()) << " 1 "
        << image_names[i] << "\n";
    for (size_t j = 0; j < tile_obs[i].size(); ++j) {
      const int o = tile_obs[i][j];
      img << (j ? " " : "") << Num(q_written(0, o) + kColmapPixelShift) << " "
          << Num(q_written(1, o) + kColmapPixelShift) << " "
          << points.point_id[observations[o].track];
    }
    img << "\n";
  }
  return img.str();
}

// points3D.txt: each point on the part plane (z = 0) with its mean
// reprojection error (q_model against q_obs) and its track; the counts and
// the mean error go into *summary.
std::string Points3DTxt(const PlaneScene& scene, const std::vector<TrackObservation>& observations,
                        const Eigen::Matrix2Xd& q_model, const Eigen::Matrix2Xd& q_obs,
                        const ColmapPoints& points, const std::vector<int>& point2d_index,
                        ColmapExportSummary* summary) {
  std::ostringstream pts;
  double error_sum = 0.0;
  pts << "# 3D point list with one line of data per point:\n"
      << "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n";
  for (size_t tr = 0; tr < points.track_obs.size(); ++tr) {
    if (points.point_id[tr] < 0) continue;
    const std::vector<int>& obs = points.track_obs[tr];
    double error = 0.0;
    for (int i : obs) error += (q_model.col(i) - q_obs.col(i)).norm();
    error /= static_cast<double>(obs.size());
    error_sum += error;
    pts << points.point_id[tr] << " " << Num(scene.track_xy_mm(0, tr)) << " "
        << Num(scene.track_xy_mm(1, tr)) << " 0 128 128 128 " << Num(error);
    for (int i : obs) pts << " " << observations[i].tile + 1 << " " << point2d_index[i];
    pts << "\n";
    summary->num_observations += static_cast<int>(obs.size());
  }
  summary->num_points = points.num_points;
  summary->mean_point_error_px = points.num_points > 0 ? error_sum / points.num_points : 0.0;
  return pts.str();
}

}  // namespace

ColmapExportSummary WriteColmapModel(const std::filesystem::path& dir, const CameraModel& camera,
                                     const PlaneScene& scene,
                                     const std::vector<TrackObservation>& observations,
                                     const std::vector<std::string>& image_names) {
  const int num_tiles = static_cast<int>(scene.table_pos_mm.size());
  if (static_cast<int>(image_names.size()) != num_tiles)
    throw InputError("colmap export", std::to_string(image_names.size()) + " image names for " +
                                          std::to_string(num_tiles) + " tiles");
  const int num_tracks = static_cast<int>(scene.track_xy_mm.cols());
  for (const TrackObservation& o : observations) {
    if (o.tile < 0 || o.tile >= num_tiles || o.track < 0 || o.track >= num_tracks)
      throw InputError("colmap export", "an observation names a tile or track out of range");
  }
  const int n_intrinsics = LensModelNumParams(camera.lens_model);
  if (n_intrinsics < 4 || camera.intrinsics.size() != n_intrinsics)
    throw InputError("colmap export", "camera intrinsics do not fit '" + camera.lens_model + "'");

  ColmapExportSummary summary;
  const std::string cameras_txt = CamerasTxt(camera, &summary);
  const ColmapPoints points = PointsOf(observations, num_tracks);

  // Model pixels of every used observation (for ERROR), and the written 2-D
  // points (undistorted if the camera is written as PINHOLE for another model).
  const double angle = scene.cam_from_part_r.norm();
  const Eigen::Matrix3d r =
      angle > 0.0 ? Eigen::AngleAxisd(angle, scene.cam_from_part_r / angle).toRotationMatrix()
                  : Eigen::Matrix3d::Identity();
  const Eigen::Index n_obs = static_cast<Eigen::Index>(observations.size());
  Eigen::Matrix3Xd p_cam(3, n_obs);
  Eigen::Matrix2Xd q_obs(2, n_obs);
  for (Eigen::Index i = 0; i < n_obs; ++i) {
    const TrackObservation& o = observations[i];
    const Eigen::Vector2d xy = scene.track_xy_mm.col(o.track) + scene.table_pos_mm[o.tile];
    p_cam.col(i) = r * Eigen::Vector3d(xy.x(), xy.y(), 0.0) + scene.cam_from_part_t_mm;
    q_obs.col(i) = o.q_px;
  }
  Eigen::Matrix2Xd q_model;
  if (!ProjectPoints(camera, p_cam, &q_model))
    throw InputError("colmap export", "the lens model cannot project the scene's points");
  Eigen::Matrix2Xd q_written = q_obs;
  if (summary.undistorted) {
    const Eigen::VectorXd& k = camera.intrinsics;
    Eigen::Matrix3Xd v;
    if (!UnprojectPixels(camera, q_obs, &v))
      throw InputError("colmap export", "cannot undistort the observations");
    for (Eigen::Index i = 0; i < n_obs; ++i) {
      q_written.col(i) << k[0] * v(0, i) / v(2, i) + k[2], k[1] * v(1, i) / v(2, i) + k[3];
    }
  }
  std::vector<int> point2d_index;
  const std::string images_txt =
      ImagesTxt(scene, r, image_names, observations, q_written, points, &point2d_index);
  const std::string points3d_txt =
      Points3DTxt(scene, observations, q_model, q_obs, points, point2d_index, &summary);
  summary.num_images = num_tiles;

  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw InputError(dir.string(), "cannot create the directory: " + ec.message());
  WriteTextFileAtomically(dir / "cameras.txt", cameras_txt);
  WriteTextFileAtomically(dir / "images.txt", images_txt);
  WriteTextFileAtomically(dir / "points3D.txt", points3d_txt);
  char line[256];
  std::snprintf(
      line, sizeof(line),
      "COLMAP model: %s camera%s, %d images, %d points, %d observations, mean error %.3f px",
      summary.camera_model.c_str(), summary.undistorted ? " (undistorted observations)" : "",
      summary.num_images, summary.num_points, summary.num_observations,
      summary.mean_point_error_px);
  summary.brief = line;
  return summary;
}

}  // namespace omm
