#include "adapters/apriltag/tag_detector.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include <apriltag/apriltag.h>
#include <apriltag/tag36h11.h>

namespace omm {

std::string TagDetectorOptions::Check() const {
  if (!(quad_decimate >= 1.0)) return "quad_decimate must be >= 1";
  if (!(gate_decimate == 0.0 || gate_decimate >= 1.0)) return "gate_decimate must be 0 or >= 1";
  if (!(quad_sigma_px >= 0.0)) return "quad_sigma_px must be >= 0";
  if (max_hamming < 0 || max_hamming > 3) return "max_hamming must be in 0..3";
  if (!(min_decision_margin >= 0.0)) return "min_decision_margin must be >= 0";
  if (num_threads < 1) return "num_threads must be >= 1";
  return {};
}

namespace {

// 8-bit copy stretched so that the 0.5 % and 99.5 % percentiles map to 0, 255.
std::vector<std::uint8_t> Stretch8(const ImageF& image, int stride) {
  std::vector<float> sample;
  sample.reserve(image.size() / 16 + 1);
  for (Eigen::Index i = 0; i < image.size(); i += 16) sample.push_back(image.data()[i]);
  const auto at = [&](double f) {
    const auto k = static_cast<std::ptrdiff_t>(f * (sample.size() - 1));
    std::nth_element(sample.begin(), sample.begin() + k, sample.end());
    return sample[k];
  };
  const float lo = at(0.005), hi = at(0.995);
  const float scale = hi > lo ? 255.0f / (hi - lo) : 1.0f;
  std::vector<std::uint8_t> out(static_cast<size_t>(stride) * image.rows(), 0);
#if defined(__SSE2__)
  // 16 pixels at a time (GCC's vectorisation of the loop below narrowed to
  // bytes in ~20 instructions a pixel, as many as the scalar loop): for
  // v >= 0, floor(2 v) - floor(v) is floor(v) + 1 exactly when frac(v) >=
  // 0.5, and 2 x is exact, so the bytes are the loop's (checked for every
  // float in [-2, 260]; NaN gives 0 in both).
  const __m128 lo4 = _mm_set1_ps(lo), scale4 = _mm_set1_ps(scale), zero = _mm_setzero_ps(),
               max1 = _mm_set1_ps(255.0f), max2 = _mm_set1_ps(510.0f);
  const auto round4 = [&](const float* p) {
    const __m128 x = _mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(p), lo4), scale4);
    const __m128 v = _mm_min_ps(_mm_max_ps(x, zero), max1);
    const __m128 v2 = _mm_min_ps(_mm_max_ps(_mm_add_ps(x, x), zero), max2);
    return _mm_sub_epi32(_mm_cvttps_epi32(v2), _mm_cvttps_epi32(v));
  };
#endif
  for (Eigen::Index r = 0; r < image.rows(); ++r) {
    const float* in = image.data() + r * image.cols();
    std::uint8_t* o = out.data() + r * stride;
    Eigen::Index c = 0;
#if defined(__SSE2__)
    for (; c + 16 <= image.cols(); c += 16) {
      const __m128i a = _mm_packs_epi32(round4(in + c), round4(in + c + 4));
      const __m128i b = _mm_packs_epi32(round4(in + c + 8), round4(in + c + 12));
      _mm_storeu_si128(reinterpret_cast<__m128i*>(o + c), _mm_packus_epi16(a, b));
    }
#endif
    for (; c < image.cols(); ++c) {
      // Clamped, then rounded half away from zero as std::round would (same
      // bytes: checked for every float in [-2, 260]; std::round is a library
      // call without SSE4.1).
      const float v = std::clamp((in[c] - lo) * scale, 0.0f, 255.0f);
      const int t = static_cast<int>(v);
      o[c] = static_cast<std::uint8_t>(t + (v - static_cast<float>(t) >= 0.5f));
    }
  }
  return out;
}

}  // namespace

std::vector<TagDetection> DetectAprilTags36h11(const ImageF& image,
                                               const TagDetectorOptions& options) {
  const int width = static_cast<int>(image.cols()), height = static_cast<int>(image.rows());
  std::vector<std::uint8_t> buffer = Stretch8(image, width);
  image_u8_t im{width, height, width, buffer.data()};

  apriltag_family_t* family = tag36h11_create();
  apriltag_detector_t* detector = apriltag_detector_create();
  apriltag_detector_add_family_bits(detector, family, options.max_hamming);
  detector->quad_sigma = static_cast<float>(options.quad_sigma_px);
  detector->refine_edges = true;
  detector->nthreads = options.num_threads;
  zarray_t* detections = nullptr;
  if (options.gate_decimate > 0) {
    detector->quad_decimate = static_cast<float>(options.gate_decimate);
    detections = apriltag_detector_detect(detector, &im);
    if (zarray_size(detections) > 0) {
      apriltag_detections_destroy(detections);
      detections = nullptr;
    }
  }
  if (detections == nullptr) {
    detector->quad_decimate = static_cast<float>(options.quad_decimate);
    detections = apriltag_detector_detect(detector, &im);
  }

  std::vector<TagDetection> found;
  for (int i = 0; i < zarray_size(detections); ++i) {
    apriltag_detection_t* det = nullptr;
    zarray_get(detections, i, &det);
    if (det->decision_margin < options.min_decision_margin) continue;
    TagDetection d;
    d.id = det->id;
    for (int k = 0; k < 4; ++k) d.corners_px.col(k) << det->p[k][0], det->p[k][1];
    d.center_px << det->c[0], det->c[1];
    d.hamming = det->hamming;
    d.decision_margin = det->decision_margin;
    found.push_back(d);
  }
  apriltag_detections_destroy(detections);
  apriltag_detector_destroy(detector);
  tag36h11_destroy(family);

  std::map<int, int> count;
  for (const TagDetection& d : found) ++count[d.id];
  std::erase_if(found, [&](const TagDetection& d) { return count[d.id] > 1; });
  std::sort(found.begin(), found.end(),
            [](const TagDetection& a, const TagDetection& b) { return a.id < b.id; });
  return found;
}

}  // namespace omm
