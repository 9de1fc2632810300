#include "pipeline/core/board.h"

namespace omm {

const char* BoardTypeName(BoardType type) {
  switch (type) {
    case BoardType::kCaltab: return "caltab";
    case BoardType::kCircles: return "circles";
    case BoardType::kChessboard: return "chessboard";
  }
  return "?";
}

std::optional<BoardType> BoardTypeFromName(std::string_view name) {
  for (BoardType type : {BoardType::kCaltab, BoardType::kCircles, BoardType::kChessboard}) {
    if (name == BoardTypeName(type)) return type;
  }
  return std::nullopt;
}

Eigen::Matrix3Xd BoardPoints(const BoardSpec& board) {
  Eigen::Matrix3Xd points(3, board.rows * board.cols);
  for (int r = 0; r < board.rows; ++r) {
    for (int c = 0; c < board.cols; ++c) {
      points.col(r * board.cols + c) << (c - 0.5 * (board.cols - 1)) * board.pitch_mm,
          (r - 0.5 * (board.rows - 1)) * board.pitch_mm, 0.0;
    }
  }
  return points;
}

}  // namespace omm
