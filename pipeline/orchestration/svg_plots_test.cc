#include "pipeline/orchestration/svg_plots.h"

#include <cmath>
#include <regex>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

namespace omm {
namespace {

using ::testing::HasSubstr;

// The grid ImagerGridPoints samples: linspace(0, W-1) x linspace(0, H-1).
Eigen::Matrix2Xd Grid(int nx, int ny, int width_px, int height_px) {
  Eigen::Matrix2Xd q(2, nx * ny);
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i)
      q.col(j * nx + i) << i * (width_px - 1.0) / (nx - 1), j * (height_px - 1.0) / (ny - 1);
  return q;
}

// A field linear in x is reproduced exactly by the bilinear interpolation and
// by marching squares' linear edge crossings: every contour of level L is the
// vertical line x = (L - 1.03) / 0.8 (W - 1), drawn at 600 / W per imager
// pixel. (The levels fall at 0.06..0.81 of a cell, so a crossing
// interpolated wrongly would show.)
TEST(UncertaintyMapSvg, ContoursOfALinearFieldAreWhereItHasTheirLevel) {
  const int nx = 16, ny = 12, w = 1600, h = 1200;
  const Eigen::Matrix2Xd q = Grid(nx, ny, w, h);
  const Eigen::VectorXd value =
      (0.8 * q.row(0).array() / (w - 1) + 1.03).matrix().transpose();  // 1.03..1.83
  const std::string svg = UncertaintyMapSvg(q, value, nx, ny, w, h, 406.0);
  EXPECT_THAT(svg, HasSubstr("at 406 mm, 16x12 grid: 1.0300 to 1.8300 px"));
  EXPECT_THAT(svg, HasSubstr("linear colour scale"));
  // 46 x 34 bilinear samples (3 per cell), one rectangle each, and the colour
  // bar's 40 and its frame.
  const std::regex rect("<rect x=");
  EXPECT_EQ(
      std::distance(std::sregex_iterator(svg.begin(), svg.end(), rect), std::sregex_iterator()),
      46 * 34 + 40 + 1);
  const double s = 600.0 / w;
  const std::regex segment("M([0-9.]+) ([0-9.]+)L([0-9.]+) ([0-9.]+)");
  int segments = 0;
  for (std::sregex_iterator it(svg.begin(), svg.end(), segment), end; it != end; ++it, ++segments) {
    const double x0 = std::stod((*it)[1]), x1 = std::stod((*it)[3]);
    // Round steps near 0.8 / 5: levels 1.2, 1.4, 1.6, 1.8; positions printed
    // to 0.05.
    const double level = 1.03 + 0.8 * x0 / s / (w - 1);
    EXPECT_NEAR(std::round(level * 5) / 5, level, 0.8 * 0.05 / s / (w - 1)) << x0;
    EXPECT_NEAR(x1, x0, 0.05 + 1e-9);
  }
  // Each level crosses the 33 rows of interpolated cells once.
  EXPECT_EQ(segments, 4 * 11 * 3);
  for (const char* label : {">1.2<", ">1.4<", ">1.6<", ">1.8<"}) EXPECT_THAT(svg, HasSubstr(label));
}

// Two decades of range: log colours, 1-2-5 contours.
TEST(UncertaintyMapSvg, WideRangeGetsALogScale) {
  const int nx = 8, ny = 6, w = 800, h = 600;
  const Eigen::Matrix2Xd q = Grid(nx, ny, w, h);
  Eigen::VectorXd value(nx * ny);
  for (int k = 0; k < nx * ny; ++k) value(k) = 0.001 * std::pow(100.0, q(0, k) / (w - 1));
  const std::string svg = UncertaintyMapSvg(q, value, nx, ny, w, h, 300.0);
  EXPECT_THAT(svg, HasSubstr("log colour scale"));
  for (const char* label : {">0.002<", ">0.005<", ">0.01<", ">0.02<", ">0.05<"})
    EXPECT_THAT(svg, HasSubstr(label)) << label;
  // The ends of the colour bar: viridis' first and last stops.
  EXPECT_THAT(svg, HasSubstr("fill=\"#440154\""));
  EXPECT_THAT(svg, HasSubstr("fill=\"#fde725\""));
}

}  // namespace
}  // namespace omm
