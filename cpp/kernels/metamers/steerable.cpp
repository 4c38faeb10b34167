// Small-filter steerable pyramid kernels; equations and conventions in steerable.h.
#include "kernels/metamers/steerable.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <type_traits>
#include <vector>

#include "ibr/parallel.h"
#include "ibr/simd.h"
#include "kernels/metamers/steerable_taps.h"

// The row loops below are compiled for AVX2 and the baseline, picked at load time
// (IBR_AVX2_CLONES, cpp/ibr/simd.h: the same bits on every CPU).

namespace ibr {
namespace {

using Taps = float[5][5];

// ---- compile-time check of the symmetry the up-sampling path relies on --------------------
constexpr bool IsD4Symmetric(const Taps& f) {
  for (int i = 0; i < 5; ++i)
    for (int j = 0; j < 5; ++j)
      if (f[i][j] != f[4 - i][j] || f[i][j] != f[i][4 - j] || f[i][j] != f[j][i]) return false;
  return true;
}
static_assert(IsD4Symmetric(SteerableTaps<2>::kL1) && IsD4Symmetric(SteerableTaps<4>::kL1) &&
                  IsD4Symmetric(SteerableTaps<2>::kL0) && IsD4Symmetric(SteerableTaps<4>::kL0) &&
                  IsD4Symmetric(SteerableTaps<2>::kH0) && IsD4Symmetric(SteerableTaps<4>::kH0),
              "L0, H0, L1 must be D4-symmetric: synthesis uses them unflipped and up-samples with L1's "
              "even rows/columns");

// reflect1 (reflect-101) index for n >= 3 and i in [-2, n + 1].
inline int Refl(int i, int n) { return i < 0 ? -i : (i >= n ? 2 * (n - 1) - i : i); }

// ---- 1-D row filters --------------------------------------------------------------------------
enum class Parity { kZero, kEven, kOdd, kGeneral };

struct RowFilter {
  Parity parity = Parity::kZero;
  float g[5] = {0, 0, 0, 0, 0};  // taps for dx = -2..2
};

RowFilter MakeRow(const float* g) {
  RowFilter r;
  std::copy(g, g + 5, r.g);
  if (g[0] == 0 && g[1] == 0 && g[2] == 0 && g[3] == 0 && g[4] == 0) r.parity = Parity::kZero;
  else if (g[0] == g[4] && g[1] == g[3]) r.parity = Parity::kEven;
  else if (g[0] == -g[4] && g[1] == -g[3] && g[2] == 0) r.parity = Parity::kOdd;
  else r.parity = Parity::kGeneral;
  return r;
}

// A 5x5 correlation kernel split along y: rows[0] acts on s0, rows[1], rows[2] on s1, s2 (even
// part), rows[3], rows[4] on d1, d2 (odd part); see steerable.h.
struct SplitFilter {
  RowFilter rows[5];
  unsigned mask = 0;       // bit i: rows[i] is not zero (combination i is read)
};

SplitFilter Split(const Taps& f, bool flip) {
  float t[5][5];
  for (int i = 0; i < 5; ++i)
    for (int j = 0; j < 5; ++j) t[i][j] = flip ? f[4 - i][4 - j] : f[i][j];
  SplitFilter s;
  s.rows[0] = MakeRow(t[2]);
  for (int j = 1; j <= 2; ++j) {
    float e[5], o[5];
    for (int x = 0; x < 5; ++x) {
      e[x] = 0.5f * (t[2 + j][x] + t[2 - j][x]);
      o[x] = 0.5f * (t[2 + j][x] - t[2 - j][x]);
    }
    s.rows[j] = MakeRow(e);
    s.rows[2 + j] = MakeRow(o);
  }
  for (int i = 0; i < 5; ++i)
    if (s.rows[i].parity != Parity::kZero) s.mask |= 1u << i;
  return s;
}

struct Filters {
  SplitFilter l0, h0, l1;  // analysis (flip = identity for these D4-symmetric filters)
  std::vector<SplitFilter> bands, bands_flipped;
  float l1_rows[3][3];     // L1 by |dy|, |dx| (D4-symmetric): for the up-sampling
};

template <int K>
Filters MakeFiltersK() {
  using T = SteerableTaps<K>;
  Filters f;
  f.l0 = Split(T::kL0, false);
  f.h0 = Split(T::kH0, false);
  f.l1 = Split(T::kL1, false);
  for (int k = 0; k < K; ++k) {
    f.bands.push_back(Split(T::kBands[k], false));
    f.bands_flipped.push_back(Split(T::kBands[k], true));
  }
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) f.l1_rows[i][j] = T::kL1[2 + i][2 + j];
  return f;
}

Filters MakeFilters(int k) { return k == 4 ? MakeFiltersK<4>() : MakeFiltersK<2>(); }

// ---- vertical combinations of one output row, reflect1-padded by 2 pixels left and right ----
// Per-thread scratch rows of the parallel loops, kept between calls so that tasks neither
// allocate nor first-touch fresh memory: slot `slot` of the calling thread, >= n floats, contents
// undefined. A thread runs one loop body at a time (the bodies start no parallel work), so a
// slot is never shared; ~21 rows of the widest image seen per thread.
enum Slot { kCombos, kRingA, kRingB, kUp0, kUp1, kSlots };
float* TaskScratch(Slot slot, std::size_t n) {
  thread_local std::vector<float> bufs[kSlots];
  std::vector<float>& b = bufs[slot];
  if (b.size() < n) b.resize(n);
  return b.data();
}

// out = a + b (sign > 0) or a - b over n samples.
IBR_AVX2_CLONES void CombineRow(const float* __restrict a, const float* __restrict b, float sign,
                                     std::ptrdiff_t n, float* __restrict out) {
  if (sign > 0) {
    for (std::ptrdiff_t i = 0; i < n; ++i) out[i] = a[i] + b[i];
  } else {
    for (std::ptrdiff_t i = 0; i < n; ++i) out[i] = a[i] - b[i];
  }
}

class Combos {
 public:
  Combos(int width, int channels)
      : w_(width), c_(channels), stride_(std::ptrdiff_t(width + 4) * channels),
        buf_(TaskScratch(kCombos, std::size_t(5 * stride_))) {}
  // Row i (0: s0, 1: s1, 2: s2, 3: d1, 4: d2), pointing at pixel 0 (readable from pixel -2 to w+1).
  const float* Row(int i) const { return buf_ + i * stride_ + 2 * c_; }

  // Forms the combinations whose bit is set in `mask` (bit i: combination i) at row y of an
  // image of h rows; row(i) gives the pointer to row i (0 <= i < h) of that image.
  template <typename RowFn>
  void Build(const RowFn& row, int h, int y, unsigned mask) {
    const std::ptrdiff_t n = std::ptrdiff_t(w_) * c_;
    const float* r0 = row(y);
    const float* rm1 = row(Refl(y - 1, h));
    const float* rp1 = row(Refl(y + 1, h));
    const float* rm2 = row(Refl(y - 2, h));
    const float* rp2 = row(Refl(y + 2, h));
    if (mask & 1u) {
      std::memcpy(Mut(0), r0, sizeof(float) * n);
      Pad(Mut(0));
    }
    if (mask & 2u) Combine(rp1, rm1, 1.0f, n, Mut(1));
    if (mask & 4u) Combine(rp2, rm2, 1.0f, n, Mut(2));
    if (mask & 8u) Combine(rp1, rm1, -1.0f, n, Mut(3));
    if (mask & 16u) Combine(rp2, rm2, -1.0f, n, Mut(4));
  }
  void Build(const ImageView<const float>& src, int y, unsigned mask) {
    Build([&](int i) { return src.Row(i); }, src.height, y, mask);
  }

 private:
  float* Mut(int i) { return buf_ + i * stride_ + 2 * c_; }
  void Combine(const float* __restrict a, const float* __restrict b, float sign, std::ptrdiff_t n,
               float* __restrict out) const {
    CombineRow(a, b, sign, n, out);
    Pad(out);
  }
  void Pad(float* v) const {
    const int c = c_;
    for (int ch = 0; ch < c; ++ch) {
      v[-1 * c + ch] = v[1 * c + ch];
      v[-2 * c + ch] = v[2 * c + ch];
      v[w_ * c + ch] = v[(w_ - 2) * c + ch];
      v[(w_ + 1) * c + ch] = v[(w_ - 3) * c + ch];
    }
  }
  int w_, c_;
  std::ptrdiff_t stride_;
  float* buf_;
};

// acc[i] += (g applied along x to v)[i], i over w * c interleaved samples; with kStore,
// acc[i] = ... instead (the first filter of a zero-initialised sum: 0 + t == t, so the result is
// the same without the zero fill and its extra pass over the row).
template <bool kStore>
IBR_AVX2_CLONES void AccumulateRow(const RowFilter& f, const float* __restrict v, std::ptrdiff_t n, int c,
                   float* __restrict acc) {
  const std::ptrdiff_t c1 = c, c2 = 2 * std::ptrdiff_t(c);
  const float g0 = f.g[2], g1 = f.g[3], g2 = f.g[4];
  switch (f.parity) {
    case Parity::kZero:
      if (kStore) std::fill(acc, acc + n, 0.0f);
      return;
    case Parity::kEven:
      for (std::ptrdiff_t i = 0; i < n; ++i) {
        const float t = g0 * v[i] + g1 * (v[i - c1] + v[i + c1]) + g2 * (v[i - c2] + v[i + c2]);
        if (kStore) acc[i] = t; else acc[i] += t;
      }
      return;
    case Parity::kOdd:
      for (std::ptrdiff_t i = 0; i < n; ++i) {
        const float t = g1 * (v[i + c1] - v[i - c1]) + g2 * (v[i + c2] - v[i - c2]);
        if (kStore) acc[i] = t; else acc[i] += t;
      }
      return;
    case Parity::kGeneral: {
      const float a = f.g[0], b = f.g[1];
      for (std::ptrdiff_t i = 0; i < n; ++i) {
        const float t = a * v[i - c2] + b * v[i - c1] + g0 * v[i] + g1 * v[i + c1] + g2 * v[i + c2];
        if (kStore) acc[i] = t; else acc[i] += t;
      }
      return;
    }
  }
}

// Same at even columns only: acc[m * c + ch] (+)= (g along x of v)[(2m) * c + ch], m < wc.
template <int CC, bool kStore>
IBR_AVX2_CLONES void DecimateRow(const RowFilter& f, const float* __restrict v, int wc, int c_runtime, float* __restrict acc) {
  const int c = CC > 0 ? CC : c_runtime;
  const std::ptrdiff_t c1 = c, c2 = 2 * std::ptrdiff_t(c);
  const float g0 = f.g[0], g1 = f.g[1], g2 = f.g[2], g3 = f.g[3], g4 = f.g[4];
  for (int m = 0; m < wc; ++m) {
    const float* p = v + 2 * std::ptrdiff_t(m) * c;
    float* a = acc + std::ptrdiff_t(m) * c;
    for (int ch = 0; ch < c; ++ch) {
      const float t = g0 * p[ch - c2] + g1 * p[ch - c1] + g2 * p[ch] + g3 * p[ch + c1] + g4 * p[ch + c2];
      if (kStore) a[ch] = t; else a[ch] += t;
    }
  }
}

template <bool kStore>
void AccumulateRowDecimated(const RowFilter& f, const float* v, int wc, int c, float* acc) {
  if (c == 3) DecimateRow<3, kStore>(f, v, wc, 3, acc);
  else if (c == 1) DecimateRow<1, kStore>(f, v, wc, 1, acc);
  else DecimateRow<0, kStore>(f, v, wc, c, acc);
}

// Applies a split filter to the combos of one row: acc += f * row, or acc = f * row with `store`
// (the first non-zero part stores, the others add, exactly as a zero-filled acc would).
void ApplySplit(const SplitFilter& f, const Combos& cb, std::ptrdiff_t n, int c, float* acc, bool store) {
  for (int i = 0; i < 5; ++i) {
    if (f.rows[i].parity == Parity::kZero) continue;
    if (store) AccumulateRow<true>(f.rows[i], cb.Row(i), n, c, acc);
    else AccumulateRow<false>(f.rows[i], cb.Row(i), n, c, acc);
    store = false;
  }
  if (store) std::fill(acc, acc + n, 0.0f);
}

// out (w_next samples of c channels) = the decimated L1 of one (even) row's combos.
void DecimateL1(const SplitFilter& l1, const Combos& cb, int w_next, int c, float* out) {
  bool store = true;
  for (int i = 0; i < 5; ++i) {
    if (l1.rows[i].parity == Parity::kZero) continue;
    if (store) AccumulateRowDecimated<true>(l1.rows[i], cb.Row(i), w_next, c, out);
    else AccumulateRowDecimated<false>(l1.rows[i], cb.Row(i), w_next, c, out);
    store = false;
  }
  if (store) std::fill(out, out + std::ptrdiff_t(w_next) * c, 0.0f);
}

std::int64_t Grain(int width, int channels) {
  return std::max<std::int64_t>(1, kMinPixelsPerTask / std::max<std::int64_t>(1, std::int64_t(width) * channels / 3));
}

// Rows per task of the fused top passes: each task also computes 4 rows of level 0 that its
// neighbours compute too, so tasks are at least 32 rows (<= 12.5% extra level-0 work).
std::int64_t FusedGrain(int width, int channels) { return std::max<std::int64_t>(32, Grain(width, channels)); }

ImageView<const float> AsConst(const ImageView<float>& v) {
  return ImageView<const float>(v.data, v.height, v.width, v.channels);
}

// BT.601 full range, chroma centred on 0 (see steerable.h).
constexpr double kRgbToYcc[3][3] = {{0.299, 0.587, 0.114},
                                    {-0.299 / 1.772, -0.587 / 1.772, 0.886 / 1.772},
                                    {0.701 / 1.402, -0.587 / 1.402, -0.114 / 1.402}};
// Exact inverse: R = Y + 1.402 Cr, B = Y + 1.772 Cb, G = (Y - .299 R - .114 B) / .587.
constexpr double kYccToRgb[3][3] = {{1.0, 0.0, 1.402},
                                    {1.0, -0.114 * 1.772 / 0.587, -0.299 * 1.402 / 0.587},
                                    {1.0, 1.772, 0.0}};

struct ColourMatrix {
  float m[3][3];
};

ColourMatrix ToFloat(const double (&m)[3][3]) {
  ColourMatrix f;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) f.m[i][j] = static_cast<float>(m[i][j]);
  return f;
}

// d = M s per pixel over a row of w RGB/YCbCr pixels; d may be s (each pixel is read first).
IBR_AVX2_CLONES void ColourRow(const float* s, const ColourMatrix& cm, int w, float* d) {
  const auto& f = cm.m;
  for (int x = 0; x < w; ++x) {
    const float a = s[3 * x], b = s[3 * x + 1], c = s[3 * x + 2];
    d[3 * x] = f[0][0] * a + f[0][1] * b + f[0][2] * c;
    d[3 * x + 1] = f[1][0] * a + f[1][1] * b + f[1][2] * c;
    d[3 * x + 2] = f[2][0] * a + f[2][1] * b + f[2][2] * c;
  }
}

// An uninitialised float buffer (every element is written before it is read): scratch is
// first touched by the parallel loops that fill it, not zeroed serially up front.
using Buffer = std::unique_ptr<float[]>;
Buffer NewBuffer(std::size_t n) { return Buffer(new float[n]); }

// kRing consecutive rows of an image of `n` samples per row, row r in slot r % kRing: the rows
// of the fused passes below that are read by the next pass and never needed again (a 5-tap
// filter reads rows r - 2 .. r + 2, reflect1 maps outside rows into that window).
class RowRing {
 public:
  static constexpr int kRing = 8;
  RowRing(Slot slot, std::ptrdiff_t n) : n_(n), buf_(TaskScratch(slot, std::size_t(kRing) * n)) {}
  float* Row(int r) const { return buf_ + (r % kRing) * n_; }

 private:
  std::ptrdiff_t n_;
  float* buf_;
};

// Horizontal up-sampling of a coarse row v (zero insertion implied) with the symmetric row taps
// (g0, g1, g2) by |dx|: even x = 2m reads v[m], v[m +- 1]; odd x = 2m + 1 reads v[m], v[m + 1].
// CC = the channel count when known at compile time (0: runtime c).
// kStore: acc = ... (every one of the w pixels is written) instead of acc += ....
template <int CC, bool kStore>
IBR_AVX2_CLONES void UpsampleRow(const float* __restrict v, int w, int c_runtime, float g0, float g1, float g2,
                 float* __restrict acc) {
  const int c = CC > 0 ? CC : c_runtime;
  const int pairs = w / 2;
  for (int m = 0; m < pairs; ++m) {
    const float* p = v + std::ptrdiff_t(m) * c;
    float* a = acc + std::ptrdiff_t(2 * m) * c;
    for (int ch = 0; ch < c; ++ch) {
      const float te = g0 * p[ch] + g2 * (p[ch - c] + p[ch + c]);
      const float to = g1 * (p[ch] + p[ch + c]);
      if (kStore) {
        a[ch] = te;
        a[c + ch] = to;
      } else {
        a[ch] += te;
        a[c + ch] += to;
      }
    }
  }
  if (w & 1) {
    const float* p = v + std::ptrdiff_t(pairs) * c;
    float* a = acc + std::ptrdiff_t(2 * pairs) * c;
    for (int ch = 0; ch < c; ++ch) {
      const float te = g0 * p[ch] + g2 * (p[ch - c] + p[ch + c]);
      if (kStore) a[ch] = te; else a[ch] += te;
    }
  }
}

// Up-sampling part of one synthesis row: acc = corr(up(lo), L1) at fine row y (size h x w),
// reading only the non-zero samples of the zero-inserted image. Coarse rows are combined in
// `tmp` (wc + 2 pixels: one reflect1-consistent pad pixel each side).
void SetUp(const ImageView<const float>& lo, const float (&l1)[3][3], int y, int h, int w,
                  float* tmp0, float* tmp1, float* __restrict acc) {
  const int c = lo.channels, wc = lo.width;
  const std::ptrdiff_t nc = std::ptrdiff_t(wc) * c;
  // Pad: fine index -2 -> 2 (coarse 1); fine w or w+1 -> coarse wc-1 (w even) or wc-2 (w odd).
  auto pad = [&](float* v) {
    const int right = (w % 2 == 0) ? wc - 1 : wc - 2;
    for (int ch = 0; ch < c; ++ch) {
      v[-c + ch] = v[c + ch];
      v[std::ptrdiff_t(wc) * c + ch] = v[std::ptrdiff_t(right) * c + ch];
    }
  };
  auto horizontal = [&](auto store, const float* v, float g0, float g1, float g2) {
    constexpr bool kStore = decltype(store)::value;
    if (c == 3) UpsampleRow<3, kStore>(v, w, 3, g0, g1, g2, acc);
    else if (c == 1) UpsampleRow<1, kStore>(v, w, 1, g0, g1, g2, acc);
    else UpsampleRow<0, kStore>(v, w, c, g0, g1, g2, acc);
  };
  const std::true_type kSet;
  const std::false_type kAdd;
  float* v0 = tmp0 + c;
  float* v1 = tmp1 + c;
  if ((y & 1) == 0) {
    const float* rc = lo.Row(y >> 1);
    const float* ra = lo.Row(Refl(y - 2, h) >> 1);
    const float* rb = lo.Row(Refl(y + 2, h) >> 1);
    std::memcpy(v0, rc, sizeof(float) * nc);
    for (std::ptrdiff_t i = 0; i < nc; ++i) v1[i] = ra[i] + rb[i];
    pad(v0);
    pad(v1);
    horizontal(kSet, v0, l1[0][0], l1[0][1], l1[0][2]);
    horizontal(kAdd, v1, l1[2][0], l1[2][1], l1[2][2]);
  } else {
    const float* ra = lo.Row(Refl(y - 1, h) >> 1);
    const float* rb = lo.Row(Refl(y + 1, h) >> 1);
    for (std::ptrdiff_t i = 0; i < nc; ++i) v1[i] = ra[i] + rb[i];
    pad(v1);
    horizontal(kSet, v1, l1[1][0], l1[1][1], l1[1][2]);
  }
}

}  // namespace

int SteerableMaxLevels(int height, int width) {
  int levels = 0;
  while (height >= 3 && width >= 3) {
    ++levels;
    height = (height + 1) / 2;
    width = (width + 1) / 2;
  }
  return levels;
}

std::int64_t SteerableCountNonFinite(const ImageView<const float>& image) {
  std::vector<std::int64_t> counts(image.height, 0);
  const std::ptrdiff_t n = std::ptrdiff_t(image.width) * image.channels;
  ParallelFor(image.height, Grain(image.width, image.channels), [&](std::int64_t y0, std::int64_t y1) {
    for (std::int64_t y = y0; y < y1; ++y) {
      const float* r = image.Row(static_cast<int>(y));
      std::int64_t bad = 0;
      for (std::ptrdiff_t i = 0; i < n; ++i) bad += !std::isfinite(r[i]);
      counts[y] = bad;
    }
  });
  std::int64_t total = 0;
  for (auto v : counts) total += v;
  return total;
}

void SteerableAnalyseKernel(const ImageView<const float>& image, bool ycbcr,
                            const SteerablePyramidViews<float>& pyr) {
  const int c = image.channels, levels = pyr.levels, k_count = pyr.orientations;
  const int height = image.height, width = image.width;
  const Filters filters = MakeFilters(k_count);
  const ColourMatrix to_ycc = ToFloat(kRgbToYcc);
  unsigned band_mask = 0;
  for (const auto& b : filters.bands) band_mask |= b.mask;
  // Scratch: lo at levels 1..L-1 (lo at level L is the lowpass output; level 0 lives in per-task
  // row rings of the fused top pass).
  std::vector<Buffer> lo_store(levels);
  std::vector<ImageView<float>> lo(levels + 1);
  for (int l = 1; l < levels; ++l) {
    const int h = SteerableLevelSize(height, l), w = SteerableLevelSize(width, l);
    lo_store[l] = NewBuffer(std::size_t(h) * w * c);
    lo[l] = ImageView<float>(lo_store[l].get(), h, w, c);
  }
  lo[levels] = pyr.lowpass;

  // Bands of level l at row y of its input (h rows, row(i) -> row i) and, at even y, row y / 2
  // of the decimated L1 low-pass `next`.
  auto level_row = [&](const auto& row, int l, int h, int y, Combos& cb, const ImageView<float>& next) {
    const std::ptrdiff_t n = std::ptrdiff_t(SteerableLevelSize(width, l)) * c;
    const bool even = (y & 1) == 0;
    cb.Build(row, h, y, band_mask | (even ? filters.l1.mask : 0u));
    for (int k = 0; k < k_count; ++k) ApplySplit(filters.bands[k], cb, n, c, pyr.bands[l * k_count + k].Row(y), true);
    if (even) DecimateL1(filters.l1, cb, next.width, c, next.Row(y >> 1));
  };

  // Top, fused with level 0: per task of rows [y0, y1), the (YCbCr) input rows stream through a
  // ring, hi = H0 * x is written for [y0, y1), lo0 = L0 * x for the rows [y0 - 2, y1 + 2) that
  // level 0 reads (the 2 + 2 overlap rows are computed by both neighbouring tasks, by the same
  // arithmetic), then level 0's bands and L1 rows. Without levels, lo0 is the lowpass output.
  // Nothing of full size is written but the outputs.
  {
    const std::ptrdiff_t n = std::ptrdiff_t(width) * c;
    const std::int64_t grain = FusedGrain(width, c);
    ParallelFor(height, grain, [&](std::int64_t t0, std::int64_t t1) {
      const int y0 = static_cast<int>(t0), y1 = static_cast<int>(t1);
      const int b0 = levels > 0 ? std::max(0, y0 - 2) : y0, b1 = levels > 0 ? std::min(height, y1 + 2) : y1;
      const int a1 = std::min(height, b1 + 2);
      Combos cb(width, c);
      RowRing ycc(kRingA, ycbcr ? n : 0), lo0(kRingB, levels > 0 ? n : 0);
      int ycc_next = std::max(0, b0 - 2);  // next input row to convert
      auto in_row = [&](int r) -> const float* { return ycbcr ? ycc.Row(r) : image.Row(r); };
      auto lo0_row = [&](int r) -> float* { return levels > 0 ? lo0.Row(r) : pyr.lowpass.Row(r); };
      int lo_next = b0;  // next lo0 row to compute
      auto compute_lo0 = [&](int upto) {  // lo0 rows [lo_next, upto)
        for (; lo_next < upto; ++lo_next) {
          const int r = lo_next;
          if (ycbcr) {
            for (const int need = std::min(a1, r + 3); ycc_next < need; ++ycc_next)
              ColourRow(image.Row(ycc_next), to_ycc, width, ycc.Row(ycc_next));
          }
          const bool own = r >= y0 && r < y1;
          cb.Build(in_row, height, r, filters.l0.mask | (own ? filters.h0.mask : 0u));
          if (own) ApplySplit(filters.h0, cb, n, c, pyr.highpass.Row(r), true);
          ApplySplit(filters.l0, cb, n, c, lo0_row(r), true);
        }
      };
      if (levels == 0) {
        compute_lo0(y1);
        return;
      }
      auto lo0_const = [&](int r) -> const float* { return lo0.Row(r); };
      for (int y = y0; y < y1; ++y) {
        compute_lo0(std::min(b1, y + 3));
        level_row(lo0_const, 0, height, y, cb, lo[1]);
      }
    });
  }
  // Levels 1..L-1: bands and the decimated L1 from the same vertical combinations.
  for (int l = 1; l < levels; ++l) {
    const ImageView<const float> in = AsConst(lo[l]);
    ParallelFor(in.height, Grain(in.width, c), [&](std::int64_t y0, std::int64_t y1) {
      Combos cb(in.width, c);
      auto row = [&](int r) { return in.Row(r); };
      for (std::int64_t y = y0; y < y1; ++y) level_row(row, l, in.height, static_cast<int>(y), cb, lo[l + 1]);
    });
  }
}

void SteerableSynthesiseKernel(const SteerablePyramidViews<const float>& pyr, bool ycbcr,
                               const ImageView<float>& out) {
  const int c = out.channels, levels = pyr.levels, k_count = pyr.orientations;
  const int height = out.height, width = out.width;
  const Filters filters = MakeFilters(k_count);
  const ColourMatrix to_rgb = ToFloat(kYccToRgb);
  // Row y of the collapsed low-pass at level l (h x w): up(coarse) * L1 + sum_k flip(B_k) * band.
  auto level_row = [&](int l, const ImageView<const float>& coarse, int h, int w, int y, Combos& cb,
                       float* t0, float* t1, float* acc) {
    const std::ptrdiff_t n = std::ptrdiff_t(w) * c;
    SetUp(coarse, filters.l1_rows, y, h, w, t0, t1, acc);
    for (int k = 0; k < k_count; ++k) {
      cb.Build(pyr.bands[l * k_count + k], y, filters.bands_flipped[k].mask);
      ApplySplit(filters.bands_flipped[k], cb, n, c, acc, false);
    }
  };
  // rec[l]: the collapsed low-pass at level l (rec[L] = lowpass); levels L-1..1 in scratch,
  // level 0 in per-task row rings of the fused top pass.
  std::vector<Buffer> store(levels);
  std::vector<ImageView<const float>> rec(levels + 1);
  rec[levels] = pyr.lowpass;
  for (int l = levels - 1; l >= 1; --l) {
    const int h = SteerableLevelSize(height, l), w = SteerableLevelSize(width, l);
    store[l] = NewBuffer(std::size_t(h) * w * c);
    const ImageView<float> dst(store[l].get(), h, w, c);
    const ImageView<const float> coarse = rec[l + 1];
    ParallelFor(h, Grain(w, c), [&](std::int64_t y0, std::int64_t y1) {
      Combos cb(w, c);
      const std::size_t nt = (coarse.width + 2) * std::size_t(c);
      float* t0 = TaskScratch(kUp0, nt);
      float* t1 = TaskScratch(kUp1, nt);
      for (std::int64_t y = y0; y < y1; ++y) level_row(l, coarse, h, w, static_cast<int>(y), cb, t0, t1, dst.Row(static_cast<int>(y)));
    });
    rec[l] = AsConst(dst);
  }
  // Top, fused with level 0: per task of rows [y0, y1), rec0 rows [y0 - 2, y1 + 2) stream
  // through a ring (overlap rows computed by both neighbouring tasks, same arithmetic), then
  // out = L0 * rec0 + H0 * hi (both D4-symmetric, so flip(f) = f), converted to RGB in place.
  {
    const std::ptrdiff_t n = std::ptrdiff_t(width) * c;
    ParallelFor(height, FusedGrain(width, c), [&](std::int64_t s0, std::int64_t s1) {
      const int y0 = static_cast<int>(s0), y1 = static_cast<int>(s1);
      const int b1 = std::min(height, y1 + 2);
      Combos cb(width, c);
      RowRing ring(kRingA, levels > 0 ? n : 0);
      const std::size_t nt = levels > 0 ? (rec[1].width + 2) * std::size_t(c) : 0;
      float* t0 = TaskScratch(kUp0, nt);
      float* t1 = TaskScratch(kUp1, nt);
      int rec_next = std::max(0, y0 - 2);
      auto rec0_row = [&](int r) -> const float* { return levels > 0 ? ring.Row(r) : pyr.lowpass.Row(r); };
      for (int y = y0; y < y1; ++y) {
        if (levels > 0) {
          for (const int need = std::min(b1, y + 3); rec_next < need; ++rec_next)
            level_row(0, rec[1], height, width, rec_next, cb, t0, t1, ring.Row(rec_next));
        }
        float* acc = out.Row(y);
        cb.Build(rec0_row, height, y, filters.l0.mask);
        ApplySplit(filters.l0, cb, n, c, acc, true);
        cb.Build(pyr.highpass, y, filters.h0.mask);
        ApplySplit(filters.h0, cb, n, c, acc, false);
        if (ycbcr) ColourRow(acc, to_rgb, width, acc);
      }
    });
  }
}

}  // namespace ibr
