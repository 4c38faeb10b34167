// Conservative max-depth queries over screen rectangles: Y-maps (Schwarz & Stamminger 2008) =
// `mip_levels` levels of a max-mipmap, then N-buffers (Décoret 2005) on the coarsest of them, as
// used by warping-based occlusion culling (Lee, Kim, Eisemann 2018, sec. 5.2).
//
// MaxMipDown: out (ceil(h/2), ceil(w/2)) = max of the 2x2 block of in, clipped to the image
//   (non-power-of-two sizes: the last row / column takes the pixels that exist).
// NBufferStep: N-buffer level i+1 from level i (both (h, w), step = 2^i):
//   out[y, x] = max(in[y, x], in[y, x'], in[y', x], in[y', x']) with x' = min(x + step, w - 1),
//   y' = min(y + step, h - 1); so level i holds the max over the 2^i x 2^i texels whose top-left
//   corner is (y, x), clipped to the image (clamping never reaches outside the square: x' >= x).
// NBufferQuery: boxes (K, 4) int32 (x0, y0, x1, y1) in full-resolution pixels, x1 / y1 exclusive,
//   clipped to the image; an empty box after clipping gives +inf. The box's texels at the coarse
//   level (full pixels / 2^mip_levels) span a x b; the N-buffer level m = floor(log2 min(a, b))
//   (at most n_levels - 1) is read at ceil(a / 2^m) x ceil(b / 2^m) tile corners, the last tile
//   of each row / column moved back so that it ends on the box's last texel: the tiles cover
//   exactly the box's texels. Result >= the true max over the box; equal when the box is aligned
//   to the 2^mip_levels grid (and clipping does not matter).
//
// Kernels trust their inputs (finite or +inf depths), never throw and never allocate. Rows /
// boxes are split over ibr::ParallelFor; every output depends only on its inputs (max is exact),
// so results are identical for any thread count.
#pragma once
#include <cstdint>

#include "ibr/image.h"

namespace ibr {

void MaxMipDown(const ImageView<const float>& in, const ImageView<float>& out);

void NBufferStep(const ImageView<const float>& in, int step, const ImageView<float>& out);

// levels[0 .. n_levels-1]: the N-buffer levels of the coarse image (levels[0] is the coarse
// max-mipmap level itself); full_height / full_width: the image the boxes refer to.
void NBufferQuery(const ImageView<const float>* levels, int n_levels, int mip_levels, int full_height,
                  int full_width, const std::int32_t* boxes, std::int64_t num_boxes, float* out);

}  // namespace ibr
