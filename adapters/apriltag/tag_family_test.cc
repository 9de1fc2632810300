#include "adapters/apriltag/tag_family.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <vector>

#include <gtest/gtest.h>

#include <apriltag/apriltag.h>
#include <apriltag/tag36h11.h>

namespace omm {
namespace {

TEST(AprilTag36h11, LayoutIsTheFamilys) {
  const TagFamilyLayout layout = AprilTag36h11Layout();
  EXPECT_EQ(layout.num_codes, 587);
  EXPECT_EQ(layout.total_width, 10);
  EXPECT_EQ(layout.width_at_border, 8);
}

// The cells are exactly libapriltag's own rendering of the tag.
TEST(AprilTag36h11, CellsMatchApriltagToImage) {
  apriltag_family_t* family = tag36h11_create();
  for (int id : {0, 1, 7, 100, 586}) {
    const TagCells cells = AprilTag36h11Cells(id);
    image_u8_t* im = apriltag_to_image(family, id);
    ASSERT_EQ(cells.rows(), static_cast<int>(im->height));
    ASSERT_EQ(cells.cols(), static_cast<int>(im->width));
    for (int r = 0; r < cells.rows(); ++r) {
      for (int c = 0; c < cells.cols(); ++c) {
        EXPECT_EQ(cells(r, c), im->buf[r * im->stride + c] > 127)
            << "id " << id << " cell " << r << "," << c;
      }
    }
    // libapriltag does not export image_u8_destroy; it allocates with calloc.
    std::free(im->buf);
    std::free(im);
  }
  tag36h11_destroy(family);
}

// A tag drawn from the cells is found by the detector with its id, and its
// corners are the outer corners of the black border.
TEST(AprilTag36h11, DetectorReadsRenderedCells) {
  constexpr int kCellPx = 12;
  constexpr int kMarginPx = 40;
  const int id = 42;
  const TagCells cells = AprilTag36h11Cells(id);
  const int size = static_cast<int>(cells.rows()) * kCellPx + 2 * kMarginPx;
  std::vector<uint8_t> buf(static_cast<size_t>(size) * size);
  image_u8_t image{size, size, size, buf.data()};
  image_u8_t* im = &image;
  for (int y = 0; y < size; ++y) {
    for (int x = 0; x < size; ++x) {
      const int r = (y - kMarginPx) / kCellPx, c = (x - kMarginPx) / kCellPx;
      const bool inside = y >= kMarginPx && x >= kMarginPx && r < cells.rows() && c < cells.cols();
      im->buf[y * im->stride + x] = (!inside || cells(r, c)) ? 230 : 20;
    }
  }
  apriltag_family_t* family = tag36h11_create();
  apriltag_detector_t* detector = apriltag_detector_create();
  apriltag_detector_add_family(detector, family);
  detector->quad_decimate = 1.0;
  zarray_t* detections = apriltag_detector_detect(detector, im);
  ASSERT_EQ(zarray_size(detections), 1);
  apriltag_detection_t* det;
  zarray_get(detections, 0, &det);
  EXPECT_EQ(det->id, id);
  // Border corners: cells 1 .. 9, pixel edges at margin + 1 cell and margin +
  // 9 cells; pixel centres are integers, so an edge between pixels k-1 and k is
  // at k - 0.5. The detector lists them from the tag's bottom-left corner
  // counter-clockwise as seen in the image (bottom-left, bottom-right,
  // top-right, top-left of the printed tag): the order the simulator's truth
  // uses. libapriltag's corners are biased by about +0.4 px, hence the bound.
  const double lo = kMarginPx + kCellPx - 0.5, hi = kMarginPx + 9 * kCellPx - 0.5;
  const double expected[4][2] = {{lo, hi}, {hi, hi}, {hi, lo}, {lo, lo}};
  for (int k = 0; k < 4; ++k) {
    EXPECT_NEAR(det->p[k][0], expected[k][0], 0.6) << k;
    EXPECT_NEAR(det->p[k][1], expected[k][1], 0.6) << k;
  }
  apriltag_detections_destroy(detections);
  apriltag_detector_destroy(detector);
  tag36h11_destroy(family);
}

}  // namespace
}  // namespace omm
