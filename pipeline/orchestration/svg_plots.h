// Self-contained SVG plots of the calibration for the report (the HTML report
// embeds them). Pure text generation, no files.
#pragma once

#include <string>

#include <Eigen/Core>

#include "pipeline/calibration/study.h"

namespace omm {

// The imager (width x height px) with every inlier mark's residual vector
// (project - observed) drawn from its pixel, scaled so the largest is ~1/12
// of the imager width (the scale is printed), and a scatter of the residuals
// (x against y, px) beside it with the rms circle.
std::string ResidualsSvg(const Eigen::Matrix2Xd& q_px, const Eigen::Matrix2Xd& residual_px,
                         int width_px, int height_px, double rms_px);

// The projection uncertainty over the imager (width x height px, drawn 600 px
// wide) as a heat map with contour lines: `value_px` (worst-direction 1-sigma
// of the projection, px) given at the grid_nx x grid_ny grid pixels `q_px`
// (2 x nx*ny, x fastest, a rectilinear grid as ImagerGridPoints samples it),
// interpolated bilinearly; contours at round levels, marked on a colour bar
// (viridis, min to max). `distance_mm`: the range the points were taken at.
std::string UncertaintyMapSvg(const Eigen::Matrix2Xd& q_px, const Eigen::VectorXd& value_px,
                              int grid_nx, int grid_ny, int width_px, int height_px,
                              double distance_mm);

// The study: spread / full-set 1-sigma of each parameter against l (log
// scale), the noise-averaging curve sqrt(N/l - 1), and the rule's l.
std::string StudySvg(const ImageCountStudy& study);

}  // namespace omm
