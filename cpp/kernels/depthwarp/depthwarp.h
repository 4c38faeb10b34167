// Iterative backward depth warping (Lee, Kim, Eisemann 2018, "Iterative Depth Warping",
// ../shared/papers/001_*, sections 3 and 4.1) and the forward baselines it is compared with.
// Python: ibrtools.depthwarp.core (the checking front is cpp/bindings/depthwarp.cpp).
//
// Conventions: cameras are ibr::Camera pinhole (OpenCV axes, pixel centres at +0.5); depth is z
// in the camera, float32, 0 = empty. A "packed" motion buffer is (H, W, 4) float32 per source
// pixel: (mx, my, z_dst, 0) with (mx, my) = target position - source pixel centre in pixels and
// z_dst the z of the moved point in the target camera; z_dst = 0 (and motion 0) marks an invalid
// pixel (empty, or landing at / behind the target's image plane, or moving by more than
// kDepthWarpMaxMotion pixels, which cannot land in any image).
//
// DepthWarpMotion (sec. 3.1): exact per-pixel reprojection (unproject with the source depth and
//   camera, optional rigid per-object motion new_world_from_old_world selected by an object id,
//   project into the target) - not finite differences.
//
// DepthWarpChooseAxes + DepthWarpMipLevel1 / DepthWarpMipDown (sec. 3.3): min-max motion
//   mipmaps. The motion is first rotated by `rot` (identity = axis-aligned bound; PCA axes for the
//   oriented bound). Level l >= 1 (ceil(H / 2^l), ceil(W / 2^l), 4) holds (min u, min w, max u,
//   max w) of the rotated motion over the valid pixels of its 2^l x 2^l block clipped to the image
//   (non-power-of-two sizes: the last texel covers the pixels that exist, so every texel is a
//   conservative bound of its block); a texel without valid pixels holds (+inf, +inf, -inf, -inf).
//   A parallel min-z mipmap holds the smallest z_dst of the block's valid pixels (+inf if none).
//   Level 0 is the packed buffer itself (read on the fly). The last level is 1 x 1: the global bound.
//
// DepthWarpBackward (sec. 3.2-3.4, Fig. 3, 5, 6): per target pixel p (centre) and source layer j:
//   bound  B = global bound of layer j; "tight": `steps` narrowing steps (Fig. 5): the source region
//          P - R^T B (its axis-aligned box, clipped to the source image) of extent e gets four corner
//          lookups at level ceil(log2 e) (at most the last level); B := B ∩ union of the four texels
//          (the intersection keeps the bound conservative: the true source's motion is in every
//          bound). An empty bound or a region outside the source means no source: layer skipped.
//          Deviation for speed: the `steps` steps run once per options.tile^2 tile of target
//          pixels (P = the tile's pixel centres, so the tile bound is conservative for each pixel),
//          then one more step per pixel (P = p) from the tile bound, skipped when the tile bound is
//          already below early_exit. "global": B = the global bound, no narrowing.
//   seeds  early exit (one seed at the bound centre) when the bound's extent < early_exit px, else
//          N seeds stratified over B (Hammersley points, Cranley-Patterson rotated by a hash of
//          (seed, pixel, layer): deterministic). q0 = p - R^T u.
//   search q_{k+1} = p - V(q_k), nearest lookup (the motion of the source pixel containing q; a
//          bilinear lookup would blend motions across depth discontinuities and converge to points
//          that do not exist); converged when |q + V(q) - p| < threshold, checked at the seed and
//          after each of the `iters` updates (iters + 1 lookups at most). A lookup outside the
//          source image fails the sample (rejected, not clamped: a clamped edge motion would
//          "converge" to a wrong depth). Cross-layer seeding (Fig. 6): a lookup that lands on an
//          empty pixel of layer j moves up to the nearest non-empty layer above (towards the
//          camera); the second empty landing of a sample fails it.
//   result the nearest converged z_dst over all layers and seeds; layer_out = the layer the sample
//          came from; 0 / -1 where nothing converged (a hole, never a guessed depth).
//   proof  (proven_out, not in the paper; for occlusion culling, docs/culling.md) a converged sample
//          says that the surface of source pixel S moves to within the threshold of p, not that it
//          covers p: at a silhouette it lands up to ~threshold + half a pixel beyond the surface's
//          edge, and two neighbouring occluders close a sub-pixel gap between them. A sample of S
//          (layer l, surface id k = layers[l].surface at S, k >= 0) proves p when p lies inside the
//          moved triangle of three source pixel centres of layer l with surface id k, one of them S,
//          from the 2x2 pixel quads around S. If surface k is convex (the culling's objects: boxes,
//          planes, cylinders), the three points lie on it, so their triangle lies inside it: p's ray
//          meets surface k no farther than the triangle's farthest corner z_dst. proven_out = the
//          least such bound over every converged sample of every searched layer (an upper bound of
//          the depth seen at p), 0 where nothing is proven. A silhouette's outer band (up to one
//          source pixel) and every seam between two surfaces are unproven. The depth / layer
//          outputs are the same with or without proven_out.
//   skip   (options.skip_farther, not in the paper) a layer's search at p is skipped when the min
//          z_dst of the texels its bound was read from is >= the nearest depth already found at p: no
//          sample of that layer can replace it (ties keep the earlier layer). Not exact in one case: a
//          cross-layer climb (Fig. 6) may return a sample of an upper layer from outside that bound;
//          measured: 2 of 518,400 pixels differ (crowd, 960x540, L = 3), searches 972 k -> 424 k.
//
// DepthWarpDilate (sec. 3.4, Fig. 8): a hole with at least `min_neighbors` converged pixels among
//   its 8 neighbours takes the depth of the nearest converged neighbour (edge neighbours before
//   diagonal ones; among equally near ones the smallest depth). One pass reading the input only.
//
// DepthWarpForward (sec. 4.1 baselines, with the half-pixel support expansion):
//   kVfw: every valid source pixel is a quad, its footprint expanded by half a pixel on each side
//         ([x - 0.5, x + 1.5] x [y - 0.5, y + 1.5]) at the pixel's depth, each corner moved and
//         projected exactly, rasterised as two triangles (pixel centres inside, 1/z interpolated
//         linearly in screen space), depth-tested. Quads whose screen box exceeds
//         kDepthWarpMaxSplat pixels on a side are skipped (grazing / near-plane cases).
//   kAfw: every valid source pixel is a point at its target position p, written with an atomic
//         min to the target pixels whose centres lie in [p - 1, p + 1)^2 (the one-pixel support
//         expanded by half a pixel on each side).
//   Writes go through an atomic min on (z bits << 32 | layer) (z > 0, so float order = integer
//   order): the result is the same for any thread count. key = ~0 where nothing landed.
//
// Kernels trust their inputs (the front checks them), never throw and never allocate policy.
// Multithreaded over rows with ibr::ParallelFor; every output depends only on the inputs (or is
// an order-independent atomic min), so results are identical for any thread count.
#pragma once
#include <cstdint>

#include "ibr/camera.h"
#include "ibr/image.h"

namespace ibr {

inline constexpr float kDepthWarpMaxMotion = 1.0e7f;
inline constexpr int kDepthWarpMaxSplat = 256;
inline constexpr int kDepthWarpMaxTile = 16;

// Moves source pixels into the target camera (both pinhole). dst_from_src: (num_motions + 1)
// affine transforms, each 3x4 row-major float64, point_in_dst_cam = A * point_in_src_cam + t:
// entry 0 for static pixels (id -1), entry k + 1 for object k (dst.cam_from_world *
// object_motion[k] * src.world_from_cam, composed by the front). ids outside [-1, num_motions)
// never reach the kernel (the front rejects them).
struct DepthWarpMover {
  const Camera* src = nullptr;
  const Camera* dst = nullptr;
  const double* dst_from_src = nullptr;
  int num_motions = 0;
  bool simd = true;  // static scene: SSE2 over 4 pixels (same bits as the scalar loop; false: scalar only, for tests)
};

// The front's input check of depth layers (n floats): counts NaN / infinite and negative values.
void DepthWarpCountBadDepth(const float* depth, std::int64_t n, std::int64_t* nonfinite, std::int64_t* negative);

void DepthWarpMotion(const ImageView<const float>& depth, const ImageView<const std::int32_t>* ids,
                     const DepthWarpMover& mover, const ImageView<float>& packed);

// How the bound's axes were chosen.
enum class DepthWarpAxes : int {
  kAxisAligned = 0,        // oriented bounds not requested
  kOriented = 1,           // PCA axes: their global box has the smaller area
  kDegeneratePca = 2,      // requested, but the PCA has no principal direction (e.g. all motions equal)
  kOrientedNotSmaller = 3, // requested, but the oriented global box is not smaller
  kEmpty = 4,              // oriented requested, but no valid pixel
};

// PCA of the motion at a fixed grid of sample_grid x sample_grid pixels (valid ones only), then
// the global boxes in both frames; rot (row-major 2x2, u = rot * v) = PCA axes or identity.
DepthWarpAxes DepthWarpChooseAxes(const ImageView<const float>& packed, bool try_oriented, int sample_grid,
                                  float rot[4]);

// out (h1, w1, 4) motion bounds and out_z (h1, w1) the min z_dst of the block's valid pixels (+inf if none).
void DepthWarpMipLevel1(const ImageView<const float>& packed, const float rot[4], const ImageView<float>& out,
                        const ImageView<float>& out_z);
// DepthWarpMotion followed by DepthWarpMipLevel1 with the identity rotation (axis-aligned bounds),
// in one pass over the rows: each pair of packed rows is reduced to its level-1 texel row while it
// is still in cache (saves re-reading the 16 bytes per pixel of the packed buffer). Results are
// bit-identical to the two calls (same arithmetic in the same order). out / out_z: level 1.
void DepthWarpMotionMipLevel1(const ImageView<const float>& depth, const ImageView<const std::int32_t>* ids,
                              const DepthWarpMover& mover, const ImageView<float>& packed, const ImageView<float>& out,
                              const ImageView<float>& out_z);
void DepthWarpMipDown(const ImageView<const float>& in, const ImageView<const float>& in_z, const ImageView<float>& out,
                      const ImageView<float>& out_z);

struct DepthWarpSeen;

struct DepthWarpOptions {
  int seeds = 16;           // N
  int iters = 3;            // T: fixed-point updates after the seed
  float threshold = 0.5f;   // px
  bool tight = true;        // Fig. 5 narrowing (false: the global bound only)
  int steps = 3;            // narrowing steps
  float early_exit = 0.5f;  // px
  std::uint32_t seed = 0;   // jitter of the stratified seeds
  bool skip_farther = true; // skip a layer's search where its min z_dst cannot beat the depth found
  int tile = 8;             // target tile side for the bound narrowing (1..kDepthWarpMaxTile)
  bool pixel_step = true;   // one more narrowing step per pixel from the tile bound
  float edge_motion = 0.0f; // px; silhouette test of converged samples (0 = off; depthwarp.cpp EdgeConsistent)
  // Unseen-space rejection (not in the paper; see DepthWarpSeen). Null: off.
  const DepthWarpSeen* seen = nullptr;
};

// Unseen-space rejection of deep samples (not in the paper). A sample of a layer >= 1 is a real
// surface point X that the source saw hidden behind something. At target pixel p it is rejected
// when the part of p's ray in front of X may hold a surface the source never saw because it lies
// outside the source's frame: the ray's segment from the target centre to X (clipped at source
// depth near_fraction * X's source depth, for a target centre behind or at the source camera)
// leaves the source image, and it leaves at a target depth >= border_fraction * the target depth
// of the surface the source saw at the border pixel where it leaves (that surface may continue
// outside the frame and hide X). A segment leaving far in front of the border surface is accepted
// (a sideways step leaves the source's view near the camera: rejecting those would reject the
// disocclusions deep layers exist for). Without it, at frame borders where the target sees new
// geometry, a deep layer (the ground under a building, the back of a facade) supplied depths that
// were far too large (city, L = 4). Layer-0 samples are always accepted (as in the paper).
struct DepthWarpSeen {
  double src_from_dst[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};  // 3x4 row-major, static scene
  double dst_fx = 1, dst_fy = 1, dst_cx = 0, dst_cy = 0;          // target intrinsics
  double src_fx = 1, src_fy = 1, src_cx = 0, src_cy = 0;          // source intrinsics
  int src_width = 0, src_height = 0;
  double near_fraction = 1e-3;  // see above
  double border_fraction = 0.5; // see above
};

struct DepthWarpLayer {
  ImageView<const float> packed;       // (H, W, 4)
  const ImageView<const float>* mips;  // levels 1..n_mips, each (ceil(H/2^l), ceil(W/2^l), 4); last is 1x1
  const ImageView<const float>* zmips; // the same levels' min z_dst, each (ceil(H/2^l), ceil(W/2^l))
  int n_mips = 0;
  float rot[4] = {1, 0, 0, 1};
  // (H, W) int32 surface id of each source pixel (the object id; < 0 = none), read by the proof of
  // DepthWarpBackward only (proven_out); may be empty otherwise.
  ImageView<const std::int32_t> surface;
};

struct DepthWarpCounters {
  std::int64_t converged = 0;       // target pixels with a depth
  std::int64_t early_exit = 0;      // (pixel, layer) searches that used one seed
  std::int64_t searched = 0;        // (pixel, layer) searches run (not skipped for an empty bound)
  std::int64_t samples = 0;         // seeds run
  std::int64_t lookups = 0;         // motion lookups of the fixed-point search
};

// depth_out (H', W') float32, layer_out (H', W') int8 (the target camera's size). proven_out
// (H', W') float32 or null: the proven occluder depth (see "proof" above; needs every layer's surface).
void DepthWarpBackward(const DepthWarpLayer* layers, int num_layers, const DepthWarpOptions& options,
                       const ImageView<float>& depth_out, const ImageView<std::int8_t>& layer_out,
                       DepthWarpCounters* counters, const ImageView<float>* proven_out = nullptr);

// In place on the warp's depth / layer: layer_in is an unmodified copy of `layer` (holes and
// converged neighbours are read from it; converged pixels' depths are never written, so reading
// them from `depth` is safe). Only the filled holes are written; returns their number.
std::int64_t DepthWarpDilate(const ImageView<const std::int8_t>& layer_in, int min_neighbors,
                             const ImageView<float>& depth, const ImageView<std::int8_t>& layer);

enum class DepthWarpForwardKind : int { kVfw = 0, kAfw = 1 };

// Splats one layer into key (H', W') uint64, which the caller initialised to ~0 (and reuses
// across layers). packed is the layer's motion buffer (used by AFW and for validity); depth and
// ids (nullable) feed VFW's corner projection.
void DepthWarpForward(DepthWarpForwardKind kind, const ImageView<const float>& depth,
                      const ImageView<const std::int32_t>* ids, const ImageView<const float>& packed,
                      const DepthWarpMover& mover, int layer, const ImageView<std::uint64_t>& key);

// key -> depth (0 in holes) and layer (-1 in holes).
void DepthWarpDecodeKeys(const ImageView<const std::uint64_t>& key, const ImageView<float>& depth,
                         const ImageView<std::int8_t>& layer);

}  // namespace ibr
