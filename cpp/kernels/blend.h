// Streaming blending of forward-warped views (Bonatto et al. 2021, Eq. 3):
//   C = sum_i w_i C_i / sum_i w_i,  w_i = (q_i / d_i)^p per pixel (cpp/kernels/forward_warp.h).
// The accumulator holds running sums only, so memory is a constant number of full-resolution
// buffers whatever the number of views:
//   sum_wc (H, W, 3) = sum w c;  sum_w (H, W) = sum w;  sum_w_invd (H, W) = sum w / d;
//   sum_q (H, W) = sum of the per-view qualities q in (0, 1] (the confidence).
// Depth is blended as the weighted harmonic mean sum w / sum (w / d): identical to the
// weighted mean when the views agree, and well defined with depth +inf (sky: 1/d = 0).
// Resolve: colour = sum_wc / sum_w, depth = sum_w / sum_w_invd (+inf if every contributor is
// at infinity), both 0 where sum_w == 0 (hole); confidence = sum_q (0 .. number of views; a
// pixel seen by one view through undistorted triangles has confidence ~1); hole = sum_w == 0.
// Never NaN: weights are finite and positive where a view covers a pixel (forward_warp.h).
#pragma once
#include <cstdint>

namespace ibr {

struct BlendBuffers {
  int height = 0, width = 0;
  float* sum_wc = nullptr;      // (H, W, 3)
  float* sum_w = nullptr;       // (H, W)
  float* sum_w_invd = nullptr;  // (H, W)
  float* sum_q = nullptr;       // (H, W)
};

// Zeroes the sums (all threads).
void ClearBlend(const BlendBuffers& acc);

// Adds rows [y0, y1) of one warped view (colour (H, W, 3), depth (H, W), weight (H, W),
// quality (H, W); weight 0 = not covered) to the sums. Single-threaded over those rows (the
// warp calls it per band, in the band's task).
void AccumulateRows(const float* color, const float* depth, const float* weight, const float* quality,
                    const BlendBuffers& acc, int y0, int y1);

// Writes colour (H, W, 3), depth (H, W), confidence (H, W), hole (H, W; 1 = hole) (all threads).
void ResolveBlend(const BlendBuffers& acc, float* color, float* depth, float* confidence, std::uint8_t* hole);

}  // namespace ibr
