// 8-bit sRGB texture atlas read (atlas8.h).
#include "kernels/atlas8.h"

#include <algorithm>
#include <array>
#include <cmath>

#include "ibr/parallel.h"

namespace ibr {
namespace {

const std::array<float, 256>& SrgbToLinear() {
  static const std::array<float, 256> lut = [] {
    std::array<float, 256> t{};
    for (int i = 0; i < 256; ++i) {
      const double s = i / 255.0;
      t[i] = static_cast<float>(s <= 0.04045 ? s / 12.92 : std::pow((s + 0.055) / 1.055, 2.4));
    }
    return t;
  }();
  return lut;
}

}  // namespace

void SampleAtlasSrgb8(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels, const float* uv,
                      ImageView<const std::uint8_t> atlas, float* out) {
  const float* lut = SrgbToLinear().data();
  const int aw = atlas.width, ah = atlas.height;
  ParallelFor(num_pixels, 16384, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t i = b; i < e; ++i) {
      float* o = out + 3 * i;
      const std::int32_t f = prim_id[i];
      if (f < 0) {
        o[0] = o[1] = o[2] = 0.f;
        continue;
      }
      const double u = bary[2 * i], v = bary[2 * i + 1], w = 1.0 - u - v;
      const float* t = uv + 6 * std::int64_t(f);
      const double x = w * t[0] + u * t[2] + v * t[4], y = w * t[1] + u * t[3] + v * t[5];
      // Bilinear, pixel centres at +0.5, clamped to the edge texels (as Bilinear3 in hybrid.cpp).
      const double fx = std::clamp(x - 0.5, 0.0, double(aw - 1)), fy = std::clamp(y - 0.5, 0.0, double(ah - 1));
      const int x0 = std::min(static_cast<int>(fx), aw - 1), y0 = std::min(static_cast<int>(fy), ah - 1);
      const int x1 = std::min(x0 + 1, aw - 1), y1 = std::min(y0 + 1, ah - 1);
      const float ax = float(fx - x0), ay = float(fy - y0);
      const std::uint8_t* r0 = atlas.Row(y0);
      const std::uint8_t* r1 = atlas.Row(y1);
      const std::uint8_t *p00 = r0 + 4 * x0, *p01 = r0 + 4 * x1, *p10 = r1 + 4 * x0, *p11 = r1 + 4 * x1;
      for (int c = 0; c < 3; ++c) {
        const float top = lut[p00[c]] + ax * (lut[p01[c]] - lut[p00[c]]);
        const float bot = lut[p10[c]] + ax * (lut[p11[c]] - lut[p10[c]]);
        o[c] = top + ay * (bot - top);
      }
    }
  });
}

}  // namespace ibr
