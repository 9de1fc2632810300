// AprilTag 36h11 tags as cell matrices, for rendering paper markers.
//
// A tag of family 36h11 is printed as a square of total_width x total_width
// cells (10 x 10 for 36h11): a white outer ring of one cell, a black ring of
// one cell (the border the detector finds; width_at_border = 8 cells across
// its outer edge) and a 6 x 6 data area. The cell matrix is the image
// libapriltag's apriltag_to_image() renders for that id: row 0 is the top of
// the printed tag, column 0 its left side, true = white.
#pragma once

#include <Eigen/Core>

namespace omm {

using TagCells = Eigen::Matrix<bool, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

struct TagFamilyLayout {
  int num_codes = 0;        // ids 0 .. num_codes-1
  int total_width = 0;      // cells across the printed tag, white ring included
  int width_at_border = 0;  // cells across the outer edge of the black border
};

// Layout of tag36h11 (587 codes, 10 cells, border 8 cells).
TagFamilyLayout AprilTag36h11Layout();

// Cells of tag36h11 id `id` (0 <= id < num_codes), total_width x total_width.
// Built from the family's codes[id], bit_x, bit_y and reversed_border exactly
// as apriltag_to_image() does.
TagCells AprilTag36h11Cells(int id);

}  // namespace omm
