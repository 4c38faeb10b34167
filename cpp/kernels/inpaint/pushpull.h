// Push-pull hole filling: the classic pyramid fill (Gortler et al. 1996, "The Lumigraph",
// section 3.4 / "image-space reconstruction using push-pull") and the depth-aware variant of
// dos Anjos et al., "Metameric Inpainting for Image Warping", section 3.3, Algorithm 1.
//
// Pyramid: level 0 is the input; level l+1 has ceil(h/2) x ceil(w/2) pixels, each the
// combination of the (up to) 2x2 "children" below it (1 or 2 children on the last row/column
// of odd-sized levels). Every level holds a colour c (C channels), a validity v in [0, 1]
// and, in the depth-aware variant, a depth d.
//
// PULL (Alg. 1 lines 1-12), per coarse pixel, children i with (c_i, v_i, d_i):
//   level 0: v_i = 0 in holes, 1 elsewhere.
//   depth-aware only: ref = the children's background depth (see below); children whose known
//     depth is nearer than ref by more than `threshold` get v_i = 0 (Alg. 1 lines 2-7);
//     d_out = ref (line 10).
//   W = sum v_i; v_out = W / n (n = number of children: partial validity is carried, line 9);
//   c_out = sum v_i c_i / W (line 8 keeps c premultiplied; we store it normalised, the same
//   thing divided by v_out), c_out = 0 and v_out = 0 when W = 0.
// PUSH (Alg. 1 lines 13-16), coarse to fine, level l from the already filled level l+1:
//   a = v^gamma (a = 1 for any v > 0 when gamma = 0, a = 0 when v = 0);
//   filled_l = a c_l + (1 - a) up(filled_{l+1}),  up = bilinear (weights 3/4, 1/4 per axis,
//   pixel centres at +0.5, clamped at the border).
//   Alg. 1 writes mix(hicolour, locolour, hiValidity^gamma), which in GLSL/HLSL order would give
//   the *coarse* colour the weight of the fine validity; the text (sec. 3.3.1: gamma = 0 is
//   "the original push-pull", gamma = 1 "maximal ... blur") only makes sense with the fine
//   colour weighted by its validity, which is what we do.
//   Level 0: out = image where not a hole (copied: exact; left untouched with holes_only),
//   up(filled_1) in holes.
//
// Classic = depth test off and gamma = 0: the pull averages the valid children weighted by their
// (partial) validity, the push fills exactly the pixels with no valid data from the coarser level
// (the normalised convolution the paper calls "the original push-pull").
//
// Depth convention (deviation in words, not in effect): the paper works in Unity's reversed-Z
// depth buffer, where a *larger* value is *nearer* ("[29]'s depth test is reversed compared to
// ours; that is, they only draw from locations close to the maximal depth (closest to the
// camera)"), so its "minimal depth of the block" is the farthest sample, the background. Our
// depth is metric (z or ray distance, larger = farther), so ref = the *largest* known depth among
// the children, and children with ref - d > threshold (nearer, foreground) are dropped. Hole
// pixels take part in ref (the warper writes background depth into holes, sec. 3.1), so a block
// that mixes a foreground sample with a background hole rejects the foreground.
// Unknown depth (NaN, +-inf or <= 0: the engine's marks of unknown depth) never sets ref and is never
// rejected.
// The threshold is "0.04 of the normalised depth" (authors' Unity code): the kernel normalises by
// the image's range of known depth, threshold_abs = depth_threshold * (max - min).
//
// Classic fallback (our deviation from Alg. 1). When the farthest depth of the image (within the
// threshold) is hole only -- a hole's background lies beyond every visible pixel, e.g. far ground
// disoccluded behind an object -- the depth test drops every valid sample at some scale and Alg. 1
// ends with no data at the 1x1 top; its push would fill with an undefined colour. We then keep
// Alg. 1 wherever it has data and give the rest of each hole pixel to the classic fill:
//   out = F0 + (1 - s) * classic,
// where F0 is Alg. 1's push with the top colour set to 0, s is the same push of the indicator
// "has data" (1 where v > 0, 0 at the top), i.e. the weight of depth-aware data in the pixel's
// fill (the fill is affine in the top colour: F0 + (1 - s) * top), and classic is the classic
// push-pull of the same pixel. A hole pixel that no depth-aware data reaches (s = 0) gets the
// classic fill exactly; when the top has data s = 1 everywhere and nothing changes. Why not fall
// back per block at the first level whose depth test drops every valid sample: such blocks sit
// on every foreground/background-hole edge, where the drop is the point of Alg. 1 (coarser levels
// usually do find background), so a per-block classic average would bleed the foreground into
// every hole beside it; the fallback must only take what Alg. 1 leaves empty at every scale.
//
// Shapes: image (H, W, C) float32, hole (H, W) one byte per pixel (non-zero = hole), depth
// (H, W) float32 or empty, out (H, W, C) float32 (may not alias image, except out == image with
// holes_only: only pixels outside the holes are read and only hole pixels written, after every
// read). H, W, C >= 1.
// The binding (cpp/bindings/inpaint.cpp) checks shapes, the front (front.h) finiteness outside
// holes and options.
// Multithreaded over the rows of each level with ibr::ParallelFor; every pixel is computed
// independently, so the result is identical for any thread count. Scratch for levels >= 1 is
// allocated here (about 1/3 of the input; the fallback adds a classic run and 1/3 of a channel);
// nothing is thrown.
#pragma once
#include <cstdint>

#include "ibr/image.h"

namespace ibr {

struct PushPullOptions {
  bool depth_aware = false;     // Alg. 1's depth test in the pull (needs depth)
  float depth_threshold = 0.04f;  // fraction of the image's known-depth range (authors' 0.04)
  float gamma = 0.0f;           // push: a = v^gamma; 0 = classic, 0.5 = the paper's default
  // Write only the hole pixels of `out` (the rest keep whatever they held): for callers that
  // read the fill in the holes only (the metameric moments), it saves copying the image.
  bool holes_only = false;
};

enum class PushPullStatus {
  kOk = 0,
  kNoHole,           // nothing to fill: out is a copy of image (untouched with holes_only)
  kNoValidPixel,     // every pixel is a hole: out untouched
  kClassicFallback,  // depth-aware found no data at the top: filled with the classic fallback
};

// write: empty, or (H, W) one byte per pixel with options.holes_only: only the hole pixels where
// write is non-zero are written (the others' fill is computed and dropped), so a caller that fills
// a part of the holes (inpaint/complete.py: the surface holes, not the holes at the background at
// infinity, which are not data either) writes into its own image in place, with no second pass.
PushPullStatus PushPullKernel(const ImageView<const float>& image,
                              const ImageView<const std::uint8_t>& hole,
                              const ImageView<const float>& depth, const PushPullOptions& options,
                              const ImageView<float>& out,
                              const ImageView<const std::uint8_t>& write = ImageView<const std::uint8_t>());

// The push-pull of the moments [X_0 .. X_{k-1}, X_0^2 .. X_{k-1}^2] of k bands (h, w, C) each
// (metameric inpainting, dos Anjos et al. sec. 3.3.1), without storing them: the level-0 rows
// are computed on the fly (metameric.h StackMomentsRow), so the result in the holes is
// PushPullKernel's of MetamericStackMoments' output. Writes the hole pixels of out (h, w, 2kC)
// only (holes_only is implied). hole and depth as for PushPullKernel.
PushPullStatus PushPullMomentsKernel(const ImageView<const float>* bands, int k,
                                     const ImageView<const std::uint8_t>& hole,
                                     const ImageView<const float>& depth, const PushPullOptions& options,
                                     const ImageView<float>& out);

// PushPullMomentsKernel fused with the metameric composite (metameric.h MetamericSynth): instead of
// writing the moments of the hole (mask) samples, each goes through MetamericChangeSample into
// synth.bands, and every row of synth.bands is cleared first, so on return the bands hold the
// level's change (sigma * noise in the mask, 0 elsewhere): the same values, bit for bit, as
// PushPullMomentsKernel then MetamericComposite(delta = true), without the (h, w, 2kC) moments
// image (75 MB at 1024^2, page-faulted anew on every call). synth.bands may be the same memory as
// `bands`: they are written only after the last read of `bands`. Allocates a classic fill of
// (h, w, 2kC) only on the kClassicFallback path.
struct MetamericSynth;
PushPullStatus PushPullMomentsChangeKernel(const ImageView<const float>* bands, int k,
                                           const ImageView<const std::uint8_t>& hole,
                                           const ImageView<const float>& depth, const PushPullOptions& options,
                                           const MetamericSynth& synth);

// Number of non-finite values of image at pixels where hole == 0 (multithreaded).
std::int64_t CountNonFiniteOutsideHoles(const ImageView<const float>& image,
                                        const ImageView<const std::uint8_t>& hole);

}  // namespace ibr
