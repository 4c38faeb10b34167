// The inpaint family's checked front (Python: ibrtools.inpaint through cpp/bindings/inpaint.cpp):
// the value checks of push-pull's options, inputs and flow and of the hole sides' ratio, and the
// kernel calls whose statuses become the typed errors of cpp/ibr/errors.h ("every pixel is a
// hole"). Callable from C++ without Python; the binding checks array dtypes and shapes
// (bindings/array.h), converts and calls these. Shapes and conventions: pushpull.h and metameric.h.
#pragma once
#include <cstdint>

#include "ibr/image.h"
#include "kernels/inpaint/hole_sides.h"
#include "kernels/inpaint/metameric.h"
#include "kernels/inpaint/pushpull.h"

namespace ibr {

// Push-pull's options: depth_threshold and gamma finite and >= 0 (BadValueError naming them).
PushPullOptions InpaintPushPullOptions(bool depth_aware, double depth_threshold, double gamma,
                                       bool holes_only = false);

// HoleSidesKernel after checking occluder_ratio: 0 or finite and > 1 (BadValueError naming it).
void InpaintHoleSides(const ImageView<const std::uint8_t>& hole, const ImageView<const std::uint8_t>& background,
                      const ImageView<const float>& known_depth, double occluder_ratio,
                      const ImageView<std::uint8_t>& sides, const ImageView<float>& around);

// PushPullKernel after checking `image` finite outside the holes (BadValueError naming "image");
// BadValueError when every pixel is a hole, or when `write` (the hole pixels to write) is given
// without options.holes_only. Returns true when the image had no hole.
bool InpaintPushPull(const ImageView<const float>& image, const ImageView<const std::uint8_t>& hole,
                     const ImageView<const float>& depth, const PushPullOptions& options,
                     const ImageView<float>& out,
                     const ImageView<const std::uint8_t>& write = ImageView<const std::uint8_t>());

// PushPullMomentsKernel after checking every band finite outside the mask (BadValueError naming
// "bands[i]"); BadValueError when every sample is masked.
void InpaintPushPullMoments(const ImageView<const float>* bands, int k, const ImageView<const std::uint8_t>& mask,
                            const ImageView<const float>& depth, const PushPullOptions& options,
                            const ImageView<float>& out);

// PushPullMomentsChangeKernel with the same checks (the bands' scan only with check_finite).
void InpaintPushPullChange(const ImageView<const float>* bands, int k, const ImageView<const std::uint8_t>& mask,
                           const ImageView<const float>& depth, const PushPullOptions& options,
                           const MetamericSynth& synth, bool check_finite);

// The noise flow of a level of h x w samples read at `scale`: scale >= 1, and (when flow is
// set) a full-resolution flow of at least ((h - 1) scale + 1) x ((w - 1) scale + 1) pixels
// (ShapeError), every value finite (BadValueError).
void InpaintCheckFlow(const MetamericFlow& flow, int h, int w, int scale);

}  // namespace ibr
