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

// log2(x) for finite x > 0 (normal or subnormal): x = m 2^e with m in [sqrt(1/2), sqrt(2)),
// log2(m) = 2/ln 2 atanh(t), t = (m - 1) / (m + 1), |t| <= 0.1716: the series to t^9 (next term
// < 3e-9 of the result's scale).
inline float Log2Pos(float x) {
  std::uint32_t bits;
  std::memcpy(&bits, &x, 4);
  int e = static_cast<int>((bits >> 23) & 0xff);
  if (e == 0) {  // subnormal: scale up by 2^32 first
    x *= 4294967296.0f;
    std::memcpy(&bits, &x, 4);
    e = static_cast<int>((bits >> 23) & 0xff) - 32;
  }
  e -= 127;
  bits = (bits & 0x007fffffu) | 0x3f800000u;  // m in [1, 2)
  float m;
  std::memcpy(&m, &bits, 4);
  if (m > 1.41421356f) {
    m *= 0.5f;
    ++e;
  }
  const float t = (m - 1.0f) / (m + 1.0f), t2 = t * t;
  const float p = t * (2.0f + t2 * (2.0f / 3 + t2 * (2.0f / 5 + t2 * (2.0f / 7 + t2 * (2.0f / 9)))));
  return static_cast<float>(e) + p * 1.44269504f;  // 1 / ln 2
}

// 2^y for finite y: 2^n 2^f, n = round(y), f in [-1/2, 1/2], 2^f by its Taylor series to f^7
// (remainder < 2e-9); n clamped so that the result over/underflows to inf / 0 as it should.
inline float Exp2(float y) {
  if (y >= 128.0f) return std::numeric_limits<float>::infinity();
  if (y < -150.0f) return 0.0f;
  const float n = std::nearbyint(y), f = (y - n) * 0.693147181f;  // f ln 2
  const float p = 1.0f + f * (1.0f + f * (0.5f + f * (1.0f / 6 + f * (1.0f / 24 + f * (1.0f / 120 +
                  f * (1.0f / 720 + f * (1.0f / 5040)))))));
  int ni = static_cast<int>(n);
  // 2^ni as two factors so that subnormal results (ni < -126) are formed by the multiplication.
  const int n1 = ni / 2, n2 = ni - n1;
  auto pow2 = [](int k) {
    const std::uint32_t b = static_cast<std::uint32_t>(k + 127) << 23;
    float v;
    std::memcpy(&v, &b, 4);
    return v;
  };
  return p * pow2(n1) * pow2(n2);
}

}  // namespace

float SrgbEncode(float v) {
  const float a = std::fabs(v);
  if (!(a > 0.0031308f)) return 12.92f * v;  // also NaN
  if (a == std::numeric_limits<float>::infinity()) return v;
  const float e = 1.055f * Exp2(Log2Pos(a) * (1.0f / 2.4f)) - 0.055f;
  return v < 0.0f ? -e : e;
}

float SrgbDecode(float e) {
  const float a = std::fabs(e);
  if (!(a > 0.04045f)) return e * (1.0f / 12.92f);  // also NaN
  if (a == std::numeric_limits<float>::infinity()) return e;
  const float v = Exp2(Log2Pos((a + 0.055f) * (1.0f / 1.055f)) * 2.4f);
  return e < 0.0f ? -v : v;
}

void MetamericEncode(const ImageView<const float>& image, const ImageView<float>& out) {
  const std::int64_t n = std::int64_t(image.width) * image.channels;
  ParallelFor(image.height, RowGrain(image.width), [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const float* in = image.Row(y);
      float* o = out.Row(y);
      for (std::int64_t i = 0; i < n; ++i) o[i] = SrgbEncode(in[i]);
    }
  });
}

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
      if (o != in) std::memcpy(o, in, sizeof(float) * std::size_t(w) * c);
      for (int x = 0; x < w; ++x) {
        if (!m[x]) continue;
        for (int ch = 0; ch < c; ++ch) {
          const std::ptrdiff_t i = std::ptrdiff_t(x) * c + ch;
          const float v = b[i] + d[i];
          o[i] = decode ? std::max(0.0f, SrgbDecode(v)) : v;
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
