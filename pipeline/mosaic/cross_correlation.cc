#include "pipeline/mosaic/cross_correlation.h"

#include <algorithm>
#include <cassert>

#include <unsupported/Eigen/FFT>

namespace omm {

int FftSize(int n) {
  for (int m = std::max(n, 1);; ++m) {
    int r = m;
    for (const int p : {2, 3, 5})
      while (r % p == 0) r /= p;
    if (r == 1) return m;
  }
}

Spectrum Fft2(const ImageF& image, int rows, int cols) {
  assert(rows >= image.rows() && cols >= image.cols());
  Eigen::FFT<double> fft;
  Spectrum out(static_cast<size_t>(rows) * cols);
  std::vector<double> row(cols, 0.0);
  Spectrum row_out, column(rows), column_out;
  for (int r = 0; r < image.rows(); ++r) {
    for (int c = 0; c < image.cols(); ++c) row[c] = image(r, c);
    fft.fwd(row_out, row);
    std::copy(row_out.begin(), row_out.end(), out.begin() + static_cast<size_t>(r) * cols);
  }
  for (int c = 0; c < cols; ++c) {  // the padding rows are zero already
    for (int r = 0; r < rows; ++r) column[r] = out[static_cast<size_t>(r) * cols + c];
    fft.fwd(column_out, column);
    for (int r = 0; r < rows; ++r) out[static_cast<size_t>(r) * cols + c] = column_out[r];
  }
  return out;
}

std::vector<double> CrossSums(const Spectrum& fa, const Spectrum& fb, int rows, int cols) {
  assert(fa.size() == static_cast<size_t>(rows) * cols && fb.size() == fa.size());
  Eigen::FFT<double> fft;
  Spectrum product(fa.size());
  for (size_t i = 0; i < fa.size(); ++i) product[i] = std::conj(fa[i]) * fb[i];
  Spectrum column(rows), column_out, row(cols), row_out;
  for (int c = 0; c < cols; ++c) {
    for (int r = 0; r < rows; ++r) column[r] = product[static_cast<size_t>(r) * cols + c];
    fft.inv(column_out, column);
    for (int r = 0; r < rows; ++r) product[static_cast<size_t>(r) * cols + c] = column_out[r];
  }
  std::vector<double> out(product.size());
  for (int r = 0; r < rows; ++r) {
    std::copy(product.begin() + static_cast<size_t>(r) * cols,
              product.begin() + static_cast<size_t>(r + 1) * cols, row.begin());
    fft.inv(row_out, row);
    for (int c = 0; c < cols; ++c) out[static_cast<size_t>(r) * cols + c] = row_out[c].real();
  }
  return out;
}

}  // namespace omm
