// The exported model read back by COLMAP itself (`colmap model_analyzer`), and
// its poses and pixel convention checked by reprojecting with COLMAP's own
// FULL_OPENCV formula.
#include "adapters/colmap/colmap_model.h"

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

#include <gtest/gtest.h>

#include "adapters/project_io/text_file.h"
#include "pipeline/mosaic/synthetic_plane.h"

namespace omm {
namespace {

namespace fs = std::filesystem;

struct Exported {
  SyntheticPlane plane;
  ColmapExportSummary summary;
  fs::path dir;
};

Exported Export(const std::string& name) {
  Exported e;
  SyntheticPlaneOptions options;
  options.num_tracks = 300;
  e.plane = MakeSyntheticPlane(options);
  std::vector<std::string> names;
  for (size_t i = 0; i < e.plane.truth.table_pos_mm.size(); ++i)
    names.push_back("tile_" + std::to_string(i) + ".png");
  e.dir = fs::temp_directory_path() / name;
  fs::remove_all(e.dir);
  e.summary =
      WriteColmapModel(e.dir, e.plane.camera, e.plane.truth, e.plane.input.observations, names);
  return e;
}

// COLMAP's FULL_OPENCV projection of a camera-frame point, COLMAP pixels.
Eigen::Vector2d ColmapFullOpencv(const std::vector<double>& k, const Eigen::Vector3d& p) {
  const double u = p.x() / p.z(), v = p.y() / p.z();
  const double r2 = u * u + v * v, r4 = r2 * r2, r6 = r4 * r2;
  const double radial =
      (1 + k[4] * r2 + k[5] * r4 + k[8] * r6) / (1 + k[9] * r2 + k[10] * r4 + k[11] * r6);
  const double du = u * radial + 2 * k[6] * u * v + k[7] * (r2 + 2 * u * u);
  const double dv = v * radial + k[6] * (r2 + 2 * v * v) + 2 * k[7] * u * v;
  return {k[0] * du + k[2], k[1] * dv + k[3]};
}

TEST(WriteColmapModel, ColmapReadsItWithTheRightCounts) {
  const Exported e = Export("omm_colmap_model_test");
  EXPECT_EQ(e.summary.camera_model, "FULL_OPENCV");
  EXPECT_FALSE(e.summary.undistorted);
  EXPECT_EQ(e.summary.num_images, 9);
  const fs::path log = e.dir / "analyzer.log";
  const std::string command =
      "colmap model_analyzer --path " + e.dir.string() + " > " + log.string() + " 2>&1";
  ASSERT_EQ(std::system(command.c_str()), 0) << ReadTextFile(log, "log");
  const std::string text = ReadTextFile(log, "log");
  auto number = [&](const std::string& label) {
    std::smatch m;
    EXPECT_TRUE(std::regex_search(text, m, std::regex(label + ":\\s*([0-9.eE+-]+)")))
        << label << "\n"
        << text;
    return m.size() > 1 ? std::stod(m[1]) : -1.0;
  };
  EXPECT_EQ(number("Cameras"), 1);
  EXPECT_EQ(number("Images"), 9);
  EXPECT_EQ(number("Registered images"), 9);
  EXPECT_EQ(number("Points"), e.summary.num_points);
  EXPECT_EQ(number("Observations"), e.summary.num_observations);
  EXPECT_NEAR(number("Mean reprojection error"), e.summary.mean_point_error_px, 1e-3);
  // The synthetic observations carry 0.07 px noise per axis: a mean error of
  // 0.07 sqrt(pi/2) ~ 0.088 px per observation.
  EXPECT_NEAR(e.summary.mean_point_error_px, 0.088, 0.02);
  fs::remove_all(e.dir);
}

// Reproject every point through the written poses and camera with COLMAP's
// formula: the model pixels must be the written observations up to their noise.
TEST(WriteColmapModel, PosesAndPixelConventionAreColmaps) {
  const Exported e = Export("omm_colmap_model_test_2");
  std::istringstream cams(ReadTextFile(e.dir / "cameras.txt", "cameras"));
  std::string line, model;
  std::vector<double> k;
  while (std::getline(cams, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream in(line);
    int id, w, h;
    in >> id >> model >> w >> h;
    for (double x; in >> x;) k.push_back(x);
  }
  ASSERT_EQ(k.size(), 12u);
  std::map<int, Eigen::Vector3d> points;
  std::istringstream pts(ReadTextFile(e.dir / "points3D.txt", "points"));
  while (std::getline(pts, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream in(line);
    int id;
    Eigen::Vector3d x;
    in >> id >> x.x() >> x.y() >> x.z();
    points[id] = x;
  }
  std::istringstream imgs(ReadTextFile(e.dir / "images.txt", "images"));
  std::vector<std::string> lines;
  while (std::getline(imgs, line)) {
    if (!line.empty() && line[0] != '#') lines.push_back(line);
  }
  ASSERT_EQ(lines.size(), 18u);
  double sum2 = 0.0;
  int n = 0;
  for (size_t i = 0; i < lines.size(); i += 2) {
    std::istringstream head(lines[i]);
    int id, cam;
    double qw, qx, qy, qz;
    Eigen::Vector3d t;
    head >> id >> qw >> qx >> qy >> qz >> t.x() >> t.y() >> t.z() >> cam;
    const Eigen::Matrix3d r = Eigen::Quaterniond(qw, qx, qy, qz).toRotationMatrix();
    std::istringstream obs(lines[i + 1]);
    Eigen::Vector2d q;
    int point;
    while (obs >> q.x() >> q.y() >> point) {
      const Eigen::Vector2d model_q = ColmapFullOpencv(k, r * points.at(point) + t);
      sum2 += (model_q - q).squaredNorm();
      ++n;
    }
  }
  ASSERT_EQ(n, e.summary.num_observations);
  // RMS of 0.07 px per axis noise: 0.099 px per observation. A missing 0.5 px
  // shift or a wrong pose would give >= 0.5 px.
  EXPECT_NEAR(std::sqrt(sum2 / n), 0.099, 0.015);
  fs::remove_all(e.dir);
}

}  // namespace
}  // namespace omm
