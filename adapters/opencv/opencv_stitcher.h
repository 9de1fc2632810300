// OpenCV's image stitcher (cv::Stitcher) as the baseline the mosaic stage is
// compared with (benchmarks/mosaic_benchmark.cc), run as a typical user runs
// it on flat scans: cv::Stitcher::create(cv::Stitcher::SCANS) (affine motion
// model, ORB features, affine bundle adjustment, no wave correction), its
// default seam finder, exposure compensator and multi-band blender, composed
// at the tiles' full resolution. It knows neither the camera nor the table
// positions: its panorama is in pixels, of unknown scale and orientation.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/image.h"
#include "pipeline/core/parallel_for.h"

namespace omm {

struct OpenCvStitcherOptions {
  // cv::setNumThreads while stitching; by default the CPUs the process may
  // use, as OpenCV's own default and `omm run`'s.
  int num_threads = HardwareThreads();

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct OpenCvStitcherResult {
  bool ok = false;
  std::string status;    // cv::Stitcher::Status by name ("OK", "ERR_NEED_MORE_IMGS", ...)
  ImageF panorama;       // gray, [0, 1]; 0 where no tile is composed
  // Tiles in the panorama (cv::Stitcher::component): it leaves out, with
  // status OK, those it could not match confidently (lens-mismatch seed 284:
  // 5 of 9, in 0.85 s against the 1.3 s of seeds that keep all nine).
  int tiles_used = 0;
  double seconds = 0.0;  // wall time of stitch()
};

// Stitches `tiles` (gray, [0, 1]; converted to 8-bit BGR, as the Stitcher
// expects). Throws InputError for invalid options or no tiles.
OpenCvStitcherResult StitchScans(const std::vector<ImageF>& tiles,
                                 const OpenCvStitcherOptions& options = {});

// Where `patch` best matches `image` by normalised cross-correlation
// (cv::matchTemplate, TM_CCOEFF_NORMED): the image position of the patch's
// centre ((0, 0) at the centre of the top-left pixel, integer px), and the
// correlation there in *score. patch must be smaller than image.
Eigen::Vector2d FindPatch(const ImageF& image, const ImageF& patch, double* score = nullptr);

}  // namespace omm
