// TM's texture atlas reads: float32 RGB (older cache entries) and 8-bit sRGB RGBA, the storage of
// the texture stage. 8-bit sRGB RGBA (issue 7: the float32 RGB atlas of ~5 M texels,
// 66 MB, made the atlas read cache-miss bound: 14 ms of CPU at 1280x720 against 4 ms for an
// atlas that fits in cache). 4 bytes per texel instead of 12; each texel is decoded through a
// 256-entry sRGB -> linear table and the bilinear weights are applied in linear light, so the
// result differs from the float32 atlas only by the 8-bit sRGB quantisation of the texels
// (at most half a code step: relative 0.4 % of the value in linear light above the sRGB toe).
#pragma once
#include <cstdint>

#include "ibr/image.h"

namespace ibr {

// out(pixel) = bilinear read of atlas (h, w, 3) at uv = (1 - u - v) uv[f, 0] + u uv[f, 1] +
// v uv[f, 2] for the hit face f = prim_id (uv (M, 3, 2) in atlas pixels, x right, y down, pixel
// centres at +0.5; reads clamped to the atlas's edge texels); 0 where prim_id < 0. Prim ids
// already checked to lie in [-1, M); the atlas is at least 1 x 1.
void SampleAtlas(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels, const float* uv,
                 ImageView<const float> atlas, float* out);

// As SampleAtlas, reading atlas (h, w, 4) uint8 sRGB (alpha unused, padding for
// 4-byte texels). Prim ids already checked to lie in [-1, M); the atlas is at least 1 x 1.
void SampleAtlasSrgb8(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels, const float* uv,
                      ImageView<const std::uint8_t> atlas, float* out);

}  // namespace ibr
