// Calibration boards and the plate coordinates of their marks.
#pragma once

#include <optional>
#include <string>
#include <string_view>

#include <Eigen/Core>

namespace omm {

enum class BoardType { kCaltab, kCircles, kChessboard };

// The plate of ../../../shared/docs/project-format.md. For a chessboard,
// rows x cols counts the INNER corners and pitch_mm is the square size.
struct BoardSpec {
  BoardType type = BoardType::kCaltab;
  int rows = 7;
  int cols = 7;
  double pitch_mm = 12.5;         // centre-to-centre distance of the marks
  double dot_diameter_mm = 6.25;  // caltab and circles only
  double frame_mm = 100.0;        // caltab: outer edge length of the frame
  double frame_bar_mm = 3.125;    // caltab: width of the frame's bar
  double triangle_mm = 12.5;      // caltab: leg length of the corner triangle
};

const char* BoardTypeName(BoardType type);

// The type BoardTypeName gives `name` ("caltab", "circles", "chessboard");
// nullopt for any other name.
std::optional<BoardType> BoardTypeFromName(std::string_view name);

// Plate coordinates (mm, z = 0) of mark (r, c), stored at column r * cols + c:
// x = (c - (cols-1)/2) pitch, y = (r - (rows-1)/2) pitch. Shape 3 x rows*cols.
Eigen::Matrix3Xd BoardPoints(const BoardSpec& board);

}  // namespace omm
