// Equations and shapes: metameric.h.
#include "kernels/inpaint/metameric.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

#include <immintrin.h>  // AVX2: only in target("avx2") functions, called when the CPU has it

#include "ibr/colour.h"
#include "ibr/parallel.h"
#include "ibr/simd.h"

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

using colour::Decode;

// o[i] = max(0, Decode(b[i] + d[i])) (o may be d).
IBR_AVX2_CLONES void DecodeSumRun(const float* b, const float* d, float* o, std::ptrdiff_t n) {
  for (std::ptrdiff_t i = 0; i < n; ++i) o[i] = std::max(0.0f, Decode(b[i] + d[i]));
}

}  // namespace

void MetamericEncode(const ImageView<const float>& image, const ImageView<float>& out) {
  const std::int64_t n = std::int64_t(image.width) * image.channels;
  ParallelFor(image.height, RowGrain(image.width), [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const float* in = image.Row(y);
      float* o = out.Row(y);
      SrgbEncodeRun(in, o, n);
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
