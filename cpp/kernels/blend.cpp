#include "kernels/blend.h"

#include <cmath>
#include <cstddef>
#include <limits>

#include "ibr/parallel.h"

namespace ibr {
namespace {
constexpr std::int64_t kRowsPerTask = 16;
}

void ClearBlend(const BlendBuffers& acc) {
  const std::ptrdiff_t w = acc.width;
  ParallelFor(acc.height, kRowsPerTask, [&](std::int64_t y0, std::int64_t y1) {
    for (std::int64_t i = y0 * w; i < y1 * w; ++i) {
      acc.sum_wc[3 * i] = acc.sum_wc[3 * i + 1] = acc.sum_wc[3 * i + 2] = 0.f;
      acc.sum_w[i] = acc.sum_w_invd[i] = acc.sum_q[i] = 0.f;
    }
  });
}

void AccumulateRows(const float* color, const float* depth, const float* weight, const float* quality,
                    const BlendBuffers& acc, int y0, int y1) {
  const std::ptrdiff_t w = acc.width;
  for (std::ptrdiff_t i = y0 * w; i < std::ptrdiff_t(y1) * w; ++i) {
    const float wi = weight[i];
    if (!(wi > 0.f)) continue;
    acc.sum_wc[3 * i] += wi * color[3 * i];
    acc.sum_wc[3 * i + 1] += wi * color[3 * i + 1];
    acc.sum_wc[3 * i + 2] += wi * color[3 * i + 2];
    acc.sum_w[i] += wi;
    acc.sum_w_invd[i] += wi / depth[i];  // depth > 0 where covered; +inf gives 0
    acc.sum_q[i] += quality[i];
  }
}

void ResolveBlend(const BlendBuffers& acc, float* color, float* depth, float* confidence, std::uint8_t* hole) {
  const std::ptrdiff_t w = acc.width;
  ParallelFor(acc.height, kRowsPerTask, [&](std::int64_t y0, std::int64_t y1) {
    for (std::int64_t i = y0 * w; i < y1 * w; ++i) {
      const float sw = acc.sum_w[i];
      if (sw > 0.f) {
        const float inv = 1.f / sw;
        color[3 * i] = acc.sum_wc[3 * i] * inv;
        color[3 * i + 1] = acc.sum_wc[3 * i + 1] * inv;
        color[3 * i + 2] = acc.sum_wc[3 * i + 2] * inv;
        const float s = acc.sum_w_invd[i];
        depth[i] = s > 0.f ? sw / s : std::numeric_limits<float>::infinity();
        confidence[i] = acc.sum_q[i];
        hole[i] = 0;
      } else {
        color[3 * i] = color[3 * i + 1] = color[3 * i + 2] = 0.f;
        depth[i] = 0.f;
        confidence[i] = 0.f;
        hole[i] = 1;
      }
    }
  });
}

}  // namespace ibr
