#include "pipeline/simulate/scene.h"

#include <algorithm>
#include <cmath>

namespace omm {

PlatePattern::PlatePattern(const BoardSpec& board, double plate_size_mm, const Materials& materials)
    : board_(board),
      half_plate_(0.5 * plate_size_mm),
      half_frame_(0.5 * board.frame_mm),
      half_inner_(0.5 * board.frame_mm - board.frame_bar_mm),
      dot_r2_(0.25 * board.dot_diameter_mm * board.dot_diameter_mm),
      inv_pitch_(1.0 / board.pitch_mm),
      white_(materials.plate_white),
      black_(materials.plate_black) {}

WorkpieceScene::WorkpieceScene(Layout layout, const SurfaceTexture* texture,
                               const Materials& materials)
    : layout_(std::move(layout)), texture_(texture), materials_(materials) {
  // part (X, Y) = t + R2 (x, y) with R2 the upper-left 2x2 of part_from_plate
  // (the plate lies in the part's Z = 0 plane).
  plate_from_part_2d_ = layout_.part_from_plate.linear().topLeftCorner<2, 2>().inverse();
  plate_origin_ = layout_.part_from_plate.translation().head<2>();
  const Eigen::Vector2d size = layout_.max_mm - layout_.min_mm;
  grid_cols_ = std::max(1, static_cast<int>(std::ceil(size.x() / kCellMm)));
  grid_rows_ = std::max(1, static_cast<int>(std::ceil(size.y() / kCellMm)));
  grid_.resize(static_cast<size_t>(grid_cols_) * grid_rows_);
  // Adds `index` to every cell the disc (centre, radius) reaches.
  auto add = [&](const Eigen::Vector2d& centre, double radius, auto member, int index) {
    const Eigen::Vector2d lo = (centre - layout_.min_mm).array() - radius;
    const Eigen::Vector2d hi = (centre - layout_.min_mm).array() + radius;
    for (int r = std::max(0, static_cast<int>(lo.y() / kCellMm));
         r <= std::min(grid_rows_ - 1, static_cast<int>(hi.y() / kCellMm)); ++r) {
      for (int c = std::max(0, static_cast<int>(lo.x() / kCellMm));
           c <= std::min(grid_cols_ - 1, static_cast<int>(hi.x() / kCellMm)); ++c) {
        (grid_[static_cast<size_t>(r) * grid_cols_ + c].*member).push_back(index);
      }
    }
  };
  for (int i = 0; i < static_cast<int>(layout_.holes.size()); ++i) {
    add(layout_.holes[i].center_mm, layout_.holes[i].radius_mm, &Cell::holes, i);
  }
  for (int i = 0; i < static_cast<int>(layout_.markers.size()); ++i) {
    const double angle = layout_.markers[i].angle_rad;
    marker_axes_.emplace_back(std::cos(angle), std::sin(angle));
    add(layout_.markers[i].center_mm, layout_.markers[i].paper_size_mm / std::sqrt(2.0),
        &Cell::markers, i);
  }
}

SceneSample WorkpieceScene::Sample(const Eigen::Vector2d& p, const Eigen::Vector3d& d_part) const {
  if (p.x() < layout_.min_mm.x() || p.x() > layout_.max_mm.x() || p.y() < layout_.min_mm.y() ||
      p.y() > layout_.max_mm.y()) {
    return {materials_.table, Region::kTable};
  }
  if (layout_.plate) {
    const Eigen::Vector2d q = plate_from_part_2d_ * (p - plate_origin_);
    if (layout_.plate->Contains(q.x(), q.y())) return layout_.plate->Sample(q.x(), q.y());
  }
  const int col =
      std::min(grid_cols_ - 1, static_cast<int>((p.x() - layout_.min_mm.x()) / kCellMm));
  const int row =
      std::min(grid_rows_ - 1, static_cast<int>((p.y() - layout_.min_mm.y()) / kCellMm));
  const Cell& cell = grid_[static_cast<size_t>(row) * grid_cols_ + col];
  for (const int m : cell.markers) {
    const MarkerShape& marker = layout_.markers[m];
    const Eigen::Vector2d v = p - marker.center_mm;
    const double c = marker_axes_[m].x(), s = marker_axes_[m].y();
    const double u = c * v.x() + s * v.y();  // along the print's +x
    const double w = s * v.x() - c * v.y();  // along the print's +y (down)
    const double half = 0.5 * marker.paper_size_mm;
    if (std::abs(u) > half || std::abs(w) > half) continue;
    const int n = static_cast<int>(marker.cells.rows());
    const double fc = u / marker.cell_mm + 0.5 * n, fr = w / marker.cell_mm + 0.5 * n;
    if (fc < 0 || fr < 0 || fc >= n || fr >= n ||
        marker.cells(static_cast<int>(fr), static_cast<int>(fc))) {
      return {materials_.paper, Region::kPaper};
    }
    return {materials_.ink, Region::kInk};
  }
  for (const int h : cell.holes) {
    const HoleShape& hole = layout_.holes[h];
    const Eigen::Vector2d v = p - hole.center_mm;
    const double r2 = hole.radius_mm * hole.radius_mm;
    if (v.squaredNorm() > r2) continue;
    // Where the ray leaves the bottom face: inside the bore's circle there it
    // saw through to the table, else it met the (convex) bore wall.
    const Eigen::Vector2d bottom = v + d_part.head<2>() * (layout_.thickness_mm / -d_part.z());
    if (bottom.squaredNorm() <= r2) return {materials_.table, Region::kTable};
    return {materials_.hole_wall, Region::kHoleWall};
  }
  return {texture_->Reflectance(p.x(), p.y()), Region::kTexture};
}

}  // namespace omm
