// MIP maps (Williams 1983) for pooled moment maps (Walton et al. 2021, "Beyond Blur", sec. 3.2
// "Pooling": the mean map is select(mip(L), sigma), the variance map comes from mip(L^2); the
// paper reads the MIP map tri-cubically, we read it trilinearly: docs/foveate.md).
//
// MipDown: one level of a box-filter pyramid. out (ceil(h/2), ceil(w/2), C) from in (h, w, C):
//   out[j, i, c] = mean of in[2j + dy, 2i + dx, c] over dy, dx in {0, 1} inside the image.
//   Odd sizes: the last row / column of out averages the 2 (or 1) pixels that exist, so every
//   level is the average of its full-resolution block clipped to the image (no padding value).
//
// MipLookup: trilinear read of a MIP chain at a per-pixel fractional level.
//   levels[0] (H, W, C) is the full resolution, levels[l] (ceil(H / 2^l), ceil(W / 2^l), C).
//   For pixel (y, x) with level lambda = level_map[y, x] clamped to [0, n - 1] (n = n_levels):
//   l0 = floor(lambda) (at most n - 2), t = lambda - l0, and
//   out[y, x, :] = (1 - t) * B(l0) + t * B(l0 + 1), B(l) the bilinear sample of levels[l] at the
//   pixel centre ((x + 0.5) / 2^l - 0.5, (y + 0.5) / 2^l - 0.5) in level-l sample coordinates,
//   clamped to the edge. lambda <= 0 copies levels[0][y, x, :] bit for bit; a level with weight 0
//   is not read.
//
// Shapes (row, col, channel), C-contiguous, float32; level_map (H, W) finite. The front
// (cpp/bindings/mip.cpp) checks everything; kernels trust their inputs, never throw and never
// allocate. Multithreaded over output rows with ibr::ParallelFor; every output sample depends only
// on its inputs, so the result is identical for any thread count.
#pragma once
#include "ibr/image.h"

namespace ibr {

void MipDown(const ImageView<const float>& in, const ImageView<float>& out);

void MipLookup(const ImageView<const float>* levels, int n_levels, const ImageView<const float>& level_map,
               const ImageView<float>& out);

}  // namespace ibr
