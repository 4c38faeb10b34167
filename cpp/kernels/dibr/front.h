// The dibr family's checked front (Python: ibrtools.dibr.method through cpp/bindings/dibr.cpp): the
// value checks of the warp's inputs and outputs (typed errors of cpp/ibr/errors.h), and the
// streaming accumulator that owns a target's running sums and the warp's scratch, with a pool of
// one spare storage. Callable from C++ without Python; the binding only converts arrays and calls these.
// Shapes and conventions: forward_warp.h, blend.h.
#pragma once
#include <cstdint>
#include <memory>
#include <string>

#include "ibr/camera.h"
#include "ibr/image.h"
#include "kernels/dibr/blend.h"
#include "kernels/dibr/forward_warp.h"

namespace ibr {

// Throws BadValueError when any of the n colour values is NaN or infinite.
void DibrCheckFiniteColor(const float* color, std::int64_t n);

// Throws BadValueError for the input errors a warp counted (bad depth, no valid depth).
void DibrCheckCounts(const WarpCounts& counts);

// As DibrCheckCounts for the hole-mode warps, non-finite flow vectors first.
void DibrCheckHoleCounts(const WarpCounts& counts);

// Throws BadValueError unless stretch_threshold is finite and > 0 and depth_jump finite and >= 0.
void DibrCheckHoleWarpOptions(const HoleWarpOptions& options);

// Throws BadValueError unless side_threshold is finite and >= 0 (0 = auto), blend_exponent in
// [0, 16] and view_weight in [1e-6, 1] (each named by its field).
void DibrCheckWarpOptions(const WarpOptions& options);

// The names of WarpOptions' enums ("side", "shape", "depth", "normal"; "combined", "nearest")
// and back (BadValueError naming the option and the names it takes).
const char* WarpQualityName(WarpQuality quality);
WarpQuality WarpQualityFromName(const std::string& name);
const char* DepthTestName(DepthTest test);
DepthTest DepthTestFromName(const std::string& name);

// Visibility across views of the streaming blend (blend.h; all off = RVS).
struct DibrAccumulatorOptions {
  float stretched_quality = 0.f;  // in [0, 1]: fragments with q below it are stretched
  bool stretched_holes = false;   // pixels only stretched fragments cover become holes (needs stretched_quality > 0)
  float depth_tolerance = 0.f;    // in [0, 1): relative; a nearer fragment replaces the sums, a farther one is dropped
  void Check() const;             // throws BadValueError
};

struct DibrAccumulatorStorage;

// Streaming DIBR into one target camera: AddView warps a colour + depth view and adds it to the
// running sums (constant memory); Resolve blends (paper Eq. 3). The sums and the warp's scratch
// come from a pool of one spare storage: the renderer makes a new accumulator per frame, and 58 MB
// of new sums + 25 MB of new vertex scratch at 1080p cost page faults (the kernel zeroes every page
// on first touch) in each frame's first views -- about 20 ms of CPU per frame, measured. A new accumulator of the same target size takes the spare (any bits in the sums are
// fine: they start fresh); one of another size frees it. So at most one unused set (83 MB at
// 1080p) stays allocated. Not thread-safe: one call at a time per object.
class DibrAccumulator {
 public:
  DibrAccumulator(const Camera& target, const DibrAccumulatorOptions& options);  // options.Check() first
  ~DibrAccumulator();
  DibrAccumulator(const DibrAccumulator&) = delete;
  DibrAccumulator& operator=(const DibrAccumulator&) = delete;

  // color (H, W, 3) and depth (H, W) of camera's size (checked by the caller). The view is added only
  // when its colour is finite and its depth valid; else throws BadValueError (after the warp).
  void AddView(const ImageView<const float>& color, const ImageView<const float>& depth, const Camera& camera,
               const WarpOptions& options);
  // color (H, W, 3), depth, confidence (H, W), hole (H, W) one byte per pixel, of the target's size.
  // srgb_to_linear: the added colours were sRGB encodings (BlendSpace::kSrgb).
  void Resolve(float* color, float* depth, float* confidence, std::uint8_t* hole, bool srgb_to_linear);
  // The next view writes the sums instead of adding to them (BlendBuffers::fresh): no clearing pass.
  void Reset();

  int num_views() const { return num_views_; }
  double last_add_ms() const { return last_ms_; }  // wall time of the last AddView's warp + accumulation
  const Camera& target() const { return target_; }

 private:
  Camera target_;
  std::unique_ptr<DibrAccumulatorStorage> storage_;  // sums (uninitialised: fresh) and scratch
  BlendBuffers buffers_;
  int num_views_ = 0;
  double last_ms_ = 0.0;
};

}  // namespace ibr
