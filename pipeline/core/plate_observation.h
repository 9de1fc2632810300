// What plate detection hands to calibration: per image, the marks' pixel
// positions with weights, or the reason the image was rejected.
#pragma once

#include <string>

#include <Eigen/Core>

namespace omm {

struct PlateObservation {
  std::string image;  // file name in calib/
  bool usable = false;
  std::string why_rejected;  // set when !usable: "plate not found", "plate partly outside the image", ...

  // Sub-pixel mark centres in board order: mark (r, c) at column r * cols + c
  // (BoardPoints' order). Shape 2 x rows*cols.
  Eigen::Matrix2Xd q_px;
  // Per-mark weight for mrcal (residual = weight * (q - q_observed)): the
  // ratio of a nominal centre sigma to this mark's estimated sigma; 0 marks a
  // mark that was not observed. Size rows*cols.
  Eigen::VectorXd weight;
  // Estimated 1-sigma of each mark centre from its fit, px (0 if unknown).
  Eigen::VectorXd sigma_px;
};

}  // namespace omm
