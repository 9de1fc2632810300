#include "pipeline/orchestration/svg_plots.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

namespace omm {
namespace {

constexpr const char* kColors[] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b",
                                   "#e377c2", "#7f7f7f", "#bcbd22", "#17becf", "#393b79"};

}  // namespace

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
