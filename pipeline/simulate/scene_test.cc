// Paper markers as rendered in tiles, read by libapriltag's own detector:
// the right ids, corners where the truth says, in the truth's order. This
// checks handedness and orientation independently of the renderer's code.
#include "pipeline/simulate/scene.h"

#include <vector>

#include <gtest/gtest.h>

#include <apriltag/apriltag.h>
#include <apriltag/tag36h11.h>

#include "adapters/mrcal/lens.h"
#include "pipeline/simulate/simulation.h"

namespace omm {
namespace {

TEST(RenderedMarkers, AprilTagDetectorFindsThemWhereTheTruthSays) {
  SimulationOptions options;
  options.preset = "markers";
  options.seed = 9;
  const SimulationPlan plan = PlanSimulation(options);
  const SimulationTruth& truth = plan.truth;
  const ProjectRenderer renderer(plan);

  apriltag_family_t* family = tag36h11_create();
  apriltag_detector_t* detector = apriltag_detector_create();
  apriltag_detector_add_family(detector, family);
  detector->quad_decimate = 1.0;
  detector->nthreads = 1;

  int checked = 0;
  for (const MarkerTruth& marker : truth.markers) {
    if (checked == 3) break;
    for (int t = 0; t < static_cast<int>(truth.tiles.size()); ++t) {
      const Eigen::Isometry3d cam_from_part =
          truth.cam_from_part *
          Eigen::Translation3d(truth.tiles[t].actual_mm.x(), truth.tiles[t].actual_mm.y(), 0.0);
      Eigen::Matrix3Xd p(3, 4);
      for (int k = 0; k < 4; ++k)
        p.col(k) = cam_from_part *
                   Eigen::Vector3d(marker.corners_part_mm(0, k), marker.corners_part_mm(1, k), 0);
      Eigen::Matrix2Xd q;
      ASSERT_TRUE(ProjectPoints(truth.camera.model, p, &q));
      const Eigen::Vector2d lo = q.rowwise().minCoeff().array() - 60,
                            hi = q.rowwise().maxCoeff().array() + 60;
      if (lo.minCoeff() < 0 || hi.x() > 1599 || hi.y() > 1199) continue;
      const PixelRect rect{static_cast<int>(lo.x()), static_cast<int>(lo.y()),
                           static_cast<int>(hi.x() - lo.x()), static_cast<int>(hi.y() - lo.y())};
      RayTableSummary summary;
      const RayTable rays =
          ComputeRayTable(truth.camera.model, rect, RayOptionsFor(options), &summary);
      const ImageF image = renderer.RenderTile(t, rays);  // with noise, 8 bit

      std::vector<uint8_t> buffer(static_cast<size_t>(rect.width) * rect.height);
      for (int r = 0; r < rect.height; ++r) {
        for (int c = 0; c < rect.width; ++c)
          buffer[r * rect.width + c] = static_cast<uint8_t>(std::lround(image(r, c) * 255));
      }
      image_u8_t im{rect.width, rect.height, rect.width, buffer.data()};
      zarray_t* detections = apriltag_detector_detect(detector, &im);
      bool found = false;
      for (int i = 0; i < zarray_size(detections); ++i) {
        apriltag_detection_t* det;
        zarray_get(detections, i, &det);
        if (det->id != marker.id) continue;
        found = true;
        for (int k = 0; k < 4; ++k) {
          // libapriltag's corners are biased by up to ~0.5 px.
          EXPECT_NEAR(det->p[k][0] + rect.x0, q(0, k), 1.0)
              << "marker " << marker.id << " corner " << k;
          EXPECT_NEAR(det->p[k][1] + rect.y0, q(1, k), 1.0)
              << "marker " << marker.id << " corner " << k;
        }
      }
      apriltag_detections_destroy(detections);
      EXPECT_TRUE(found) << "marker " << marker.id << " in " << truth.tiles[t].image;
      ++checked;
      break;
    }
  }
  EXPECT_EQ(checked, 3);
  apriltag_detector_destroy(detector);
  tag36h11_destroy(family);
}

}  // namespace
}  // namespace omm
