// The background at infinity, looked up in the inputs (python/ibrtools/inpaint/background.py,
// docs/FORMAT.md "Background"): a target pixel is a direction; an input sees that direction at
// the pixel it projects to with its camera at the origin (a rotation-only warp: a direction has no
// parallax).
//
// For every hole pixel of the target (its centre's ray, in world axes), the inputs are asked in
// the order given (the caller sorts them by viewing-direction agreement) until one decides:
//   - the direction projects inside the input (0 <= x < W, 0 <= y < H) to the pixel (floor x,
//     floor y), whose depth d is known (d > 0, +inf included): the input decides;
//   - and the pixel is background (d = +inf) and `clear` (no surface pixel near it): the
//     direction is the background, with the colour of the input's background pixels around it:
//     bilinear between pixel centres over the 2 x 2 neighbourhood (clamped at the border), each
//     weight multiplied by "that pixel's depth is +inf" and the sum renormalised (the nearest
//     pixel, background, is always among them), accumulated in double;
//   - an input where the direction falls outside, behind the camera, or on unknown depth (0)
//     does not decide: the next one is asked;
//   - the ray test (BackgroundRay, when 0 < near < far): a background direction is background
//     only when the target's ray is free space as the inputs show it. The ray's points at
//     kRaySamples depths from near to far (geometric steps, the target's depth convention: z for
//     a pinhole, distance for an equirect camera) are projected into every input (with its pose);
//     an input sees past a point when its depth there (nearest pixel) is above the point's by
//     more than the relative `tolerance`, or +inf; a point outside an input's image, behind it or
//     on unknown depth is not seen by it. Every point some input sees must be seen past by one of
//     them; else the pixel is undecided (state 0: a hole for the inpainting). Without it, a pixel
//     of a surface that no input sees (self-occluded, behind another part) took the colour of the
//     background that a displaced input sees beside the object.
// state (H, W) is written at every pixel: at a hole pixel 0 no input decided, 1 an input saw a
// surface there (or background too near a surface), 2 background: its colour written into
// `color`; 0 outside the holes, where `color` is neither read nor written.
//
// Shapes: hole (H, W) one byte per pixel (non-zero = hole), color (H, W, 3) float32; per input:
// depth (h, w) float32, clear (h, w) one byte (non-zero = clear), color (h, w, 3) float32, h, w
// the input camera's size. The binding (cpp/bindings/inpaint.cpp) checks them. Multithreaded over
// rows with ibr::ParallelFor; every pixel is independent, so the result is the same for any
// thread count. Nothing is allocated or thrown.
#pragma once
#include <cmath>
#include <cstdint>

#include "ibr/camera.h"
#include "ibr/image.h"

namespace ibr {

// The target's ray, searched for surfaces between near and far (background.h header).
struct BackgroundRay {
  static constexpr int kRaySamples = 64;
  double near = 0.0, far = 0.0;  // no ray test unless 0 < near < far
  double tolerance = 0.01;       // relative depth margin of a free point

  bool Active() const { return near > 0.0 && far > near && std::isfinite(far); }
};

struct BackgroundInput {
  Camera camera;                         // the direction: rotation and intrinsics; the ray test: its pose
  ImageView<const float> depth;          // (h, w)
  ImageView<const std::uint8_t> clear;   // (h, w)
  ImageView<const float> color;          // (h, w, 3), linear
};

void BackgroundLookupKernel(const Camera& target, const BackgroundInput* inputs, int num_inputs,
                            const BackgroundRay& ray, const ImageView<const std::uint8_t>& hole,
                            const ImageView<float>& color, const ImageView<std::uint8_t>& state);

}  // namespace ibr
