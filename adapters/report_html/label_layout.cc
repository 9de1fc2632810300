#include "adapters/report_html/label_layout.h"

#include <cmath>
#include <cstring>
#include <limits>

namespace omm {
namespace {

// DejaVu Sans advance widths, em (its hmtx table over 2048 units), by class:
// the widest member of each class, so that estimates err on the wide side.
double AdvanceEm(unsigned char c) {
  auto in = [c](const char* set) { return c != 0 && std::strchr(set, c) != nullptr; };
  if (c >= '0' && c <= '9') return 0.636;
  if (in(" .,:;'")) return 0.318;
  if (in("ijl")) return 0.278;
  if (in("frt()[]{}!|-")) return 0.411;
  if (in("_")) return 0.5;
  if (in("mwMW")) return 0.989;
  if (c >= 'a' && c <= 'z') return 0.635;
  if (c >= 'A' && c <= 'Z') return 0.787;
  return 0.838;  // other symbols, and any non-ASCII character (e.g. the plus-minus sign)
}

double OverlapArea(const Eigen::AlignedBox2d& a, const Eigen::AlignedBox2d& b) {
  const Eigen::AlignedBox2d i = a.intersection(b);
  return i.isEmpty() ? 0.0 : i.volume();
}

}  // namespace

double TextWidthEstimate(std::string_view text, double font_size) {
  double em = 0.0;
  for (const char c : text) {
    const auto byte = static_cast<unsigned char>(c);
    if ((byte & 0xC0) == 0x80) continue;  // a UTF-8 continuation byte: its character is counted
    em += AdvanceEm(byte);
  }
  return em * font_size;
}

Eigen::AlignedBox2d LabelBoxBeside(const Eigen::Vector2d& at, const Eigen::Vector2d& d, double w,
                                   double h) {
  // Per axis: a direction that leans one way puts the box on that side of
  // `at`; a direction across the axis centres the box on it.
  auto side = [](double at_k, double d_k, double size) {
    constexpr double kLean = 0.38;  // sin 22.5 deg: the eight compass sectors
    if (d_k > kLean) return at_k;
    if (d_k < -kLean) return at_k - size;
    return at_k - size / 2;
  };
  const Eigen::Vector2d min(side(at.x(), d.x(), w), side(at.y(), d.y(), h));
  return Eigen::AlignedBox2d(min, min + Eigen::Vector2d(w, h));
}

std::vector<Eigen::AlignedBox2d> CircleLabelCandidates(const Eigen::Vector2d& centre, double radius,
                                                       double gap, double w, double h) {
  const double s = std::sqrt(0.5);
  // y down: "upper" is -y.
  const Eigen::Vector2d directions[] = {{s, -s}, {-s, -s}, {s, s},  {-s, s},
                                        {1, 0},  {-1, 0},  {0, -1}, {0, 1}};
  std::vector<Eigen::AlignedBox2d> boxes;
  for (const Eigen::Vector2d& d : directions)
    boxes.push_back(LabelBoxBeside(centre + (radius + gap) * d, d, w, h));
  return boxes;
}

std::vector<Eigen::AlignedBox2d> SegmentLabelCandidates(const Eigen::Vector2d& a,
                                                        const Eigen::Vector2d& b, double gap,
                                                        double w, double h) {
  const Eigen::Vector2d along = b - a;
  Eigen::Vector2d normal(along.y(), -along.x());
  if (normal.norm() == 0.0) normal = Eigen::Vector2d(0, -1);
  normal.normalize();
  if (normal.y() > 0 || (normal.y() == 0 && normal.x() > 0)) normal = -normal;  // upper side
  std::vector<Eigen::AlignedBox2d> boxes;
  for (const double t : {0.5, 0.4, 0.6, 0.3, 0.7, 0.2, 0.8}) {
    const Eigen::Vector2d p = a + t * along;
    for (const Eigen::Vector2d& d : {normal, Eigen::Vector2d(-normal)})
      boxes.push_back(LabelBoxBeside(p + gap * d, d, w, h));
  }
  return boxes;
}

std::vector<int> PlaceLabels(const std::vector<std::vector<Eigen::AlignedBox2d>>& candidates,
                             const Eigen::AlignedBox2d& figure) {
  std::vector<int> chosen(candidates.size(), -1);
  std::vector<Eigen::AlignedBox2d> placed;
  for (size_t i = 0; i < candidates.size(); ++i) {
    double least = std::numeric_limits<double>::infinity();
    for (size_t k = 0; k < candidates[i].size(); ++k) {
      const Eigen::AlignedBox2d& box = candidates[i][k];
      double covered = box.volume() - OverlapArea(box, figure);
      for (const Eigen::AlignedBox2d& other : placed) covered += OverlapArea(box, other);
      if (covered < least) {
        least = covered;
        chosen[i] = static_cast<int>(k);
      }
      if (covered == 0.0) break;
    }
    if (chosen[i] >= 0) placed.push_back(candidates[i][chosen[i]]);
  }
  return chosen;
}

}  // namespace omm
