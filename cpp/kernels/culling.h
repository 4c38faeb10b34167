// Warping-based occlusion culling, the geometric half (Lee, Kim, Eisemann 2018, sec. 5.2):
// per-object world AABBs, view-frustum culling of each box, and the screen-space rectangle and
// minimum camera z of the boxes that remain. The max-depth half (Y-map / N-buffer queries of the
// warped depth) is ibrtools.depthwarp.MaxDepthQuery; python/ibrtools/culling.py joins the two:
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
// Kernels trust their inputs (python/ibrtools/culling.py and cpp/bindings/culling.cpp check
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

}  // namespace ibr
