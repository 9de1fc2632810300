// The matching kernels on images with a known motion: EstimateImageMotion on
// a grid of crops of one texture, and SearchNcc / MatchPatch on a band-limited
// texture sampled at a known sub-pixel shift (so the truth is exact).
#include "pipeline/mosaic/tile_matching.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include "pipeline/core/cubic_bspline.h"
#include "pipeline/mosaic/tile_features.h"

namespace omm {
namespace {

ImageF RandomTexture(int rows, int cols, double blur_px, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> n(0.0f, 1.0f);
  ImageF image(rows, cols);
  for (Eigen::Index i = 0; i < image.size(); ++i) image.data()[i] = n(rng);
  return NormalizeTileIntensity(GaussianBlur(image, blur_px));
}

// A 3 x 3 grid of tiles cropped from one weak, smooth texture with dark
// discs (holes) and noise, each tile then vignetted alike: the tile at table
// position T shows the scene offset by -A T, so the content at q in tile i
// is at q + A (T_j - T_i) in tile j, exactly.
struct GridTiles {
  std::vector<ImageF> tiles;
  std::vector<Eigen::Vector2d> table_mm;
  std::vector<std::pair<int, int>> neighbours;
};

GridTiles CropGrid(const Eigen::Matrix2d& a_px_per_mm, unsigned seed) {
  const int rows = 240, cols = 320;
  const Eigen::Vector2d step_mm(20, 15);
  // Room for the largest shift |A T| (6 px/mm x 40 mm) on every side.
  const int margin = 260;
  ImageF scene = RandomTexture(rows + 2 * margin, cols + 2 * margin, 12.0, seed);
  std::mt19937 rng(seed + 1);
  std::uniform_real_distribution<float> where(0.0f, 1.0f);
  for (int d = 0; d < 12; ++d) {
    const float cx = where(rng) * scene.cols(), cy = where(rng) * scene.rows();
    for (int r = 0; r < scene.rows(); ++r)
      for (int c = 0; c < scene.cols(); ++c)
        if ((c - cx) * (c - cx) + (r - cy) * (r - cy) < 15 * 15) scene(r, c) = -6.0f;
  }
  std::normal_distribution<float> noise(0.0f, 0.3f);
  GridTiles g;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      const Eigen::Vector2d t(c * step_mm.x(), r * step_mm.y());
      const Eigen::Vector2d origin = Eigen::Vector2d(margin, margin) - a_px_per_mm * t;
      ImageF tile = scene.block(std::lround(origin.y()), std::lround(origin.x()), rows, cols);
      for (int y = 0; y < rows; ++y) {
        for (int x = 0; x < cols; ++x) {
          const double u = (x - 0.5 * cols) / cols, v = (y - 0.5 * rows) / cols;
          tile(y, x) =
              static_cast<float>((tile(y, x) + 8.0) * (1.0 - 1.2 * (u * u + v * v))) + noise(rng);
        }
      }
      g.tiles.push_back(NormalizeTileIntensity(tile));
      g.table_mm.push_back(t);
    }
  }
  for (int i = 0; i < 9; ++i) {
    if (i % 3 < 2) g.neighbours.emplace_back(i, i + 1);
    if (i < 6) g.neighbours.emplace_back(i, i + 3);
  }
  return g;
}

TEST(EstimateImageMotion, FindsAMirroredOrRotatedMotionOnWeakTexture) {
  // A mirror (det < 0: table X -> image -y, Y -> image -x) and a rotation by
  // 180 deg, 6 px/mm: shifts of 120 and 90 px.
  for (const Eigen::Matrix2d& truth : {(Eigen::Matrix2d() << 0, -6, -6, 0).finished(),
                                       (Eigen::Matrix2d() << -6, 0, 0, -6).finished()}) {
    const GridTiles g = CropGrid(truth, 3);
    const ImageMotionOptions options;
    const ImageMotionEstimate e = EstimateImageMotion(g.tiles, g.table_mm, g.neighbours, options);
    ASSERT_TRUE(e.ok) << e.brief;
    EXPECT_EQ(e.mirrored, truth.determinant() < 0);
    EXPECT_EQ(e.num_agreeing, 12) << e.brief;
    EXPECT_GE(e.margin, options.min_margin);
    for (size_t k = 0; k < g.neighbours.size(); ++k) {
      const auto [i, j] = g.neighbours[k];
      const Eigen::Vector2d dt = g.table_mm[j] - g.table_mm[i];
      ASSERT_TRUE(e.pair_shifts[k].ok);
      // One step of the finest level's pixel at most, and A predicts the
      // shift as well (what the matching needs from it).
      EXPECT_LE((e.pair_shifts[k].shift_px - truth * dt).cwiseAbs().maxCoeff(),
                options.finest_factor)
          << i << "-" << j << ": " << e.pair_shifts[k].shift_px.transpose();
      EXPECT_LE(((e.px_per_table_mm - truth) * dt).cwiseAbs().maxCoeff(), options.finest_factor);
    }
  }
}

// A strip of four 1600 x 1200 tiles, the table moving 80 mm along X between
// neighbours and the image 500 px along y: the content at q in tile i is at
// q + (0, 500 (j - i)) in tile j. The scene is a coarse pattern that repeats
// every 200 px along y, so that it fits shifts of 300, 500 and 700 px alike,
// plus `fine_amplitude` times a fine texture that does not repeat.
struct StripTiles {
  std::vector<ImageF> tiles;
  std::vector<Eigen::Vector2d> table_mm;
  std::vector<std::pair<int, int>> neighbours;
  Eigen::Vector2d shift_px{0.0, 500.0};  // between neighbours
};

StripTiles PeriodicStrip(float fine_amplitude) {
  const int rows = 1200, cols = 1600, period = 200, step = 500, num_tiles = 4;
  const ImageF coarse = RandomTexture(period, cols, 12.0, 5);
  const ImageF fine = RandomTexture(rows + (num_tiles - 1) * step, cols, 3.0, 6);
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.0f, 0.05f);
  StripTiles s;
  for (int i = 0; i < num_tiles; ++i) {
    // Tile i shows the scene from row (num_tiles - 1 - i) step down.
    const int top = (num_tiles - 1 - i) * step;
    ImageF tile(rows, cols);
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c)
        tile(r, c) = coarse((top + r) % period, c) + fine_amplitude * fine(top + r, c) + noise(rng);
    s.tiles.push_back(NormalizeTileIntensity(tile));
    s.table_mm.emplace_back(80.0 * i, 0.0);
    if (i > 0) s.neighbours.emplace_back(i - 1, i);
  }
  return s;
}

// Where only the coarse pattern tells the tiles apart at the coarsest level,
// the shifts a period off the true one score alike there (step 3 fails);
// followed to the finest level, the fine texture settles it (step 3b).
TEST(EstimateImageMotion, AShiftThatOnlyTheCoarseLevelsCannotTellIsSettledAtTheFinest) {
  const StripTiles s = PeriodicStrip(1.0f);
  const ImageMotionOptions options;
  const ImageMotionEstimate e = EstimateImageMotion(s.tiles, s.table_mm, s.neighbours, options);
  std::printf("%s\n", e.brief.c_str());
  ASSERT_TRUE(e.ok) << e.brief;
  EXPECT_LT(e.margin, options.min_margin);
  EXPECT_GE(e.finest_margin, options.min_margin);
  EXPECT_EQ(e.num_agreeing, 3);
  for (size_t k = 0; k < s.neighbours.size(); ++k) {
    ASSERT_TRUE(e.pair_shifts[k].ok);
    EXPECT_LE((e.pair_shifts[k].shift_px - s.shift_px).cwiseAbs().maxCoeff(), options.finest_factor)
        << e.pair_shifts[k].shift_px.transpose();
  }
  EXPECT_LE((e.px_per_table_mm * Eigen::Vector2d(80.0, 0.0) - s.shift_px).norm(),
            options.finest_factor);
}

// Without the fine texture the scene repeats at every level: the motion is
// refused as ambiguous rather than guessed.
TEST(EstimateImageMotion, AShiftThatNoLevelCanTellIsRefusedAsAmbiguous) {
  const StripTiles s = PeriodicStrip(0.0f);
  const ImageMotionOptions options;
  const ImageMotionEstimate e = EstimateImageMotion(s.tiles, s.table_mm, s.neighbours, options);
  std::printf("%s\n", e.brief.c_str());
  EXPECT_FALSE(e.ok);
  EXPECT_NE(e.brief.find("the image motion per table mm is ambiguous"), std::string::npos);
  EXPECT_LT(e.finest_margin, options.min_margin);
}

// A faint texture seen by two tiles at a known shift, under shading ramps
// that run opposite ways (vignetting at two tiles' facing borders): plain
// NCC counts the ramps against the texture, the detrended NCC finds the
// texture at the true shift; a window that is a plane has no NCC.
TEST(BestDetrendedNcc, FindsAFaintTextureUnderOppositeShadingRamps) {
  const ImageF texture = RandomTexture(80, 80, 1.5, 11);
  const Eigen::Vector2i shift(3, -2);  // content at q in a is at q + shift in b
  ImageF a(60, 60), b(60, 60);
  for (int r = 0; r < 60; ++r) {
    for (int c = 0; c < 60; ++c) {
      a(r, c) = 0.1f * texture(r + 10, c + 10) + 0.1f * c;
      b(r, c) = 0.1f * texture(r + 10 - shift.y(), c + 10 - shift.x()) - 0.1f * c;
    }
  }
  const Eigen::Vector2i anchor(30, 30);
  const int h = 5, radius = 4;
  const NccPeak plain = SearchNcc(a, anchor, h, b, anchor + shift, radius);
  ASSERT_TRUE(plain.ok);
  EXPECT_LT(plain.ncc, 0.3);
  EXPECT_NEAR(BestDetrendedNcc(a, anchor, h, b, anchor + shift, radius), 1.0, 1e-6);
  EXPECT_NEAR(BestDetrendedNcc(a, anchor, h, b, anchor + shift, 0), 1.0, 1e-6);
  EXPECT_LT(BestDetrendedNcc(a, anchor, h, b, anchor + shift + Eigen::Vector2i(3, 0), 0), 0.7);
  ImageF plane(60, 60);
  for (int r = 0; r < 60; ++r)
    for (int c = 0; c < 60; ++c) plane(r, c) = 0.3f * r - 0.2f * c + 1.0f;
  EXPECT_EQ(BestDetrendedNcc(plane, anchor, h, b, anchor, radius), -2.0);
  EXPECT_EQ(BestDetrendedNcc(a, anchor, h, b, Eigen::Vector2i(2, 30), radius), -2.0);  // leaves b
}

// A sum of sinusoids below 0.2 cycles/px, sampled at (x - dx, y - dy).
ImageF Sinusoids(int rows, int cols, double dx, double dy) {
  ImageF image(rows, cols);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const double x = c - dx, y = r - dy;
      image(r, c) = static_cast<float>(std::sin(0.61 * x + 0.2 * y) + 0.7 * std::cos(0.37 * y - 0.5 * x + 1.0) +
                                       0.5 * std::sin(0.9 * y + 0.3));
    }
  }
  return image;
}

TEST(MatchPatch, RecoversAKnownSubPixelShift) {
  const ImageF reference = Sinusoids(120, 120, 0, 0);
  const Eigen::Vector2d shift(2.37, -1.62);
  const ImageF target = Sinusoids(120, 120, shift.x(), shift.y());
  const ImageF spline = CubicBSplineCoefficients(target);
  PatchMatchOptions options;
  const Eigen::Vector2i anchor(60, 55);
  // Predicted 2 px off: the NCC search finds the integer peak, LSQ the rest.
  const PatchMatch m = MatchPatch(reference, anchor, target, spline,
                                  anchor.cast<double>() + shift + Eigen::Vector2d(1.4, -0.9),
                                  PatchWarp(), 3, options);
  ASSERT_TRUE(m.ok);
  // Truth: the anchor's content sits at anchor + shift. The bound is the
  // B-spline's interpolation error at these frequencies (<= 0.15 cycles/px).
  EXPECT_LT((m.q_px - (anchor.cast<double>() + shift)).norm(), 2e-3);
  EXPECT_GT(m.ncc, 0.9999);

  // Radius 0 (a relocation) starts at the prediction and converges to the same point.
  const PatchMatch warm = MatchPatch(reference, anchor, target, spline,
                                     m.q_px + Eigen::Vector2d(0.2, 0.1), PatchWarp(), 0, options);
  ASSERT_TRUE(warm.ok);
  EXPECT_LT((warm.q_px - m.q_px).norm(), 10 * options.convergence_px);
}

// A tile-to-tile map with curvature, w(x) = x + d + 1/2 (x^T H_0 x, x^T
// H_1 x) about the image centre, and a reference tile that is exactly the
// target's B-spline interpolant warped by it: the anchor's content is at
// w(anchor) in the target, exactly, and MatchPatch's model holds exactly
// under the second-order warp.
struct CurvedPair {
  ImageF reference, target, spline;
  Eigen::Vector2d d, centre;
  Eigen::Matrix2d h[2];
  Eigen::Vector2d Map(const Eigen::Vector2d& q) const {
    const Eigen::Vector2d x = q - centre;
    return q + d + 0.5 * Eigen::Vector2d(x.dot(h[0] * x), x.dot(h[1] * x));
  }
  Eigen::Matrix2d Jacobian(const Eigen::Vector2d& q) const {
    const Eigen::Vector2d x = q - centre;
    Eigen::Matrix2d j = Eigen::Matrix2d::Identity();
    j.row(0) += (h[0] * x).transpose();
    j.row(1) += (h[1] * x).transpose();
    return j;
  }
};

CurvedPair MakeCurvedPair(const Eigen::Matrix2d& h0, const Eigen::Matrix2d& h1, double blur_px) {
  CurvedPair p;
  const int size = 360;
  p.target = RandomTexture(size, size, blur_px, 5);
  p.spline = CubicBSplineCoefficients(p.target);
  p.d = Eigen::Vector2d(3.3, -2.1);
  p.centre = Eigen::Vector2d(0.5 * size, 0.5 * size);
  p.h[0] = h0;
  p.h[1] = h1;
  p.reference = ImageF::Zero(size, size);
  for (int r = 0; r < size; ++r) {
    for (int c = 0; c < size; ++c) {
      const Eigen::Vector2d q = p.Map(Eigen::Vector2d(c, r));
      double v;
      if (SampleBSpline(p.spline, q.x(), q.y(), &v)) p.reference(r, c) = static_cast<float>(v);
    }
  }
  return p;
}

// The mean of MatchPatch's error (found minus true position) over a grid of
// anchors, with the warp's second-order term or J alone; *count the matches.
// *theory: the mean of J alone's error to first order, the least-squares
// translation of the unmodelled second-order term q(x) = 1/2 (x^T H_k x):
// (sum g g^T)^-1 sum g g^T q(x), g the template's gradient (central
// differences), over the same anchors.
Eigen::Vector2d MeanMatchError(const CurvedPair& p, bool second_order,
                               const PatchMatchOptions& options, int* count,
                               Eigen::Vector2d* theory) {
  Eigen::Vector2d sum = Eigen::Vector2d::Zero();
  *theory = Eigen::Vector2d::Zero();
  *count = 0;
  for (int y = 70; y <= 290; y += 10) {
    for (int x = 70; x <= 290; x += 10) {
      const Eigen::Vector2i anchor(x, y);
      const Eigen::Vector2d a = anchor.cast<double>(), step(1.0, 0.0);
      const Eigen::Vector2d step_y(0.0, 1.0);
      PatchWarp warp =
          PatchWarp::FromJacobians(p.Jacobian(a), p.Jacobian(a + step), p.Jacobian(a - step),
                                   p.Jacobian(a + step_y), p.Jacobian(a - step_y), 1.0);
      if (!second_order) warp.hessian[0] = warp.hessian[1] = Eigen::Matrix2d::Zero();
      const Eigen::Vector2d truth = p.Map(a);
      const PatchMatch m = MatchPatch(p.reference, anchor, p.target, p.spline,
                                      truth + Eigen::Vector2d(0.4, -0.3), warp, 2, options);
      if (!m.ok) continue;
      sum += m.q_px - truth;
      ++*count;
      Eigen::Matrix2d normal = Eigen::Matrix2d::Zero();
      Eigen::Vector2d rhs = Eigen::Vector2d::Zero();
      const int h = options.half_size_px;
      for (int r = -h; r <= h; ++r) {
        for (int c = -h; c <= h; ++c) {
          const Eigen::Vector2d g(
              0.5 * (p.reference(y + r, x + c + 1) - p.reference(y + r, x + c - 1)),
              0.5 * (p.reference(y + r + 1, x + c) - p.reference(y + r - 1, x + c)));
          const Eigen::Vector2d o(c, r);
          normal += g * g.transpose();
          rhs += g * g.dot(0.5 * Eigen::Vector2d(o.dot(p.h[0] * o), o.dot(p.h[1] * o)));
        }
      }
      *theory += normal.ldlt().solve(rhs);
    }
  }
  *theory /= std::max(*count, 1);
  return sum / std::max(*count, 1);
}

TEST(PatchWarp, FromJacobiansIsExactForAQuadraticMap) {
  const Eigen::Matrix2d h0 = (Eigen::Matrix2d() << 2e-4, -1e-4, -1e-4, 3e-4).finished();
  const Eigen::Matrix2d h1 = (Eigen::Matrix2d() << -1e-4, 1.5e-4, 1.5e-4, 2e-4).finished();
  CurvedPair p;
  p.d = Eigen::Vector2d(3.3, -2.1);
  p.centre = Eigen::Vector2d(180, 180);
  p.h[0] = h0, p.h[1] = h1;
  const Eigen::Vector2d a(100, 250), sx(7, 0), sy(0, 7);
  const PatchWarp warp =
      PatchWarp::FromJacobians(p.Jacobian(a), p.Jacobian(a + sx), p.Jacobian(a - sx),
                               p.Jacobian(a + sy), p.Jacobian(a - sy), 7.0);
  for (const Eigen::Vector2d& x : {Eigen::Vector2d(15, -15), Eigen::Vector2d(-4, 9)})
    EXPECT_LT((warp.Offset(x) - (p.Map(a + x) - p.Map(a))).norm(), 1e-12);
}

TEST(MatchPatch, TheWarpsSecondOrderTermRemovesTheCurvatureBias) {
  // Laplacians (tr H_k) of 4e-4 and 1e-4 px^-1: the x one like the
  // lens-mismatch preset's tile-to-tile map over a 950 px displacement.
  const Eigen::Matrix2d h0 = (Eigen::Matrix2d() << 2e-4, -1e-4, -1e-4, 2e-4).finished();
  const Eigen::Matrix2d h1 = (Eigen::Matrix2d() << -1e-4, 1.5e-4, 1.5e-4, 2e-4).finished();
  const CurvedPair p = MakeCurvedPair(h0, h1, 1.5);
  // Plain least squares for the theory (Tukey's weights cut the corners'
  // unmodelled residuals of these noise-free tiles: 0.0131 instead of 0.016).
  PatchMatchOptions plain;
  plain.robust_tukey_c = 0.0;
  int n_affine = 0, n_quadratic = 0;
  Eigen::Vector2d theory, unused;
  const Eigen::Vector2d affine = MeanMatchError(p, false, plain, &n_affine, &theory);
  const Eigen::Vector2d quadratic =
      MeanMatchError(p, true, PatchMatchOptions(), &n_quadratic, &unused);
  ASSERT_GE(n_affine, 500);  // of 529
  ASSERT_GE(n_quadratic, 500);
  // J alone: the template's mean of the second-order term, 1/2 <x_i^2>
  // tr H_k = (0.016, 0.004) px with <x_i^2> = h (h + 1) / 3 = 80 px^2 for
  // uniform gradients; the first-order theory with the actual gradients
  // agrees to 1% (blurs 1-2.5 px, h 10-20).
  EXPECT_NEAR(affine.x(), theory.x(), 0.05 * theory.x()) << affine.transpose();
  EXPECT_NEAR(affine.y(), theory.y(), 0.05 * theory.y()) << affine.transpose();
  // The second-order warp: the model holds exactly; what is left is the
  // B-spline sampling's error averaged over the anchors (<= 8e-5 px over
  // blurs 1-2.5 px, h 10-20, plain or Tukey).
  EXPECT_LT(quadratic.norm(), 2e-4) << quadratic.transpose();
}

TEST(SearchNcc, FindsTheIntegerShiftWithNccOne) {
  const ImageF reference = RandomTexture(100, 100, 1.5, 9);
  ImageF target = ImageF::Constant(100, 100, 0.0f);
  target.block(13, 8, 80, 85) = reference.block(10, 10, 80, 85);  // content moves by (-2, +3)
  const NccPeak peak = SearchNcc(reference, {50, 50}, 7, target, {47, 54}, 4);
  ASSERT_TRUE(peak.ok);
  EXPECT_EQ(peak.pixel, Eigen::Vector2i(48, 53));
  EXPECT_NEAR(peak.ncc, 1.0, 1e-5);
  EXPECT_FALSE(SearchNcc(reference, {50, 50}, 7, target, {5, 50}, 4).ok);  // window leaves target
}

}  // namespace
}  // namespace omm
