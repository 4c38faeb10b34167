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

// One output row of MipDownMoments for band i: X averages at o[i*C..], X^2 averages at o[(k+i)*C..]
// (the operations of MipDown on the stacked values).
void DownMomentRow(const float* __restrict a, const float* __restrict b, bool two_rows, int in_w, int c, int k,
                   int i, int out_c, float* __restrict o) {
  const int pairs = in_w / 2;
  const std::ptrdiff_t ox = static_cast<std::ptrdiff_t>(i) * c, oq = static_cast<std::ptrdiff_t>(k + i) * c;
  for (int x = 0; x < pairs; ++x) {
    const float* a0 = a + static_cast<std::ptrdiff_t>(2 * x) * c;
    const float* b0 = b + static_cast<std::ptrdiff_t>(2 * x) * c;
    float* px = o + static_cast<std::ptrdiff_t>(x) * out_c;
    for (int ch = 0; ch < c; ++ch) {
      const float p = a0[ch], q = a0[c + ch];
      const float pp = p * p, qq = q * q;
      if (two_rows) {
        const float r = b0[ch], s = b0[c + ch];
        const float rr = r * r, ss = s * s;
        px[ox + ch] = ((p + q) + (r + s)) * 0.25f;
        px[oq + ch] = ((pp + qq) + (rr + ss)) * 0.25f;
      } else {
        px[ox + ch] = (p + q) * 0.5f;
        px[oq + ch] = (pp + qq) * 0.5f;
      }
    }
  }
  if (in_w & 1) {
    const float* a0 = a + static_cast<std::ptrdiff_t>(in_w - 1) * c;
    const float* b0 = b + static_cast<std::ptrdiff_t>(in_w - 1) * c;
    float* px = o + static_cast<std::ptrdiff_t>(pairs) * out_c;
    for (int ch = 0; ch < c; ++ch) {
      const float p = a0[ch], pp = p * p;
      if (two_rows) {
        const float r = b0[ch], rr = r * r;
        px[ox + ch] = (p + r) * 0.5f;
        px[oq + ch] = (pp + rr) * 0.5f;
      } else {
        px[ox + ch] = p;
        px[oq + ch] = pp;
      }
    }
  }
}

// TapsAt without floating-point floor: for level l >= 1 the sample coordinate (x + 0.5) / 2^l - 0.5
// is q / 2^(l+1) with the integer q = 2x + 1 - 2^l, so its floor is q >> (l + 1) and its fraction
// (q & (2^(l+1) - 1)) / 2^(l+1), both exact: bit-identical to TapsAt's float values.
struct AxisTap {
  int i0, i1;
  float f;
};

AxisTap AxisAt(int x, int level, int size) {
  const int q = 2 * x + 1 - (1 << level);
  const int i = q >> (level + 1);  // arithmetic shift: floor for negative q
  AxisTap a;
  a.f = static_cast<float>(q & ((2 << level) - 1)) * (1.0f / static_cast<float>(2 << level));
  a.i0 = std::clamp(i, 0, size - 1);
  a.i1 = std::clamp(i + 1, 0, size - 1);
  return a;
}

Taps FastTapsAt(const ImageView<const float>& lv, const AxisTap& row, int level, int x) {
  const AxisTap col = AxisAt(x, level, lv.width);
  Taps t;
  t.fx = col.f;
  t.fy = row.f;
  t.r0 = lv.Row(row.i0);
  t.r1 = lv.Row(row.i1);
  t.x0 = static_cast<std::ptrdiff_t>(col.i0) * lv.channels;
  t.x1 = static_cast<std::ptrdiff_t>(col.i1) * lv.channels;
  return t;
}

// Rows [y0, y1) of MipFoveateChange; kM > 0 fixes the moment count 2kC at compile time.
template <int kM>
void FoveateRows(const ImageView<float>* bands, int k, const ImageView<const float>* mip, int n,
                 const ImageView<const float>& level_map, const ImageView<const float>* noise, int y0, int y1) {
  const int c = bands[0].channels, kc = k * c, nm = kM > 0 ? kM : 2 * kc;
  const float top = static_cast<float>(n);
  float m[kMipMaxMomentChannels];
  AxisTap rows[32];  // per chain level 1..n (n <= 31: sizes are int): the row taps of this row
  for (int y = y0; y < y1; ++y) {
    const float* lam_row = level_map.Row(y);
    for (int l = 1; l <= n; ++l) rows[l] = AxisAt(y, l, mip[l - 1].height);
    for (int x = 0; x < bands[0].width; ++x) {
      const float lam_raw = lam_row[x];
      if (!(lam_raw > 0.0f)) {  // not pooled: no change
        for (int i = 0; i < k; ++i) {
          float* b = &bands[i].At(y, x);
          for (int ch = 0; ch < c; ++ch) b[ch] = 0.0f;
        }
        continue;
      }
      const float lam = std::min(lam_raw, top);
      int l0 = 0;
      float t = 0.0f;
      if (lam > 0.0f) {
        l0 = static_cast<int>(std::floor(lam));
        if (l0 > n - 1) l0 = n - 1;
        t = lam - static_cast<float>(l0);
      }
      if (l0 == 0) {  // the stack's level 0: the pixel's own [X, X^2] (bilinear taps at weight 0 skipped)
        const float w0 = lam > 0.0f ? 1.0f - t : 1.0f;
        for (int i = 0; i < k; ++i) {
          const float* b = &bands[i].At(y, x);
          for (int ch = 0; ch < c; ++ch) {
            const float v = b[ch];
            m[i * c + ch] = w0 * v;
            m[kc + i * c + ch] = w0 * (v * v);
          }
        }
      } else {
        Accumulate<kM, false>(FastTapsAt(mip[l0 - 1], rows[l0], l0, x), 1.0f - t, nm, m);
      }
      if (t > 0.0f) Accumulate<kM, true>(FastTapsAt(mip[l0], rows[l0 + 1], l0 + 1, x), t, nm, m);
      for (int i = 0; i < k; ++i) {
        const float* nz = &noise[i].At(y, x);
        float* b = &bands[i].At(y, x);
        for (int ch = 0; ch < c; ++ch) {
          const float mean = m[i * c + ch];
          const float sq = m[kc + i * c + ch];
          const float mm = mean * mean;
          const float d = sq - mm;
          const float sigma = d > 0.0f ? std::sqrt(d) : 0.0f;
          const float s = sigma * nz[ch];
          const float nv = mean + s;
          b[ch] = nv - b[ch];
        }
      }
    }
  }
}

}  // namespace

void MipDownMoments(const ImageView<const float>* bands, int k, const ImageView<float>& out) {
  const int c = bands[0].channels, in_h = bands[0].height, in_w = bands[0].width;
  ParallelFor(out.height, RowGrain(out.width), [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const bool two_rows = 2 * y + 1 < in_h;
      for (int i = 0; i < k; ++i) {
        const float* a = bands[i].Row(2 * y);
        const float* b = two_rows ? bands[i].Row(2 * y + 1) : a;
        DownMomentRow(a, b, two_rows, in_w, c, k, i, out.channels, out.Row(y));
      }
    }
  });
}

void MipFoveateChange(const ImageView<float>* bands, int k, const ImageView<const float>* mip, int n,
                      const ImageView<const float>& level_map, const ImageView<const float>* noise) {
  const int nm = 2 * k * bands[0].channels;
  ParallelFor(bands[0].height, RowGrain(bands[0].width), [&](std::int64_t y0, std::int64_t y1) {
    const int a = static_cast<int>(y0), b = static_cast<int>(y1);
    switch (nm) {
      case 12: FoveateRows<12>(bands, k, mip, n, level_map, noise, a, b); break;
      case 18: FoveateRows<18>(bands, k, mip, n, level_map, noise, a, b); break;
      case 30: FoveateRows<30>(bands, k, mip, n, level_map, noise, a, b); break;
      default: FoveateRows<0>(bands, k, mip, n, level_map, noise, a, b); break;
    }
  });
}

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
