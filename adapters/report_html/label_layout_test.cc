// Label placement for report.html's mosaic figure (label_layout.h): boxes
// beside circles and segments, and the greedy placement that keeps them
// apart. The real font's widths against TextWidthEstimate are checked where
// the page is rendered (tests/report_html_test.cc, ReportHtmlChromium).
#include "adapters/report_html/label_layout.h"

#include <cmath>

#include <gtest/gtest.h>

namespace omm {
namespace {

using Box = Eigen::AlignedBox2d;

bool Overlap(const Box& a, const Box& b) {
  const Box i = a.intersection(b);
  return !i.isEmpty() && i.volume() > 0;
}

TEST(LabelLayout, TextWidthCountsCharactersNotBytes) {
  // "±" is two bytes in UTF-8, one glyph; ASCII digits are 0.636 em.
  EXPECT_DOUBLE_EQ(TextWidthEstimate("\u00b1", 10.0), TextWidthEstimate("+", 10.0));
  EXPECT_DOUBLE_EQ(TextWidthEstimate("00", 10.0), 2 * TextWidthEstimate("0", 10.0));
  EXPECT_DOUBLE_EQ(TextWidthEstimate("0", 10.0), 6.36);
  EXPECT_LT(TextWidthEstimate("iiii", 10.0), TextWidthEstimate("mmmm", 10.0));
}

TEST(LabelLayout, BoxBesideTouchesThePointWithItsNearestEdgeOrCorner) {
  const Eigen::Vector2d at(100, 50);
  const double s = std::sqrt(0.5);
  // Right: left edge on `at`, centred vertically.
  const Box right = LabelBoxBeside(at, {1, 0}, 40, 10);
  EXPECT_EQ(right.min(), Eigen::Vector2d(100, 45));
  EXPECT_EQ(right.max(), Eigen::Vector2d(140, 55));
  // Upper left (y down): lower-right corner on `at`.
  const Box upper_left = LabelBoxBeside(at, {-s, -s}, 40, 10);
  EXPECT_EQ(upper_left.max(), at);
  // Below: top edge on `at`, centred horizontally.
  const Box below = LabelBoxBeside(at, {0, 1}, 40, 10);
  EXPECT_EQ(below.min(), Eigen::Vector2d(80, 50));
}

TEST(LabelLayout, CircleCandidatesLieOutsideTheCircleUpperRightFirst) {
  const Eigen::Vector2d centre(200, 200);
  const double r = 30, gap = 2;
  const std::vector<Box> boxes = CircleLabelCandidates(centre, r, gap, 50, 12);
  ASSERT_EQ(boxes.size(), 8u);
  EXPECT_GT(boxes[0].min().x(), centre.x());  // upper right
  EXPECT_LT(boxes[0].max().y(), centre.y());
  for (const Box& box : boxes) {
    // The box's nearest point to the centre is at least r + gap from it
    // (up to the corner directions' diagonal touch).
    const Eigen::Vector2d nearest = centre.cwiseMax(box.min()).cwiseMin(box.max());
    EXPECT_GE((nearest - centre).norm(), r + gap - 1e-9);
  }
}

TEST(LabelLayout, SegmentCandidatesStartAtTheMiddleOnTheUpperSide) {
  const Eigen::Vector2d a(0, 100), b(400, 100);  // horizontal
  const std::vector<Box> boxes = SegmentLabelCandidates(a, b, 3, 80, 14);
  ASSERT_EQ(boxes.size(), 14u);
  EXPECT_DOUBLE_EQ(boxes[0].center().x(), 200);
  EXPECT_DOUBLE_EQ(boxes[0].max().y(), 97);   // above the line by the gap
  EXPECT_DOUBLE_EQ(boxes[1].min().y(), 103);  // then below
  // A vertical segment: beside it, not across it.
  for (const Box& box : SegmentLabelCandidates({50, 0}, {50, 300}, 3, 80, 14))
    EXPECT_TRUE(box.max().x() <= 47 || box.min().x() >= 53);
}

// Eight segments through one point, as distances across a part cross near
// its middle: every label's first choice is the same place. All of them are
// placed apart, inside the figure.
TEST(LabelLayout, LabelsCrossingAtOnePointArePlacedApart) {
  const Box figure(Eigen::Vector2d(0, 0), Eigen::Vector2d(1200, 1000));
  const Eigen::Vector2d middle(600, 500);
  std::vector<std::vector<Box>> candidates;
  for (int k = 0; k < 8; ++k) {
    const double angle = M_PI * k / 8;
    const Eigen::Vector2d d(std::cos(angle), std::sin(angle));
    candidates.push_back(SegmentLabelCandidates(middle - 400 * d, middle + 400 * d, 3, 280, 20));
    ASSERT_TRUE(Overlap(candidates.back()[0], candidates[0][0]) || k == 0);
  }
  const std::vector<int> chosen = PlaceLabels(candidates, figure);
  ASSERT_EQ(chosen.size(), candidates.size());
  EXPECT_EQ(chosen[0], 0);  // the first label keeps its first choice
  for (size_t i = 0; i < chosen.size(); ++i) {
    ASSERT_GE(chosen[i], 0);
    const Box& box = candidates[i][chosen[i]];
    EXPECT_TRUE(figure.contains(box)) << i;
    for (size_t j = 0; j < i; ++j)
      EXPECT_FALSE(Overlap(box, candidates[j][chosen[j]])) << i << " " << j;
  }
}

TEST(LabelLayout, ACandidateOutsideTheFigureIsPassedOver) {
  const Box figure(Eigen::Vector2d(0, 0), Eigen::Vector2d(100, 100));
  const std::vector<std::vector<Box>> candidates = {
      {Box(Eigen::Vector2d(90, 10), Eigen::Vector2d(130, 20)),
       Box(Eigen::Vector2d(40, 10), Eigen::Vector2d(80, 20))}};
  EXPECT_EQ(PlaceLabels(candidates, figure), std::vector<int>({1}));
}

// Where every candidate covers something, the label takes the one covering
// least (labels are drawn, never dropped); one without candidates gets -1.
TEST(LabelLayout, WithNoFreePlaceTheLeastCoveringCandidateIsTaken) {
  const Box figure(Eigen::Vector2d(0, 0), Eigen::Vector2d(100, 100));
  const Box first(Eigen::Vector2d(0, 0), Eigen::Vector2d(60, 20));
  const std::vector<std::vector<Box>> candidates = {
      {first},
      {Box(Eigen::Vector2d(10, 5), Eigen::Vector2d(50, 15)),    // 400 covered
       Box(Eigen::Vector2d(50, 10), Eigen::Vector2d(90, 30)),   // 100 covered
       Box(Eigen::Vector2d(80, 0), Eigen::Vector2d(120, 10))},  // 200 outside
      {}};
  EXPECT_EQ(PlaceLabels(candidates, figure), std::vector<int>({0, 1, -1}));
}

}  // namespace
}  // namespace omm
