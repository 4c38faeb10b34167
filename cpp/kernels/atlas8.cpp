// TM texture atlas reads, float32 and 8-bit sRGB (atlas8.h).
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


// The one atlas read loop: per pixel, the hit face's UVs interpolated with the barycentrics,
// then a bilinear read (texel centres at +0.5, clamped to the edge texels) of channel c of texel
// (x, y) through `texel(row_y, x, c)` (linear float); black where prim_id < 0.
template <class Texel, class RowOf>
void SampleAtlasBilinear(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels, const float* uv,
                         int aw, int ah, RowOf row_of, Texel texel, float* out) {
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
      const double fx = std::clamp(x - 0.5, 0.0, double(aw - 1)), fy = std::clamp(y - 0.5, 0.0, double(ah - 1));
      const int x0 = std::min(static_cast<int>(fx), aw - 1), y0 = std::min(static_cast<int>(fy), ah - 1);
      const int x1 = std::min(x0 + 1, aw - 1), y1 = std::min(y0 + 1, ah - 1);
      const float ax = float(fx - x0), ay = float(fy - y0);
      const auto r0 = row_of(y0);
      const auto r1 = row_of(y1);
      for (int c = 0; c < 3; ++c) {
        const float t00 = texel(r0, x0, c), t01 = texel(r0, x1, c), t10 = texel(r1, x0, c), t11 = texel(r1, x1, c);
        const float top = t00 + ax * (t01 - t00);
        const float bot = t10 + ax * (t11 - t10);
        o[c] = top + ay * (bot - top);
      }
    }
  });
}

}  // namespace

void SampleAtlas(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels, const float* uv,
                 ImageView<const float> atlas, float* out) {
  SampleAtlasBilinear(
      prim_id, bary, num_pixels, uv, atlas.width, atlas.height, [&](int y) { return atlas.Row(y); },
      [](const float* row, int x, int c) { return row[3 * x + c]; }, out);
}

void SampleAtlasSrgb8(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels, const float* uv,
                      ImageView<const std::uint8_t> atlas, float* out) {
  const float* lut = SrgbToLinear().data();
  SampleAtlasBilinear(
      prim_id, bary, num_pixels, uv, atlas.width, atlas.height, [&](int y) { return atlas.Row(y); },
      [lut](const std::uint8_t* row, int x, int c) { return lut[row[4 * x + c]]; }, out);
}

}  // namespace ibr
