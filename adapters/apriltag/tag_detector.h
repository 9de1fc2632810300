// AprilTag 36h11 detection through libapriltag 3.3, on the pipeline's images.
//
// libapriltag finds quads by clustering edge segments, fits each side with a
// line (refine_edges) and decodes the 6 x 6 data cells. Its corners are the
// intersections of those lines: good to ~0.1-0.2 px, which is enough to
// identify a corner; the mosaic stage then locates the corner's neighbourhood
// by least-squares template matching between tiles (pipeline/mosaic), so the
// detector's corner precision does not enter the measurement.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/image.h"

namespace omm {

struct TagDetectorOptions {
  // Quad detection on an image decimated by this factor (1 = full resolution;
  // 2 is ~4x faster and still finds tags >= ~40 px); the corners are refined
  // on the full image either way.
  double quad_decimate = 2.0;
  // A first pass with quads found at this decimation (0: none): if it
  // detects nothing (whatever the decision margin), the tile is taken to
  // have no tags and the full pass is skipped; else the full pass runs as
  // without it (the same detections). Over the demo's nine tiles, which have
  // no tags, the library spends 392 million instructions at 1/6 and 246 at
  // 1/8 against 950 for a pass at 1/3. It must see a tag in every tagged
  // tile. The markers preset's tiles (seeds 101-103, 27 tiles, 89 tags of
  // ~130 px: both see a tag in every tile), scaled so that the tags span ~90,
  // ~65 and ~45 px: at 1/8 a tag is seen in 27, 17 and 3 of the 27 tiles, at
  // 1/6 in 27, 27 and 15; at 1/4 in all 27 at ~45 px (the full pass at 1/3
  // finds 89-90 tags at every size). So 1/6 keeps tags down to ~65 px.
  double gate_decimate = 0.0;
  double quad_sigma_px = 0.0;  // Gaussian blur before quad detection, px (0: none)
  int max_hamming = 1;         // bit errors corrected (36h11: up to 3; 1 keeps false ids away)
  double min_decision_margin = 30.0;  // libapriltag's decoding confidence, below: rejected
  int num_threads = 1;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct TagDetection {
  int id = 0;
  // Outer corners of the black border, px, libapriltag's order: bottom-left,
  // bottom-right, top-right, top-left of the printed tag.
  Eigen::Matrix<double, 2, 4> corners_px;
  Eigen::Vector2d center_px = Eigen::Vector2d::Zero();
  int hamming = 0;               // bits corrected
  double decision_margin = 0.0;  // libapriltag's confidence
};

// Detects tag36h11 tags in `image` (intensities in [0, 1], converted to 8
// bits after a robust stretch to the 0.5 % / 99.5 % percentiles, so the gain
// of the tile does not matter). Precondition: options.Check() is empty.
// Tags seen twice (the same id) are both dropped: an id must identify.
std::vector<TagDetection> DetectAprilTags36h11(const ImageF& image,
                                               const TagDetectorOptions& options = {});

}  // namespace omm
