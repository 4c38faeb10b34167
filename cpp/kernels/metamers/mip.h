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
// MipDownMoments: level 1 of the MIP chain of the moment stack [X_0..X_{k-1}, X_0^2..X_{k-1}^2]
//   of k bands (h, w, C) without materialising the stack: out (ceil(h/2), ceil(w/2), 2kC) is
//   MipDown of out0[y, x, i*C + ch] = band_i[y, x, ch], out0[y, x, (k + i)*C + ch] = band_i^2
//   (the same float operations, so bit-identical to stacking then MipDown).
//
// MipFoveateChange: the fused moment lookup + metamer composite of one pyramid level (Walton et
//   al. sec. 3.2-3.4; python/ibrtools/foveate.py), in place. mip[0 .. n-1] are levels 1..n of the
//   moment stack's chain (MipDownMoments then MipDown), the stack itself (level 0) is never stored:
//   it is read from the bands at the pixel. Per sample with lam = level_map[y, x]:
//   lam <= 0: band_i[y, x, :] = 0 (no change); otherwise the 2kC moments m are MipLookup's value at
//   min(lam, n) (the stack's level 0 is the pixel's own [X, X^2]), and
//   band_i[y, x, ch] = (mean + sigma * noise_i[y, x, ch]) - band_i[y, x, ch] (the band's change),
//   mean = m[i*C + ch], sigma = sqrt(max(0, m[(k + i)*C + ch] - mean^2)), as MetamericComposite.
//   Requires 2kC <= kMipMaxMomentChannels (the per-sample buffer on the stack; the front checks).
//   Matches mip_build + mip_lookup + metameric_composite + subtraction to float rounding (the level-0
//   bilinear taps of weight 0 are skipped; compilers may contract differently: ~1 ulp).
//   RGB bands (C = 3, k = 2..5) take a fixed-size path (row chunks: moments of both levels summed in
//   registers into per-band planes, then the composite over contiguous floats in SIMD lanes; an AVX2
//   build of it, without FMA, when the CPU has AVX2) with the same float operations in the same order:
//   bit-identical to the generic path (tests/metamers/test_mip_foveate_level.py, against a numpy reference).
//
// Shapes (row, col, channel), C-contiguous, float32; level_map (H, W) finite. The front
// (cpp/bindings/metamers.cpp) checks everything; kernels trust their inputs, never throw and never
// allocate. Multithreaded over output rows with ibr::ParallelFor; every output sample depends only
// on its inputs, so the result is identical for any thread count.
#pragma once
#include "ibr/image.h"

namespace ibr {

void MipDown(const ImageView<const float>& in, const ImageView<float>& out);

void MipLookup(const ImageView<const float>* levels, int n_levels, const ImageView<const float>& level_map,
               const ImageView<float>& out);

inline constexpr int kMipMaxMomentChannels = 256;

void MipDownMoments(const ImageView<const float>* bands, int k, const ImageView<float>& out);

void MipFoveateChange(const ImageView<float>* bands, int k, const ImageView<const float>* mip, int n,
                      const ImageView<const float>& level_map, const ImageView<const float>* noise);

}  // namespace ibr
