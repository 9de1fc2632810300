#include "pipeline/mosaic/tile_features.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Dense>

namespace omm {

namespace {

float NthValue(std::vector<float>* v, double fraction) {
  const auto k = static_cast<std::ptrdiff_t>(fraction * (v->size() - 1));
  std::nth_element(v->begin(), v->begin() + k, v->end());
  return (*v)[k];
}

}  // namespace

ImageF NormalizeTileIntensity(const ImageF& image) {
  std::vector<float> sample;
  sample.reserve(image.size() / 7 + 1);
  for (Eigen::Index i = 0; i < image.size(); i += 7) sample.push_back(image.data()[i]);
  const float median = NthValue(&sample, 0.5);
  for (float& v : sample) v = std::abs(v - median);
  const float mad = NthValue(&sample, 0.5);
  const float scale = mad > 0 ? 1.0f / (1.4826f * mad) : 1.0f;
  return ((image.array() - median) * scale).matrix();
}

std::optional<double> BlankImageLevel(const ImageF& image, double max_fraction) {
  std::vector<float> sample;
  sample.reserve(image.size() / 7 + 1);
  for (Eigen::Index i = 0; i < image.size(); i += 7) sample.push_back(image.data()[i]);
  if (sample.empty()) return std::nullopt;
  std::vector<float> sorted = sample;
  const float median = NthValue(&sorted, 0.5);
  const auto differing =
      std::count_if(sample.begin(), sample.end(), [&](float v) { return v != median; });
  if (static_cast<double>(differing) > max_fraction * static_cast<double>(sample.size()))
    return std::nullopt;
  return median;
}

double SaturatedFraction(const ImageF& image) {
  if (image.size() == 0) return 0.0;
  return static_cast<double>((image.array() >= 1.0f).count()) / static_cast<double>(image.size());
}

ImageF DownsampleBox(const ImageF& image, int factor) {
  const Eigen::Index rows = image.rows() / factor, cols = image.cols() / factor;
  ImageF out(rows, cols);
  const float norm = 1.0f / static_cast<float>(factor * factor);
  std::vector<float> row_sum(static_cast<size_t>(cols));
  for (Eigen::Index r = 0; r < rows; ++r) {
    std::fill(row_sum.begin(), row_sum.end(), 0.0f);
    for (int k = 0; k < factor; ++k) {
      const float* in = image.data() + (r * factor + k) * image.cols();
      for (Eigen::Index c = 0; c < cols; ++c)
        for (int j = 0; j < factor; ++j) row_sum[c] += in[c * factor + j];
    }
    for (Eigen::Index c = 0; c < cols; ++c) out(r, c) = row_sum[c] * norm;
  }
  return out;
}

namespace {

// Columns per register block of the blur's passes (Eigen: packed arithmetic).
constexpr int kBlurBlock = 16;
using BlurBlock = Eigen::Array<float, kBlurBlock, 1>;

// Normalised Gaussian taps, radius ceil(3 sigma).
std::vector<float> GaussianKernel(double sigma_px) {
  const int radius = static_cast<int>(std::ceil(3.0 * sigma_px));
  std::vector<float> kernel(2 * radius + 1);
  float sum = 0;
  for (int k = -radius; k <= radius; ++k) {
    kernel[k + radius] = static_cast<float>(std::exp(-0.5 * k * k / (sigma_px * sigma_px)));
    sum += kernel[k + radius];
  }
  for (float& w : kernel) w /= sum;
  return kernel;
}

// The horizontal pass of one row (borders clamped).
void BlurRow(const std::vector<float>& kernel, const float* in, int cols, float* o) {
  const int radius = static_cast<int>(kernel.size() / 2);
  const int lo = std::min(radius, cols), hi = std::max(lo, cols - radius);
  const auto clamped = [&](int c) {
    float acc = 0;
    for (int k = -radius; k <= radius; ++k)
      acc += kernel[k + radius] * in[std::clamp(c + k, 0, cols - 1)];
    o[c] = acc;
  };
  for (int c = 0; c < lo; ++c) clamped(c);
  for (int c = hi; c < cols; ++c) clamped(c);
  // Interior: kBlock columns' sums held in registers over the taps (they
  // vectorise; a whole row's taps outer would load and store it per tap).
  int c = lo;
  for (; c + kBlurBlock <= hi; c += kBlurBlock) {
    BlurBlock acc = BlurBlock::Zero();
    for (int k = -radius; k <= radius; ++k) acc += kernel[k + radius] * BlurBlock::Map(in + c + k);
    BlurBlock::Map(o + c) = acc;
  }
  for (; c < hi; ++c) clamped(c);
}

// The vertical pass of one output row: in[k] is the horizontally blurred
// row at offset k - radius (rows clamped by the caller).
void BlurColumn(const std::vector<float>& kernel, const float* const* in, int cols, float* o) {
  // As the horizontal pass: kBlock columns' sums in registers over the taps.
  const int taps = static_cast<int>(kernel.size());
  int c = 0;
  for (; c + kBlurBlock <= cols; c += kBlurBlock) {
    BlurBlock acc = BlurBlock::Zero();
    for (int k = 0; k < taps; ++k) acc += kernel[k] * BlurBlock::Map(in[k] + c);
    BlurBlock::Map(o + c) = acc;
  }
  for (; c < cols; ++c) {
    float acc = 0;
    for (int k = 0; k < taps; ++k) acc += kernel[k] * in[k][c];
    o[c] = acc;
  }
}

}  // namespace

ImageF GaussianBlur(const ImageF& image, double sigma_px) {
  const std::vector<float> kernel = GaussianKernel(sigma_px);
  const int rows = static_cast<int>(image.rows()), cols = static_cast<int>(image.cols());
  ImageF tmp(rows, cols), out(rows, cols);
  for (int r = 0; r < rows; ++r)
    BlurRow(kernel, image.data() + static_cast<size_t>(r) * cols, cols,
            tmp.data() + static_cast<size_t>(r) * cols);
  const int radius = static_cast<int>(kernel.size() / 2);
  std::vector<const float*> in(kernel.size());
  for (int r = 0; r < rows; ++r) {
    for (int k = -radius; k <= radius; ++k)
      in[k + radius] = tmp.data() + static_cast<size_t>(std::clamp(r + k, 0, rows - 1)) * cols;
    BlurColumn(kernel, in.data(), cols, out.data() + static_cast<size_t>(r) * cols);
  }
  return out;
}

std::string HarrisOptions::Check() const {
  if (!(window_sigma_px > 0)) return "harris.window_sigma_px must be > 0";
  if (!(k > 0 && k < 0.25)) return "harris.k must be in (0, 0.25)";
  if (cell_px < 8) return "harris.cell_px must be >= 8";
  if (max_per_cell < 1) return "harris.max_per_cell must be >= 1";
  if (nms_radius_px < 1) return "harris.nms_radius_px must be >= 1";
  if (!(min_response_fraction >= 0)) return "harris.min_response_fraction must be >= 0";
  if (border_px < 2) return "harris.border_px must be >= 2";
  if (texture_half_size_px < 1) return "harris.texture_half_size_px must be >= 1";
  if (!(min_texture_std >= 0)) return "harris.min_texture_std must be >= 0";
  return {};
}

namespace {

// R = det M - k tr(M)^2 at the pixels [x0, x1) x [y0, y1) into `response`,
// the same values as over the whole image: the gradient products are zero on
// the image's border rows and columns, the window is clamped at the image's
// borders only (a box's rows and columns reach radius beyond it).
void HarrisResponse(const ImageF& image, const std::vector<float>& kernel, float k, int x0, int x1,
                    int y0, int y1, ImageF* response) {
  const int rows = static_cast<int>(image.rows()), cols = static_cast<int>(image.cols());
  // The gradient products row by row, straight into the window's horizontal
  // pass, kept in a ring of the 2 radius + 1 rows the vertical pass needs,
  // whose output goes straight into R: no full-size product or blurred
  // images (their allocation and memory traffic cost more than the taps).
  const int radius = static_cast<int>(kernel.size() / 2), ring_rows = 2 * radius + 1;
  // The products' columns: the window's reach beyond the box.
  const int px0 = std::max(0, x0 - radius), px1 = std::min(cols, x1 + radius);
  ImageF ring_xx(ring_rows, cols), ring_yy(ring_rows, cols), ring_xy(ring_rows, cols);
  std::vector<float> xx(cols), yy(cols), xy(cols);
  int next_row = std::max(0, y0 - radius);  // the next row to blur horizontally into the ring
  const auto blur_rows_through = [&](int last) {
    for (; next_row <= last; ++next_row) {
      const int r = next_row;
      if (r >= 1 && r + 1 < rows) {
        // Zero at the border columns (no central difference), the rest written
        // below: a fill of the whole rows cost 3 % of the registration.
        for (std::vector<float>* v : {&xx, &yy, &xy}) v->front() = v->back() = 0.0f;
        const float* row = image.data() + static_cast<size_t>(r) * cols;
        for (int c = std::max(1, px0); c < std::min(cols - 1, px1); ++c) {
          const float gx = 0.5f * (row[c + 1] - row[c - 1]);
          const float gy = 0.5f * (row[c + cols] - row[c - cols]);
          xx[c] = gx * gx;
          yy[c] = gy * gy;
          xy[c] = gx * gy;
        }
      } else {
        std::fill(xx.begin(), xx.end(), 0.0f);
        std::fill(yy.begin(), yy.end(), 0.0f);
        std::fill(xy.begin(), xy.end(), 0.0f);
      }
      const size_t offset = static_cast<size_t>(r % ring_rows) * cols + px0;
      BlurRow(kernel, xx.data() + px0, px1 - px0, ring_xx.data() + offset);
      BlurRow(kernel, yy.data() + px0, px1 - px0, ring_yy.data() + offset);
      BlurRow(kernel, xy.data() + px0, px1 - px0, ring_xy.data() + offset);
    }
  };
  std::vector<const float*> in_xx(ring_rows), in_yy(ring_rows), in_xy(ring_rows);
  for (int r = y0; r < y1; ++r) {
    blur_rows_through(std::min(r + radius, rows - 1));
    for (int j = 0; j < ring_rows; ++j) {
      const size_t offset =
          static_cast<size_t>(std::clamp(r + j - radius, 0, rows - 1) % ring_rows) * cols + x0;
      in_xx[j] = ring_xx.data() + offset;
      in_yy[j] = ring_yy.data() + offset;
      in_xy[j] = ring_xy.data() + offset;
    }
    BlurColumn(kernel, in_xx.data(), x1 - x0, xx.data() + x0);
    BlurColumn(kernel, in_yy.data(), x1 - x0, yy.data() + x0);
    BlurColumn(kernel, in_xy.data(), x1 - x0, xy.data() + x0);
    float* out = response->data() + static_cast<size_t>(r) * cols;
    for (int c = x0; c < x1; ++c)
      out[c] = xx[c] * yy[c] - xy[c] * xy[c] - k * ((xx[c] + yy[c]) * (xx[c] + yy[c]));
  }
}

// The bucketing cells that meet a region (all of them without regions) as
// disjoint pixel boxes: per row of cells the runs of such cells, a run
// continuing one of the row above when it spans the same cells.
std::vector<Eigen::AlignedBox2i> SearchedBoxes(int rows, int cols, int cell_px,
                                               const std::vector<Eigen::AlignedBox2i>& regions) {
  const int cells_x = (cols + cell_px - 1) / cell_px, cells_y = (rows + cell_px - 1) / cell_px;
  std::vector<unsigned char> searched(static_cast<size_t>(cells_x) * cells_y, regions.empty());
  const Eigen::AlignedBox2i image(Eigen::Vector2i(0, 0), Eigen::Vector2i(cols - 1, rows - 1));
  for (const Eigen::AlignedBox2i& region : regions) {
    const Eigen::AlignedBox2i box = region.intersection(image);
    if (box.isEmpty()) continue;
    for (int cy = box.min().y() / cell_px; cy <= box.max().y() / cell_px; ++cy)
      for (int cx = box.min().x() / cell_px; cx <= box.max().x() / cell_px; ++cx)
        searched[static_cast<size_t>(cy) * cells_x + cx] = 1;
  }
  std::vector<Eigen::AlignedBox2i> boxes;
  std::vector<int> open;  // boxes ending at the row above
  for (int cy = 0; cy < cells_y; ++cy) {
    std::vector<int> now;
    for (int cx = 0; cx < cells_x;) {
      if (!searched[static_cast<size_t>(cy) * cells_x + cx]) {
        ++cx;
        continue;
      }
      const int cx0 = cx;
      while (cx < cells_x && searched[static_cast<size_t>(cy) * cells_x + cx]) ++cx;
      const int x0 = cx0 * cell_px, x1 = std::min(cols, cx * cell_px) - 1;
      const int y1 = std::min(rows, (cy + 1) * cell_px) - 1;
      const auto same = std::find_if(open.begin(), open.end(), [&](int b) {
        return boxes[b].min().x() == x0 && boxes[b].max().x() == x1;
      });
      if (same != open.end()) {
        boxes[*same].max().y() = y1;
        now.push_back(*same);
      } else {
        boxes.emplace_back(Eigen::Vector2i(x0, cy * cell_px), Eigen::Vector2i(x1, y1));
        now.push_back(static_cast<int>(boxes.size()) - 1);
      }
    }
    open = std::move(now);
  }
  return boxes;
}

}  // namespace

std::vector<Corner> DetectHarrisCorners(const ImageF& image, const HarrisOptions& options,
                                        const std::vector<Eigen::AlignedBox2i>& regions) {
  const int rows = static_cast<int>(image.rows()), cols = static_cast<int>(image.cols());
  const std::vector<float> kernel = GaussianKernel(options.window_sigma_px);
  const float k = static_cast<float>(options.k);
  const int b = std::max(options.border_px, options.nms_radius_px + 1), n = options.nms_radius_px;
  // R where the maxima of the searched boxes are looked for and compared
  // (n beyond them); the rest is never read.
  ImageF response(rows, cols);
  const std::vector<Eigen::AlignedBox2i> boxes =
      SearchedBoxes(rows, cols, options.cell_px, regions);
  for (const Eigen::AlignedBox2i& box : boxes) {
    HarrisResponse(image, kernel, k, std::max(0, box.min().x() - n),
                   std::min(cols, box.max().x() + 1 + n), std::max(0, box.min().y() - n),
                   std::min(rows, box.max().y() + 1 + n), &response);
  }

  // Local maxima inside the border.
  // The texture test: the window's variance by direct sums, only for the
  // corners that reach the bucketing (a few per cell).
  const int t = options.texture_half_size_px;
  const double min_texture_var = options.min_texture_std * options.min_texture_std;
  const auto textured = [&](int r, int c) {
    if (options.min_texture_std <= 0) return true;
    const int r0 = std::max(0, r - t), r1 = std::min(rows, r + t + 1);
    const int c0 = std::max(0, c - t), c1 = std::min(cols, c + t + 1);
    double sum = 0, sum_sq = 0;
    for (int y = r0; y < r1; ++y) {
      const float* row = image.data() + static_cast<size_t>(y) * cols;
      float row_sum = 0, row_sq = 0;  // <= a few dozen terms
      for (int x = c0; x < c1; ++x) row_sum += row[x], row_sq += row[x] * row[x];
      sum += row_sum, sum_sq += row_sq;
    }
    const double count = static_cast<double>(r1 - r0) * (c1 - c0);
    const double mean = sum / count;
    return sum_sq / count - mean * mean >= min_texture_var;
  };
  std::vector<Corner> maxima;
  std::vector<unsigned char> candidate(cols, 0);
  for (const Eigen::AlignedBox2i& box : boxes) {
    const int c0 = std::max(b, box.min().x()), c1 = std::min(cols - b, box.max().x() + 1);
    for (int r = std::max(b, box.min().y()); r < std::min(rows - b, box.max().y() + 1); ++r) {
      // Most pixels fail against a direct neighbour: that test first, for a
      // whole row without branches (it vectorises; the branches mispredicted).
      const float* row = response.data() + static_cast<size_t>(r) * cols;
      const float *up = row - cols, *down = row + cols;
      for (int c = c0; c < c1; ++c) {
        const float v = row[c];
        candidate[c] =
            !(v <= 0) & !(row[c - 1] >= v) & !(row[c + 1] > v) & !(up[c] >= v) & !(down[c] > v);
      }
      for (int c = c0; c < c1; ++c) {
        if (!candidate[c]) continue;
        const float v = row[c];
        bool is_max = true;
        for (int dr = -n; dr <= n && is_max; ++dr) {
          for (int dc = -n; dc <= n; ++dc) {
            const float w = response(r + dr, c + dc);
            if (w > v || (w == v && (dr < 0 || (dr == 0 && dc < 0)))) {
              is_max = false;
              break;
            }
          }
        }
        if (!is_max) continue;
        Corner corner;
        corner.pixel << c, r;
        corner.response = v;
        maxima.push_back(corner);
      }
    }
  }
  if (maxima.empty()) return maxima;
  std::vector<float> responses;
  responses.reserve(maxima.size());
  for (const Corner& m : maxima) responses.push_back(static_cast<float>(m.response));
  const double threshold = options.min_response_fraction * NthValue(&responses, 0.9);

  // Bucketing: the strongest max_per_cell of each cell.
  // Ties by pixel, so that the order does not depend on the boxes'.
  std::sort(maxima.begin(), maxima.end(), [](const Corner& x, const Corner& y) {
    if (x.response != y.response) return x.response > y.response;
    return std::make_pair(x.pixel.y(), x.pixel.x()) < std::make_pair(y.pixel.y(), y.pixel.x());
  });
  const int cells_x = (cols + options.cell_px - 1) / options.cell_px;
  const int cells_y = (rows + options.cell_px - 1) / options.cell_px;
  std::vector<int> count(static_cast<size_t>(cells_x) * cells_y, 0);
  std::vector<Corner> corners;
  for (Corner& m : maxima) {
    if (m.response < threshold) break;
    int& in_cell = count[(m.pixel.y() / options.cell_px) * cells_x + m.pixel.x() / options.cell_px];
    if (in_cell >= options.max_per_cell || !textured(m.pixel.y(), m.pixel.x())) continue;
    ++in_cell;
    const int x = m.pixel.x(), y = m.pixel.y();
    // Quadratic fit over the 3 x 3 neighbourhood (separable second differences).
    const double dx = 0.5 * (response(y, x + 1) - response(y, x - 1));
    const double dy = 0.5 * (response(y + 1, x) - response(y - 1, x));
    const double dxx = response(y, x + 1) - 2.0 * response(y, x) + response(y, x - 1);
    const double dyy = response(y + 1, x) - 2.0 * response(y, x) + response(y - 1, x);
    const double dxy = 0.25 * (response(y + 1, x + 1) - response(y + 1, x - 1) -
                               response(y - 1, x + 1) + response(y - 1, x - 1));
    Eigen::Matrix2d hessian;
    hessian << dxx, dxy, dxy, dyy;
    Eigen::Vector2d step = Eigen::Vector2d::Zero();
    if (hessian.determinant() > 0 && dxx < 0) step = -hessian.inverse() * Eigen::Vector2d(dx, dy);
    if (step.cwiseAbs().maxCoeff() > 0.5) step.setZero();
    m.q_px = m.pixel.cast<double>() + step;
    corners.push_back(m);
  }
  return corners;
}

namespace {

// SampleBSpline's body. In float: an SSE register holds four floats but two
// doubles, which halved the packed arithmetic. Forced inline: GCC otherwise
// calls it from SampleBSplinePatch's loop, reloading its constants per pixel.
[[gnu::always_inline]] inline bool SampleBSplineAt(const ImageF& coefficients, double x, double y,
                                                   double* value, double* dvalue_dx,
                                                   double* dvalue_dy) {
  // floor(x) in [1, cols - 3] (false for NaN), then truncation is floor (SSE2
  // has no rounding instruction: std::floor took a dozen).
  if (!(x >= 1.0 && y >= 1.0 && x < coefficients.cols() - 2.0 && y < coefficients.rows() - 2.0))
    return false;
  const int ix = static_cast<int>(x), iy = static_cast<int>(y);
  // The four weights and their derivatives as packed polynomials in the
  // fraction f (Horner): w = ((a3 f + a2) f + a1) f + a0, dw = (b2 f + b1) f + b0.
  const auto weights = [](float f, Eigen::Array4f* w, Eigen::Array4f* dw) {
    constexpr float k6 = 1.0f / 6.0f;
    const Eigen::Array4f a0(k6, 4 * k6, k6, 0), a1(-0.5f, 0, 0.5f, 0), a2(0.5f, -1, 0.5f, 0),
        a3(-k6, 0.5f, -0.5f, k6);
    const Eigen::Array4f b0(-0.5f, 0, 0.5f, 0), b1(1, -2, 1, 0), b2(-0.5f, 1.5f, -1.5f, 0.5f);
    *w = ((a3 * f + a2) * f + a1) * f + a0;
    *dw = (b2 * f + b1) * f + b0;
  };
  Eigen::Array4f wx, dwx, wy, dwy;
  weights(static_cast<float>(x - ix), &wx, &dwx);
  weights(static_cast<float>(y - iy), &wy, &dwy);
  // The rows combined first (by wy and dwy), then the columns.
  const float* row =
      coefficients.data() + static_cast<size_t>(iy - 1) * coefficients.cols() + (ix - 1);
  const Eigen::Index stride = coefficients.cols();
  const Eigen::Map<const Eigen::Array4f> r0(row), r1(row + stride), r2(row + 2 * stride),
      r3(row + 3 * stride);
  const Eigen::Array4f t = wy(0) * r0 + wy(1) * r1 + wy(2) * r2 + wy(3) * r3;
  const Eigen::Array4f dt = dwy(0) * r0 + dwy(1) * r1 + dwy(2) * r2 + dwy(3) * r3;
  *value = (wx * t).sum();
  *dvalue_dx = (dwx * t).sum();
  *dvalue_dy = (wx * dt).sum();
  return true;
}

}  // namespace

bool SampleBSpline(const ImageF& coefficients, double x, double y, double* value, double* dvalue_dx,
                   double* dvalue_dy) {
  return SampleBSplineAt(coefficients, x, y, value, dvalue_dx, dvalue_dy);
}

bool SampleBSplinePatch(const ImageF& coefficients, const Eigen::Vector2d& p0,
                        const std::vector<Eigen::Vector2d>& offsets, Eigen::VectorXd* value,
                        Eigen::VectorXd* dvalue_dx, Eigen::VectorXd* dvalue_dy) {
  const Eigen::Index n = static_cast<Eigen::Index>(offsets.size());
  value->resize(n), dvalue_dx->resize(n), dvalue_dy->resize(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Vector2d p = p0 + offsets[i];
    if (!SampleBSplineAt(coefficients, p.x(), p.y(), &(*value)(i), &(*dvalue_dx)(i),
                         &(*dvalue_dy)(i)))
      return false;
  }
  return true;
}

}  // namespace omm
