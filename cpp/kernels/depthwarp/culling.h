// Warping-based occlusion culling, the geometric half (Lee, Kim, Eisemann 2018, sec. 5.2):
// per-object world AABBs, view-frustum culling of each box, and the screen-space rectangle and
// minimum camera z of the boxes that remain. The max-depth half (Y-map / N-buffer queries of the
// warped depth) is ibrtools.depthwarp.core.MaxDepthQuery; python/ibrtools/culling.py joins the two:
// an on-screen box is occluded when its min z exceeds the max depth over its rectangle.
//
// ObjectBoxes: boxes (K, 2, 3) float32 = (min corner, max corner) in world units of the
//   vertices used by the faces of each object id k in [0, K); faces whose id is outside
//   [0, K) are ignored. An object with no face gets min = +inf, max = -inf (empty).
//
// ProjectBoxes (pinhole camera, OpenCV axes, pixel centres at +0.5; cpp/ibr/camera.h):
//   the 8 corners of each box are moved into the camera (point_in_cam = R p + t, double).
//   state[k] = kCullOutside   empty box, or all 8 corners outside one frustum plane (near
//                             z >= near; left fx X + cx Z >= 0; right (W - cx) Z - fx X >= 0;
//                             top fy Y + cy Z >= 0; bottom (H - cy) Z - fy Y >= 0), or the
//                             rectangle below is empty after clipping to the image;
//              kCullNear      some corner has z <= near: the box crosses the near plane, its
//                             projection is unbounded, so it is kept visible untested;
//              kCullTest      on screen: rect[k] = (x0, y0, x1, y1) int32, x1 / y1 exclusive, the
//                             pixels whose footprint [u, u + 1) x [v, v + 1) meets the bounding
//                             rectangle of the projected corners, grown by `pad` pixels on every
//                             side and clipped to the image; min_z[k] = the least corner z (a
//                             convex box's least z is at a corner), rounded down to float.
//   Other states leave rect = (0, 0, 0, 0) and min_z = 0. The frustum test is conservative (a box
//   outside the frustum but not outside any single plane is kept); the rectangle test catches
//   most of those boxes.
//
// AwocFill (approximate WOC, paper sec. 5.3: "fills the holes using the motion vectors at the
//   extrema of the local search bound ... we simply consider the nearest of them as an approximate
//   depth"). Inputs: the source frame's motion (H, W, 2) float32 = target pixel position - source
//   pixel position and dst_depth (H, W) float32 = z of each source pixel moved into the target
//   camera (0 = invalid), i.e. ibrtools.depthwarp.core.motion_buffer; the warped target depth
//   (H', W') float32 and hole (H', W') uint8, both updated in place.
//   Search bound (Fig. 5): a min-max mipmap of the valid motions (level 0 = the pixels, level
//   l + 1 = 2x2 blocks of level l, up to one texel). For a hole pixel p (integer index; its source
//   solution q satisfies q + V(q) = p) the global bound is B = [p - Vmax, p - Vmin] from the top
//   texel; each of `steps` narrowing steps reads the level l = ceil(log2(max extent of B)) at the
//   texels under B's four corners (they cover B), takes their motion range and intersects
//   [p - Vmax', p - Vmin'] with B. The source pixels at the final B's four corners (rounded,
//   clamped to the image) are the candidates; the least positive dst_depth among them fills p
//   (hole cleared). Where no candidate is valid (or no motion is valid at all), p stays a hole.
//   Empty background: our depth buffers have no "far plane" value (0 = no surface), so a target
//   pixel that sees the sky is a hole of the warp, while in the paper's rasteriser it converges to
//   the far depth. With `sky_from_target` (3x3 row-major, K_src R_src R_dst^T K_dst^-1: the map of
//   directions, i.e. of points at infinity) and `source_depth` (H, W), a hole whose direction lands
//   on an empty source pixel (or outside the source image) is left a hole (far), as the paper's
//   warp would have found the far plane there. Null pointers turn this off.
//   scratch: AwocScratchSize(H, W) floats, owned by the front.
//
// Kernels trust their inputs (python/ibrtools/culling.py and cpp/bindings/depthwarp.cpp check
// them), never throw and never allocate. ProjectBoxes is multithreaded over boxes with
// ibr::ParallelFor; every output depends on its box only (identical for any thread count).
#pragma once
#include <cstdint>

#include "ibr/camera.h"

namespace ibr {

enum CullState : std::uint8_t { kCullOutside = 0, kCullNear = 1, kCullTest = 2 };

struct CullOptions {
  double near = 1e-3;  // near plane z in world units (> 0)
  int pad = 1;         // pixels added around each rectangle (>= 0): rasterisation slack
};

void ObjectBoxes(const float* vertices, const std::int32_t* faces, std::int64_t num_faces,
                 const std::int32_t* object_ids, std::int32_t num_objects, float* boxes);

void ProjectBoxes(const float* boxes, std::int64_t num_boxes, const Camera& camera, const CullOptions& options,
                  std::uint8_t* state, std::int32_t* rect, float* min_z);

std::int64_t AwocScratchSize(int height, int width);

void AwocFill(const float* motion, const float* dst_depth, int height, int width, int steps,
              const double* sky_from_target, const float* source_depth, float* scratch, float* depth,
              std::uint8_t* hole, int out_height, int out_width);

}  // namespace ibr
