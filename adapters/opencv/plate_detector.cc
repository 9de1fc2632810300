#include "adapters/opencv/plate_detector.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <optional>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "adapters/opencv/adaptive_threshold.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

constexpr double kPi = 3.14159265358979323846;

// A dark blob that may be a dot: its contour's ellipse.
struct Blob {
  Eigen::Vector2d centre_px;
  Ellipse rough;
  bool touches_border = false;
};

struct Coarse {
  cv::Mat gray8;
  cv::Mat dark;  // 255 where darker than the local mean
  std::vector<std::vector<cv::Point>> contours;
  std::vector<cv::Vec4i> hierarchy;
};

// 8 bits are plenty for the coarse stage; the sub-pixel stage reads the
// float pixels.
cv::Mat ToGray8(const GrayImage& image) {
  const cv::Mat as_float(image.height(), image.width(), CV_32F, const_cast<float*>(image.pixels.data()));
  cv::Mat gray8;
  as_float.convertTo(gray8, CV_8U, 255.0);
  return gray8;
}

Coarse Threshold(const GrayImage& image, const PlateDetectionOptions& options) {
  Coarse coarse;
  coarse.gray8 = ToGray8(image);
  int window = static_cast<int>(options.threshold_window_fraction * std::max(image.width(), image.height()));
  window = std::max(3, window | 1);
  coarse.dark = AdaptiveDarkMask(coarse.gray8, window, options.threshold_offset * 255.0);
  cv::findContours(coarse.dark, coarse.contours, coarse.hierarchy, cv::RETR_TREE, cv::CHAIN_APPROX_NONE);
  return coarse;
}

bool TouchesBorder(const std::vector<cv::Point>& contour, const cv::Size& size, double margin) {
  const cv::Rect box = cv::boundingRect(contour);
  return box.x < margin || box.y < margin || box.x + box.width - 1 > size.width - 1 - margin ||
         box.y + box.height - 1 > size.height - 1 - margin;
}

// The contour as a dot, if it looks like a filled ellipse.
std::optional<Blob> AsBlob(const std::vector<cv::Point>& contour, const cv::Size& size,
                           const PlateDetectionOptions& options) {
  if (contour.size() < 6) return std::nullopt;
  const double area = cv::contourArea(contour);
  if (area < options.min_mark_area_px) return std::nullopt;
  const cv::RotatedRect box = cv::fitEllipse(contour);
  const double a = 0.5 * std::max(box.size.width, box.size.height);
  const double b = 0.5 * std::min(box.size.width, box.size.height);
  if (!(b > 1.0) || b < 0.15 * a) return std::nullopt;
  // Both the contour and its ellipse run through the blob's outer pixel
  // centres, so a filled ellipse has an area ratio near 1.
  const double ratio = area / (kPi * a * b);
  if (ratio < 0.85 || ratio > 1.15) return std::nullopt;
  Blob blob;
  blob.centre_px = {box.center.x, box.center.y};
  const double angle = box.angle * kPi / 180.0 + (box.size.width >= box.size.height ? 0.0 : 0.5 * kPi);
  // The true edge lies ~half a pixel outside the outer pixel centres.
  blob.rough = Ellipse::FromAxes(blob.centre_px, a + 0.5, b + 0.5, angle);
  blob.touches_border = TouchesBorder(contour, size, options.border_margin_px);
  return blob;
}

// Whether contour i bounds a dark region (even depth in the contour tree),
// not a hole in one.
bool IsOuter(const Coarse& coarse, size_t i) {
  const int parent = coarse.hierarchy[i][3];
  return parent < 0 || coarse.hierarchy[static_cast<size_t>(parent)][3] >= 0;
}

std::vector<int> Children(const Coarse& coarse, int parent) {
  std::vector<int> children;
  for (int child = coarse.hierarchy[static_cast<size_t>(parent)][2]; child >= 0;
       child = coarse.hierarchy[static_cast<size_t>(child)][0]) {
    children.push_back(child);
  }
  return children;
}

PlateObservation Rejected(int num_marks, std::string why) {
  PlateObservation observation;
  observation.usable = false;
  observation.why_rejected = std::move(why);
  observation.q_px.setZero(2, num_marks);
  observation.weight.setZero(num_marks);
  observation.sigma_px.setZero(num_marks);
  return observation;
}

std::string MarkName(const BoardSpec& board, int index) {
  return "mark (" + std::to_string(index / board.cols) + ", " + std::to_string(index % board.cols) + ")";
}

// Refines every mark from its rough ellipse and applies the quality gates.
PlateObservation RefineMarks(const GrayImage& image, const BoardSpec& board, const std::vector<Ellipse>& rough,
                             const PlateDetectionOptions& options) {
  const int n = board.rows * board.cols;
  PlateObservation observation = Rejected(n, "");
  std::vector<double> edge_sigmas;
  for (int i = 0; i < n; ++i) {
    const MarkFit mark = RefineEllipticalMark(image.pixels, rough[static_cast<size_t>(i)], options.refinement);
    if (!mark.ok) {
      if (mark.why_failed == "mark touches the image border") return Rejected(n, "plate partly outside the image");
      return Rejected(n, MarkName(board, i) + ": " + mark.why_failed);
    }
    observation.q_px.col(i) = mark.ellipse.centre_px;
    observation.sigma_px(i) = mark.sigma_px;
    observation.weight(i) = MarkWeight(mark.sigma_px, options);
    edge_sigmas.push_back(mark.edge_sigma_px);
  }
  std::nth_element(edge_sigmas.begin(), edge_sigmas.begin() + n / 2, edge_sigmas.end());
  const double edge_sigma = edge_sigmas[static_cast<size_t>(n / 2)];
  if (edge_sigma > options.max_edge_sigma_px) {
    char why[96];
    std::snprintf(why, sizeof(why), "too blurred (edge sigma %.2f px > %.2f px)", edge_sigma, options.max_edge_sigma_px);
    return Rejected(n, why);
  }
  observation.usable = true;
  return observation;
}

// Proper (non-mirrored) board order: the image of plate +x (along a row) turns
// towards the image of plate +y (down a column) like image +x towards +y.
// Reverses the rows of a mirrored grid.
void MakeProper(const BoardSpec& board, std::vector<cv::Point2f>* points) {
  Eigen::Vector2d along_row = Eigen::Vector2d::Zero(), down_column = Eigen::Vector2d::Zero();
  auto at = [&](int r, int c) {
    const cv::Point2f& p = (*points)[static_cast<size_t>(r * board.cols + c)];
    return Eigen::Vector2d(p.x, p.y);
  };
  for (int r = 0; r < board.rows; ++r) along_row += at(r, board.cols - 1) - at(r, 0);
  for (int c = 0; c < board.cols; ++c) down_column += at(board.rows - 1, c) - at(0, c);
  if (along_row.x() * down_column.y() - along_row.y() * down_column.x() >= 0.0) return;
  std::vector<cv::Point2f> flipped(points->size());
  for (int r = 0; r < board.rows; ++r) {
    for (int c = 0; c < board.cols; ++c) {
      flipped[static_cast<size_t>(r * board.cols + c)] = (*points)[static_cast<size_t>((board.rows - 1 - r) * board.cols + c)];
    }
  }
  *points = std::move(flipped);
}

// Index of the blob nearest to p within radius, or -1.
int NearestBlob(const std::vector<Blob>& blobs, const Eigen::Vector2d& p, double radius) {
  int best = -1;
  double best_d = radius;
  for (size_t i = 0; i < blobs.size(); ++i) {
    const double d = (blobs[i].centre_px - p).norm();
    if (d < best_d) {
      best_d = d;
      best = static_cast<int>(i);
    }
  }
  return best;
}

// The dark blob around q from an Otsu threshold of the square of half size
// `half_px` around it: robust to the uneven lighting of hand-held shots,
// where a global window may merge a dot with its surroundings.
std::optional<Blob> LocalBlob(const cv::Mat& gray8, const Eigen::Vector2d& q, double half_px,
                              const PlateDetectionOptions& options) {
  const cv::Rect image_rect(0, 0, gray8.cols, gray8.rows);
  const int half = std::max(3, static_cast<int>(half_px));
  const cv::Rect roi = cv::Rect(static_cast<int>(std::lround(q.x())) - half, static_cast<int>(std::lround(q.y())) - half,
                                2 * half + 1, 2 * half + 1) &
                       image_rect;
  if (roi.width < 7 || roi.height < 7) return std::nullopt;
  cv::Mat dark;
  cv::threshold(gray8(roi), dark, 0, 255, cv::THRESH_BINARY_INV | cv::THRESH_OTSU);
  std::vector<std::vector<cv::Point>> contours;
  cv::findContours(dark, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE, roi.tl());
  const cv::Point2f at(static_cast<float>(q.x()), static_cast<float>(q.y()));
  for (const std::vector<cv::Point>& contour : contours) {
    if (cv::pointPolygonTest(contour, at, false) < 0) continue;
    std::optional<Blob> blob = AsBlob(contour, gray8.size(), options);
    if (blob) {
      // Cut by the window rather than by the image: not a clean outline.
      const cv::Rect box = cv::boundingRect(contour);
      if ((box & cv::Rect(roi.x + 1, roi.y + 1, roi.width - 2, roi.height - 2)) != box) return std::nullopt;
    }
    return blob;
  }
  return std::nullopt;
}

Eigen::Vector2d Apply(const cv::Matx33d& h, double x, double y) {
  const cv::Vec3d q = h * cv::Vec3d(x, y, 1.0);
  return {q[0] / q[2], q[1] / q[2]};
}

bool Inside(const cv::Size& size, const Eigen::Vector2d& q, double margin) {
  return q.x() >= margin && q.y() >= margin && q.x() <= size.width - 1 - margin && q.y() <= size.height - 1 - margin;
}

PlateObservation DetectCaltab(const GrayImage& image, const BoardSpec& board, const PlateDetectionOptions& options) {
  const int n = board.rows * board.cols;
  const Coarse coarse = Threshold(image, options);
  const cv::Size size = coarse.gray8.size();
  const double min_frame_area = 0.002 * size.area();

  // Frame candidates: an outer contour that is a convex quadrilateral with a
  // hole whose children are dots. Best: the one with the most dots.
  struct Frame {
    std::vector<cv::Point2f> corners;
    std::vector<Blob> dots;
    bool cut = false;
  };
  std::optional<Frame> best;
  bool cut_dark_region = false;
  for (size_t i = 0; i < coarse.contours.size(); ++i) {
    const std::vector<cv::Point>& outer = coarse.contours[i];
    if (!IsOuter(coarse, i)) continue;
    const double area = cv::contourArea(outer);
    if (area < min_frame_area) continue;
    const bool cut = TouchesBorder(outer, size, options.border_margin_px);
    cut_dark_region |= cut;
    std::vector<cv::Point> hull, quad;
    cv::convexHull(outer, hull);
    cv::approxPolyDP(hull, quad, 0.03 * cv::arcLength(hull, true), true);
    if (quad.size() != 4) continue;
    // The largest hole is the frame's inside.
    int hole = -1;
    double hole_area = 0.0;
    for (const int child : Children(coarse, static_cast<int>(i))) {
      const double a = cv::contourArea(coarse.contours[static_cast<size_t>(child)]);
      if (a > hole_area) hole_area = a, hole = child;
    }
    if (hole < 0 || hole_area < 0.5 * area * 0.5) continue;
    Frame frame;
    frame.cut = cut;
    for (const cv::Point& p : quad) frame.corners.emplace_back(static_cast<float>(p.x), static_cast<float>(p.y));
    for (const int child : Children(coarse, hole)) {
      if (std::optional<Blob> blob = AsBlob(coarse.contours[static_cast<size_t>(child)], size, options)) {
        frame.dots.push_back(*blob);
      }
    }
    if (!best || frame.dots.size() > best->dots.size()) best = std::move(frame);
  }
  if (!best || best->dots.empty()) {
    // A frame cut by the image border has no hole; if a dark region runs off
    // the image and a good share of the dots is seen, the plate is there.
    if (cut_dark_region) {
      // Counted until there are enough: a textured part has thousands of
      // contours and each cv::fitEllipse is an SVD.
      int dots = 0;
      for (size_t i = 0; i < coarse.contours.size() && dots < n / 4; ++i) {
        if (coarse.hierarchy[i][2] >= 0) continue;  // dots have no holes
        const std::optional<Blob> blob = AsBlob(coarse.contours[i], size, options);
        dots += blob && !blob->touches_border;
      }
      if (dots >= n / 4) return Rejected(n, "plate partly outside the image");
    }
    return Rejected(n, "plate not found");
  }
  if (best->cut) return Rejected(n, "plate partly outside the image");

  // Corners in the image's positive (clockwise on screen) order, like the
  // plate's (-,-), (+,-), (+,+), (-,+) corners seen from the printed side.
  std::vector<cv::Point2f>& corners = best->corners;
  double shoelace = 0.0;
  for (size_t k = 0; k < 4; ++k) {
    const cv::Point2f& p = corners[k];
    const cv::Point2f& q = corners[(k + 1) % 4];
    shoelace += p.x * q.y - q.x * p.y;
  }
  if (shoelace < 0.0) std::reverse(corners.begin(), corners.end());
  const double half = 0.5 * board.frame_mm;
  const std::array<cv::Point2f, 4> plate_corners = {
      cv::Point2f(static_cast<float>(-half), static_cast<float>(-half)),
      cv::Point2f(static_cast<float>(half), static_cast<float>(-half)),
      cv::Point2f(static_cast<float>(half), static_cast<float>(half)),
      cv::Point2f(static_cast<float>(-half), static_cast<float>(half))};

  // The rotation whose triangle corner is dark: three points inside the
  // triangle (its centroid and two towards the legs' middles) must all be dark.
  const double inner = half - board.frame_bar_mm;
  const double t = board.triangle_mm;
  const std::array<Eigen::Vector2d, 3> triangle_probes = {Eigen::Vector2d(t / 3, t / 3), Eigen::Vector2d(t / 2, t / 5),
                                                          Eigen::Vector2d(t / 5, t / 2)};
  std::vector<cv::Matx33d> found;
  for (int k = 0; k < 4; ++k) {
    std::vector<cv::Point2f> image_corners(4);
    for (int j = 0; j < 4; ++j) image_corners[static_cast<size_t>(j)] = corners[static_cast<size_t>((k + j) % 4)];
    const cv::Matx33d h = cv::getPerspectiveTransform(std::vector<cv::Point2f>(plate_corners.begin(), plate_corners.end()),
                                                      image_corners);
    bool dark = true;
    for (const Eigen::Vector2d& probe : triangle_probes) {
      const Eigen::Vector2d q = Apply(h, -inner + probe.x(), -inner + probe.y());
      if (!Inside(size, q, 0.0) ||
          coarse.dark.at<uchar>(static_cast<int>(std::lround(q.y())), static_cast<int>(std::lround(q.x()))) == 0) {
        dark = false;
      }
    }
    if (dark) found.push_back(h);
  }
  if (found.empty()) return Rejected(n, "orientation triangle not found");
  if (found.size() > 1) return Rejected(n, "ambiguous orientation (" + std::to_string(found.size()) + " triangle candidates)");
  const cv::Matx33d& h = found.front();

  // Each mark is the dot nearest to its predicted position.
  const Eigen::Matrix3Xd plate = BoardPoints(board);
  std::vector<Ellipse> rough(static_cast<size_t>(n));
  std::vector<bool> used(best->dots.size(), false);
  int matched = 0;
  bool predicted_outside = false;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d q = Apply(h, plate(0, i), plate(1, i));
    const double pitch_px = (Apply(h, plate(0, i) + board.pitch_mm, plate(1, i)) - q).norm();
    predicted_outside |= !Inside(size, q, 0.0);
    const int j = NearestBlob(best->dots, q, options.match_radius_pitch * pitch_px);
    if (j < 0 || used[static_cast<size_t>(j)]) continue;
    used[static_cast<size_t>(j)] = true;
    if (best->dots[static_cast<size_t>(j)].touches_border) predicted_outside = true;
    rough[static_cast<size_t>(i)] = best->dots[static_cast<size_t>(j)].rough;
    ++matched;
  }
  if (predicted_outside) return Rejected(n, "plate partly outside the image");
  if (matched < n) {
    return Rejected(n, "only " + std::to_string(matched) + " of " + std::to_string(n) + " marks found");
  }
  return RefineMarks(image, board, rough, options);
}

// Candidate dots for cv::findCirclesGrid: the centres of the dark blobs
// (IsOuter) that look like filled ellipses, within the area range.
std::vector<cv::Point2f> DotCandidates(const Coarse& coarse, double min_area_px, double max_area_px,
                                       const PlateDetectionOptions& options) {
  std::vector<cv::Point2f> centres;
  for (size_t i = 0; i < coarse.contours.size(); ++i) {
    if (!IsOuter(coarse, i)) continue;
    const double area = cv::contourArea(coarse.contours[i]);
    if (area < min_area_px || area > max_area_px) continue;
    if (const std::optional<Blob> blob = AsBlob(coarse.contours[i], coarse.gray8.size(), options)) {
      centres.emplace_back(static_cast<float>(blob->centre_px.x()), static_cast<float>(blob->centre_px.y()));
    }
  }
  return centres;
}

PlateObservation DetectCircles(const GrayImage& image, const BoardSpec& board, const PlateDetectionOptions& options) {
  const int n = board.rows * board.cols;
  const Coarse coarse = Threshold(image, options);
  const cv::Mat& gray8 = coarse.gray8;
  const cv::Size size = gray8.size();
  double min_area_px = options.min_mark_area_px, max_area_px = 0.05 * size.area();
  if (options.expected_pitch_px > 0.0 && board.dot_diameter_mm > 0.0 && board.pitch_mm > 0.0) {
    const double radius_px = 0.5 * board.dot_diameter_mm / board.pitch_mm * options.expected_pitch_px;
    min_area_px = std::max(min_area_px, 0.5 * kPi * radius_px * radius_px);
    max_area_px = std::min(max_area_px, 2.0 * kPi * radius_px * radius_px);
  }
  const cv::Size pattern(board.cols, board.rows);
  const std::vector<cv::Point2f> candidates = DotCandidates(coarse, min_area_px, max_area_px, options);
  if (static_cast<int>(candidates.size()) < n) return Rejected(n, "plate not found");
  std::vector<cv::Point2f> centres;
  bool found = cv::findCirclesGrid(candidates, pattern, centres, cv::CALIB_CB_SYMMETRIC_GRID,
                                   cv::Ptr<cv::FeatureDetector>());
  if (!found) {
    cv::SimpleBlobDetector::Params params;
    params.minArea = static_cast<float>(min_area_px);
    params.maxArea = static_cast<float>(max_area_px);
    found = cv::findCirclesGrid(gray8, pattern, centres, cv::CALIB_CB_SYMMETRIC_GRID,
                                cv::SimpleBlobDetector::create(params));
  }
  if (!found || static_cast<int>(centres.size()) != n) return Rejected(n, "plate not found");
  MakeProper(board, &centres);

  // Each grid point's rough ellipse: the dark blob around it, thresholded
  // within half the spacing to its nearest grid neighbour.
  std::vector<Ellipse> rough(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d q(centres[static_cast<size_t>(i)].x, centres[static_cast<size_t>(i)].y);
    double spacing = 1e30;
    for (int j = 0; j < n; ++j) {
      if (j != i) spacing = std::min<double>(spacing, cv::norm(centres[static_cast<size_t>(j)] - centres[static_cast<size_t>(i)]));
    }
    const std::optional<Blob> blob = LocalBlob(gray8, q, 0.5 * spacing, options);
    if (!blob) return Rejected(n, MarkName(board, i) + ": no clean dot outline");
    if (blob->touches_border) return Rejected(n, "plate partly outside the image");
    rough[static_cast<size_t>(i)] = blob->rough;
  }
  return RefineMarks(image, board, rough, options);
}

// The reductions of the image (factors 2^k) that a chessboard is searched
// in, coarsest first (PlateDetectionOptions).
std::vector<int> ChessboardSearchFactors(const cv::Size& size, const PlateDetectionOptions& options) {
  if (options.expected_pitch_px > 0.0) {
    int factor = 1;
    while (2 * factor <= std::max(size.width, size.height) &&
           options.expected_pitch_px / (2 * factor) >= options.chessboard_min_square_px) {
      factor *= 2;
    }
    return {factor};
  }
  std::vector<int> factors = {1};
  while (std::max(size.width, size.height) / (2 * factors.back()) >= options.chessboard_min_search_side_px) {
    factors.push_back(2 * factors.back());
  }
  std::reverse(factors.begin(), factors.end());
  return factors;
}

// cornerSubPix's half window for corners spacing_px apart: well inside one
// square.
int CornerHalfWindow(double spacing_px) { return std::clamp(static_cast<int>(0.3 * spacing_px), 2, 11); }

void RefineCorners(const ImageF& image, int half_window, std::vector<cv::Point2f>* corners) {
  const cv::Mat as_float(static_cast<int>(image.rows()), static_cast<int>(image.cols()), CV_32F,
                         const_cast<float*>(image.data()));
  cv::cornerSubPix(as_float, *corners, cv::Size(half_window, half_window), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 1e-4));
}

PlateObservation DetectChessboard(const GrayImage& image, const BoardSpec& board, const PlateDetectionOptions& options) {
  const int n = board.rows * board.cols;
  const cv::Mat gray8 = ToGray8(image);
  const cv::Size pattern(board.cols, board.rows);
  std::vector<cv::Point2f> corners;
  bool found = false;
  for (const int factor : ChessboardSearchFactors(gray8.size(), options)) {
    cv::Mat reduced = gray8;
    if (factor > 1) cv::resize(gray8, reduced, cv::Size(), 1.0 / factor, 1.0 / factor, cv::INTER_AREA);
    found = cv::findChessboardCornersSB(reduced, pattern, corners, cv::CALIB_CB_NORMALIZE_IMAGE);
    if (!found) continue;
    // Reduced pixel i covers full-size pixels factor i .. factor i + factor - 1.
    const float offset = 0.5f * static_cast<float>(factor - 1);
    for (cv::Point2f& corner : corners) corner = static_cast<float>(factor) * corner + cv::Point2f(offset, offset);
    break;
  }
  if (!found || static_cast<int>(corners.size()) != n) return Rejected(n, "plate not found");
  double spacing = 1e30;
  for (int r = 0; r < board.rows; ++r) {
    for (int c = 0; c + 1 < board.cols; ++c) {
      spacing = std::min<double>(spacing, cv::norm(corners[static_cast<size_t>(r * board.cols + c + 1)] -
                                                   corners[static_cast<size_t>(r * board.cols + c)]));
    }
  }
  const int half_window = CornerHalfWindow(spacing);
  RefineCorners(image.pixels, half_window, &corners);
  MakeProper(board, &corners);
  PlateObservation observation = Rejected(n, "");
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d q(corners[static_cast<size_t>(i)].x, corners[static_cast<size_t>(i)].y);
    if (!Inside(gray8.size(), q, options.border_margin_px + half_window)) {
      return Rejected(n, "plate partly outside the image");
    }
    observation.q_px.col(i) = q;
  }
  observation.sigma_px.setConstant(options.chessboard_sigma_px);
  observation.weight.setConstant(MarkWeight(options.chessboard_sigma_px, options));
  observation.usable = true;
  return observation;
}

}  // namespace

void RefineChessboardCorners(const ImageF& image, const Eigen::Matrix2Xd& rough_px, double spacing_px,
                             double margin_px, double max_shift_px, Eigen::Matrix2Xd* refined_px,
                             std::vector<bool>* found) {
  const int half_window = CornerHalfWindow(spacing_px);
  const double reach = half_window + margin_px;
  *refined_px = rough_px;
  found->assign(static_cast<size_t>(rough_px.cols()), false);
  std::vector<cv::Point2f> corners;
  std::vector<Eigen::Index> index;
  for (Eigen::Index k = 0; k < rough_px.cols(); ++k) {
    const Eigen::Vector2d q = rough_px.col(k);
    if (q.x() - reach < 0 || q.y() - reach < 0 || q.x() + reach > image.cols() - 1 ||
        q.y() + reach > image.rows() - 1)
      continue;
    corners.emplace_back(static_cast<float>(q.x()), static_cast<float>(q.y()));
    index.push_back(k);
  }
  if (corners.empty()) return;
  RefineCorners(image, half_window, &corners);
  for (size_t j = 0; j < corners.size(); ++j) {
    const Eigen::Vector2d q(corners[j].x, corners[j].y);
    if ((q - rough_px.col(index[j])).norm() > max_shift_px || q.x() - reach < 0 || q.y() - reach < 0 ||
        q.x() + reach > image.cols() - 1 || q.y() + reach > image.rows() - 1)
      continue;
    refined_px->col(index[j]) = q;
    (*found)[static_cast<size_t>(index[j])] = true;
  }
}

std::string PlateDetectionOptions::Check() const {
  if (!(threshold_window_fraction > 0.0 && threshold_window_fraction < 1.0)) {
    return "threshold_window_fraction must be in (0, 1)";
  }
  if (!(threshold_offset >= 0.0 && threshold_offset < 1.0)) return "threshold_offset must be in [0, 1)";
  if (!(min_mark_area_px > 0.0)) return "min_mark_area_px must be > 0";
  if (!(border_margin_px >= 0.0)) return "border_margin_px must be >= 0";
  if (!(match_radius_pitch > 0.0 && match_radius_pitch < 0.5)) return "match_radius_pitch must be in (0, 0.5)";
  if (std::string why = refinement.Check(); !why.empty()) return "refinement: " + why;
  if (!(max_edge_sigma_px > 0.0)) return "max_edge_sigma_px must be > 0";
  if (!(nominal_sigma_px > 0.0)) return "nominal_sigma_px must be > 0";
  if (!(min_weight > 0.0 && min_weight <= max_weight)) return "need 0 < min_weight <= max_weight";
  if (!(chessboard_sigma_px > 0.0)) return "chessboard_sigma_px must be > 0";
  if (chessboard_min_search_side_px < 1) return "chessboard_min_search_side_px must be >= 1";
  if (!(chessboard_min_square_px > 0.0)) return "chessboard_min_square_px must be > 0";
  if (!(expected_pitch_px >= 0.0 && std::isfinite(expected_pitch_px))) {
    return "expected_pitch_px must be finite and >= 0 (0: unknown)";
  }
  return {};
}

double MarkWeight(double sigma_px, const PlateDetectionOptions& options) {
  return std::clamp(options.nominal_sigma_px / std::max(sigma_px, 1e-9), options.min_weight,
                    options.max_weight);
}

PlateObservation DetectPlate(const GrayImage& image, const BoardSpec& board, const PlateDetectionOptions& options) {
  if (std::string why = options.Check(); !why.empty()) throw InputError("", "plate detection options: " + why);
  if (board.rows < 2 || board.cols < 2) throw InputError("", "board: rows and cols must be >= 2");
  if (board.type == BoardType::kCaltab &&
      !(board.frame_mm > 2.0 * board.frame_bar_mm && board.triangle_mm > 0.0 && board.dot_diameter_mm > 0.0)) {
    throw InputError("", "board: caltab needs frame_mm > 2 frame_bar_mm, triangle_mm > 0, dot_diameter_mm > 0");
  }
  switch (board.type) {
    case BoardType::kCaltab: return DetectCaltab(image, board, options);
    case BoardType::kCircles: return DetectCircles(image, board, options);
    case BoardType::kChessboard: return DetectChessboard(image, board, options);
  }
  return Rejected(board.rows * board.cols, "unknown board type");
}

}  // namespace omm
