#include "pipeline/orchestration/svg_plots.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <string>
#include <vector>

#include <fmt/format.h>

namespace omm {
namespace {

constexpr const char* kColors[] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b",
                                   "#e377c2", "#7f7f7f", "#bcbd22", "#17becf", "#393b79"};

// Viridis at 9 evenly spaced stops.
constexpr unsigned kViridis[] = {0x440154, 0x472d7b, 0x3b528b, 0x2c728e, 0x21918c,
                                 0x28ae80, 0x5ec962, 0xaadc32, 0xfde725};

// Colour of t in [0, 1], linear between the stops.
std::string Viridis(double t) {
  const double u = std::clamp(t, 0.0, 1.0) * (std::size(kViridis) - 1);
  const size_t i = std::min(static_cast<size_t>(u), std::size(kViridis) - 2);
  const double f = u - static_cast<double>(i);
  auto channel = [&](int shift) {
    const double a = (kViridis[i] >> shift) & 0xff, b = (kViridis[i + 1] >> shift) & 0xff;
    return static_cast<int>(std::lround(a + f * (b - a)));
  };
  return fmt::format("#{:02x}{:02x}{:02x}", channel(16), channel(8), channel(0));
}

// A round step (1, 2 or 5 times a power of ten) near span / 5.
double RoundStep(double span) {
  const double raw = span / 5.0;
  const double decade = std::pow(10.0, std::floor(std::log10(raw)));
  for (const double m : {1.0, 2.0, 5.0})
    if (m * decade >= raw) return m * decade;
  return 10.0 * decade;
}

// Contour segments of `level` through a grid of values v (rows: y) whose
// nodes are at (x[i], y[j]), by marching squares; saddles resolved by the
// cell's mean. Appended to `path` as "M x y L x y" in the coordinates given.
void Contour(const Eigen::MatrixXd& v, const std::vector<double>& x, const std::vector<double>& y,
             double level, std::string& path) {
  for (Eigen::Index j = 0; j + 1 < v.rows(); ++j) {
    for (Eigen::Index i = 0; i + 1 < v.cols(); ++i) {
      // Corners a b / d c (x right, y down); edges top, right, bottom, left.
      const double a = v(j, i), b = v(j, i + 1), c = v(j + 1, i + 1), d = v(j + 1, i);
      const double corner[4] = {a, b, c, d};
      const double cx[4] = {x[i], x[i + 1], x[i + 1], x[i]};
      const double cy[4] = {y[j], y[j], y[j + 1], y[j + 1]};
      Eigen::Vector2d cross[4];
      bool has[4] = {false, false, false, false};
      int count = 0;
      for (int e = 0; e < 4; ++e) {
        const double v0 = corner[e], v1 = corner[(e + 1) % 4];
        if ((v0 >= level) == (v1 >= level)) continue;
        const double f = (level - v0) / (v1 - v0);
        const int n = (e + 1) % 4;
        cross[e] = {cx[e] + f * (cx[n] - cx[e]), cy[e] + f * (cy[n] - cy[e])};
        has[e] = true;
        ++count;
      }
      auto segment = [&](int e0, int e1) {
        path += fmt::format("M{:.1f} {:.1f}L{:.1f} {:.1f}", cross[e0].x(), cross[e0].y(),
                            cross[e1].x(), cross[e1].y());
      };
      if (count == 2) {
        int e0 = -1, e1 = -1;
        for (int e = 0; e < 4; ++e)
          if (has[e]) (e0 < 0 ? e0 : e1) = e;
        segment(e0, e1);
      } else if (count == 4) {
        // The centre on a's side joins a and c: cut b's and d's corners.
        if (((a + b + c + d) / 4 >= level) == (a >= level)) {
          segment(0, 1);
          segment(2, 3);
        } else {
          segment(3, 0);
          segment(1, 2);
        }
      }
    }
  }
}

}  // namespace

std::string UncertaintyMapSvg(const Eigen::Matrix2Xd& q_px, const Eigen::VectorXd& value_px,
                              int grid_nx, int grid_ny, int width_px, int height_px,
                              double distance_mm) {
  assert(grid_nx >= 2 && grid_ny >= 2 && q_px.cols() == grid_nx * grid_ny &&
         value_px.size() == q_px.cols());
  const double panel_w = 600.0;
  const double s = panel_w / std::max(1, width_px);
  const double panel_h = height_px * s;
  const double total_h = panel_h + 60.0;
  const double lo = value_px.minCoeff(), hi = value_px.maxCoeff();
  // Uncertainty grows by orders of magnitude towards the corners: a log colour
  // scale and 1-2-5 contours then, else linear ones.
  const bool log_scale = lo > 0 && hi / lo >= 5.0;
  auto scale = [&](double value) {
    if (log_scale) return std::log(std::max(value, lo) / lo) / std::log(hi / lo);
    return (value - lo) / std::max(hi - lo, 1e-12);
  };
  // Contour levels; none within 3% of the scale's ends, where they would only
  // trace the flat bottom (or top) of the map.
  std::vector<double> levels;
  auto keep = [&](double level) { return scale(level) > 0.03 && scale(level) < 0.97; };
  if (log_scale) {
    for (double decade = std::pow(10.0, std::floor(std::log10(lo))); decade <= hi; decade *= 10) {
      for (const double m : {1.0, 2.0, 5.0})
        if (m * decade > lo && m * decade < hi && keep(m * decade)) levels.push_back(m * decade);
    }
  } else if (hi > lo) {
    const double step = RoundStep(hi - lo);
    for (double level = std::ceil(lo / step) * step; level < hi; level += step)
      if (level > lo && keep(level)) levels.push_back(level);
  }

  // Each grid cell split into kSub x kSub bilinear samples.
  constexpr int kSub = 3;
  const int fine_nx = (grid_nx - 1) * kSub + 1, fine_ny = (grid_ny - 1) * kSub + 1;
  Eigen::MatrixXd fine(fine_ny, fine_nx);
  std::vector<double> fine_x(fine_nx), fine_y(fine_ny);
  for (int fi = 0; fi < fine_nx; ++fi) {
    const int i = std::min(fi / kSub, grid_nx - 2);
    const double f = static_cast<double>(fi - i * kSub) / kSub;
    fine_x[fi] = s * ((1 - f) * q_px(0, i) + f * q_px(0, i + 1));
  }
  for (int fj = 0; fj < fine_ny; ++fj) {
    const int j = std::min(fj / kSub, grid_ny - 2);
    const double f = static_cast<double>(fj - j * kSub) / kSub;
    const Eigen::Index row_start = static_cast<Eigen::Index>(j) * grid_nx;
    fine_y[fj] = s * ((1 - f) * q_px(1, row_start) + f * q_px(1, row_start + grid_nx));
  }
  for (int fj = 0; fj < fine_ny; ++fj) {
    const int j = std::min(fj / kSub, grid_ny - 2);
    const double fy = static_cast<double>(fj - j * kSub) / kSub;
    for (int fi = 0; fi < fine_nx; ++fi) {
      const int i = std::min(fi / kSub, grid_nx - 2);
      const double fx = static_cast<double>(fi - i * kSub) / kSub;
      auto at = [&](int ii, int jj) { return value_px(jj * grid_nx + ii); };
      fine(fj, fi) = (1 - fy) * ((1 - fx) * at(i, j) + fx * at(i + 1, j)) +
                     fy * ((1 - fx) * at(i, j + 1) + fx * at(i + 1, j + 1));
    }
  }

  std::string svg = fmt::format(
      "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"760\" height=\"{0:.0f}\" "
      "viewBox=\"0 0 760 {0:.0f}\" font-family=\"sans-serif\" font-size=\"12\">\n"
      "<rect width=\"760\" height=\"{0:.0f}\" fill=\"white\"/>\n",
      total_h);
  svg += fmt::format(
      "<text x=\"10\" y=\"16\">Projection uncertainty (worst-direction 1-sigma, px) at "
      "{:.0f} mm, {}x{} grid: {:.4f} to {:.4f} px</text>\n",
      distance_mm, grid_nx, grid_ny, lo, hi);
  svg += "<g transform=\"translate(10,30)\">\n<g shape-rendering=\"crispEdges\">\n";
  // Heat map: a rectangle around every fine sample, reaching half-way to its
  // neighbours (the grid spans pixel centres 0..W-1, so it stops half a pixel
  // short of the imager's outer edge).
  for (int fj = 0; fj < fine_ny; ++fj) {
    const double y0 = fj == 0 ? fine_y[0] : (fine_y[fj - 1] + fine_y[fj]) / 2;
    const double y1 = fj + 1 == fine_ny ? fine_y[fj] : (fine_y[fj] + fine_y[fj + 1]) / 2;
    for (int fi = 0; fi < fine_nx; ++fi) {
      const double x0 = fi == 0 ? fine_x[0] : (fine_x[fi - 1] + fine_x[fi]) / 2;
      const double x1 = fi + 1 == fine_nx ? fine_x[fi] : (fine_x[fi] + fine_x[fi + 1]) / 2;
      // +0.5: no hairline gaps where crisp edges round apart.
      svg += fmt::format(
          "<rect x=\"{:.1f}\" y=\"{:.1f}\" width=\"{:.1f}\" height=\"{:.1f}\" fill=\"{}\"/>", x0,
          y0, x1 - x0 + 0.5, y1 - y0 + 0.5, Viridis(scale(fine(fj, fi))));
    }
    svg += "\n";
  }
  svg += "</g>\n";
  std::string levels_path;
  for (const double level : levels) Contour(fine, fine_x, fine_y, level, levels_path);
  if (!levels_path.empty()) {
    svg += "<path fill=\"none\" stroke=\"white\" stroke-width=\"1\" d=\"" + levels_path + "\"/>\n";
  }
  for (int k = 0; k < q_px.cols(); ++k) {
    svg += fmt::format("<circle cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"1\" fill=\"black\"/>",
                       s * q_px(0, k), s * q_px(1, k));
  }
  svg += fmt::format(
      "\n<rect width=\"{:.1f}\" height=\"{:.1f}\" fill=\"none\" stroke=\"black\"/>\n</g>\n",
      panel_w, panel_h);
  // Colour bar: min at the bottom, max at the top, contour levels ticked.
  const double bar_x = 640, bar_w = 20;
  auto bar_y = [&](double value) { return 30 + panel_h * (1 - scale(value)); };
  constexpr int kBarSteps = 40;
  svg += "<g shape-rendering=\"crispEdges\">";
  for (int k = 0; k < kBarSteps; ++k) {
    svg += fmt::format("<rect x=\"{}\" y=\"{:.1f}\" width=\"{}\" height=\"{:.1f}\" fill=\"{}\"/>",
                       bar_x, 30 + panel_h * (1 - static_cast<double>(k + 1) / kBarSteps), bar_w,
                       panel_h / kBarSteps + 0.5, Viridis((k + 0.5) / kBarSteps));
  }
  svg += "</g>";
  svg += fmt::format(
      "\n<rect x=\"{}\" y=\"30\" width=\"{}\" height=\"{:.1f}\" fill=\"none\" stroke=\"black\"/>\n",
      bar_x, bar_w, panel_h);
  for (const double value : {lo, hi}) {
    svg += fmt::format("<text x=\"{}\" y=\"{:.1f}\">{:.4f}</text>\n", bar_x + bar_w + 4,
                       bar_y(value) + 4, value);
  }
  for (const double level : levels) {
    const double y = bar_y(level);
    svg +=
        fmt::format("<line x1=\"{0}\" y1=\"{1:.1f}\" x2=\"{2}\" y2=\"{1:.1f}\" stroke=\"white\"/>",
                    bar_x, y, bar_x + bar_w);
    // No label where it would overprint the min or max label.
    if (std::min(std::abs(y - bar_y(lo)), std::abs(y - bar_y(hi))) >= 12) {
      svg += fmt::format("<text x=\"{}\" y=\"{:.1f}\" fill=\"#555\">{:g}</text>", bar_x + bar_w + 4,
                         y + 4, level);
    }
    svg += "\n";
  }
  svg += fmt::format(
      "<text x=\"10\" y=\"{:.0f}\">{} colour scale; white lines: contours at the ticked "
      "levels; dots: where mrcal's projection uncertainty was evaluated</text>\n</svg>\n",
      total_h - 10, log_scale ? "log" : "linear");
  return svg;
}

std::string ResidualsSvg(const Eigen::Matrix2Xd& q_px, const Eigen::Matrix2Xd& residual_px,
                         int width_px, int height_px, double rms_px) {
  // Left panel: the imager scaled to 600 px wide; right panel: 300 x 300 scatter.
  const double panel_w = 600.0;
  const double s = panel_w / std::max(1, width_px);
  const double panel_h = height_px * s;
  const double total_h = std::max(panel_h, 300.0) + 50.0;
  double max_r = 0.0;
  for (int i = 0; i < residual_px.cols(); ++i) max_r = std::max(max_r, residual_px.col(i).norm());
  // Vectors: the largest residual drawn 50 panel px long.
  const double vector_scale = max_r > 0 ? 50.0 / max_r : 1.0;
  std::string svg = fmt::format(
      "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"960\" height=\"{:.0f}\" "
      "viewBox=\"0 0 960 {:.0f}\" font-family=\"sans-serif\" font-size=\"12\">\n"
      "<rect width=\"960\" height=\"{:.0f}\" fill=\"white\"/>\n",
      total_h, total_h, total_h);
  svg += fmt::format(
      "<text x=\"10\" y=\"16\">Residuals (projected - observed) of {} inlier marks, rms {:.4f} px; "
      "vectors x{:.0f} (longest {:.4f} px)</text>\n",
      residual_px.cols(), rms_px, vector_scale / s, max_r);
  svg += fmt::format(
      "<g transform=\"translate(10,30)\">\n<rect width=\"{:.1f}\" height=\"{:.1f}\" "
      "fill=\"none\" stroke=\"black\"/>\n",
      panel_w, panel_h);
  for (int i = 0; i < q_px.cols(); ++i) {
    const double x = q_px(0, i) * s, y = q_px(1, i) * s;
    svg += fmt::format(
        "<line x1=\"{:.1f}\" y1=\"{:.1f}\" x2=\"{:.1f}\" y2=\"{:.1f}\" stroke=\"#1f77b4\"/>", x, y,
        x + residual_px(0, i) * vector_scale, y + residual_px(1, i) * vector_scale);
    svg += fmt::format("<circle cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"1\"/>\n", x, y);
  }
  svg += "</g>\n";
  // Scatter: +-max(3 rms, max_r) across 300 px.
  const double half = std::max({3.0 * rms_px, max_r, 1e-6});
  const double k = 150.0 / half;
  svg +=
      "<g transform=\"translate(640,30)\">\n<rect width=\"300\" height=\"300\" fill=\"none\" "
      "stroke=\"black\"/>\n"
      "<line x1=\"150\" y1=\"0\" x2=\"150\" y2=\"300\" stroke=\"#ccc\"/>"
      "<line x1=\"0\" y1=\"150\" x2=\"300\" y2=\"150\" stroke=\"#ccc\"/>\n";
  for (int i = 0; i < residual_px.cols(); ++i) {
    svg += fmt::format("<circle cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"1.2\" fill=\"#1f77b4\"/>",
                       150 + residual_px(0, i) * k, 150 + residual_px(1, i) * k);
  }
  svg += fmt::format(
      "\n<circle cx=\"150\" cy=\"150\" r=\"{:.1f}\" fill=\"none\" stroke=\"#d62728\"/>\n",
      rms_px * std::sqrt(2.0) * k);
  svg += fmt::format(
      "<text x=\"0\" y=\"318\">x, y residual; box +-{:.4f} px; red: rms circle</text>\n</g>\n",
      half);
  svg += "</svg>\n";
  return svg;
}

std::string StudySvg(const ImageCountStudy& study) {
  const double w = 640, h = 400, left = 60, top = 30, plot_w = 540, plot_h = 320;
  if (study.num_images.empty()) {
    return "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"640\" height=\"40\"><text x=\"10\" "
           "y=\"20\">" +
           study.brief + "</text></svg>\n";
  }
  const int l_min = study.num_images.front(), l_max = study.num_images.back();
  // y: log10 of spread / sigma_N.
  double y_lo = -1.0, y_hi = 1.0;
  for (const StudyParameter& p : study.parameters) {
    for (size_t k = 0; k < p.spread.size(); ++k) {
      if (p.full_sigma <= 0 || p.spread[k] <= 0) continue;
      const double v = std::log10(p.spread[k] / p.full_sigma);
      y_lo = std::min(y_lo, std::floor(v));
      y_hi = std::max(y_hi, std::ceil(v));
    }
  }
  auto X = [&](double l) { return left + (l - l_min) / std::max(1, l_max - l_min) * plot_w; };
  auto Y = [&](double v) { return top + (y_hi - v) / (y_hi - y_lo) * plot_h; };
  std::string svg = fmt::format(
      "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{0:.0f}\" height=\"{1:.0f}\" viewBox=\"0 "
      "0 {0:.0f} "
      "{1:.0f}\" font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"{0:.0f}\" "
      "height=\"{1:.0f}\" "
      "fill=\"white\"/>\n",
      w, h);
  svg += fmt::format(
      "<text x=\"10\" y=\"16\">Image-count study ({}): spread over subsets / full-set "
      "1-sigma</text>\n",
      study.lens_model);
  svg += fmt::format(
      "<rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"black\"/>\n", left,
      top, plot_w, plot_h);
  for (double v = y_lo; v <= y_hi; v += 1.0) {
    svg += fmt::format(
        "<line x1=\"{0}\" y1=\"{1:.1f}\" x2=\"{2}\" y2=\"{1:.1f}\" stroke=\"#eee\"/>"
        "<text x=\"{3}\" y=\"{4:.1f}\" text-anchor=\"end\">1e{5:.0f}</text>\n",
        left, Y(v), left + plot_w, left - 4, Y(v) + 4, v);
  }
  for (int l = l_min; l <= l_max; ++l) {
    svg += fmt::format("<text x=\"{:.1f}\" y=\"{:.1f}\" text-anchor=\"middle\">{}</text>", X(l),
                       top + plot_h + 16, l);
  }
  svg += fmt::format("\n<text x=\"{:.1f}\" y=\"{:.1f}\" text-anchor=\"middle\">images l</text>\n",
                     left + plot_w / 2, top + plot_h + 34);
  // Noise-averaging curve sqrt(N/l - 1), for l < N.
  std::string ideal;
  for (int l = l_min; l < l_max; ++l) {
    ideal += fmt::format("{:.1f},{:.1f} ", X(l),
                         Y(std::log10(std::sqrt(static_cast<double>(l_max) / l - 1.0))));
  }
  svg += "<polyline fill=\"none\" stroke=\"black\" stroke-dasharray=\"5,4\" points=\"" + ideal +
         "\"/>\n";
  for (size_t i = 0; i < study.parameters.size(); ++i) {
    const StudyParameter& p = study.parameters[i];
    if (p.full_sigma <= 0) continue;
    std::string points;
    for (size_t k = 0; k < p.spread.size(); ++k) {
      if (p.spread[k] <= 0) continue;
      points += fmt::format("{:.1f},{:.1f} ", X(study.num_images[k]),
                            Y(std::log10(p.spread[k] / p.full_sigma)));
    }
    const char* color = kColors[i % std::size(kColors)];
    svg += fmt::format("<polyline fill=\"none\" stroke=\"{}\" points=\"{}\"/>", color, points);
    svg += fmt::format("<text x=\"{:.0f}\" y=\"{:.0f}\" fill=\"{}\">{}</text>\n", left + plot_w + 8,
                       top + 14 * (i + 1), color, p.name);
  }
  if (study.suffices_from > 0) {
    svg += fmt::format(
        "<line x1=\"{0:.1f}\" y1=\"{1}\" x2=\"{0:.1f}\" y2=\"{2}\" stroke=\"#d62728\"/>"
        "<text x=\"{3:.1f}\" y=\"{4}\" fill=\"#d62728\">{5} images suffice</text>\n",
        X(study.suffices_from), top, top + plot_h, X(study.suffices_from) + 4, top + 14,
        study.suffices_from);
  }
  svg += fmt::format(
      "<text x=\"{}\" y=\"{}\">dashed: sqrt(N/l - 1), noise averaging alone</text>\n", left, h - 4);
  svg += "</svg>\n";
  return svg;
}

}  // namespace omm
