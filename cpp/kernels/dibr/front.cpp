// The dibr family's front (front.h).
#include "kernels/dibr/front.h"

#include <chrono>
#include <cmath>
#include <cstring>
#include <mutex>
#include <string>

#include "ibr/errors.h"
#include "ibr/simd.h"

namespace ibr {

// The memory of a DibrAccumulator: the running sums of its target size (uninitialised: the sums
// start "fresh", blend.h, and the first view writes every pixel) and the warp's scratch.
struct DibrAccumulatorStorage {
  std::size_t pixels = 0;
  std::unique_ptr<float[]> sum_wc, sum_w, sum_w_invd, sum_q, max_q;
  WarpScratch scratch;
};

namespace {

void ThrowBadColor(std::int64_t bad) {
  throw BadValueError("color: " + std::to_string(bad) + " values are NaN or infinite (expected finite colour)");
}

double MsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// The spare storage (front.h DibrAccumulator), the last one a destroyed accumulator left.
std::mutex g_spare_mutex;
std::unique_ptr<DibrAccumulatorStorage> g_spare;

std::unique_ptr<DibrAccumulatorStorage> TakeStorage(std::size_t n) {
  std::unique_ptr<DibrAccumulatorStorage> s;
  {
    std::lock_guard<std::mutex> lock(g_spare_mutex);
    s = std::move(g_spare);
  }
  if (s && s->pixels == n) return s;
  s.reset();  // another size: free it before allocating
  s = std::make_unique<DibrAccumulatorStorage>();
  s->pixels = n;
  s->sum_wc.reset(new float[3 * n]);
  s->sum_w.reset(new float[n]);
  s->sum_w_invd.reset(new float[n]);
  s->sum_q.reset(new float[n]);
  s->max_q.reset(new float[n]);
  return s;
}

void ReturnStorage(std::unique_ptr<DibrAccumulatorStorage> s) {
  std::unique_ptr<DibrAccumulatorStorage> old;
  std::lock_guard<std::mutex> lock(g_spare_mutex);
  old = std::move(g_spare);  // freed after the lock is released (declared before the guard)
  g_spare = std::move(s);
}

}  // namespace

// Colour must be finite everywhere: a NaN or inf input colour would otherwise be blended into
// the output image (NaN never leaks into an output). A float is not finite when its exponent bits
// are all set; the integer OR-reduction vectorises (one pass over the colour, about a millisecond
// per 1080p view).
void DibrCheckFiniteColor(const float* p, std::int64_t n) {
  std::uint32_t any = 0;
  for (std::int64_t i = 0; i < n; ++i) {
    std::uint32_t u;
    std::memcpy(&u, p + i, sizeof u);
    any |= std::uint32_t((u & 0x7f800000u) == 0x7f800000u);
  }
  if (any) {
    std::int64_t bad = 0;
    for (std::int64_t i = 0; i < n; ++i) bad += !std::isfinite(p[i]);
    ThrowBadColor(bad);
  }
}

void DibrCheckCounts(const WarpCounts& c) {
  if (c.bad_depths > 0) {
    throw BadValueError("depth: " + std::to_string(c.bad_depths) +
                        " values are NaN or negative (expected > 0, 0 = unknown, +inf = at infinity)");
  }
  if (c.valid_vertices == 0) throw BadValueError("depth: no valid depth (every value is 0 = unknown)");
}

void DibrCheckHoleCounts(const WarpCounts& counts) {
  if (counts.bad_flow > 0) {
    throw BadValueError("flow: " + std::to_string(counts.bad_flow) + " vectors are not finite (NaN or inf)");
  }
  DibrCheckCounts(counts);
}

void DibrCheckHoleWarpOptions(const HoleWarpOptions& o) {
  if (!(o.stretch_threshold > 0.f) || std::isinf(o.stretch_threshold)) {
    throw BadValueError("stretch_threshold: expected a finite number of pixels > 0, got " +
                        std::to_string(o.stretch_threshold));
  }
  if (!(o.depth_jump >= 0.f) || std::isinf(o.depth_jump)) {
    throw BadValueError("depth_jump: expected a finite number >= 0 (0 = off), got " + std::to_string(o.depth_jump));
  }
}

void DibrCheckWarpOptions(const WarpOptions& o) {
  if (!(o.side_threshold >= 0.f) || std::isinf(o.side_threshold)) {
    throw BadValueError("side_threshold: expected a finite value >= 0 (0 = auto)");
  }
  if (!(o.blend_exponent >= 0.f && o.blend_exponent <= 16.f)) {
    throw BadValueError("blend_exponent: expected a value in [0, 16]");
  }
  if (!(o.view_weight >= 1e-6f && o.view_weight <= 1.f)) throw BadValueError("view_weight: expected a value in [1e-6, 1]");
}

const char* WarpQualityName(WarpQuality q) {
  switch (q) {
    case WarpQuality::kSide: return "side";
    case WarpQuality::kShape: return "shape";
    case WarpQuality::kDepth: return "depth";
    case WarpQuality::kNormal: return "normal";
  }
  return "?";
}

WarpQuality WarpQualityFromName(const std::string& s) {
  if (s == "side") return WarpQuality::kSide;
  if (s == "shape") return WarpQuality::kShape;
  if (s == "depth") return WarpQuality::kDepth;
  if (s == "normal") return WarpQuality::kNormal;
  throw BadValueError("quality: expected 'side', 'shape', 'depth' or 'normal', got '" + s + "'");
}

const char* DepthTestName(DepthTest t) { return t == DepthTest::kCombined ? "combined" : "nearest"; }

DepthTest DepthTestFromName(const std::string& s) {
  if (s == "combined") return DepthTest::kCombined;
  if (s == "nearest") return DepthTest::kNearest;
  throw BadValueError("depth_test: expected 'combined' or 'nearest', got '" + s + "'");
}

void DibrAccumulatorOptions::Check() const {
  if (!(stretched_quality >= 0.f && stretched_quality <= 1.f)) {
    throw BadValueError("stretched_quality: expected a number in [0, 1], got " + std::to_string(stretched_quality));
  }
  if (!(depth_tolerance >= 0.f && depth_tolerance < 1.f)) {
    throw BadValueError("depth_tolerance: expected a number in [0, 1), got " + std::to_string(depth_tolerance));
  }
  if (stretched_holes && stretched_quality == 0.f) {
    throw BadValueError("stretched_holes: needs stretched_quality > 0 to say which fragments are stretched");
  }
}

DibrAccumulator::DibrAccumulator(const Camera& target, const DibrAccumulatorOptions& options) : target_(target) {
  options.Check();
  // Not cleared: the sums start "fresh" (blend.h), the first view writes them.
  storage_ = TakeStorage(std::size_t(target.width) * target.height);
  buffers_.stretched_quality = options.stretched_quality;
  buffers_.stretched_holes = options.stretched_holes;
  buffers_.depth_tolerance = options.depth_tolerance;
  buffers_.height = target_.height;
  buffers_.width = target_.width;
  buffers_.sum_wc = storage_->sum_wc.get();
  buffers_.sum_w = storage_->sum_w.get();
  buffers_.sum_w_invd = storage_->sum_w_invd.get();
  buffers_.sum_q = storage_->sum_q.get();
  buffers_.max_q = storage_->max_q.get();
  buffers_.fresh = true;
}

DibrAccumulator::~DibrAccumulator() {
  if (storage_) ReturnStorage(std::move(storage_));
}

void DibrAccumulator::AddView(const ImageView<const float>& color, const ImageView<const float>& depth,
                              const Camera& camera, const WarpOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  // The kernel adds the view to the sums only when its colour and depth pass the checks below
  // (it counts the colour's non-finite values in its parallel projection pass). Band-local mode
  // (forward_warp.h): no per-view full-size buffers.
  const WarpCounts counts = ForwardWarp(color, depth, camera, target_, options, storage_->scratch, ImageView<float>(),
                                        ImageView<float>(), ImageView<float>(), nullptr, &buffers_, true);
  if (counts.bad_depths == 0 && counts.valid_vertices > 0 && counts.bad_colors == 0) {
    ++num_views_;
    buffers_.fresh = false;  // the view wrote every pixel's sums
  }
  last_ms_ = MsSince(t0);
  if (counts.bad_colors > 0) ThrowBadColor(counts.bad_colors);
  DibrCheckCounts(counts);
}

void DibrAccumulator::Resolve(float* color, float* depth, float* confidence, std::uint8_t* hole, bool srgb_to_linear) {
  if (buffers_.fresh) {  // no view since Reset(): empty sums
    ClearBlend(buffers_);
    buffers_.fresh = false;
  }
  ResolveBlend(buffers_, color, depth, confidence, hole, UseAvx2(),
               srgb_to_linear ? BlendSpace::kSrgb : BlendSpace::kLinear);
}

void DibrAccumulator::Reset() {
  buffers_.fresh = true;
  num_views_ = 0;
}

}  // namespace ibr
