// Equations and shapes: mip.h.
#include "kernels/mip.h"

#include <algorithm>
#include <cmath>
#include <cstddef>

#include "ibr/parallel.h"

namespace ibr {
namespace {

std::int64_t RowGrain(int width) { return std::max<std::int64_t>(1, kMinPixelsPerTask / std::max(1, width)); }

// Bilinear taps of one level at a pixel: two rows, two columns (clamped), two weights.
struct Taps {
  const float* r0;
  const float* r1;
  std::ptrdiff_t x0, x1;  // element offsets (column * channels)
  float fx, fy;
};

Taps TapsAt(const ImageView<const float>& lv, int level, int y, int x) {
  const float inv = 1.0f / static_cast<float>(1 << level);
  const float u = (static_cast<float>(x) + 0.5f) * inv - 0.5f;
  const float v = (static_cast<float>(y) + 0.5f) * inv - 0.5f;
  const float uf = std::floor(u), vf = std::floor(v);
  int xi = static_cast<int>(uf), yi = static_cast<int>(vf);
  Taps t;
  t.fx = u - uf;
  t.fy = v - vf;
  const int xa = std::clamp(xi, 0, lv.width - 1), xb = std::clamp(xi + 1, 0, lv.width - 1);
  const int ya = std::clamp(yi, 0, lv.height - 1), yb = std::clamp(yi + 1, 0, lv.height - 1);
  t.r0 = lv.Row(ya);
  t.r1 = lv.Row(yb);
  t.x0 = static_cast<std::ptrdiff_t>(xa) * lv.channels;
  t.x1 = static_cast<std::ptrdiff_t>(xb) * lv.channels;
  return t;
}

// o[c] (+)= w * bilinear(taps)[c] over the channels; kC > 0 fixes the count at compile time (the
// moment stacks of RGB have 12 or 18 channels: fully unrolled, vectorised), 0 = run time.
template <int kC, bool kAccumulate>
void Accumulate(const Taps& t, float w, int channels, float* __restrict o) {
  const int n = kC > 0 ? kC : channels;
  const float w00 = w * (1.0f - t.fx) * (1.0f - t.fy), w01 = w * t.fx * (1.0f - t.fy);
  const float w10 = w * (1.0f - t.fx) * t.fy, w11 = w * t.fx * t.fy;
  const float* __restrict a = t.r0 + t.x0;
  const float* __restrict b = t.r0 + t.x1;
  const float* __restrict c = t.r1 + t.x0;
  const float* __restrict d = t.r1 + t.x1;
  for (int k = 0; k < n; ++k) {
    const float v = w00 * a[k] + w01 * b[k] + w10 * c[k] + w11 * d[k];
    o[k] = kAccumulate ? o[k] + v : v;
  }
}

template <int kC>
void LookupRows(const ImageView<const float>* levels, int n_levels, const ImageView<const float>& level_map,
                const ImageView<float>& out, int y0, int y1) {
  const int c = kC > 0 ? kC : out.channels;
  const float top = static_cast<float>(n_levels - 1);
  for (int y = y0; y < y1; ++y) {
    const float* lam_row = level_map.Row(y);
    const float* src0 = levels[0].Row(y);
    float* o_row = out.Row(y);
    for (int x = 0; x < out.width; ++x) {
      float* o = o_row + static_cast<std::ptrdiff_t>(x) * c;
      const float lam = std::min(lam_row[x], top);
      if (!(lam > 0.0f)) {  // the pixel itself, bit for bit
        const float* s = src0 + static_cast<std::ptrdiff_t>(x) * c;
        for (int k = 0; k < c; ++k) o[k] = s[k];
        continue;
      }
      int l0 = static_cast<int>(std::floor(lam));
      if (l0 > n_levels - 2) l0 = n_levels - 2;  // lam == top: weight 1 on the last level
      const float t = lam - static_cast<float>(l0);
      Accumulate<kC, false>(TapsAt(levels[l0], l0, y, x), 1.0f - t, c, o);
      if (t > 0.0f) Accumulate<kC, true>(TapsAt(levels[l0 + 1], l0 + 1, y, x), t, c, o);
    }
  }
}

}  // namespace

void MipDown(const ImageView<const float>& in, const ImageView<float>& out) {
  const int c = in.channels;
  ParallelFor(out.height, RowGrain(out.width), [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const float* __restrict a = in.Row(2 * y);
      const bool two_rows = 2 * y + 1 < in.height;
      const float* __restrict b = two_rows ? in.Row(2 * y + 1) : a;
      float* __restrict o = out.Row(y);
      const int pairs = in.width / 2;  // output columns with two input columns
      const float row_w = two_rows ? 0.25f : 0.5f;
      for (int x = 0; x < pairs; ++x) {
        const float* a0 = a + static_cast<std::ptrdiff_t>(2 * x) * c;
        const float* b0 = b + static_cast<std::ptrdiff_t>(2 * x) * c;
        float* ox = o + static_cast<std::ptrdiff_t>(x) * c;
        if (two_rows) {
          for (int k = 0; k < c; ++k) ox[k] = ((a0[k] + a0[c + k]) + (b0[k] + b0[c + k])) * row_w;
        } else {
          for (int k = 0; k < c; ++k) ox[k] = (a0[k] + a0[c + k]) * row_w;
        }
      }
      if (in.width & 1) {  // last column: one input column
        const float* a0 = a + static_cast<std::ptrdiff_t>(in.width - 1) * c;
        const float* b0 = b + static_cast<std::ptrdiff_t>(in.width - 1) * c;
        float* ox = o + static_cast<std::ptrdiff_t>(pairs) * c;
        if (two_rows) {
          for (int k = 0; k < c; ++k) ox[k] = (a0[k] + b0[k]) * 0.5f;
        } else {
          for (int k = 0; k < c; ++k) ox[k] = a0[k];
        }
      }
    }
  });
}

void MipLookup(const ImageView<const float>* levels, int n_levels, const ImageView<const float>& level_map,
               const ImageView<float>& out) {
  ParallelFor(out.height, RowGrain(out.width), [&](std::int64_t y0, std::int64_t y1) {
    const int a = static_cast<int>(y0), b = static_cast<int>(y1);
    switch (out.channels) {
      case 12: LookupRows<12>(levels, n_levels, level_map, out, a, b); break;
      case 18: LookupRows<18>(levels, n_levels, level_map, out, a, b); break;
      default: LookupRows<0>(levels, n_levels, level_map, out, a, b); break;
    }
  });
}

}  // namespace ibr
