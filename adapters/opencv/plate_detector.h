// Calibration-plate detection: which mark is where, to a fraction of a pixel.
//
// Three boards (pipeline/core/board.h, docs/project-format.md):
// - caltab: a dark square frame (outer edge frame_mm, bar frame_bar_mm) around
//   rows x cols dark dots, and a dark right-angled triangle filling the
//   frame's inner corner next to mark (0, 0). Coarse stage (OpenCV): adaptive
//   threshold, contour hierarchy (the dots are holes' children inside the
//   frame's inner contour), the frame's outer quadrilateral gives four
//   plate->image homographies, one per rotation; the one that finds the
//   triangle dark at its centroid fixes the orientation, and its homography
//   orders the dots. Every rotation 0-360 deg and tilts past 45 deg.
// - circles: a symmetric grid of dark dots. cv::findCirclesGrid orders the
//   dark filled-ellipse blobs of the caltab's coarse stage; where that fails
//   and there are at least rows x cols of them, it tries again with OpenCV's
//   SimpleBlobDetector, whose 17 thresholds took 40-110 ms per 1600 x 1200
//   image where the blobs take ~8 ms (ViSP's grid36-02 needs it: labels
//   beside its dots).
// - chessboard: rows x cols INNER corners (cv::findChessboardCornersSB on a
//   reduced image, coarsest first, + cv::cornerSubPix at full size). Not
//   cv::findChessboardCorners: on rendered 1600 x 1200 images it took 62 s
//   where the board was partly outside the image and 147 s where there was
//   none (FAST_CHECK rejected the latter only). SB's time grows with the
//   pixels searched, found or not: ~0.35 s on the whole image, ~0.07 s at
//   half size and ~0.02 s at a quarter, where the rendered plate's 73 px
//   squares are still found at an eighth.
//
// Sub-pixel centres of dots (caltab, circles): mid-level edge points along
// rays and an ellipse fit (pipeline/core/subpixel_edges.h); the centre is the
// fitted ellipse's centre, its 1-sigma from the fit's residuals. That is the
// centre of the IMAGED ellipse, which is not the image of the dot's centre
// under perspective (~0.05 px at 35 deg on the demo plate); the calibration
// stage corrects it with a first pose (pipeline/calibration/perspective_bias.h).
// The refinement kernels live in pipeline/core so this adapter can return
// finished centres without depending on a pipeline stage.
//
// Handedness: plates are seen from their printed side, so the plate -> image
// mapping is proper (the image of plate +x turns towards plate +y the way
// image +x turns towards image +y). For the symmetric boards, whose order
// OpenCV may return mirrored, the rows are reversed when needed so that
// mrcal never sees a mirrored board; their remaining 180-degree (and for
// square grids 90-degree) ambiguity is harmless for calibration.
//
// Rejections (usable = false, why_rejected says which): "plate not found",
// "plate partly outside the image", "only N of M marks found", "orientation
// triangle not found", "ambiguous orientation", "too blurred", "mark (r, c):
// <why the fit failed>". A rejected image is never returned half-right.
#pragma once

#include <string>

#include "pipeline/core/board.h"
#include "pipeline/core/image.h"
#include "pipeline/core/plate_observation.h"
#include "pipeline/core/subpixel_edges.h"

namespace omm {

struct PlateDetectionOptions {
  // Coarse stage.
  double threshold_window_fraction = 0.0625;  // adaptive-threshold window / larger image side
  double threshold_offset = 0.04;   // dark = below the local mean by this much (full scale 1)
  double min_mark_area_px = 25.0;   // smaller dark blobs are not marks, px^2
  double border_margin_px = 2.0;    // a frame or mark closer than this to the border is cut, px
  double match_radius_pitch = 0.3;  // a blob matches a predicted mark within this * pitch

  // Sub-pixel stage and the quality gates.
  MarkRefinementOptions refinement;
  double max_edge_sigma_px = 2.5;   // median edge blur above this: "too blurred", px
  double nominal_sigma_px = 0.02;   // centre 1-sigma that gets mrcal weight 1, px
  double min_weight = 0.1;          // weights are nominal / sigma clamped to [min, max]
  double max_weight = 4.0;
  // Assumed corner 1-sigma, px: cornerSubPix gives none. The calibration
  // stage replaces it by the corners' scatter about its solve; a chessboard
  // lying on the part (pipeline/mosaic/plate_on_part.h) keeps it.
  double chessboard_sigma_px = 0.1;
  // A chessboard is searched first in the coarsest power-of-2 reduction of
  // the image (1/2, 1/4, ...) whose longer side keeps at least this many
  // pixels, then in each finer one up to the whole image, until found.
  int chessboard_min_search_side_px = 400;
  // With expected_pitch_px, only in the coarsest reduction whose squares keep
  // at least this many pixels.
  double chessboard_min_square_px = 12.0;

  // The marks' spacing in the image when it is known beforehand (a plate
  // lying on the part, seen at the tiles' scale), px; 0: unknown. A
  // chessboard is then searched at one scale (chessboard_min_square_px), a
  // circles grid's dots must be within a factor 2 of the area the board's
  // dot_diameter_mm gives.
  double expected_pitch_px = 0.0;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// mrcal's weight of a mark of 1-sigma `sigma_px`: nominal_sigma_px / sigma_px
// clamped to [min_weight, max_weight].
double MarkWeight(double sigma_px, const PlateDetectionOptions& options);

// Chessboard corners refined by cv::cornerSubPix in `image` (gray, [0, 1])
// from rough positions (2 x N; a plate lying on the part predicts them where
// a tile cuts it), with the window DetectPlate uses for corners spacing_px
// apart. found[k] is false where the window leaves the image (with
// margin_px) or the corner moved more than max_shift_px: not that corner.
void RefineChessboardCorners(const ImageF& image, const Eigen::Matrix2Xd& rough_px,
                             double spacing_px, double margin_px, double max_shift_px,
                             Eigen::Matrix2Xd* refined_px, std::vector<bool>* found);

// Detects `board` in `image`. q_px, weight and sigma_px are filled (size
// rows*cols, BoardPoints' order) only when usable. image name is left empty.
// Throws InputError if the options or the board are invalid.
PlateObservation DetectPlate(const GrayImage& image, const BoardSpec& board,
                             const PlateDetectionOptions& options = {});

}  // namespace omm
