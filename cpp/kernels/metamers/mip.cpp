// Equations and shapes: mip.h.
#include "kernels/metamers/mip.h"

#include <algorithm>
#include <cmath>
#include <cstddef>

#include "ibr/parallel.h"
#include "ibr/simd.h"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

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

// The change of one band row chunk from its moment planes (MetamericComposite's operations in the
// same order): out[j] = (mean + sigma * noise) - band, sigma = d > 0 ? sqrt(d) : 0 with
// d = sq - mean^2, over n contiguous floats. SSE2 lanes compute the same IEEE values as the scalar
// tail (sqrtps is correctly rounded; the compare-and-mask gives 0 for d <= 0 as the scalar select).
inline void CompositeChange(const float* __restrict mean, const float* __restrict sq, const float* __restrict nz,
                            float* __restrict b, int n) {
  int j = 0;
#if defined(__SSE2__)
  const __m128 zero = _mm_setzero_ps();
  for (; j + 4 <= n; j += 4) {
    const __m128 mv = _mm_loadu_ps(mean + j);
    const __m128 d = _mm_sub_ps(_mm_loadu_ps(sq + j), _mm_mul_ps(mv, mv));
    const __m128 sigma = _mm_and_ps(_mm_sqrt_ps(d), _mm_cmpgt_ps(d, zero));
    const __m128 nv = _mm_add_ps(mv, _mm_mul_ps(sigma, _mm_loadu_ps(nz + j)));
    _mm_storeu_ps(b + j, _mm_sub_ps(nv, _mm_loadu_ps(b + j)));
  }
#endif
  for (; j < n; ++j) {
    const float mm = mean[j] * mean[j];
    const float d = sq[j] - mm;
    const float sigma = d > 0.0f ? std::sqrt(d) : 0.0f;
    const float s = sigma * nz[j];
    const float nv = mean[j] + s;
    b[j] = nv - b[j];
  }
}

// FoveateRows for kK bands of kC channels fixed at compile time: a row is done in chunks of
// kChunk samples, first the moments of every sample (both trilinear levels summed in registers)
// into per-band planes laid out as the band rows, then the composite over each band's contiguous
// chunk (CompositeChange, vectorised), then the unpooled samples (lam <= 0) set to 0. The same
// float operations in the same order as FoveateRows<2 kK kC>: bit-identical output.
template <int kK, int kC>
__attribute__((always_inline)) inline void FoveateRowsFixed(const ImageView<float>* bands,
                                                            const ImageView<const float>* mip, int n,
                                                            const ImageView<const float>& level_map,
                                                            const ImageView<const float>* noise, int y0, int y1) {
  constexpr int kc = kK * kC, nm = 2 * kc, kChunk = 64;
  const float top = static_cast<float>(n);
  const int width = bands[0].width;
  alignas(16) float mean[kK][kChunk * kC];
  alignas(16) float sq[kK][kChunk * kC];
  AxisTap rows[32];
  for (int y = y0; y < y1; ++y) {
    const float* lam_row = level_map.Row(y);
    for (int l = 1; l <= n; ++l) rows[l] = AxisAt(y, l, mip[l - 1].height);
    float* brow[kK];
    const float* nrow[kK];
    for (int i = 0; i < kK; ++i) {
      brow[i] = bands[i].Row(y);
      nrow[i] = noise[i].Row(y);
    }
    for (int x0 = 0; x0 < width; x0 += kChunk) {
      const int cn = std::min(kChunk, width - x0);
      bool any_unpooled = false;
      for (int dx = 0; dx < cn; ++dx) {
        const int x = x0 + dx;
        const float lam_raw = lam_row[x];
        const std::ptrdiff_t o = static_cast<std::ptrdiff_t>(dx) * kC;
        if (!(lam_raw > 0.0f)) {  // not pooled: set to 0 below
          any_unpooled = true;
          for (int i = 0; i < kK; ++i) {
            for (int ch = 0; ch < kC; ++ch) mean[i][o + ch] = sq[i][o + ch] = 0.0f;
          }
          continue;
        }
        const float lam = std::min(lam_raw, top);
        int l0 = static_cast<int>(std::floor(lam));
        if (l0 > n - 1) l0 = n - 1;
        const float t = lam - static_cast<float>(l0);
        // m = (1 - t) * B(l0) + t * B(l0 + 1) summed in registers: the same two terms, added in the
        // same order as Accumulate<false> then Accumulate<true>.
        if (t > 0.0f) {
          const Taps tb = FastTapsAt(mip[l0], rows[l0 + 1], l0 + 1, x);
          const float v00 = t * (1.0f - tb.fx) * (1.0f - tb.fy), v01 = t * tb.fx * (1.0f - tb.fy);
          const float v10 = t * (1.0f - tb.fx) * tb.fy, v11 = t * tb.fx * tb.fy;
          const float* __restrict pa = tb.r0 + tb.x0;
          const float* __restrict pb = tb.r0 + tb.x1;
          const float* __restrict pc = tb.r1 + tb.x0;
          const float* __restrict pd = tb.r1 + tb.x1;
          if (l0 == 0) {  // the stack's level 0: the pixel's own [X, X^2]
            const float w0 = 1.0f - t;
            for (int i = 0; i < kK; ++i) {
              const float* b = brow[i] + static_cast<std::ptrdiff_t>(x) * kC;
              for (int ch = 0; ch < kC; ++ch) {
                const int j = i * kC + ch, q = kc + j;
                const float v = b[ch];
                mean[i][o + ch] = w0 * v + (v00 * pa[j] + v01 * pb[j] + v10 * pc[j] + v11 * pd[j]);
                sq[i][o + ch] = w0 * (v * v) + (v00 * pa[q] + v01 * pb[q] + v10 * pc[q] + v11 * pd[q]);
              }
            }
          } else {
            const Taps ta = FastTapsAt(mip[l0 - 1], rows[l0], l0, x);
            const float w = 1.0f - t;
            const float u00 = w * (1.0f - ta.fx) * (1.0f - ta.fy), u01 = w * ta.fx * (1.0f - ta.fy);
            const float u10 = w * (1.0f - ta.fx) * ta.fy, u11 = w * ta.fx * ta.fy;
            const float* __restrict qa = ta.r0 + ta.x0;
            const float* __restrict qb = ta.r0 + ta.x1;
            const float* __restrict qc = ta.r1 + ta.x0;
            const float* __restrict qd = ta.r1 + ta.x1;
            float m[nm];
            for (int j = 0; j < nm; ++j) {
              m[j] = (u00 * qa[j] + u01 * qb[j] + u10 * qc[j] + u11 * qd[j]) +
                     (v00 * pa[j] + v01 * pb[j] + v10 * pc[j] + v11 * pd[j]);
            }
            for (int i = 0; i < kK; ++i) {
              for (int ch = 0; ch < kC; ++ch) {
                mean[i][o + ch] = m[i * kC + ch];
                sq[i][o + ch] = m[kc + i * kC + ch];
              }
            }
          }
          continue;
        }
        float m[nm];  // t == 0: one level
        if (l0 == 0) {
          for (int i = 0; i < kK; ++i) {
            const float* b = brow[i] + static_cast<std::ptrdiff_t>(x) * kC;
            for (int ch = 0; ch < kC; ++ch) {
              const float v = b[ch];
              m[i * kC + ch] = 1.0f * v;
              m[kc + i * kC + ch] = 1.0f * (v * v);
            }
          }
        } else {
          Accumulate<nm, false>(FastTapsAt(mip[l0 - 1], rows[l0], l0, x), 1.0f, nm, m);
        }
        for (int i = 0; i < kK; ++i) {
          for (int ch = 0; ch < kC; ++ch) {
            mean[i][o + ch] = m[i * kC + ch];
            sq[i][o + ch] = m[kc + i * kC + ch];
          }
        }
      }
      const std::ptrdiff_t off = static_cast<std::ptrdiff_t>(x0) * kC;
      for (int i = 0; i < kK; ++i) CompositeChange(mean[i], sq[i], nrow[i] + off, brow[i] + off, cn * kC);
      if (any_unpooled) {
        for (int dx = 0; dx < cn; ++dx) {
          if (lam_row[x0 + dx] > 0.0f) continue;
          for (int i = 0; i < kK; ++i) {
            for (int ch = 0; ch < kC; ++ch) brow[i][static_cast<std::ptrdiff_t>(x0 + dx) * kC + ch] = 0.0f;
          }
        }
      }
    }
  }
}

#if defined(__x86_64__) && defined(__GNUC__)
// The same code compiled with AVX2 lanes (no FMA: every product and sum rounds as in the SSE2 build,
// so the output is bit-identical), used when the CPU has AVX2.
template <int kK, int kC>
__attribute__((target("avx2"))) void FoveateRowsFixedAvx2(const ImageView<float>* bands,
                                                          const ImageView<const float>* mip, int n,
                                                          const ImageView<const float>& level_map,
                                                          const ImageView<const float>* noise, int y0, int y1) {
  FoveateRowsFixed<kK, kC>(bands, mip, n, level_map, noise, y0, y1);
}
#endif

template <int kK, int kC>
void FoveateRowsBest(const ImageView<float>* bands, const ImageView<const float>* mip, int n,
                     const ImageView<const float>& level_map, const ImageView<const float>* noise, int y0, int y1) {
#if defined(__x86_64__) && defined(__GNUC__)
  if (CpuHasAvx2()) return FoveateRowsFixedAvx2<kK, kC>(bands, mip, n, level_map, noise, y0, y1);
#endif
  FoveateRowsFixed<kK, kC>(bands, mip, n, level_map, noise, y0, y1);
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
  const bool rgb = bands[0].channels == 3;
  ParallelFor(bands[0].height, RowGrain(bands[0].width), [&](std::int64_t y0, std::int64_t y1) {
    const int a = static_cast<int>(y0), b = static_cast<int>(y1);
    if (rgb && k == 3) return FoveateRowsBest<3, 3>(bands, mip, n, level_map, noise, a, b);
    if (rgb && k == 2) return FoveateRowsBest<2, 3>(bands, mip, n, level_map, noise, a, b);
    if (rgb && k == 5) return FoveateRowsBest<5, 3>(bands, mip, n, level_map, noise, a, b);
    if (rgb && k == 4) return FoveateRowsBest<4, 3>(bands, mip, n, level_map, noise, a, b);
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
