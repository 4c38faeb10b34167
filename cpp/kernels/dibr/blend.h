// Streaming blending of forward-warped views (Bonatto et al. 2021, Eq. 3):
//   C = sum_i w_i C_i / sum_i w_i,  w_i = (q_i / d_i)^p per pixel (cpp/kernels/dibr/forward_warp.h).
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
//
// Visibility across views (optional; RVS blends every view's front fragment, so both are off by
// default and the pure Eq. 3 mean is kept). Each view's z-buffer only resolves occlusion within
// that view; a background fragment of view A and the foreground fragment of view B at the same
// target pixel are otherwise averaged (ghosting, damped only by the 1/d^p factor). Two rules,
// applied as each fragment arrives, keep the sums streaming (no per-view buffers):
//  * stretched_quality > 0: a fragment with q < stretched_quality lies on a stretched triangle
//    (a disocclusion bridge). It never mixes into a pixel that holds unstretched content, and
//    unstretched content replaces it. With stretched_holes, pixels that only stretched
//    fragments cover are holes ("background that no input sees is a hole, not stretched
//    foreground").
//  * depth_tolerance > 0: among fragments of the same class, one nearer than the accumulated
//    depth by more than this relative tolerance replaces the sums (a foreground surface the
//    earlier views did not see); one farther by more is occluded and dropped.
// Both depend on view order only when fragments tie at the thresholds; the order is fixed by
// the caller, so results stay deterministic.
#pragma once
#include <cstdint>

namespace ibr {

struct BlendBuffers {
  int height = 0, width = 0;
  float* sum_wc = nullptr;      // (H, W, 3)
  float* sum_w = nullptr;       // (H, W)
  float* sum_w_invd = nullptr;  // (H, W)
  float* sum_q = nullptr;       // (H, W)
  float* max_q = nullptr;       // (H, W) largest q among the fragments in the sums
  float stretched_quality = 0.f;  // see "Visibility across views"; 0 = off
  bool stretched_holes = false;
  float depth_tolerance = 0.f;    // relative; 0 = off
  // The sums hold no view yet and their memory is not cleared (any bits): the next accumulation
  // of a whole view (every target row, as ForwardWarp does) writes each pixel's sums as if they
  // were 0 (0 + the view's values, the same bits as ClearBlend then adding; 0 where the view has
  // no fragment) instead of reading them. The caller clears the flag after that view. Saves the
  // clearing pass and the first view's read of the sums. ResolveBlend needs fresh == false.
  bool fresh = false;
};
#define IBR_BLEND_FRESH 1  // BlendBuffers::fresh exists (benchmarks/dibr_ab builds older kernels too)

// Zeroes the sums (all threads).
void ClearBlend(const BlendBuffers& acc);

// max_q is read and written only when stretched_quality > 0 (the only rule that uses it; without
// it ResolveBlend does not read it either).
// Adds rows [y0, y1) of one warped view (colour (H, W, 3), depth (H, W), weight (H, W),
// quality (H, W); weight 0 = not covered) to the sums. Single-threaded over those rows (the
// warp calls it per band, in the band's task).
void AccumulateRows(const float* color, const float* depth, const float* weight, const float* quality,
                    const BlendBuffers& acc, int y0, int y1);

// The same for one target row y, the view's values given as row pointers (color (W, 3), depth,
// weight, quality (W)): the warp's band-local buffers hold only the band being drawn.
void AccumulateRow(const float* color, const float* depth, const float* weight, const float* quality,
                   const BlendBuffers& acc, int y);
// AccumulateRow when neither visibility rule is on (stretched_quality == 0, depth_tolerance ==
// 0), compiled for AVX2: call it only on a CPU with AVX2 (cpp/ibr/simd.h UseAvx2). Same bits.
void AccumulateRowPlainAvx2(const float* color, const float* depth, const float* weight, const float* quality,
                            const BlendBuffers& acc, int y);

// The space of the colours in the sums, i.e. of the views given to the warp. kSrgb: they are sRGB
// encodings (the DIBR blend space "srgb": RVS blends stored code values, docs/dibr.md "Blend
// space") and ResolveBlend decodes the blended colour to linear with the curve of SrgbToLinear
// (cpp/ibr/colour.h: x / 12.92 up to 0.04045, the power above, beyond 1 too), row by row
// while the row is in cache instead of a second pass over the image. In [0, 1] the curve is read
// from a table of its values (4097 nodes, linear interpolation: within 1e-6 of SrgbToLinear, exact
// at the nodes; colour.h SrgbToLinearTableRun), outside it evaluated. Holes stay exactly 0.
enum class BlendSpace : int { kLinear = 0, kSrgb = 1 };

// Writes colour (H, W, 3), depth (H, W), confidence (H, W), hole (H, W; 1 = hole) (all threads).
// avx2: eight pixels per step, compiled for AVX2 (call it so only on a CPU with AVX2; the same
// bits; the engine's ISA switch decides, cpp/ibr/simd.h UseAvx2); the sRGB decoding follows
// the same flag, with the same bits. Depth, confidence and hole do not depend on the space; the
// colour of BlendSpace::kSrgb is that of kLinear decoded by SrgbToLinear, within 1e-6.
void ResolveBlend(const BlendBuffers& acc, float* color, float* depth, float* confidence, std::uint8_t* hole,
                  bool avx2 = false, BlendSpace space = BlendSpace::kLinear);
#define IBR_BLEND_RESOLVE_AVX2 1  // ResolveBlend has the avx2 flag (benchmarks/dibr_ab)
#define IBR_BLEND_RESOLVE_SRGB 1  // ResolveBlend has the BlendSpace argument (benchmarks/dibr_ab)

}  // namespace ibr
