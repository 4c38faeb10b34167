// The inpaint family's checked front (front.h).
#include "kernels/inpaint/front.h"

#include <cmath>
#include <string>

#include "ibr/checks.h"
#include "ibr/errors.h"

namespace ibr {

PushPullOptions InpaintPushPullOptions(bool depth_aware, double depth_threshold, double gamma, bool holes_only) {
  if (!(std::isfinite(gamma) && gamma >= 0.0)) {
    throw BadValueError("gamma: expected a finite number >= 0, got " + std::to_string(gamma));
  }
  if (!(std::isfinite(depth_threshold) && depth_threshold >= 0.0)) {
    throw BadValueError("depth_threshold: expected a finite number >= 0, got " + std::to_string(depth_threshold));
  }
  PushPullOptions options;
  options.gamma = static_cast<float>(gamma);
  options.depth_threshold = static_cast<float>(depth_threshold);
  options.depth_aware = depth_aware;
  options.holes_only = holes_only;
  return options;
}

void InpaintHoleSides(const ImageView<const std::uint8_t>& hole, const ImageView<const std::uint8_t>& background,
                      const ImageView<const float>& known_depth, double occluder_ratio,
                      const ImageView<std::uint8_t>& sides, const ImageView<float>& around) {
  if (!(occluder_ratio == 0.0 || (std::isfinite(occluder_ratio) && occluder_ratio > 1.0))) {
    throw BadValueError("occluder_ratio: expected 0 (no occluders) or a finite ratio > 1, got " +
                        std::to_string(occluder_ratio));
  }
  HoleSidesKernel(hole, background, known_depth, occluder_ratio, sides, around);
}

bool InpaintPushPull(const ImageView<const float>& image, const ImageView<const std::uint8_t>& hole,
                     const ImageView<const float>& depth, const PushPullOptions& options,
                     const ImageView<float>& out, const ImageView<const std::uint8_t>& write) {
  if (!write.Empty() && !options.holes_only) {
    throw BadValueError("write: only with holes_only (the pixels outside the holes would be written)");
  }
  if (const std::int64_t bad = CountNonFiniteOutsideHoles(image, hole)) {
    throw BadValueError("image: contains " + std::to_string(bad) + " NaN or infinite values outside the holes");
  }
  const PushPullStatus status = PushPullKernel(image, hole, depth, options, out, write);
  if (status == PushPullStatus::kNoValidPixel) {
    throw BadValueError("hole: every pixel is a hole; push-pull needs at least one pixel outside the holes");
  }
  return status == PushPullStatus::kNoHole;
}

namespace {

void CheckBandsFinite(const ImageView<const float>* bands, int k, const ImageView<const std::uint8_t>& mask) {
  for (int i = 0; i < k; ++i) {
    if (const std::int64_t bad = CountNonFiniteOutsideHoles(bands[i], mask)) {
      throw BadValueError("bands[" + std::to_string(i) + "]: contains " + std::to_string(bad) +
                          " NaN or infinite values outside the mask");
    }
  }
}

void ThrowIfAllMasked(PushPullStatus status) {
  if (status == PushPullStatus::kNoValidPixel) {
    throw BadValueError("mask: every sample is masked; the moments need samples outside the mask");
  }
}

}  // namespace

void InpaintPushPullMoments(const ImageView<const float>* bands, int k, const ImageView<const std::uint8_t>& mask,
                            const ImageView<const float>& depth, const PushPullOptions& options,
                            const ImageView<float>& out) {
  CheckBandsFinite(bands, k, mask);
  ThrowIfAllMasked(PushPullMomentsKernel(bands, k, mask, depth, options, out));
}

void InpaintPushPullChange(const ImageView<const float>* bands, int k, const ImageView<const std::uint8_t>& mask,
                           const ImageView<const float>& depth, const PushPullOptions& options,
                           const MetamericSynth& synth, bool check_finite) {
  if (check_finite) CheckBandsFinite(bands, k, mask);
  ThrowIfAllMasked(PushPullMomentsChangeKernel(bands, k, mask, depth, options, synth));
}

void InpaintCheckFlow(const MetamericFlow& flow, int h, int w, int scale) {
  if (scale < 1) throw BadValueError("scale: expected an integer >= 1, got " + std::to_string(scale));
  if (flow.f32 == nullptr && flow.f64 == nullptr) return;
  if (std::int64_t(h - 1) * scale >= flow.height || std::int64_t(w - 1) * scale >= flow.width) {
    throw ShapeError("flow: expected the full-resolution flow of a level of " + std::to_string(h) + "x" +
                     std::to_string(w) + " samples at scale " + std::to_string(scale) + " (at least " +
                     std::to_string((h - 1) * scale + 1) + "x" + std::to_string((w - 1) * scale + 1) +
                     " pixels), got (" + std::to_string(flow.height) + ", " + std::to_string(flow.width) + ", 2)");
  }
  const std::int64_t n = std::int64_t(flow.height) * flow.width * 2;
  const std::int64_t bad = flow.f64 ? CountNonFiniteValues(flow.f64, n) : CountNonFiniteValues(flow.f32, n);
  if (bad) throw BadValueError("flow: contains " + std::to_string(bad) + " NaN or infinite values");
}

}  // namespace ibr
