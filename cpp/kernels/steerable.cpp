// Small-filter steerable pyramid kernels; equations and conventions in steerable.h.
#include "kernels/steerable.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "ibr/parallel.h"
#include "kernels/steerable_taps.h"

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
class Combos {
 public:
  Combos(int width, int channels) : w_(width), c_(channels), stride_(std::ptrdiff_t(width + 4) * channels),
                                    buf_(5 * stride_) {}
  // Row i (0: s0, 1: s1, 2: s2, 3: d1, 4: d2), pointing at pixel 0 (readable from pixel -2 to w+1).
  const float* Row(int i) const { return buf_.data() + i * stride_ + 2 * c_; }

  // Forms the combinations whose bit is set in `mask` (bit i: combination i).
  void Build(const ImageView<const float>& src, int y, unsigned mask) {
    const int h = src.height;
    const std::ptrdiff_t n = std::ptrdiff_t(w_) * c_;
    const float* r0 = src.Row(y);
    const float* rm1 = src.Row(Refl(y - 1, h));
    const float* rp1 = src.Row(Refl(y + 1, h));
    const float* rm2 = src.Row(Refl(y - 2, h));
    const float* rp2 = src.Row(Refl(y + 2, h));
    if (mask & 1u) {
      std::memcpy(Mut(0), r0, sizeof(float) * n);
      Pad(Mut(0));
    }
    if (mask & 2u) Combine(rp1, rm1, 1.0f, n, Mut(1));
    if (mask & 4u) Combine(rp2, rm2, 1.0f, n, Mut(2));
    if (mask & 8u) Combine(rp1, rm1, -1.0f, n, Mut(3));
    if (mask & 16u) Combine(rp2, rm2, -1.0f, n, Mut(4));
  }

 private:
  float* Mut(int i) { return buf_.data() + i * stride_ + 2 * c_; }
  void Combine(const float* __restrict a, const float* __restrict b, float sign, std::ptrdiff_t n,
               float* __restrict out) const {
    if (sign > 0) {
      for (std::ptrdiff_t i = 0; i < n; ++i) out[i] = a[i] + b[i];
    } else {
      for (std::ptrdiff_t i = 0; i < n; ++i) out[i] = a[i] - b[i];
    }
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
  std::vector<float> buf_;
};

// acc[i] += (g applied along x to v)[i], i over w * c interleaved samples.
void AccumulateRow(const RowFilter& f, const float* __restrict v, std::ptrdiff_t n, int c,
                   float* __restrict acc) {
  const std::ptrdiff_t c1 = c, c2 = 2 * std::ptrdiff_t(c);
  const float g0 = f.g[2], g1 = f.g[3], g2 = f.g[4];
  switch (f.parity) {
    case Parity::kZero:
      return;
    case Parity::kEven:
      for (std::ptrdiff_t i = 0; i < n; ++i)
        acc[i] += g0 * v[i] + g1 * (v[i - c1] + v[i + c1]) + g2 * (v[i - c2] + v[i + c2]);
      return;
    case Parity::kOdd:
      for (std::ptrdiff_t i = 0; i < n; ++i) acc[i] += g1 * (v[i + c1] - v[i - c1]) + g2 * (v[i + c2] - v[i - c2]);
      return;
    case Parity::kGeneral: {
      const float a = f.g[0], b = f.g[1];
      for (std::ptrdiff_t i = 0; i < n; ++i)
        acc[i] += a * v[i - c2] + b * v[i - c1] + g0 * v[i] + g1 * v[i + c1] + g2 * v[i + c2];
      return;
    }
  }
}

// Same at even columns only: acc[m * c + ch] += (g along x of v)[(2m) * c + ch], m < wc.
template <int CC>
void DecimateRow(const RowFilter& f, const float* __restrict v, int wc, int c_runtime, float* __restrict acc) {
  const int c = CC > 0 ? CC : c_runtime;
  const std::ptrdiff_t c1 = c, c2 = 2 * std::ptrdiff_t(c);
  const float g0 = f.g[0], g1 = f.g[1], g2 = f.g[2], g3 = f.g[3], g4 = f.g[4];
  for (int m = 0; m < wc; ++m) {
    const float* p = v + 2 * std::ptrdiff_t(m) * c;
    float* a = acc + std::ptrdiff_t(m) * c;
    for (int ch = 0; ch < c; ++ch) {
      a[ch] += g0 * p[ch - c2] + g1 * p[ch - c1] + g2 * p[ch] + g3 * p[ch + c1] + g4 * p[ch + c2];
    }
  }
}

void AccumulateRowDecimated(const RowFilter& f, const float* v, int wc, int c, float* acc) {
  if (f.parity == Parity::kZero) return;
  if (c == 3) DecimateRow<3>(f, v, wc, 3, acc);
  else if (c == 1) DecimateRow<1>(f, v, wc, 1, acc);
  else DecimateRow<0>(f, v, wc, c, acc);
}

// Applies a split filter to the combos of one row.
void ApplySplit(const SplitFilter& f, const Combos& cb, std::ptrdiff_t n, int c, float* acc) {
  for (int i = 0; i < 5; ++i) AccumulateRow(f.rows[i], cb.Row(i), n, c, acc);
}

std::int64_t Grain(int width, int channels) {
  return std::max<std::int64_t>(1, kMinPixelsPerTask / std::max<std::int64_t>(1, std::int64_t(width) * channels / 3));
}

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

void ColourTransform(const ImageView<const float>& src, const double (&m)[3][3], const ImageView<float>& dst) {
  float f[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) f[i][j] = static_cast<float>(m[i][j]);
  ParallelFor(src.height, Grain(src.width, 3), [&](std::int64_t y0, std::int64_t y1) {
    for (std::int64_t y = y0; y < y1; ++y) {
      const float* s = src.Row(static_cast<int>(y));
      float* d = dst.Row(static_cast<int>(y));
      for (int x = 0; x < src.width; ++x) {
        const float a = s[3 * x], b = s[3 * x + 1], c = s[3 * x + 2];
        d[3 * x] = f[0][0] * a + f[0][1] * b + f[0][2] * c;
        d[3 * x + 1] = f[1][0] * a + f[1][1] * b + f[1][2] * c;
        d[3 * x + 2] = f[2][0] * a + f[2][1] * b + f[2][2] * c;
      }
    }
  });
}

// Horizontal up-sampling of a coarse row v (zero insertion implied) with the symmetric row taps
// (g0, g1, g2) by |dx|: even x = 2m reads v[m], v[m +- 1]; odd x = 2m + 1 reads v[m], v[m + 1].
// CC = the channel count when known at compile time (0: runtime c).
template <int CC>
void UpsampleRow(const float* __restrict v, int w, int c_runtime, float g0, float g1, float g2,
                 float* __restrict acc) {
  const int c = CC > 0 ? CC : c_runtime;
  const int pairs = w / 2;
  for (int m = 0; m < pairs; ++m) {
    const float* p = v + std::ptrdiff_t(m) * c;
    float* a = acc + std::ptrdiff_t(2 * m) * c;
    for (int ch = 0; ch < c; ++ch) {
      a[ch] += g0 * p[ch] + g2 * (p[ch - c] + p[ch + c]);
      a[c + ch] += g1 * (p[ch] + p[ch + c]);
    }
  }
  if (w & 1) {
    const float* p = v + std::ptrdiff_t(pairs) * c;
    float* a = acc + std::ptrdiff_t(2 * pairs) * c;
    for (int ch = 0; ch < c; ++ch) a[ch] += g0 * p[ch] + g2 * (p[ch - c] + p[ch + c]);
  }
}

// Up-sampling part of one synthesis row: acc += corr(up(lo), L1) at fine row y (size h x w),
// reading only the non-zero samples of the zero-inserted image. Coarse rows are combined in
// `tmp` (wc + 2 pixels: one reflect1-consistent pad pixel each side).
void AccumulateUp(const ImageView<const float>& lo, const float (&l1)[3][3], int y, int h, int w,
                  std::vector<float>& tmp0, std::vector<float>& tmp1, float* __restrict acc) {
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
  auto horizontal = [&](const float* v, float g0, float g1, float g2) {
    if (c == 3) UpsampleRow<3>(v, w, 3, g0, g1, g2, acc);
    else if (c == 1) UpsampleRow<1>(v, w, 1, g0, g1, g2, acc);
    else UpsampleRow<0>(v, w, c, g0, g1, g2, acc);
  };
  float* v0 = tmp0.data() + c;
  float* v1 = tmp1.data() + c;
  if ((y & 1) == 0) {
    const float* rc = lo.Row(y >> 1);
    const float* ra = lo.Row(Refl(y - 2, h) >> 1);
    const float* rb = lo.Row(Refl(y + 2, h) >> 1);
    std::memcpy(v0, rc, sizeof(float) * nc);
    for (std::ptrdiff_t i = 0; i < nc; ++i) v1[i] = ra[i] + rb[i];
    pad(v0);
    pad(v1);
    horizontal(v0, l1[0][0], l1[0][1], l1[0][2]);
    horizontal(v1, l1[2][0], l1[2][1], l1[2][2]);
  } else {
    const float* ra = lo.Row(Refl(y - 1, h) >> 1);
    const float* rb = lo.Row(Refl(y + 1, h) >> 1);
    for (std::ptrdiff_t i = 0; i < nc; ++i) v1[i] = ra[i] + rb[i];
    pad(v1);
    horizontal(v1, l1[1][0], l1[1][1], l1[1][2]);
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
  const Filters filters = MakeFilters(k_count);
  ImageView<const float> src = image;
  std::vector<float> ycc;
  if (ycbcr) {
    ycc.resize(std::size_t(image.height) * image.width * 3);
    ImageView<float> v(ycc.data(), image.height, image.width, 3);
    ColourTransform(image, kRgbToYcc, v);
    src = AsConst(v);
  }
  // Scratch: lo at levels 0..L-1 (lo at level L is the lowpass output).
  std::vector<std::vector<float>> lo_store(levels);
  std::vector<ImageView<float>> lo(levels + 1);
  for (int l = 0; l < levels; ++l) {
    const int h = SteerableLevelSize(image.height, l), w = SteerableLevelSize(image.width, l);
    lo_store[l].resize(std::size_t(h) * w * c);
    lo[l] = ImageView<float>(lo_store[l].data(), h, w, c);
  }
  lo[levels] = pyr.lowpass;

  // Top: hi = H0 * x, lo0 = L0 * x.
  {
    const int h = image.height, w = image.width;
    const std::ptrdiff_t n = std::ptrdiff_t(w) * c;
    ParallelFor(h, Grain(w, c), [&](std::int64_t y0, std::int64_t y1) {
      Combos cb(w, c);
      for (std::int64_t y = y0; y < y1; ++y) {
        cb.Build(src, static_cast<int>(y), filters.h0.mask | filters.l0.mask);
        float* hi = pyr.highpass.Row(static_cast<int>(y));
        float* l0 = lo[0].Row(static_cast<int>(y));
        std::fill(hi, hi + n, 0.0f);
        std::fill(l0, l0 + n, 0.0f);
        ApplySplit(filters.h0, cb, n, c, hi);
        ApplySplit(filters.l0, cb, n, c, l0);
      }
    });
  }
  // Levels: bands and the decimated L1 from the same vertical combinations.
  for (int l = 0; l < levels; ++l) {
    const ImageView<const float> in = AsConst(lo[l]);
    const ImageView<float> next = lo[l + 1];
    const int h = in.height, w = in.width;
    const std::ptrdiff_t n = std::ptrdiff_t(w) * c;
    unsigned level_mask = 0;
    for (const auto& b : filters.bands) level_mask |= b.mask;
    ParallelFor(h, Grain(w, c), [&](std::int64_t y0, std::int64_t y1) {
      Combos cb(w, c);
      for (std::int64_t yy = y0; yy < y1; ++yy) {
        const int y = static_cast<int>(yy);
        cb.Build(in, y, level_mask | ((y & 1) == 0 ? filters.l1.mask : 0u));
        for (int k = 0; k < k_count; ++k) {
          float* b = pyr.bands[l * k_count + k].Row(y);
          std::fill(b, b + n, 0.0f);
          ApplySplit(filters.bands[k], cb, n, c, b);
        }
        if ((y & 1) == 0) {
          float* out = next.Row(y >> 1);
          std::fill(out, out + std::ptrdiff_t(next.width) * c, 0.0f);
          for (int i = 0; i < 5; ++i) AccumulateRowDecimated(filters.l1.rows[i], cb.Row(i), next.width, c, out);
        }
      }
    });
  }
}

void SteerableSynthesiseKernel(const SteerablePyramidViews<const float>& pyr, bool ycbcr,
                               const ImageView<float>& out) {
  const int c = out.channels, levels = pyr.levels, k_count = pyr.orientations;
  const Filters filters = MakeFilters(k_count);
  // rec[l]: the collapsed low-pass at level l (rec[L] = lowpass).
  std::vector<std::vector<float>> store(levels);
  std::vector<ImageView<const float>> rec(levels + 1);
  rec[levels] = pyr.lowpass;
  for (int l = levels - 1; l >= 0; --l) {
    const int h = SteerableLevelSize(out.height, l), w = SteerableLevelSize(out.width, l);
    store[l].resize(std::size_t(h) * w * c);
    const ImageView<float> dst(store[l].data(), h, w, c);
    const ImageView<const float> coarse = rec[l + 1];
    const std::ptrdiff_t n = std::ptrdiff_t(w) * c;
    ParallelFor(h, Grain(w, c), [&](std::int64_t y0, std::int64_t y1) {
      Combos cb(w, c);
      std::vector<float> t0((coarse.width + 2) * std::size_t(c)), t1(t0.size());
      for (std::int64_t yy = y0; yy < y1; ++yy) {
        const int y = static_cast<int>(yy);
        float* acc = dst.Row(y);
        std::fill(acc, acc + n, 0.0f);
        AccumulateUp(coarse, filters.l1_rows, y, h, w, t0, t1, acc);
        for (int k = 0; k < k_count; ++k) {
          cb.Build(pyr.bands[l * k_count + k], y, filters.bands_flipped[k].mask);
          ApplySplit(filters.bands_flipped[k], cb, n, c, acc);
        }
      }
    });
    rec[l] = AsConst(dst);
  }
  // Top: out = L0 * rec0 + H0 * hi (both D4-symmetric, so flip(f) = f).
  {
    const int h = out.height, w = out.width;
    const std::ptrdiff_t n = std::ptrdiff_t(w) * c;
    ParallelFor(h, Grain(w, c), [&](std::int64_t y0, std::int64_t y1) {
      Combos cb(w, c);
      for (std::int64_t yy = y0; yy < y1; ++yy) {
        const int y = static_cast<int>(yy);
        float* acc = out.Row(y);
        std::fill(acc, acc + n, 0.0f);
        cb.Build(rec[0], y, filters.l0.mask);
        ApplySplit(filters.l0, cb, n, c, acc);
        cb.Build(pyr.highpass, y, filters.h0.mask);
        ApplySplit(filters.h0, cb, n, c, acc);
      }
    });
  }
  if (ycbcr) ColourTransform(AsConst(out), kYccToRgb, out);
}

}  // namespace ibr
