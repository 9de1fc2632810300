// Where a figure's text labels go, so that none covers another: the mosaic
// overlay of report.html names every feature and every distance, and on a
// real part many distances cross near the same midpoint.
//
// Boxes are in the figure's user space (x right, y down), each a label's
// ink plus the margin it needs (its white halo).
#pragma once

#include <string_view>
#include <vector>

#include <Eigen/Geometry>

namespace omm {

// Width of `text` (UTF-8, not escaped) set in DejaVu Sans, Debian's default
// sans-serif, at `font_size`: the sum of advance widths by glyph class
// (digits 0.636 em, space and punctuation 0.318, lowercase 0.62, capitals
// 0.75, ...). Within a few per cent of the real width for names and numbers;
// an estimate, so callers pad it.
double TextWidthEstimate(std::string_view text, double font_size);

// The box of a w x h label set beside the point `at` in direction `d`
// (a unit vector, y down): its edge or corner nearest to `at` touches it,
// e.g. d = (1, 0): the box's left edge centred on `at`; d = (0.7, -0.7):
// its lower-left corner on `at`.
Eigen::AlignedBox2d LabelBoxBeside(const Eigen::Vector2d& at, const Eigen::Vector2d& d, double w,
                                   double h);

// The candidate boxes of a label for a circle (centre, radius): beside it,
// `gap` beyond its rim, in the eight compass directions, upper right first
// (where a reader looks for a name), then upper left, lower right, lower
// left, right, left, above, below.
std::vector<Eigen::AlignedBox2d> CircleLabelCandidates(const Eigen::Vector2d& centre, double radius,
                                                       double gap, double w, double h);

// The candidate boxes of a label for the segment a-b: beside it, `gap` off
// the line on either side (the upper side first), at 0.5 of its length, then
// 0.4, 0.6, 0.3, 0.7, 0.2, 0.8 (near the middle, where it reads as the
// segment's).
std::vector<Eigen::AlignedBox2d> SegmentLabelCandidates(const Eigen::Vector2d& a,
                                                        const Eigen::Vector2d& b, double gap,
                                                        double w, double h);

// Places the labels one by one, in the given order (earlier ones have the
// first choice): each takes its first candidate that lies inside `figure`
// and overlaps no label placed before it, or, when there is none, the
// candidate that covers the least: the area it shares with the labels placed
// before it plus its area outside `figure` (ties: the earlier candidate).
// Returns the chosen candidate's index per label; -1 for one without
// candidates. O(n^2 k) for n labels of k candidates: report figures hold
// tens.
std::vector<int> PlaceLabels(const std::vector<std::vector<Eigen::AlignedBox2d>>& candidates,
                             const Eigen::AlignedBox2d& figure);

}  // namespace omm
