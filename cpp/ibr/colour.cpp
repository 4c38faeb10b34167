// The sRGB curves and their tables (colour.h).
#include "ibr/colour.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include <immintrin.h>  // AVX2: only in target("avx2") functions, called when the CPU has it

#include "ibr/errors.h"
#include "ibr/parallel.h"
#include "ibr/simd.h"

namespace ibr {
namespace {

using colour::Decode;
using colour::Encode;
using colour::EncodePower;
using colour::Select;

// The row loops of the curves, for AVX2 (8 floats a vector instead of SSE2's 4) and the portable
// default, picked at load time (IBR_AVX2_CLONES, cpp/ibr/simd.h: the same bits either way).

}  // namespace

IBR_AVX2_CLONES void SrgbEncodeRun(const float* in, float* o, std::int64_t n) {

  for (std::int64_t i = 0; i < n; ++i) o[i] = Encode(in[i]);
}

namespace {

// o[i] = Encode of in[i] clamped to [0, 1] (NaN -> 0: the comparisons are false), and exactly 1
// at 1 (the polynomial gives 1 - 2^-24 there).
IBR_AVX2_CLONES void EncodeUnitRun(const float* in, float* o, std::int64_t n) {
  for (std::int64_t i = 0; i < n; ++i) {
    const float x = in[i];
    const float v = Select(x > 0.0f, x, 0.0f);
    const bool below = v < 1.0f;
    o[i] = Select(below, Encode(Select(below, v, 1.0f)), 1.0f);
  }
}

// o[i] = the sRGB decoding of in[i] with the linear toe extended below 0 (x / 12.92 for every
// x <= 0.04045) and the power above 1; NaN stays NaN, +-inf stay +-inf.
IBR_AVX2_CLONES void DecodeStdRun(const float* in, float* o, std::int64_t n) {
  for (std::int64_t i = 0; i < n; ++i) {
    const float x = in[i];
    o[i] = Select(x <= 0.04045f, x * (1.0f / 12.92f), Decode(x));
  }
}

}  // namespace

float SrgbEncode(float v) { return Encode(v); }
float SrgbDecode(float e) { return Decode(e); }

namespace {
// run(in + i0, out + i0, count) over n values in parallel chunks.
template <class Run>
void ParallelValues(const float* in, float* out, std::int64_t n, Run run) {
  const std::int64_t chunk = std::int64_t(1) << 16;  // values per task
  ParallelFor((n + chunk - 1) / chunk, 1, [&](std::int64_t c0, std::int64_t c1) {
    const std::int64_t i0 = c0 * chunk, i1 = std::min(n, c1 * chunk);
    run(in + i0, out + i0, i1 - i0);
  });
}
}  // namespace

void LinearToSrgb(const float* in, float* out, std::int64_t n) { ParallelValues(in, out, n, EncodeUnitRun); }

namespace {
// q[i] = e[i] * 255 rounded to nearest, ties to even (nearbyint in the default rounding mode:
// numpy's round), for e in [0, 1]: float32 multiply, as numpy multiplies a float32 array by 255.
IBR_AVX2_CLONES void Quantize8Run(const float* e, std::uint8_t* q, std::int64_t n) {
  for (std::int64_t i = 0; i < n; ++i) q[i] = static_cast<std::uint8_t>(std::nearbyint(e[i] * 255.0f));
}
}  // namespace

void LinearToSrgb8(const float* in, std::uint8_t* out, std::int64_t n) {
  const std::int64_t chunk = std::int64_t(1) << 16;  // values per task
  ParallelFor((n + chunk - 1) / chunk, 1, [&](std::int64_t c0, std::int64_t c1) {
    float encoded[4096];  // one cache-resident run of the curve at a time
    for (std::int64_t i = c0 * chunk, i1 = std::min(n, c1 * chunk); i < i1; i += 4096) {
      const std::int64_t m = std::min<std::int64_t>(4096, i1 - i);
      EncodeUnitRun(in + i, encoded, m);
      Quantize8Run(encoded, out + i, m);
    }
  });
}

namespace {
template <class T>
void LookupCodesT(const T* codes, const float* table, float* out, std::int64_t n) {
  const std::int64_t chunk = std::int64_t(1) << 16;  // values per task
  ParallelFor((n + chunk - 1) / chunk, 1, [&](std::int64_t c0, std::int64_t c1) {
    const std::int64_t i1 = std::min(n, c1 * chunk);
    for (std::int64_t i = c0 * chunk; i < i1; ++i) out[i] = table[codes[i]];
  });
}
}  // namespace

void LookupCodes(const std::uint8_t* codes, const float* table, float* out, std::int64_t n) {
  LookupCodesT(codes, table, out, n);
}
void LookupCodes(const std::uint16_t* codes, const float* table, float* out, std::int64_t n) {
  LookupCodesT(codes, table, out, n);
}

namespace {
// The encode of LinearToSrgbUnclipped (colour.h). The curve per value (Encode) is compute-bound
// (two polynomials: 17.6 ms of one core per 1080p RGB view). Linear colour of LDR images lies in
// [0, 1], so there the curve is read from a table indexed by the float's bits: piecewise linear with
// 2^10 segments per binade (the nodes are the floats whose low 13 mantissa bits are 0) from 2^-9 (the
// toe 0.0031308 lies in [2^-9, 2^-8)) to 1: 9 * 1024 + 1 nodes. The nodes are the curve's own values
// (EncodePower, the power branch of Encode, so the curve exists once; it is used for the nodes just
// below the toe too, so the segment across the toe does not straddle the kink), except at 1: 1
// exactly, the curve's value, where the polynomial gives 1 - 2^-24. The lerp's error h^2 / 8 max|f''|
// = 0.032 2^(0.417 e - 20) in binade [2^e, 2^(e+1)), 2.3e-8 at most (e = -1); with the nodes' own
// error and float rounding, measured 1.8e-7 absolute against the float64 curve in [0, 1] (Encode:
// 1.5e-7; tests/dibr/test_srgb_encode.py). At and below the toe 12.92 x, Encode's operation (the same
// bits); above 1 (HDR), +inf and NaN Encode itself (at least 1: monotonic across 1), so NaN stays
// NaN. Negative values and -inf give +0 (negative light does not exist).
// The table is stored as pairs (node k, node k + 1) at 2 k: the AVX2 loop reads a segment's two
// nodes with one 64-bit gather (two 32-bit gathers per 8 values: 5.7 ms of one core per 1080p view in
// cache, the 64-bit gathers 3.1 ms; eight scalar loads 4.3 ms); 73.7 KB, of which an image touches
// mostly the top binades. The last pair (1, 1) is read times f = 0 at x = 1.
constexpr int kEncodeShift = 23 - 10;            // mantissa bits below the segment index
constexpr std::uint32_t kEncodeLow = 118u << 23;  // 2^-9
constexpr std::uint32_t kOneBits = 0x3f800000u;   // 1.0f
constexpr std::uint32_t kToeBits = 0x3b4d2e1cu;   // 0.0031308f (as Encode)
constexpr int kEncodePairs = int((kOneBits - kEncodeLow) >> kEncodeShift) + 1;
constexpr float kEncodeFrac = 1.0f / float(1u << kEncodeShift);  // exact (power of two)

const float* EncodeTable() {
  static const std::vector<float> pairs = [] {
    std::vector<float> node(kEncodePairs + 1);
    for (int k = 0; k < kEncodePairs; ++k) node[k] = EncodePower(AsFloat(kEncodeLow + (std::uint32_t(k) << kEncodeShift)));
    node[kEncodePairs - 1] = node[kEncodePairs] = 1.0f;  // x = 1, and the pad
    std::vector<float> p(2 * kEncodePairs);
    for (int k = 0; k < kEncodePairs; ++k) {
      p[2 * k] = node[k];
      p[2 * k + 1] = node[k + 1];
    }
    return p;
  }();
  return pairs.data();
}

// One value x <= 1 (not NaN): 0 for negative x (its bits as a negative integer), 12.92 x up to the
// toe, the table's lerp above.
inline float EncodeTableValue(const float* p, float x) {
  const std::int32_t b = static_cast<std::int32_t>(AsBits(x));
  if (b < 0) return 0.0f;
  if (b <= std::int32_t(kToeBits)) return 12.92f * x;
  const std::uint32_t u = std::uint32_t(b) - kEncodeLow;
  const std::uint32_t k = u >> kEncodeShift;
  const float f = float(std::int32_t(u & ((1u << kEncodeShift) - 1))) * kEncodeFrac;  // exact
  const float t0 = p[2 * k];
  return t0 + f * (p[2 * k + 1] - t0);
}

inline bool EncodeOutside(float x) { return !(x <= 1.0f); }  // above 1, +inf, NaN (of either sign)

// v[0, m) -> o[0, m), m <= 8, value by value: the table, Encode (one vectorised call for the block)
// for values outside it (HDR images cost the curve, not a call per value). o may be v.
inline void EncodeBlock(const float* p, const float* v, float* o, int m) {
  bool outside = false;
  for (int k = 0; k < m; ++k) outside |= EncodeOutside(v[k]);
  float c[8] = {};
  if (outside) SrgbEncodeRun(v, c, m);
  // Above 1 at least 1: the polynomial gives 1 - 2^-24 just above 1, below the table's 1 at 1 (NaN
  // stays NaN: the comparison is false).
  for (int k = 0; k < m; ++k) o[k] = EncodeOutside(v[k]) ? (c[k] < 1.0f ? 1.0f : c[k]) : EncodeTableValue(p, v[k]);
}

// Eight values per step, EncodeTableValue lane by lane (no FMA: the same bits as the portable loop);
// a step with a value outside the table is done by EncodeBlock.
__attribute__((target("avx2"))) void EncodeTableRunAvx2(const float* p, const float* in, float* o, std::int64_t n) {
  const __m256 one = _mm256_set1_ps(1.0f), toe_slope = _mm256_set1_ps(12.92f), frac = _mm256_set1_ps(kEncodeFrac);
  const __m256i low = _mm256_set1_epi32(std::int32_t(kEncodeLow)), toe = _mm256_set1_epi32(std::int32_t(kToeBits));
  const __m256i mask = _mm256_set1_epi32(std::int32_t((1u << kEncodeShift) - 1)), zero = _mm256_setzero_si256();
  const __m256i order = _mm256_setr_epi32(0, 1, 4, 5, 2, 3, 6, 7);
  const long long* pairs = reinterpret_cast<const long long*>(p);
  std::int64_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const __m256 x = _mm256_loadu_ps(in + i);
    if (_mm256_movemask_ps(_mm256_cmp_ps(x, one, _CMP_NLE_UQ)) != 0) {  // above 1 or NaN
      EncodeBlock(p, in + i, o + i, 8);
      continue;
    }
    const __m256i b = _mm256_castps_si256(x);
    const __m256i u = _mm256_sub_epi32(_mm256_max_epi32(b, low), low);  // an index in the table for every lane
    const __m256i k = _mm256_srli_epi32(u, kEncodeShift);
    const __m256 f = _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_and_si256(u, mask)), frac);
    // The pairs of lanes 0 1 4 5 in a, of lanes 2 3 6 7 in c: the in-lane shuffles then give t0 and
    // t1 in lane order.
    const __m256i kk = _mm256_permutevar8x32_epi32(k, order);
    const __m256 a = _mm256_castsi256_ps(_mm256_i32gather_epi64(pairs, _mm256_castsi256_si128(kk), 8));
    const __m256 c = _mm256_castsi256_ps(_mm256_i32gather_epi64(pairs, _mm256_extracti128_si256(kk, 1), 8));
    const __m256 t0 = _mm256_shuffle_ps(a, c, 0x88), t1 = _mm256_shuffle_ps(a, c, 0xdd);
    const __m256 lerp = _mm256_add_ps(t0, _mm256_mul_ps(f, _mm256_sub_ps(t1, t0)));
    const __m256 lin = _mm256_mul_ps(x, toe_slope);
    __m256 r = _mm256_blendv_ps(lin, lerp, _mm256_castsi256_ps(_mm256_cmpgt_epi32(b, toe)));
    r = _mm256_andnot_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(zero, b)), r);  // negative -> +0
    _mm256_storeu_ps(o + i, r);
  }
  if (i < n) EncodeBlock(p, in + i, o + i, int(n - i));
}

void EncodeTableRun(const float* p, const float* in, float* o, std::int64_t n, bool avx2) {
  if (avx2) {
    EncodeTableRunAvx2(p, in, o, n);
    return;
  }
  for (std::int64_t i = 0; i < n; i += 8) EncodeBlock(p, in + i, o + i, int(std::min<std::int64_t>(8, n - i)));
}
}  // namespace

void LinearToSrgbUnclipped(const float* in, float* out, std::int64_t n, bool avx2) {
  const float* p = EncodeTable();
  ParallelValues(in, out, n, [&](const float* i, float* o, std::int64_t m) { EncodeTableRun(p, i, o, m, avx2); });
}
void SrgbToLinear(const float* in, float* out, std::int64_t n) { ParallelValues(in, out, n, DecodeStdRun); }

namespace {

// One row of a chroma plane upsampled vertically to output row `row` (numpy's first axis pass).
template <class T>
void ChromaRowUp(const T* c, int ch, int cw, int row, float* t) {
  const int i = row / 2, j = (row % 2 == 0) ? std::max(i - 1, 0) : std::min(i + 1, ch - 1);
  const T* a = c + std::ptrdiff_t(i) * cw;
  const T* b = c + std::ptrdiff_t(j) * cw;
  for (int x = 0; x < cw; ++x) t[x] = 0.75f * static_cast<float>(a[x]) + 0.25f * static_cast<float>(b[x]);
}

// The horizontal pass at output column x of a vertically upsampled row t (cw values).
inline float ChromaColUp(const float* t, int cw, int x) {
  const int i = x / 2, j = (x % 2 == 0) ? std::max(i - 1, 0) : std::min(i + 1, cw - 1);
  return 0.75f * t[i] + 0.25f * t[j];
}

}  // namespace

void YuvCheckArgs(int bits, double kr, double kb, int min_bits) {
  if (bits < min_bits || bits > 16) {
    throw BadValueError("bits: expected " + std::to_string(min_bits) + "..16, got " + std::to_string(bits));
  }
  if (!(std::isfinite(kr) && std::isfinite(kb) && kr > 0 && kb > 0 && kr + kb < 1)) {
    throw BadValueError("kr, kb: expected a Y'CbCr matrix's weights (positive, kr + kb < 1)");
  }
}

template <class T>
void YuvToLinearRgb(const T* y, const T* cb, const T* cr, int h, int w, int bits, double kr, double kb,
                    bool full_range, float* out) {
  const int ch = (h + 1) / 2, cw = (w + 1) / 2;
  const double scale = bits >= 8 ? double(1 << (bits - 8)) : 1.0 / double(1 << (8 - bits));
  const double vmax = double((1 << bits) - 1), mid = double(1 << (bits - 1));
  // The numpy definition's constants: Python floats, rounded to float32 where they meet the arrays.
  const float y_off = full_range ? 0.0f : static_cast<float>(16 * scale);
  const float y_div = full_range ? static_cast<float>(vmax) : static_cast<float>(219 * scale);
  const float c_off = full_range ? static_cast<float>(mid) : static_cast<float>(128 * scale);
  const float c_div = full_range ? static_cast<float>(vmax) : static_cast<float>(224 * scale);
  const float k_r = static_cast<float>(2 * (1 - kr)), k_b = static_cast<float>(2 * (1 - kb));
  const float f_kr = static_cast<float>(kr), f_kb = static_cast<float>(kb), f_kg = static_cast<float>(1 - kr - kb);
  const bool chroma = cb != nullptr && cr != nullptr;
  ParallelFor(h, 8, [&](std::int64_t r0, std::int64_t r1) {
    std::vector<float> tb(chroma ? cw : 0), tr(chroma ? cw : 0);
    for (int r = static_cast<int>(r0); r < static_cast<int>(r1); ++r) {
      if (chroma) {
        ChromaRowUp(cb, ch, cw, r, tb.data());
        ChromaRowUp(cr, ch, cw, r, tr.data());
      }
      const T* yr = y + std::ptrdiff_t(r) * w;
      float* o = out + std::ptrdiff_t(r) * w * 3;
      for (int x = 0; x < w; ++x) {
        const float yv = static_cast<float>(yr[x]);
        // full range: y / vmax (no offset: the subtraction of 0 is skipped, as numpy does not do it)
        const float yn = full_range ? yv / y_div : (yv - y_off) / y_div;
        float cbn = 0.0f, crn = 0.0f;
        if (chroma) {
          cbn = (ChromaColUp(tb.data(), cw, x) - c_off) / c_div;
          crn = (ChromaColUp(tr.data(), cw, x) - c_off) / c_div;
        }
        const float rv = yn + k_r * crn;
        const float bv = yn + k_b * cbn;
        const float gv = (yn - f_kr * rv - f_kb * bv) / f_kg;
        o[3 * x + 0] = std::min(std::max(rv, 0.0f), 1.0f);
        o[3 * x + 1] = std::min(std::max(gv, 0.0f), 1.0f);
        o[3 * x + 2] = std::min(std::max(bv, 0.0f), 1.0f);
      }
      DecodeStdRun(o, o, std::int64_t(w) * 3);
    }
  });
}

template <class T>
void LinearRgbToYuv(const float* rgb, int h, int w, int bits, double kr, double kb, bool full_range, T* y, T* cb,
                    T* cr) {
  const int ch = (h + 1) / 2, cw = (w + 1) / 2;
  const double kg = 1 - kr - kb, db = 2 * (1 - kb), dr = 2 * (1 - kr);
  const double vmax = double((1 << bits) - 1), scale = double(1 << (bits - 8)), mid = double(1 << (bits - 1));
  const double y_off = 16 * scale, y_mul = 219 * scale, c_off = 128 * scale, c_mul = 224 * scale;
  auto code = [&](double v) {  // np.clip(np.rint(v), 0, vmax).astype(T)
    return static_cast<T>(std::min(std::max(std::nearbyint(v), 0.0), vmax));
  };
  ParallelFor(ch, 4, [&](std::int64_t i0, std::int64_t i1) {
    std::vector<float> enc(std::size_t(2) * w * 3);
    std::vector<double> ys(std::size_t(2) * w), cbs(std::size_t(2) * w), crs(std::size_t(2) * w);
    for (int i = static_cast<int>(i0); i < static_cast<int>(i1); ++i) {
      const int rows[2] = {2 * i, std::min(2 * i + 1, h - 1)};
      for (int k = 0; k < 2; ++k) {
        float* e = enc.data() + std::size_t(k) * w * 3;
        EncodeUnitRun(rgb + std::ptrdiff_t(rows[k]) * w * 3, e, std::int64_t(w) * 3);
        for (int x = 0; x < w; ++x) {
          const double r = e[3 * x], g = e[3 * x + 1], b = e[3 * x + 2];
          const double yv = kr * r + kg * g + kb * b;
          ys[std::size_t(k) * w + x] = yv;
          cbs[std::size_t(k) * w + x] = (b - yv) / db;
          crs[std::size_t(k) * w + x] = (r - yv) / dr;
        }
      }
      for (int k = 0; k < 2; ++k) {
        if (k == 1 && 2 * i + 1 >= h) break;
        T* yrow = y + std::ptrdiff_t(rows[k]) * w;
        for (int x = 0; x < w; ++x) {
          const double v = ys[std::size_t(k) * w + x];
          yrow[x] = code(full_range ? v * vmax : y_off + y_mul * v);
        }
      }
      T* cbrow = cb + std::ptrdiff_t(i) * cw;
      T* crrow = cr + std::ptrdiff_t(i) * cw;
      for (int j = 0; j < cw; ++j) {
        const int x0 = 2 * j, x1 = std::min(2 * j + 1, w - 1);
        // 0.25 * (c[0::2, 0::2] + c[1::2, 0::2] + c[0::2, 1::2] + c[1::2, 1::2]), in that order
        const double mb = 0.25 * (cbs[x0] + cbs[std::size_t(w) + x0] + cbs[x1] + cbs[std::size_t(w) + x1]);
        const double mr = 0.25 * (crs[x0] + crs[std::size_t(w) + x0] + crs[x1] + crs[std::size_t(w) + x1]);
        cbrow[j] = code(full_range ? mid + mb * vmax : c_off + c_mul * mb);
        crrow[j] = code(full_range ? mid + mr * vmax : c_off + c_mul * mr);
      }
    }
  });
}

template void LinearRgbToYuv<std::uint8_t>(const float*, int, int, int, double, double, bool, std::uint8_t*,
                                            std::uint8_t*, std::uint8_t*);
template void LinearRgbToYuv<std::uint16_t>(const float*, int, int, int, double, double, bool, std::uint16_t*,
                                             std::uint16_t*, std::uint16_t*);

template void YuvToLinearRgb<std::uint8_t>(const std::uint8_t*, const std::uint8_t*, const std::uint8_t*, int, int,
                                            int, double, double, bool, float*);
template void YuvToLinearRgb<std::uint16_t>(const std::uint16_t*, const std::uint16_t*, const std::uint16_t*, int,
                                             int, int, double, double, bool, float*);

namespace {
// SrgbToLinearTableRun (colour.h), the decoding of DIBR's resolve (blend.h BlendSpace::kSrgb). The curve
// is SrgbToLinear's; evaluated per value it is compute-bound (two polynomials, ~85 AVX2 instructions
// per 8 values): the resolve of 1080p went from 3.4 to 14.6 ms of one core, +7 % of the job's CPU,
// fused into the resolve or not (benchmarks/dibr_ab.py --srgb-b; docs/dibr.md "Blend space").
// Blended encodings of LDR colour lie in [0, 1], so there the resolve reads the curve from a table
// of its values at the kSrgbSteps + 2 nodes i / kSrgbSteps (made once by DecodeStdRun: the
// curve exists once) and interpolates linearly: two gathers and six operations per 8 values, the
// resolve 3.4 -> 8.1 ms. Within 1e-6 (absolute) of SrgbToLinear (measured 2.4e-7: the lerp's error
// h^2 / 8 max|f''| = 2.5e-8, ~1e-7 at the toe's joint, and the polynomial curve's own wiggle between
// the nodes), 1000x below the smallest 8-bit step (3e-4 linear, at the darkest codes); exact at the
// nodes, so 0 (holes) stays exactly 0. Values outside [0, 1] (HDR encodings above 1, negative colour) take
// the curve itself. The AVX2 loop is the scalar loop's operations lane by lane (no FMA): the same bits.
constexpr int kSrgbSteps = 4096;

const float* SrgbTable() {
  static const std::vector<float> table = [] {
    std::vector<float> x(kSrgbSteps + 2), t(kSrgbSteps + 2);
    for (int i = 0; i < kSrgbSteps + 2; ++i) x[i] = float(i) / float(kSrgbSteps);  // exact (power of two)
    DecodeStdRun(x.data(), t.data(), std::int64_t(t.size()));
    return t;
  }();
  return table.data();
}

inline bool InTable(float e) { return e >= 0.f && e <= 1.f; }  // false for NaN

// The table's value at e in [0, 1].
inline float Lerp(const float* table, float e) {
  const float s = e * float(kSrgbSteps);  // exact (power of two)
  const int k = int(s);                   // floor (s >= 0); k <= kSrgbSteps
  const float f = s - float(k);           // exact
  const float t0 = table[k];
  return t0 + f * (table[k + 1] - t0);
}

// v[0, m), m <= 8, in place, value by value: the table in [0, 1], the curve elsewhere (one call of
// the curve for the block when it has such values: HDR images cost the curve, not a call per value).
inline void SrgbDecodeBlock(const float* table, float* v, int m) {
  bool outside = false;
  for (int k = 0; k < m; ++k) outside |= !InTable(v[k]);
  float c[8];
  if (outside) DecodeStdRun(v, c, m);
  for (int k = 0; k < m; ++k) v[k] = InTable(v[k]) ? Lerp(table, v[k]) : c[k];
}

// Eight values per step: Lerp lane by lane (the gathers read table[k], table[k + 1]); a step with
// a value outside the table is done by SrgbDecodeBlock.
__attribute__((target("avx2"))) void SrgbDecodeRowAvx2(const float* table, float* v, std::ptrdiff_t n) {
  const __m256 scale = _mm256_set1_ps(float(kSrgbSteps)), zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.f);
  std::ptrdiff_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const __m256 e = _mm256_loadu_ps(v + i);
    const __m256 in = _mm256_and_ps(_mm256_cmp_ps(e, zero, _CMP_GE_OQ), _mm256_cmp_ps(e, one, _CMP_LE_OQ));
    if (_mm256_movemask_ps(in) != 0xff) {
      SrgbDecodeBlock(table, v + i, 8);
      continue;
    }
    const __m256 s = _mm256_mul_ps(e, scale);
    const __m256i k = _mm256_cvttps_epi32(s);
    const __m256 f = _mm256_sub_ps(s, _mm256_cvtepi32_ps(k));
    const __m256 t0 = _mm256_i32gather_ps(table, k, 4), t1 = _mm256_i32gather_ps(table + 1, k, 4);
    _mm256_storeu_ps(v + i, _mm256_add_ps(t0, _mm256_mul_ps(f, _mm256_sub_ps(t1, t0))));
  }
  if (i < n) SrgbDecodeBlock(table, v + i, int(n - i));
}

}  // namespace

void SrgbToLinearTableRun(float* v, std::int64_t n, bool avx2) {
  const float* table = SrgbTable();
  if (avx2) {
    SrgbDecodeRowAvx2(table, v, n);
    return;
  }
  for (std::int64_t i = 0; i < n; i += 8) SrgbDecodeBlock(table, v + i, int(std::min<std::int64_t>(8, n - i)));
}

const float* Srgb8ToLinearTable() {
  static const std::vector<float> table = [] {
    std::vector<float> code(256), t(256);
    for (int c = 0; c < 256; ++c) code[c] = float(c) / 255.0f;
    DecodeStdRun(code.data(), t.data(), 256);
    return t;
  }();
  return table.data();
}

}  // namespace ibr
