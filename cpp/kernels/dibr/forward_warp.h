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
// Rasterisation. Vertex positions are snapped to 1/256 pixel; integer edge functions, sampled at
// pixel centres (x + 0.5, y + 0.5). Fill rule of the DIBR shader (ForwardWarp): inclusive edges
// -- a centre exactly on an edge (or vertex) is inside every triangle that has it, so a centre on
// an edge shared by two triangles of the view is offered to both and the within-view depth test
// below keeps one of them (no double blending: one fragment per pixel per view; no cracks). This
// matters in rectified pairs (Middlebury), where every target centre lies exactly on a horizontal
// edge: with an exclusive rule the sample was lost whenever its one owning triangle was dropped
// (unknown depth) or stretched. The hole mode (WarpWithHoles below) keeps the exclusive
// top-left-style tie rule (an edge owns its points iff dy > 0, or dy == 0 and dx < 0, so of two
// triangles sharing an edge exactly one owns it: no cracks, no double coverage). Triangles whose winding is reversed in the target
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
// target y and x ranges of each input row's 16-column segments; a counting sort then lists, per
// 32-row target band, the block-row segments whose y range reaches it and whose x range reaches
// the image (segments wholly left or right of the target are never scanned), in input order; pass 2
// rasterises each band (bands own their pixels) from its list, triangles in input order (no
// per-triangle bins). The partition depends on the image sizes only, so results are
// bit-identical for any thread count.
#pragma once
#include <cstdint>
#include <vector>

#include "ibr/camera.h"
#include "ibr/image.h"
#include "kernels/dibr/blend.h"

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
  // A factor on every fragment weight of the view, w = view_weight * (q / d)^p, in [1e-6, 1]: a
  // per-view blending weight (e.g. by the input camera's distance to the target, as MPEG's VSRS
  // weights its two views; docs/dibr.md). 1 = RVS. Never changes which fragment a view keeps.
  float view_weight = 1.f;
};

// Instruction set of the hot loops (vertex projection, rasterisation): the engine is built for
// the SSE2 baseline; on a CPU with AVX2 (checked at run time) versions compiled for AVX2 run
// instead (no FMA: bit-identical results), as the engine's process-wide switch says (cpp/ibr/simd.h
// SetIsa / UseAvx2; _core.set_warp_isa).

// Side threshold used for a target camera (auto rule above when options.side_threshold == 0).
float SideThreshold(const WarpOptions& options, const Camera& target);

// One projected input pixel. Array of structs: a triangle reads its three vertices from two
// cache lines (rows v and v + 1) instead of six with one array per field.
struct WarpVertex {
  std::int32_t x, y;  // target position, 1/256 px (x = INT32_MIN: invalid)
  float inv;          // 1 / target depth (0 = infinite)
};

// Target y and x (1/256 px) ranges of a run of projected vertices (lo > hi: none valid).
struct YRange {
  std::int32_t lo, hi;
  std::int32_t x_lo, x_hi;
};

// Working memory of the warp, grown (never shrunk) by ForwardWarp and reused across views.
struct WarpScratch {
  std::vector<WarpVertex> verts;              // per input pixel
  std::vector<double> ray_x;                  // per input column (pinhole source)
  std::vector<double> lon_sin, lon_cos;       // per input column (equirect source): sin, cos of the longitude
  std::vector<YRange> seg_y;                  // per input row, per column segment
  std::vector<std::uint32_t> seg_bands;       // per block row segment: first, last band
  std::vector<std::uint32_t> band_start;      // per band: start in band_segs (+ end)
  std::vector<std::uint32_t> band_fill;
  std::vector<std::uint32_t> band_segs;       // per band: segment ids (row * segments + s)
  std::vector<std::uint32_t> band_order;      // bands by decreasing segment count (the task order)
  std::vector<float> score;                   // per target pixel: q / d^3 of the kept fragment
  std::vector<double> depth_key;              // hole mode, per target pixel: Eq. 1 key of the kept fragment
};

struct WarpCounts {
  std::int64_t valid_vertices = 0;  // input pixels with a usable depth (> 0, not NaN)
  std::int64_t bad_depths = 0;      // NaN or negative depths (the front rejects these)
  std::int64_t covered_pixels = 0;  // target pixels written (hole mode: surface pixels)
  std::int64_t disoccluded_pixels = 0;  // hole mode: pixels only stretched quads cover
  std::int64_t bad_flow = 0;        // flow form: non-finite flow vectors (the front rejects these)
  std::int64_t bad_colors = 0;      // with check_color: NaN or infinite colour values (the front rejects these)
};

// color (H, W, 3) and depth (H, W) of the input, `source` camera of size W x H; outputs of the
// target size: color (Ht, Wt, 3), depth (Ht, Wt) (0 = not covered), weight (Ht, Wt) (0 = not
// covered), quality (Ht, Wt) (q of the kept fragment, 0 = not covered; required).
// With `accumulate` non-null, each finished band is added to those sums (AccumulateRows) in
// the band's own task (one pass over the view's pixels while they are in cache), unless the
// depth has NaN / negative values or no valid value (counts tell; the front then raises).
// Weights are clamped to [1e-30, 1e30] so that sums over views stay finite.
// Band-local mode: with `accumulate` non-null, out_color.data may be null (then out_depth,
// out_weight and out_quality are not used either): the view is drawn band by band into
// per-thread buffers of one band and only added to the sums (no full-size per-view buffers:
// less memory traffic; the same sums, bit for bit). A rejected view then draws nothing.
// check_color: count the colour values that are NaN or infinite (counts.bad_colors; in the
// projection pass, rows in parallel, instead of a serial pass before the call); a view with any
// is not added to the sums either (the front then raises).
// Never throws (beyond std::bad_alloc from the scratch and the per-thread band buffers).
#define IBR_FORWARD_WARP_BAND_LOCAL 1
#define IBR_FORWARD_WARP_CHECK_COLOR 1  // check_color exists (benchmarks/dibr_ab builds older kernels too)
WarpCounts ForwardWarp(const ImageView<const float>& color, const ImageView<const float>& depth,
                       const Camera& source, const Camera& target, const WarpOptions& options,
                       WarpScratch& scratch, const ImageView<float>& out_color,
                       const ImageView<float>& out_depth, const ImageView<float>& out_weight,
                       float* out_quality, const BlendBuffers* accumulate = nullptr, bool check_color = false);

// ---- Warp with background-depth holes ---------------------------------------------------------
// dos Anjos et al., "Metameric Inpainting for Image Warping", sec. 3.1, Eq. 1. One RGB-D view is
// warped into a target camera (or by a per-pixel flow field) with the rasteriser above (same
// implicit mesh, projection, 1/256 px snap, edge functions, back-face and seam
// rules, band-parallel deterministic structure; the exclusive tie rule) and a different shader:
//
// Stretched quad. A quad (2x2 input pixel centres = the mesh's two triangles) is stretched when
// the longest of its five edges (4 sides + the diagonal) in the target is longer than
// HoleWarpOptions::stretch_threshold pixels: the paper's "when a quad stretches more than a
// threshold it means it connects foreground and background" (a quad that is not stretched in the
// image is a surface, whatever its depth spread) AND its corners' depths differ by more than a
// factor 1 + depth_jump (the "connects foreground and background" part, checked rather than
// assumed: without it a smooth surface magnified by a larger view change -- a ground plane seen
// at a grazing angle -- turns into a disocclusion; depth_jump = 0 is the stretch test alone).
// One decision per quad: both triangles get it.
//
// Depth convention. The paper draws into Unity's reversed-Z buffer (larger value = nearer) and
// writes "the minimum of the depth of all four vertices" into a stretched quad: that is the
// FARTHEST corner, the background. Our depth is metric (z for a pinhole target, ray distance for
// equirect; larger = farther), so a stretched quad is written flat (no interpolation) with the
// LARGEST corner depth = the smallest 1/z of its valid corners (+inf if a corner is at infinity).
//
// Depth re-partitioning, Eq. 1, with d = z / (1 + z) in [0, 1] (monotone in z, +inf -> 1):
//   d_r = 0.5 d        unstretched (interpolated d, perspective-correct as in DIBR)
//   d_r = 1 - 0.5 d    stretched   (d of the background depth above)
// and the depth test keeps the SMALLEST d_r (in our conventional direction; this is how Eq. 1's
// text reads: "stretched quads have greater depth values ... and will always fail the depth
// test", "the quad with the greater raw depth value d will be drawn"). Hence unstretched content
// always beats stretched content, nearer unstretched content beats farther (a plain z-buffer; no
// triangle quality here: the quality of DIBR's Eq. 2 is what separates stretched from unstretched,
// and that is now exact), and where stretched quads overlap the FARTHEST one wins. Keys are
// doubles (distinct depths keep distinct keys); d = 1 in the stretched branch is lifted to the
// next double above 0.5 so that the two ranges never touch. Ties: the first fragment in input
// order is kept (strict <), as in DIBR.
//
// Outputs of the target size: colour (Ht, Wt, 3) (0 in holes), depth (Ht, Wt) (metric: surface
// depth on kMaskSurface, the background depth on kMaskDisoccluded, 0 on kMaskUncovered) and a
// mask (Ht, Wt) uint8 with the codes below. The paper's un-partitioning of the depth for the
// inpainting is the identity here: the output depth is already metric.
//
// Flow form (temporal up-sampling): the source pixel centre (u + 0.5, v + 0.5) moves to
// (u + 0.5 + flow[v][u][0], v + 0.5 + flow[v][u][1]) (target - source, pixels; target size =
// source size); 1 / depth orders the fragments and is interpolated as above. Depth 0 = unknown
// (vertex dropped); non-finite flow is counted in WarpCounts::bad_flow (the front raises).
constexpr std::uint8_t kMaskSurface = 0, kMaskDisoccluded = 1, kMaskUncovered = 2;
constexpr float kDefaultStretchThreshold = 2.f;
constexpr float kDefaultDepthJump = kDepthVariation;

struct HoleWarpOptions {
  // Longest target edge (pixels) of an unstretched quad. An undistorted quad has edges of 1 px
  // and a diagonal of sqrt(2) = 1.41 px; 2 px lets a view change magnify the surface by up to
  // 1.41x before it opens holes, and makes every gap wider than about one pixel a hole.
  float stretch_threshold = kDefaultStretchThreshold;
  // Relative depth spread (z_far / z_near - 1) a stretched quad must also have; 0 = off. 0.1 is
  // DIBR's kDepthVariation ("depth" quality reaches 0 at a 10 % jump between neighbours).
  float depth_jump = kDefaultDepthJump;
};

// color (H, W, 3), depth (H, W) of the `source` camera (W x H); outputs of the target's size.
// Never throws (beyond std::bad_alloc from the scratch). Counts: valid_vertices, bad_depths,
// covered_pixels (kMaskSurface), disoccluded_pixels (kMaskDisoccluded).
WarpCounts WarpWithHoles(const ImageView<const float>& color, const ImageView<const float>& depth,
                         const Camera& source, const Camera& target, const HoleWarpOptions& options,
                         WarpScratch& scratch, const ImageView<float>& out_color,
                         const ImageView<float>& out_depth, std::uint8_t* out_mask);

// Flow form: flow is (H, W, 2) float32, C order; outputs (H, W[, 3]) like the input.
WarpCounts WarpFlowWithHoles(const ImageView<const float>& color, const ImageView<const float>& depth,
                             const float* flow, const HoleWarpOptions& options, WarpScratch& scratch,
                             const ImageView<float>& out_color, const ImageView<float>& out_depth,
                             std::uint8_t* out_mask);

}  // namespace ibr
