// TM's texture atlas reads: float32 RGB (older cache entries) and 8-bit sRGB RGBA, the storage of
// the texture stage. 8-bit sRGB RGBA (issue 7: the float32 RGB atlas of ~5 M texels,
// 66 MB, made the atlas read cache-miss bound: 14 ms of CPU at 1280x720 against 4 ms for an
// atlas that fits in cache). 4 bytes per texel instead of 12; each texel is decoded through a
// 256-entry sRGB -> linear table and the bilinear weights are applied in linear light, so the
// result differs from the float32 atlas only by the 8-bit sRGB quantisation of the texels
// (at most half a code step: relative 0.4 % of the value in linear light above the sRGB toe).
//
// PointColors: the texture bake's per-point colour (ULR-weighted blend of the views at surface
// points), the kernel of ibrtools.hybrid.globalmesh.point_colors: per-vertex colour and the
// atlas's per-texel colour (tens of millions of texels on a fused mesh: the numpy version took
// ~23 us a point on lego's 36 views, this one ~1 us on 2 threads).
#pragma once
#include <cstdint>

#include "ibr/image.h"
#include "kernels/hybrid/hybrid.h"

namespace ibr {

// out(pixel) = bilinear read of atlas (h, w, 3) at uv = (1 - u - v) uv[f, 0] + u uv[f, 1] +
// v uv[f, 2] for the hit face f = prim_id (uv (M, 3, 2) in atlas pixels, x right, y down, pixel
// centres at +0.5; reads clamped to the atlas's edge texels); 0 where prim_id < 0. Prim ids
// already checked to lie in [-1, M); the atlas is at least 1 x 1. A hit whose barycentrics or
// face uv are not finite is left 0 and not read: returns the smallest such pixel index, else -1.
std::int64_t SampleAtlas(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels, const float* uv,
                         ImageView<const float> atlas, float* out);

// As SampleAtlas, reading atlas (h, w, 4) uint8 sRGB (alpha unused, padding for
// 4-byte texels). Prim ids already checked to lie in [-1, M); the atlas is at least 1 x 1.
std::int64_t SampleAtlasSrgb8(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels,
                              const float* uv, ImageView<const std::uint8_t> atlas, float* out);

// TexelPoints: the used texels of atlas rows [row0, row0 + rows) (face_of_texel (rows, width)
// int32, -1 = unused), in row-major order: their row (ys, absolute) and column (xs), face, the
// barycentrics of the texel centre (x + 0.5, y + 0.5) in the face's chart uv (M, 3, 2) (negative
// weights set to 0, renormalised), the surface point (the barycentric blend of the face's
// vertices (N, 3) float32) and the unit normal (of the per-vertex normals (N, 3) float32; zero
// length: left at 0 / 1e-12). float64 arithmetic in the order of the numpy expressions it
// replaced (atlas.texel_barycentrics and bake's einsum / norm): the same bits. Face and vertex
// indices already checked. TexelRowStarts gives row_start (rows + 1): each row's first output
// slot, the used texels' count last (the caller sizes the outputs with it).
void TexelRowStarts(const std::int32_t* face_of_texel, int rows, int width, std::int64_t* row_start);
void TexelPoints(const std::int32_t* face_of_texel, const std::int64_t* row_start, int rows, int width, int row0,
                 const float* uv,
                 const float* vertices, const std::int32_t* faces, const float* normals, std::int64_t* ys,
                 std::int64_t* xs, std::int32_t* face, double* bary, double* points, double* unit_normals);

struct PointColorOptions {
  int k = 4;                // views blended per point (the (k+1)-th smallest penalty is the threshold)
  float depth_tol = 0.02f;  // visibility: |depth of the point - view depth| <= depth_tol * view depth
};

// Per point p (n, 3) world, unit normal nrm (n, 3), both float64: every view whose image holds p
// (0 <= x < w, 0 <= y < h, in front), whose depth at p's pixel (nearest, floor) is finite, > 0 and
// within depth_tol of p's depth, and that sees p from the front (angle between nrm and the
// direction to the camera centre < pi/2 - 1e-3) gets penalty = that angle + 0.5 max(0, r / r_min
// - 1) (r: distance to the camera centre, r_min its minimum over those views); the views with a
// penalty below the (k+1)-th smallest (all of them when num_views <= k) are blended with weights
// max(1e-3, 1 - penalty / threshold) (1 without a threshold) of their colour read bilinearly
// (centres at +0.5, edge-clamped). color (n, 3): the blend, 0 where no view sees p; seen (n):
// how many views see p. Views' colour (h, w, 3) and depth (h, w) have the camera's size.
void PointColors(const double* points, const double* normals, std::int64_t n, const UlrInputView* views,
                 int num_views, const PointColorOptions& options, float* color, std::int32_t* seen);

}  // namespace ibr
