// Y-maps / N-buffers for conservative max-depth queries: see nbuffer.h.
#include "kernels/depthwarp/nbuffer.h"

#include <algorithm>
#include <limits>

#include "ibr/parallel.h"

namespace ibr {
namespace {
std::int64_t RowGrain(int width) { return std::max<std::int64_t>(1, kMinPixelsPerTask / std::max(1, width)); }
}  // namespace

void MaxMipDown(const ImageView<const float>& in, const ImageView<float>& out) {
  ParallelFor(out.height, RowGrain(2 * out.width), [&](std::int64_t r0, std::int64_t r1) {
    for (int j = int(r0); j < int(r1); ++j) {
      const float* a = in.Row(2 * j);
      const float* b = in.Row(std::min(2 * j + 1, in.height - 1));  // clipped: the row itself again
      float* o = out.Row(j);
      for (int i = 0; i < out.width; ++i) {
        const int x0 = 2 * i, x1 = std::min(2 * i + 1, in.width - 1);
        o[i] = std::max(std::max(a[x0], a[x1]), std::max(b[x0], b[x1]));
      }
    }
  });
}

void NBufferStep(const ImageView<const float>& in, int step, const ImageView<float>& out) {
  const int w = in.width, h = in.height;
  ParallelFor(h, RowGrain(w), [&](std::int64_t r0, std::int64_t r1) {
    for (int y = int(r0); y < int(r1); ++y) {
      const float* a = in.Row(y);
      const float* b = in.Row(std::min(y + step, h - 1));
      float* o = out.Row(y);
      const int split = std::max(0, w - step);  // x + step < w for x < split
      for (int x = 0; x < split; ++x) o[x] = std::max(std::max(a[x], a[x + step]), std::max(b[x], b[x + step]));
      for (int x = split; x < w; ++x) o[x] = std::max(std::max(a[x], a[w - 1]), std::max(b[x], b[w - 1]));
    }
  });
}

void NBufferQuery(const ImageView<const float>* levels, int n_levels, int mip_levels, int full_height,
                  int full_width, const std::int32_t* boxes, std::int64_t num_boxes, float* out) {
  const int cw = levels[0].width, ch = levels[0].height;
  ParallelFor(num_boxes, 4096, [&](std::int64_t k0, std::int64_t k1) {
    for (std::int64_t k = k0; k < k1; ++k) {
      const std::int32_t* b = boxes + 4 * k;
      const int x0 = std::max(0, b[0]), y0 = std::max(0, b[1]);
      const int x1 = std::min(full_width, b[2]), y1 = std::min(full_height, b[3]);
      if (x0 >= x1 || y0 >= y1) {
        out[k] = std::numeric_limits<float>::infinity();
        continue;
      }
      const int tx0 = x0 >> mip_levels, tx1 = std::min(cw - 1, (x1 - 1) >> mip_levels);
      const int ty0 = y0 >> mip_levels, ty1 = std::min(ch - 1, (y1 - 1) >> mip_levels);
      const int a = tx1 - tx0 + 1, bb = ty1 - ty0 + 1;
      int m = 31 - __builtin_clz(static_cast<unsigned>(std::min(a, bb)));
      m = std::min(m, n_levels - 1);
      const int s = 1 << m;
      const ImageView<const float>& lv = levels[m];
      float best = -std::numeric_limits<float>::infinity();
      for (int ty = ty0;; ty += s) {
        const float* row = lv.Row(std::min(ty, ty1 - s + 1));
        for (int tx = tx0;; tx += s) {
          best = std::max(best, row[std::min(tx, tx1 - s + 1)]);
          if (tx + s > tx1) break;
        }
        if (ty + s > ty1) break;
      }
      out[k] = best;
    }
  });
}

}  // namespace ibr
