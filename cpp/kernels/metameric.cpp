// Equations and shapes: metameric.h.
#include "kernels/metameric.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#include "ibr/parallel.h"

namespace ibr {
namespace {

std::int64_t RowGrain(int width) { return std::max<std::int64_t>(1, kMinPixelsPerTask / std::max(1, width)); }

// rint(v) mod n in [0, n), v finite (numpy: np.rint(v).astype(int64) % n).
int WrapIndex(double v, int n) {
  double r = std::nearbyint(v);
  r = std::fmod(r, static_cast<double>(n));  // exact
  if (r < 0) r += n;
  return static_cast<int>(r);
}

template <typename F>
void Positions(const F* flow, int flow_w, int y, int x, int scale, int h, int w, int* yy, int* xx) {
  const F* f = flow + (static_cast<std::ptrdiff_t>(y) * scale * flow_w + static_cast<std::ptrdiff_t>(x) * scale) * 2;
  // dx / scale: scale is a power of two in practice; double division of the (exactly promoted)
  // flow equals numpy's float32 division then promotion whenever that one is exact.
  *yy = WrapIndex(static_cast<double>(y) + static_cast<double>(f[1]) / scale, h);
  *xx = WrapIndex(static_cast<double>(x) + static_cast<double>(f[0]) / scale, w);
}

inline float AsFloat(std::uint32_t b) {
  float v;
  std::memcpy(&v, &b, 4);
  return v;
}
inline std::uint32_t AsBits(float v) {
  std::uint32_t b;
  std::memcpy(&b, &v, 4);
  return b;
}
// c ? a : b on the bits. Every select and comparison of the display curve is done on integers:
// under GCC's default -ftrapping-math a float comparison blocks if-conversion, and the row loops
// would not be vectorised (measured 3.5x slower).
inline float Select(bool c, float a, float b) {
  const std::uint32_t m = 0u - static_cast<std::uint32_t>(c);
  return AsFloat((AsBits(a) & m) | (AsBits(b) & ~m));
}

// log2(x) for a positive normal float (finite garbage for 0, subnormals, inf and NaN, which the
// callers select away): x = m 2^e with m in [sqrt(1/2), sqrt(2)), log2(m) = u q(u), u = m - 1,
// q of degree 8 fitted (Chebyshev, least squares) on that range: absolute error 3.5e-8, below
// float32's rounding of the result.
inline float Log2Pos(float x) {
  const std::uint32_t bits = AsBits(x);
  const std::uint32_t mant = bits & 0x007fffffu;
  const bool big = mant > 0x003504f3u;  // m > sqrt(2): take m / 2 and e + 1
  const int e = static_cast<int>((bits >> 23) & 0xffu) - 127 + (big ? 1 : 0);
  const float u = AsFloat(mant | (big ? 0x3f000000u : 0x3f800000u)) - 1.0f;
  const float q = 1.44269501f + u * (-0.72134744f + u * (0.480907938f + u * (-0.36069331f + u * (0.288005203f +
                  u * (-0.239245699f + u * (0.215087393f + u * (-0.204805449f + u * 0.124539019f)))))));
  return static_cast<float>(e) + u * q;
}

// 2^y for |y| < 2^22: 2^n 2^f, n = round(y) (by adding 1.5 * 2^23), f in [-1/2, 1/2], 2^f by its
// Taylor series to f^7 (remainder < 2e-9). n is clamped to [-126, 128] on integers: n = 128 is the
// bit pattern of +inf (overflow); results below 2^-126 are not needed here.
inline float Exp2(float y) {
  constexpr float kMagic = 12582912.0f;
  const float r = y + kMagic;
  const float n_f = r - kMagic;
  int n = static_cast<int>(AsBits(r) & 0x007fffffu) - 0x00400000;
  n = n < -126 ? -126 : n;
  n = n > 128 ? 128 : n;
  const float f = (y - n_f) * 0.693147181f;  // f ln 2, |.| <= 0.347
  const float p = 1.0f + f * (1.0f + f * (0.5f + f * (1.0f / 6 + f * (1.0f / 24 + f * (1.0f / 120 +
                  f * (1.0f / 720 + f * (1.0f / 5040)))))));
  return p * AsFloat(static_cast<std::uint32_t>(n + 127) << 23);
}

// The curves (metameric.h). Internal and inline: the exported SrgbEncode / SrgbDecode may be
// interposed in a shared library (-fPIC), so GCC would not inline them into the row loops.
inline float Encode(float v) {
  const std::uint32_t bits = AsBits(v), abits = bits & 0x7fffffffu;
  const float a = AsFloat(abits);
  const float pw = 1.055f * Exp2(Log2Pos(a) * (1.0f / 2.4f)) - 0.055f;
  float r = Select(abits <= 0x3b4d2e1cu /* 0.0031308f */, 12.92f * a, pw);
  r = Select(abits >= 0x7f800000u, a, r);  // inf and NaN pass through
  return AsFloat(AsBits(r) | (bits & 0x80000000u));
}

inline float Decode(float e) {
  const std::uint32_t bits = AsBits(e), abits = bits & 0x7fffffffu;
  const float a = AsFloat(abits);
  const float pw = Exp2(Log2Pos((a + 0.055f) * (1.0f / 1.055f)) * 2.4f);
  float r = Select(abits <= 0x3d25aee6u /* 0.04045f */, a * (1.0f / 12.92f), pw);
  r = Select(abits >= 0x7f800000u, a, r);
  return AsFloat(AsBits(r) | (bits & 0x80000000u));
}

// The row loops of the curves, compiled twice (GCC function multi-versioning, picked once at load
// time by the CPU): for AVX2 (8 floats a vector instead of SSE2's 4) and the portable default.
// No FMA in the AVX2 version, so no contraction: the same IEEE operations, the same bits.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define IBR_AVX2_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define IBR_AVX2_CLONES
#endif

IBR_AVX2_CLONES void EncodeRun(const float* in, float* o, std::int64_t n) {
  for (std::int64_t i = 0; i < n; ++i) o[i] = Encode(in[i]);
}

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

// o[i] = max(0, Decode(b[i] + d[i])) (o may be d).
IBR_AVX2_CLONES void DecodeSumRun(const float* b, const float* d, float* o, std::ptrdiff_t n) {
  for (std::ptrdiff_t i = 0; i < n; ++i) o[i] = std::max(0.0f, Decode(b[i] + d[i]));
}

}  // namespace

float SrgbEncode(float v) { return Encode(v); }
float SrgbDecode(float e) { return Decode(e); }

void MetamericEncode(const ImageView<const float>& image, const ImageView<float>& out) {
  const std::int64_t n = std::int64_t(image.width) * image.channels;
  ParallelFor(image.height, RowGrain(image.width), [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const float* in = image.Row(y);
      float* o = out.Row(y);
      EncodeRun(in, o, n);
    }
  });
}

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
void SrgbToLinear(const float* in, float* out, std::int64_t n) { ParallelValues(in, out, n, DecodeStdRun); }
void SrgbToLinearRun(const float* in, float* out, std::int64_t n) { DecodeStdRun(in, out, n); }

void MetamericFillHoles(const ImageView<const float>& image, const ImageView<const std::uint8_t>& hole,
                        const ImageView<const float>& base, const ImageView<const float>& change, bool decode,
                        const ImageView<float>& out) {
  const int c = image.channels, w = image.width;
  ParallelFor(image.height, RowGrain(w), [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const float* in = image.Row(y);
      const std::uint8_t* m = hole.Row(y);
      const float* b = base.Row(y);
      const float* d = change.Row(y);
      float* o = out.Row(y);
      if (o == d) {
        // out is change's memory: each value is read before it is written. By runs of the row:
        // a run of hole pixels is decoded in place (a vectorisable loop), a run of other pixels
        // is one memcpy from image (the same values as pixel by pixel, without a branch each).
        for (int x = 0; x < w;) {
          int e = x;
          const bool in_hole = m[x] != 0;
          while (e < w && (m[e] != 0) == in_hole) ++e;
          const std::ptrdiff_t i0 = std::ptrdiff_t(x) * c, i1 = std::ptrdiff_t(e) * c;
          if (in_hole) {
            if (decode) {
              DecodeSumRun(b + i0, d + i0, o + i0, i1 - i0);
            } else {
              for (std::ptrdiff_t i = i0; i < i1; ++i) o[i] = b[i] + d[i];
            }
          } else {
            std::memcpy(o + i0, in + i0, sizeof(float) * std::size_t(i1 - i0));
          }
          x = e;
        }
        continue;
      }
      if (o != in) std::memcpy(o, in, sizeof(float) * std::size_t(w) * c);
      for (int x = 0; x < w; ++x) {
        if (!m[x]) continue;
        for (int ch = 0; ch < c; ++ch) {
          const std::ptrdiff_t i = std::ptrdiff_t(x) * c + ch;
          const float v = b[i] + d[i];
          o[i] = decode ? std::max(0.0f, Decode(v)) : v;
        }
      }
    }
  });
}

void MetamericStackMoments(const ImageView<const float>* bands, int k, const ImageView<float>& out) {
  ParallelFor(out.height, RowGrain(out.width), [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) StackMomentsRow(bands, k, y, out.Row(y));
  });
}

void MetamericZeroRow(const MetamericSynth& synth, int y) {
  for (int i = 0; i < synth.k; ++i) {
    const ImageView<float>& b = synth.bands[i];
    std::fill_n(b.Row(y), std::size_t(b.width) * b.channels, 0.0f);
  }
}

void MetamericFlowPosition(const MetamericSynth& synth, int y, int x, int* yy, int* xx) {
  const MetamericFlow& flow = synth.flow;
  const int h = synth.bands[0].height, w = synth.bands[0].width;
  if (flow.f32) Positions(flow.f32, flow.width, y, x, synth.scale, h, w, yy, xx);
  if (flow.f64) Positions(flow.f64, flow.width, y, x, synth.scale, h, w, yy, xx);
}

void MetamericComposite(const ImageView<const float>& moments, const ImageView<const std::uint8_t>& mask,
                        const ImageView<const float>* noise, const ImageView<float>* bands, int k,
                        const MetamericFlow& flow, int scale, bool delta) {
  const int c = bands[0].channels, h = mask.height, w = mask.width, kc = k * c;
  ParallelFor(h, RowGrain(w), [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const std::uint8_t* m = mask.Row(y);
      const float* mom = moments.Row(y);
      for (int x = 0; x < w; ++x) {
        if (!m[x]) {
          if (delta) {
            for (int i = 0; i < k; ++i) std::fill_n(&bands[i].At(y, x), c, 0.0f);
          }
          continue;
        }
        int yy = y, xx = x;
        if (flow.f32) Positions(flow.f32, flow.width, y, x, scale, h, w, &yy, &xx);
        if (flow.f64) Positions(flow.f64, flow.width, y, x, scale, h, w, &yy, &xx);
        const float* mx = mom + std::ptrdiff_t(x) * moments.channels;
        for (int i = 0; i < k; ++i) {
          const float* n = &noise[i].At(yy, xx);
          float* b = &bands[i].At(y, x);
          for (int ch = 0; ch < c; ++ch) {
            const float mean = mx[i * c + ch];
            const float sq = mx[kc + i * c + ch];
            const float mm = mean * mean;  // rounded as numpy's mean * mean
            const float d = sq - mm;
            const float sigma = d > 0.0f ? std::sqrt(d) : 0.0f;
            const float s = sigma * n[ch];
            b[ch] = delta ? s : mean + s;
          }
        }
      }
    }
  });
}

}  // namespace ibr
