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
  // without it (the same detections). At 1/8 it costs the library a quarter
  // of a pass at 1/3 (246 against 953 million instructions over the demo's
  // nine tiles, which have no tags). It must see a tag in every tagged tile:
  // at 1/8 it finds 174 of the 176 tags that 1/3 finds on the markers
  // preset's 54 tiles (20 mm tags, ~130 px; seeds 1, 101-105), a tag in
  // each tile. Much smaller tags need a finer first pass (not measured).
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
