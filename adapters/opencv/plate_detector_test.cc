#include "adapters/opencv/plate_detector.h"

#include <cmath>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "adapters/opencv/image_io.h"
#include "pipeline/core/statistics.h"
#include "tests/test_util.h"

namespace omm {
namespace {

using testing::SharedDataDir;

// An OpenCV FileStorage reference (.dat): the grid size and its points.
struct Reference {
  bool found = false;
  int rows = 0, cols = 0;
  Eigen::Matrix2Xd q_px;
};

Reference ReadReference(const std::filesystem::path& path) {
  Reference ref;
  cv::FileStorage fs(path.string(), cv::FileStorage::READ);
  int found = 0;
  fs["isFound"] >> found;
  cv::Mat corners;
  fs["corners"] >> corners;
  ref.found = found != 0;
  ref.rows = corners.rows;
  ref.cols = corners.cols;
  corners = corners.reshape(2, 1);
  ref.q_px.resize(2, static_cast<Eigen::Index>(corners.total()));
  for (int i = 0; i < static_cast<int>(corners.total()); ++i) {
    ref.q_px.col(i) << corners.at<cv::Vec2f>(0, i)[0], corners.at<cv::Vec2f>(0, i)[1];
  }
  return ref;
}

BoardSpec Board(BoardType type, int rows, int cols) {
  BoardSpec board;
  board.type = type;
  board.rows = rows;
  board.cols = cols;
  return board;
}

// Signed turn from the image of plate +x (along a row) to plate +y (down a
// column): positive for the proper (non-mirrored) order.
double Handedness(const PlateObservation& o, const BoardSpec& board) {
  const Eigen::Vector2d along_row = o.q_px.col(board.cols - 1) - o.q_px.col(0);
  const Eigen::Vector2d down_column = o.q_px.col((board.rows - 1) * board.cols) - o.q_px.col(0);
  return along_row.x() * down_column.y() - along_row.y() * down_column.x();
}

// Distance from each of our marks to the nearest reference point; also
// checks that the nearest points are distinct (a one-to-one match).
std::vector<double> DistancesToReference(const PlateObservation& o, const Eigen::Matrix2Xd& ref) {
  std::vector<double> d;
  std::vector<bool> used(static_cast<size_t>(ref.cols()), false);
  for (int i = 0; i < o.q_px.cols(); ++i) {
    Eigen::Index j;
    d.push_back((ref.colwise() - o.q_px.col(i)).colwise().norm().minCoeff(&j));
    EXPECT_FALSE(used[static_cast<size_t>(j)]) << "two marks on one reference point";
    used[static_cast<size_t>(j)] = true;
  }
  return d;
}

#define SKIP_WITHOUT_DATA() \
  if (!std::filesystem::is_directory(SharedDataDir())) GTEST_SKIP() << "no " << SharedDataDir()

// A chessboard of 24 px squares, 6 x 5 of them, turned by 10 deg, each
// pixel the mean of 8 x 8 samples of its area (pixel centres at integers),
// blurred by a Gaussian of 0.7 px: its 5 x 4 inner corners are known
// exactly.
ImageF RenderedChessboard(Eigen::Matrix2Xd* corners_px) {
  const double angle = 10.0 * M_PI / 180.0, square_px = 24.0;
  const Eigen::Vector2d origin(40.0, 30.0), u(std::cos(angle), std::sin(angle)),
      v(-std::sin(angle), std::cos(angle));
  ImageF image(200, 240);
  constexpr int kSamples = 8;
  for (int y = 0; y < image.rows(); ++y) {
    for (int x = 0; x < image.cols(); ++x) {
      double sum = 0.0;
      for (int sy = 0; sy < kSamples; ++sy) {
        for (int sx = 0; sx < kSamples; ++sx) {
          const Eigen::Vector2d p(x - 0.5 + (sx + 0.5) / kSamples, y - 0.5 + (sy + 0.5) / kSamples);
          const double a = (p - origin).dot(u) / square_px, b = (p - origin).dot(v) / square_px;
          const bool on_board = a >= 0 && b >= 0 && a < 6 && b < 5;
          sum += !on_board ? 0.5 : (static_cast<int>(a) + static_cast<int>(b)) % 2 ? 0.9 : 0.1;
        }
      }
      image(y, x) = static_cast<float>(sum / (kSamples * kSamples));
    }
  }
  cv::Mat as_mat(static_cast<int>(image.rows()), static_cast<int>(image.cols()), CV_32F,
                 image.data());  // row-major, as ImageF
  cv::GaussianBlur(as_mat.clone(), as_mat, cv::Size(0, 0), 0.7);  // the simulator's lens blur
  corners_px->resize(2, 20);
  for (int j = 1, k = 0; j <= 4; ++j)
    for (int i = 1; i <= 5; ++i, ++k) corners_px->col(k) = origin + square_px * (i * u + j * v);
  return image;
}

// Rough corners up to 0.9 px off are refined to the drawn ones; one whose
// window would leave the image, and one that moved more than allowed (3 px
// off, 2 px allowed), are not found, and keep their rough position.
TEST(RefineChessboardCorners, RoughCornersRefinedToTheTruthOrNotFound) {
  Eigen::Matrix2Xd truth;
  const ImageF image = RenderedChessboard(&truth);
  Eigen::Matrix2Xd rough(2, truth.cols() + 2);
  for (Eigen::Index k = 0; k < truth.cols(); ++k) {
    rough.col(k) = truth.col(k) + 0.9 * Eigen::Vector2d(std::cos(k), std::sin(k));
  }
  rough.col(truth.cols()) << 6.0, 100.0;  // half window 7 px + margin 2 px reach past x = 0
  rough.col(truth.cols() + 1) = truth.col(7) + Eigen::Vector2d(3.0, 0.0);
  Eigen::Matrix2Xd refined;
  std::vector<bool> found;
  RefineChessboardCorners(image, rough, 24.0, 2.0, 2.0, &refined, &found);
  ASSERT_EQ(found.size(), static_cast<size_t>(rough.cols()));
  double worst_px = 0.0;
  for (Eigen::Index k = 0; k < truth.cols(); ++k) {
    ASSERT_TRUE(found[k]) << k;
    worst_px = std::max(worst_px, (refined.col(k) - truth.col(k)).norm());
  }
  // cornerSubPix's own error on these corners: 0.036 px at most, the same
  // from any start within the pixel; the detector weighs corners as 0.1 px.
  EXPECT_LT(worst_px, 0.05);
  Eigen::Matrix2Xd from_truth;
  RefineChessboardCorners(image, truth, 24.0, 2.0, 2.0, &from_truth, &found);
  EXPECT_LT((from_truth - refined.leftCols(truth.cols())).cwiseAbs().maxCoeff(), 1e-3);
  for (const Eigen::Index k : {truth.cols(), truth.cols() + 1}) {
    EXPECT_FALSE(found[k]) << k;
    EXPECT_EQ(refined.col(k), rough.col(k)) << k;
  }
}

TEST(PlateDetector, OptionsCheck) {
  EXPECT_EQ(PlateDetectionOptions{}.Check(), "");
  PlateDetectionOptions bad;
  bad.match_radius_pitch = 0.7;
  EXPECT_NE(bad.Check(), "");
  for (const double pitch : {-1.0, std::numeric_limits<double>::infinity(), std::nan("")}) {
    PlateDetectionOptions bad_pitch;
    bad_pitch.expected_pitch_px = pitch;
    EXPECT_NE(bad_pitch.Check(), "") << pitch;
  }
}

// OpenCV's 7x7 dot plate: every image found, centres in proper order and
// within a fraction of a pixel of OpenCV's own blob centres (which are blob
// centroids, with their own bias: agreement, not accuracy).
TEST(PlateDetector, OpenCvCircles7x7AgreeWithOpenCv) {
  SKIP_WITHOUT_DATA();
  const BoardSpec board = Board(BoardType::kCircles, 7, 7);
  for (int k = 1; k <= 14; ++k) {
    const auto dir = SharedDataDir() / "opencv_circles_7x7";
    const PlateObservation o = DetectPlate(ReadGrayImage(dir / ("circles" + std::to_string(k) + ".png")), board);
    ASSERT_TRUE(o.usable) << k << ": " << o.why_rejected;
    EXPECT_GT(Handedness(o, board), 0.0) << k;
    const std::vector<double> d =
        DistancesToReference(o, ReadReference(dir / ("circles_corners" + std::to_string(k) + ".dat")).q_px);
    // circles12 is 3908 x 2602 with ~75 px dots: OpenCV's binary-blob centres
    // scatter more there.
    const double scale = k == 12 ? 3.0 : 1.0;
    EXPECT_LT(Median(d), 0.25 * scale) << k;
    EXPECT_LT(*std::max_element(d.begin(), d.end()), 1.0 * scale) << k;
    EXPECT_GT(o.sigma_px.minCoeff(), 0.0);
    EXPECT_LT(o.sigma_px.maxCoeff(), 0.2) << k;
  }
}

TEST(PlateDetector, VispGrid6x6IsFoundInProperOrder) {
  SKIP_WITHOUT_DATA();
  const BoardSpec board = Board(BoardType::kCircles, 6, 6);
  for (int k = 1; k <= 4; ++k) {
    const PlateObservation o =
        DetectPlate(ReadGrayImage(SharedDataDir() / "visp_grid36_circles_6x6" /
                                  ("grid36-0" + std::to_string(k) + ".pgm")),
                    board);
    ASSERT_TRUE(o.usable) << k << ": " << o.why_rejected;
    EXPECT_GT(Handedness(o, board), 0.0) << k;
    EXPECT_LT(o.sigma_px.maxCoeff(), 0.1) << k;
  }
}

// BoofCV's 10x8 grid: 00000 runs off the image; the others are found, 00004
// too: a steep view where cv::findCirclesGrid fails on the 80 blobs of
// OpenCV's SimpleBlobDetector and orders those of our coarse stage.
TEST(PlateDetector, BoofCvCircleRegular) {
  SKIP_WITHOUT_DATA();
  const BoardSpec board = Board(BoardType::kCircles, 8, 10);
  const auto dir = SharedDataDir() / "boofcv_mono_calibration" / "Sony_DSC-HX5V_CircleRegular";
  for (int k = 0; k <= 5; ++k) {
    const PlateObservation o = DetectPlate(ReadGrayImage(dir / ("image0000" + std::to_string(k) + ".jpg")), board);
    if (k == 0) {
      EXPECT_FALSE(o.usable) << k;
      EXPECT_FALSE(o.why_rejected.empty());
      continue;
    }
    ASSERT_TRUE(o.usable) << k << ": " << o.why_rejected;
    EXPECT_GT(Handedness(o, board), 0.0) << k;
  }
}

// Asymmetric grids are not symmetric grids: asked for a symmetric grid of the
// same point count, the detector must reject them, never return a mis-ordered
// grid.
TEST(PlateDetector, AsymmetricGridsAreRejected) {
  SKIP_WITHOUT_DATA();
  for (int k = 1; k <= 9; ++k) {
    const auto dir = SharedDataDir() / "opencv_acircles";
    const Reference ref = ReadReference(dir / ("acircles_corners" + std::to_string(k) + ".dat"));
    const BoardSpec board = Board(BoardType::kCircles, ref.rows, ref.cols);
    const PlateObservation o = DetectPlate(ReadGrayImage(dir / ("acircles" + std::to_string(k) + ".png")), board);
    EXPECT_FALSE(o.usable) << k;
    EXPECT_FALSE(o.why_rejected.empty()) << k;
  }
}

TEST(PlateDetector, OpenCvChessboardsAgreeWithOpenCv) {
  SKIP_WITHOUT_DATA();
  const auto dir = SharedDataDir() / "opencv_chessboards";
  std::vector<std::pair<std::string, std::string>> sets;
  for (int k = 1; k <= 9; ++k) sets.emplace_back("chess" + std::to_string(k) + ".png", "chess_corners" + std::to_string(k) + ".dat");
  for (int k = 1; k <= 3; ++k) sets.emplace_back("small_chessboard" + std::to_string(k) + ".png", "small_chessboard" + std::to_string(k) + ".dat");
  for (const auto& [image, dat] : sets) {
    const Reference ref = ReadReference(dir / dat);
    const BoardSpec board = Board(BoardType::kChessboard, ref.rows, ref.cols);
    const PlateObservation o = DetectPlate(ReadGrayImage(dir / image), board);
    if (!ref.found) {
      EXPECT_FALSE(o.usable) << image;
      continue;
    }
    ASSERT_TRUE(o.usable) << image << ": " << o.why_rejected;
    EXPECT_GT(Handedness(o, board), 0.0) << image;
    const std::vector<double> d = DistancesToReference(o, ref.q_px);
    // The references used cornerSubPix with an 11 x 11 window; ours scales
    // with the squares (up to 23 x 23), so they differ by tenths of a pixel.
    EXPECT_LT(Median(d), 0.5) << image;
  }
}

TEST(PlateDetector, OpenCvSamplesChessboard9x6AllFound) {
  SKIP_WITHOUT_DATA();
  const BoardSpec board = Board(BoardType::kChessboard, 6, 9);
  for (const char* side : {"left", "right"}) {
    for (int k : {1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14}) {
      char name[32];
      std::snprintf(name, sizeof(name), "%s%02d.jpg", side, k);
      const PlateObservation o = DetectPlate(
          ReadGrayImage(SharedDataDir() / "opencv_samples_chessboard_9x6" / name), board);
      ASSERT_TRUE(o.usable) << name << ": " << o.why_rejected;
      EXPECT_GT(Handedness(o, board), 0.0) << name;
    }
  }
}

}  // namespace
}  // namespace omm
