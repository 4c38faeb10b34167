// Equations and shapes: metameric.h.
#include "kernels/metameric.h"

#include <algorithm>
#include <cmath>

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

}  // namespace

void MetamericStackMoments(const ImageView<const float>* bands, int k, const ImageView<float>& out) {
  ParallelFor(out.height, RowGrain(out.width), [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) StackMomentsRow(bands, k, y, out.Row(y));
  });
}

void MetamericComposite(const ImageView<const float>& moments, const ImageView<const std::uint8_t>& mask,
                        const ImageView<const float>* noise, const ImageView<float>* bands, int k,
                        const MetamericFlow& flow, int scale) {
  const int c = bands[0].channels, h = mask.height, w = mask.width, kc = k * c;
  ParallelFor(h, RowGrain(w), [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const std::uint8_t* m = mask.Row(y);
      const float* mom = moments.Row(y);
      for (int x = 0; x < w; ++x) {
        if (!m[x]) continue;
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
            b[ch] = mean + s;
          }
        }
      }
    }
  });
}

}  // namespace ibr
