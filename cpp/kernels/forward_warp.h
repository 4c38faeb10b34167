// Forward mesh warp of one colour + depth view into a target camera (depth-image-based
// rendering, Bonatto et al. 2021, "Real-Time Depth Video-Based Rendering for 6-DoF HMD
// Navigation and Light Field Displays", sections III-A and III-B1; MPEG RVS 4.0 defaults).
//
// Mesh. The input pixel grid is an implicit triangle mesh: pixel centres (u + 0.5, v + 0.5)
// are vertices, each 2x2 block of centres gives two triangles with one consistent diagonal,
//   triangle 0 = (u, v), (u+1, v), (u, v+1);  triangle 1 = (u+1, v), (u+1, v+1), (u, v+1).
// Vertices are un-projected with Camera::RayInCam (pinhole: z-depth, equirect: ray distance)
// and projected into the target with Camera::ProjectCam. Depth 0 (unknown) or a failed
// projection (behind a pinhole target) invalidates a vertex; triangles touching an invalid
// vertex are dropped (never clipped: a straddling triangle would cover the screen). Depth
// +inf (sky of an equirect view) is a direction: it is rotated into the target, not moved.
//
// Rasterisation. Vertex positions are snapped to 1/256 pixel; integer edge functions with a
// top-left-style tie rule (an edge owns its points iff dy > 0, or dy == 0 and dx < 0, so of two
// triangles sharing an edge exactly one owns it): no cracks, no double coverage. Sampled at
// pixel centres (x + 0.5, y + 0.5). Triangles whose winding is reversed in the target
// (back-facing) or whose snapped area is 0 are discarded; on an equirect target, triangles
// spanning more than half the width straddle the longitude seam and are dropped. Vertices more
// than 16384 px outside the image drop their triangle (fixed-point range).
// Interpolation: barycentrics of 1/d and c/d are linear in screen space, hence depth
// d = 1 / sum(b_i / d_i) and colour = sum(b_i c_i / d_i) * d: exact (perspective-correct) for a
// pinhole target (d = z). For an equirect target (d = ray distance) the same formula is used:
// exact in the limit of small triangles (the projection is smooth; our triangles span about a
// pixel), documented approximation otherwise. Triangles with an infinite vertex: all three
// infinite -> affine colour, depth +inf; mixed finite/infinite -> dropped.
//
// Quality q in (0, 1] per triangle (paper Table 1; all floored at kQualityFloor, never 0,
// as RVS -- unless WarpOptions::discard_stretched):
//   side   q = 1 - L / T, L = longest edge in target pixels; T = side_threshold or, when 0,
//          T = max(4, 10 * sqrt(W * H / (1920 * 1080))) (RVS: q = 10000 - 1000 L at 1080p, i.e.
//          T = 10 px there, scaled with the target's linear resolution as the paper asks; the
//          paper's own T = 15 at 1200x1080 per eye is the same order). The floor of 4 px keeps
//          undistorted triangles (L = sqrt 2) at q >= 0.65 in small targets.
//   shape  q = 4 sqrt(3) area / (sum of squared edges) (1 = equilateral, -> 0 for slivers),
//          divided by its value 0.866 for the undistorted grid triangle and clamped to 1.
//   depth  q = 1 - (d_max - d_min) / (kDepthVariation * d_min) over the triangle's input depths
//          (a relative jump of kDepthVariation = 10 % between neighbouring pixels = discontinuity).
//   normal q = |cos| of the angle between the triangle's normal and the input camera's ray to
//          it (triangles seen edge-on by the input camera lie on disocclusions).
// Depth test within the view (paper Eq. 2, RVS): a fragment wins if q / d^3 > q_old / d_old^3,
// i.e. (d_new / d_old)^3 q_old < q_new: foreground first, stretched triangles last
// (DepthTest::kCombined); DepthTest::kNearest is the plain z-buffer for comparison.
// Weight of the winning fragment (RVS BlendingFactor): w = (q / d)^p, p = blend_exponent (5; the
// paper's Eq. 2 is q / d^3). d is clamped to [1e-6, 1e6] in q / d^3 and in w so that both stay
// finite float (infinite depth gets the smallest weight).
//
// Parallel and deterministic: pass 1 projects vertices (rows in parallel) and records the
// target y range of each input row's 16-column segments; a counting sort then lists, per
// 32-row target band, the block-row segments whose y range reaches it, in input order; pass 2
// rasterises each band (bands own their pixels) from its list, triangles in input order (no
// per-triangle bins). The partition depends on the image sizes only, so results are
// bit-identical for any thread count.
#pragma once
#include <cstdint>
#include <vector>

#include "ibr/camera.h"
#include "ibr/image.h"
#include "kernels/blend.h"

namespace ibr {

enum class WarpQuality : int { kSide = 0, kShape = 1, kDepth = 2, kNormal = 3 };
enum class DepthTest : int { kCombined = 0, kNearest = 1 };

constexpr float kQualityFloor = 1e-4f;   // RVS: q = clamp(10000 - 1000 L, 1, 10000) / 10000
constexpr float kDepthVariation = 0.1f;  // "depth" quality: relative jump that gives q = 0
constexpr double kMinAutoSide = 4.0;   // floor of the automatic T, pixels
constexpr float kMinWeightDepth = 1e-6f, kMaxWeightDepth = 1e6f;

struct WarpOptions {
  WarpQuality quality = WarpQuality::kSide;
  float side_threshold = 0.f;     // T in target pixels; 0 = auto (see above)
  float blend_exponent = 5.f;     // p in w = (q / d)^p (RVS); the paper's Eq. 2 is q / d^3
  DepthTest depth_test = DepthTest::kCombined;
  bool discard_stretched = false; // paper Eq. 1: drop triangles whose quality reaches 0
};

// Side threshold used for a target camera (auto rule above when options.side_threshold == 0).
float SideThreshold(const WarpOptions& options, const Camera& target);

// One projected input pixel. Array of structs: a triangle reads its three vertices from two
// cache lines (rows v and v + 1) instead of six with one array per field.
struct WarpVertex {
  std::int32_t x, y;  // target position, 1/256 px (x = INT32_MIN: invalid)
  float inv;          // 1 / target depth (0 = infinite)
};

// Target y (1/256 px) range of a run of projected vertices (lo > hi: none valid).
struct YRange {
  std::int32_t lo, hi;
};

// Working memory of the warp, grown (never shrunk) by ForwardWarp and reused across views.
struct WarpScratch {
  std::vector<WarpVertex> verts;              // per input pixel
  std::vector<double> ray_x;                  // per input column (pinhole source)
  std::vector<YRange> seg_y;                  // per input row, per column segment
  std::vector<std::uint32_t> seg_bands;       // per block row segment: first, last band
  std::vector<std::uint32_t> band_start;      // per band: start in band_segs (+ end)
  std::vector<std::uint32_t> band_fill;
  std::vector<std::uint32_t> band_segs;       // per band: segment ids (row * segments + s)
  std::vector<float> score;                   // per target pixel: q / d^3 of the kept fragment
};

struct WarpCounts {
  std::int64_t valid_vertices = 0;  // input pixels with a usable depth (> 0, not NaN)
  std::int64_t bad_depths = 0;      // NaN or negative depths (the front rejects these)
  std::int64_t covered_pixels = 0;  // target pixels written
};

// color (H, W, 3) and depth (H, W) of the input, `source` camera of size W x H; outputs of the
// target size: color (Ht, Wt, 3), depth (Ht, Wt) (0 = not covered), weight (Ht, Wt) (0 = not
// covered), quality (Ht, Wt) (q of the kept fragment, 0 = not covered; required).
// With `accumulate` non-null, each finished band is added to those sums (AccumulateRows) in
// the band's own task (one pass over the view's pixels while they are in cache), unless the
// depth has NaN / negative values or no valid value (counts tell; the front then raises).
// Weights are clamped to [1e-30, 1e30] so that sums over views stay finite.
// Never throws (beyond std::bad_alloc from the scratch).
WarpCounts ForwardWarp(const ImageView<const float>& color, const ImageView<const float>& depth,
                       const Camera& source, const Camera& target, const WarpOptions& options,
                       WarpScratch& scratch, const ImageView<float>& out_color,
                       const ImageView<float>& out_depth, const ImageView<float>& out_weight,
                       float* out_quality, const BlendBuffers* accumulate = nullptr);

}  // namespace ibr
