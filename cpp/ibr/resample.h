// Reading an input view's colour at a continuous image position: the per-pixel ULR blend
// (hybrid.cpp) and the PVM candidates' colours (pvm_render.cpp) share these.
//
// Bilinear interpolation at a position between pixel centres is a 2-tap box on each axis: it
// blurs (at half a pixel it averages two pixels), and a blend of 3-4 views reprojected to
// sub-pixel positions piles those blurs up. Catmull-Rom (the cubic convolution kernel with a =
// -0.5, Keys 1981) interpolates the samples, reproduces linear ramps exactly and keeps more of
// the detail; its negative lobes ring at a step (a halo over- and undershooting the data), so
// each channel is clamped to the range of the 2 x 2 texels a bilinear read would use: the result
// stays within its neighbours' colours (a blend of such reads within the inputs' range, never
// negative for non-negative images), as the clamped bicubic of temporal reprojection does.
// Positions: pixel centres at +0.5, clamped to the edge pixels (the 4 x 4 neighbourhood is
// clamped too, so a read at the border repeats the edge).
#pragma once
#include <algorithm>
#include <cstddef>
#if defined(__SSE2__)
#include <immintrin.h>
#endif

namespace ibr {

// Catmull-Rom weights of the 4 taps at offsets -1, 0, 1, 2 for fraction t in [0, 1]; they sum to 1.
inline void CatmullRomWeights(float t, float w[4]) {
  const float t2 = t * t, t3 = t2 * t;
  w[0] = 0.5f * (-t3 + 2.f * t2 - t);
  w[1] = 0.5f * (3.f * t3 - 5.f * t2 + 2.f);
  w[2] = 0.5f * (-3.f * t3 + 4.f * t2 + t);
  w[3] = 0.5f * (t3 - t2);
}

#if defined(__SSE2__)
// CatmullRomWeights in the four lanes, the same operations per lane (a term with a zero or unit
// coefficient adds or multiplies exactly), so the same weights (up to the sign of a zero weight).
inline __m128 CatmullRomWeights4(float t) {
  const __m128 T = _mm_set1_ps(t), T2 = _mm_mul_ps(T, T), T3 = _mm_mul_ps(T2, T);
  __m128 w = _mm_add_ps(_mm_mul_ps(_mm_setr_ps(-1.f, 3.f, -3.f, 1.f), T3), _mm_mul_ps(_mm_setr_ps(2.f, -5.f, 4.f, -1.f), T2));
  w = _mm_add_ps(w, _mm_mul_ps(_mm_setr_ps(-1.f, 0.f, 1.f, 0.f), T));
  w = _mm_add_ps(w, _mm_setr_ps(0.f, 2.f, 0.f, 0.f));
  return _mm_mul_ps(_mm_set1_ps(0.5f), w);
}
#endif

// The 4 x 4 taps of a Catmull-Rom read at the clamped position (fx, fy) = (x, y) - 0.5 of an (h, w,
// 3) image: col[i] (float offsets in a row) and rows[j], clamped to the image's edge pixels.
inline void CubicRgbTaps(const float* data, std::ptrdiff_t row_stride, int w, int h, int x0, int y0, int col[4],
                         const float* rows[4]) {
  if (x0 >= 1 && x0 + 2 <= w - 1 && y0 >= 1 && y0 + 2 <= h - 1) {  // inside: no clamping
    for (int i = 0; i < 4; ++i) col[i] = 3 * (x0 - 1 + i);
    for (int j = 0; j < 4; ++j) rows[j] = data + static_cast<std::ptrdiff_t>(y0 - 1 + j) * row_stride;
  } else {
    for (int i = 0; i < 4; ++i) col[i] = 3 * std::min(std::max(x0 - 1 + i, 0), w - 1);
    for (int j = 0; j < 4; ++j) {
      rows[j] = data + static_cast<std::ptrdiff_t>(std::min(std::max(y0 - 1 + j, 0), h - 1)) * row_stride;
    }
  }
}

#if defined(__SSE2__)
// CubicRgbAdd's SSE2 sum: acc[0..4) += weight * (the taps weighted by WX (per column) and WY (per
// row), clamped to the centre 2 x 2 taps' range), four floats per tap (RGB and the next pixel's
// red, unused: not for taps at the image's last pixel, whose fourth float is past the end).
inline void CubicRgbTapsAdd(const float* const rows[4], const int col[4], __m128 WX, __m128 WY, float weight,
                            float* acc) {
  const __m128 wxs[4] = {_mm_shuffle_ps(WX, WX, 0x00), _mm_shuffle_ps(WX, WX, 0x55), _mm_shuffle_ps(WX, WX, 0xAA),
                         _mm_shuffle_ps(WX, WX, 0xFF)};
  const __m128 wys[4] = {_mm_shuffle_ps(WY, WY, 0x00), _mm_shuffle_ps(WY, WY, 0x55), _mm_shuffle_ps(WY, WY, 0xAA),
                         _mm_shuffle_ps(WY, WY, 0xFF)};
  __m128 sum = _mm_setzero_ps();
  __m128 lo = _mm_set1_ps(3.4e38f), hi = _mm_set1_ps(-3.4e38f);
  for (int j = 0; j < 4; ++j) {
    __m128 r = _mm_setzero_ps();
    for (int i = 0; i < 4; ++i) {
      const __m128 q = _mm_loadu_ps(rows[j] + col[i]);
      r = _mm_add_ps(r, _mm_mul_ps(wxs[i], q));
      if ((j == 1 || j == 2) && (i == 1 || i == 2)) {
        lo = _mm_min_ps(lo, q);
        hi = _mm_max_ps(hi, q);
      }
    }
    sum = _mm_add_ps(sum, _mm_mul_ps(wys[j], r));
  }
  const __m128 c = _mm_min_ps(_mm_max_ps(sum, lo), hi);
  _mm_storeu_ps(acc, _mm_add_ps(_mm_loadu_ps(acc), _mm_mul_ps(_mm_set1_ps(weight), c)));
}
#endif

// acc[0..3) += weight * (Catmull-Rom of an (h, w, 3) image, rows row_stride floats apart, at (x, y),
// clamped per channel to the 2 x 2 centre texels' range); acc holds 4 floats (the fourth is
// scratch). SSE2 where available (the same sums in another order: within float rounding of the
// scalar loop, which stays for the image's last pixel and for other CPUs); the SSE2 path adds
// weight x colour to all four floats of acc at once (per lane the scalar adds' operations).
inline void CubicRgbAdd(const float* data, std::ptrdiff_t row_stride, int w, int h, float x, float y, float weight,
                        float* acc) {
  const float fx = std::min(std::max(x - 0.5f, 0.f), static_cast<float>(w - 1));
  const float fy = std::min(std::max(y - 0.5f, 0.f), static_cast<float>(h - 1));
  const int x0 = static_cast<int>(fx), y0 = static_cast<int>(fy);
  int col[4];
  const float* rows[4];
  CubicRgbTaps(data, row_stride, w, h, x0, y0, col, rows);
#if defined(__SSE2__)
  // Four floats per tap (RGB and the next pixel's red, unused): the three channels at once. Not
  // where a tap is the image's last pixel, whose fourth float is past the end.
  if (y0 + 2 < h - 1 || x0 + 2 < w - 1) {
    CubicRgbTapsAdd(rows, col, CatmullRomWeights4(fx - static_cast<float>(x0)),
                    CatmullRomWeights4(fy - static_cast<float>(y0)), weight, acc);
    return;
  }
#endif
  float wx[4], wy[4];
  CatmullRomWeights(fx - static_cast<float>(x0), wx);
  CatmullRomWeights(fy - static_cast<float>(y0), wy);
  float out[3] = {0.f, 0.f, 0.f};
  float lo[3] = {3.4e38f, 3.4e38f, 3.4e38f}, hi[3] = {-3.4e38f, -3.4e38f, -3.4e38f};
  for (int j = 0; j < 4; ++j) {
    float r[3] = {0.f, 0.f, 0.f};
    for (int i = 0; i < 4; ++i) {
      const float* q = rows[j] + col[i];
      for (int k = 0; k < 3; ++k) {
        r[k] += wx[i] * q[k];
        if ((j == 1 || j == 2) && (i == 1 || i == 2)) {
          lo[k] = std::min(lo[k], q[k]);
          hi[k] = std::max(hi[k], q[k]);
        }
      }
    }
    for (int k = 0; k < 3; ++k) out[k] += wy[j] * r[k];
  }
  for (int k = 0; k < 3; ++k) acc[k] += weight * std::min(std::max(out[k], lo[k]), hi[k]);
}

// Bilinear read of an (h, w, 3) image, rows row_stride floats apart, at (x, y) (positions in double,
// as the scalar reference paths compute them).
inline void BilinearRgb(const float* data, std::ptrdiff_t row_stride, int w, int h, double x, double y, float out[3]) {
  const double fx = std::min(std::max(x - 0.5, 0.0), static_cast<double>(w - 1));
  const double fy = std::min(std::max(y - 0.5, 0.0), static_cast<double>(h - 1));
  const int x0 = std::min(static_cast<int>(fx), w - 1), y0 = std::min(static_cast<int>(fy), h - 1);
  const int x1 = std::min(x0 + 1, w - 1), y1 = std::min(y0 + 1, h - 1);
  const float ax = static_cast<float>(fx - x0), ay = static_cast<float>(fy - y0);
  const float* r0 = data + static_cast<std::ptrdiff_t>(y0) * row_stride;
  const float* r1 = data + static_cast<std::ptrdiff_t>(y1) * row_stride;
  for (int c = 0; c < 3; ++c) {
    const float top = r0[3 * x0 + c] + ax * (r0[3 * x1 + c] - r0[3 * x0 + c]);
    const float bot = r1[3 * x0 + c] + ax * (r1[3 * x1 + c] - r1[3 * x0 + c]);
    out[c] = top + ay * (bot - top);
  }
}

// The colour at (x, y): Catmull-Rom (clamped as above) with cubic, else bilinear.
inline void ReadRgb(const float* data, std::ptrdiff_t row_stride, int w, int h, double x, double y, bool cubic,
                    float out[3]) {
  if (cubic) {
    float acc[4] = {0.f, 0.f, 0.f, 0.f};
    CubicRgbAdd(data, row_stride, w, h, static_cast<float>(x), static_cast<float>(y), 1.f, acc);
    out[0] = acc[0], out[1] = acc[1], out[2] = acc[2];
  } else {
    BilinearRgb(data, row_stride, w, h, x, y, out);
  }
}

}  // namespace ibr
