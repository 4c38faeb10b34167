// Small-filter steerable pyramid: analysis and synthesis (collapse) with the fitted 5x5 taps of
// steerable_taps.h (Walton et al. 2021, "Beyond Blur", sec. 3.2: a YCbCr steerable pyramid with
// small oriented filters and a low-pass residual; structure of Simoncelli & Freeman 1995 as in
// pyrtools' SteerablePyramidSpace). docs/steerable.md documents the filters and their error.
//
// Exactly the numpy reference of tools/fit_steerable_filters.py (analyse / synthesise), per
// channel, with corr(x, f)[y, x] = sum_{dy,dx in -2..2} f[dy+2][dx+2] x[y+dy, x+dx] and reflect1
// borders (reflect-101: index -1 -> 1, n -> n-2; scipy.ndimage 'mirror', pyrtools 'reflect1'):
//   analysis:  hi = corr(x, H0); lo = corr(x, L0);
//              per level l = 0..L-1: band[l][k] = corr(lo, B_k); lo = corr(lo, L1)[::2, ::2];
//              lowpass = lo.
//   synthesis: lo = lowpass; per level l = L-1..0 (fine size h_l x w_l):
//                up = zeros(h_l, w_l); up[::2, ::2] = lo;
//                lo = corr(up, flip(L1)) + sum_k corr(band[l][k], flip(B_k));
//              out = corr(lo, flip(L0)) + corr(hi, flip(H0)).
//   flip(f) = f[::-1, ::-1] (the adjoint of the analysis correlation, as pyrtools).
// The zero-inserted image is never built: reflect1 maps even indices to even indices, so each
// fine output pixel reads only the L1 taps that land on non-zero samples (at most 3x3 of them,
// 2x2 / 2x1 / 1x1 for odd rows or columns).
//
// Multiply-adds: every 5x5 filter f is split into its even and odd parts along y,
//   f[2+j] r(y+j) + f[2-j] r(y-j) = fe_j (r(y+j) + r(y-j)) + fo_j (r(y+j) - r(y-j)),
// so the five vertical combinations s0 = r(y), s_j = r(y+j) + r(y-j), d_j = r(y+j) - r(y-j)
// (j = 1, 2) are formed once per output row and shared by every filter reading that image; each
// of the (up to) five 1-D row filters fe_j, fo_j is then applied as even (3 multiplies), odd (2)
// or zero (skipped), general 5 taps only if neither. L0, H0, L1 (D4-symmetric) cost 9 multiplies
// per sample instead of 25, the axis-aligned bands 6 and the diagonal bands (K = 4, point-odd) 12.
// The split rounds differently from a direct 25-tap sum (float32 storage and accumulation):
// against the float64 numpy reference the result differs by ~1e-6 relative to the image range.
//
// Colour (optional, `ycbcr`): BT.601 full-range YCbCr with Cb, Cr centred on 0 — Y = .299 R +
// .587 G + .114 B, Cb = (B - Y) / 1.772, Cr = (R - Y) / 1.402 — *without* the usual +0.5 (or +128)
// chroma offset, so the whole pipeline stays linear (analyse(a x + b y) = a analyse(x) + b
// analyse(y)), a grey image has zero chroma everywhere, and an offset cannot leak into the
// statistics of the chroma low-pass that metameric synthesis pools. Synthesis applies the exact
// inverse matrix. Without `ycbcr` the channels are filtered as given (any number C >= 1).
//
// Shapes (row, col, channel), float32, C-contiguous: image (H, W, C); level l has size
// h_l x w_l with h_0 = H, h_{l+1} = ceil(h_l / 2); highpass (H, W, C); band[l][k] (h_l, w_l, C);
// lowpass (h_L, w_L, C). Every level's input must be at least 3 x 3 (h_l, w_l >= 3 for
// l < L: a 5-tap reflect1 border needs 3 samples), see SteerableMaxLevels. ycbcr needs C = 3.
// The front (cpp/bindings/metamers.cpp) checks all of it; kernels trust their inputs, never
// throw, and allocate only scratch: the low-pass images of levels 1..L-1 (~0.33 x the input,
// uninitialised, first touched by the parallel loop that writes them) and per-thread row
// buffers kept between calls (~21 rows of the widest image seen). Full resolution is never
// stored but in the outputs: the YCbCr conversion happens row by row inside the first filter
// pass, and the top pass (H0, L0) is fused with level 0 (analysis: the level-0 low-pass rows
// stream through a ring of 8 rows; synthesis: the collapsed level-0 rows likewise, then the
// inverse colour matrix in place). Every output row is written by a store of its first filter
// part (no zero fill). Multithreaded over rows with ibr::ParallelFor: each output row is
// computed alone, by the same arithmetic (rows at the edges of the fused tasks are computed by
// both neighbours, identically), so results are identical for any thread count.
#pragma once
#include <vector>

#include "ibr/image.h"

namespace ibr {

// Supported numbers of orientations (taps in steerable_taps.h).
constexpr bool SteerableOrientationsSupported(int k) { return k == 2 || k == 4; }

// Size of level `level` along an axis of n samples: ceil(n / 2^level).
inline int SteerableLevelSize(int n, int level) {
  for (int l = 0; l < level; ++l) n = (n + 1) / 2;
  return n;
}

// The largest number of levels for an H x W image (every level's input >= 3 x 3); 0 if H or W < 3.
int SteerableMaxLevels(int height, int width);

// The pyramid's images. T = float (analysis writes them) or const float (synthesis reads them).
// bands[l * orientations + k] is level l, orientation k.
template <typename T>
struct SteerablePyramidViews {
  int levels = 0;
  int orientations = 2;
  ImageView<T> highpass;
  std::vector<ImageView<T>> bands;
  ImageView<T> lowpass;
};

void SteerableAnalyseKernel(const ImageView<const float>& image, bool ycbcr,
                            const SteerablePyramidViews<float>& pyr);

// out (H, W, C) must not alias the pyramid.
void SteerableSynthesiseKernel(const SteerablePyramidViews<const float>& pyr, bool ycbcr,
                               const ImageView<float>& out);

// Number of non-finite values in an image (multithreaded; for the checking front).
std::int64_t SteerableCountNonFinite(const ImageView<const float>& image);

}  // namespace ibr
