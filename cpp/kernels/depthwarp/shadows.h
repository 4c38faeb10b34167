// Soft shadows of a rectangular area light from S light samples (Lee, Kim, Eisemann 2018,
// sec. 6): the visibility of each surface point of a view = the fraction of the S light samples
// it sees.
//
// Surface points: pixel (u, v) of the view with depth z = view_depth[v, u] > 0 (pinhole z, or
// equirect ray distance: the scene model's depth) is the world point
//   p = world_from_cam(RayInCam(u + 0.5, v + 0.5) * z)            (cpp/ibr/camera.h).
// Pixels with depth <= 0 (no surface) get visibility 1.
//
// ShadowMapVisibility (the shadow-map test of Williams 1978, one map per light sample):
//   maps (S, Hs, Ws) float32 pinhole z depth buffers of the cameras cams[s] (0 = no surface or a
//   hole of a warped map: no known occluder there). For each point p and sample s: q = cams[s]
//   point_in_cam of p; p is lit by s when q.z <= 0, or q projects outside the map, or the texel
//   under it (nearest: floor(x), floor(y)) holds d = 0, or
//     q.z <= d + bias * q.z / fx_s + slope_bias * (sx + sy)
//   (a constant and a slope-scaled bias, the usual remedy for shadow acne): q.z / fx_s is the
//   world size of one texel at the point's depth, so `bias` is in texels; sx, sy are the receiver's
//   depth change per texel along x and y read from the map (per axis the smaller of the forward and
//   backward differences, so that a depth edge beside the texel does not count). The point lies
//   within half a texel of the texel centre along each axis, so its own surface differs from d by at
//   most 0.5 (sx + sy): slope_bias = 1 covers that twice.
//   visibility[v, u] = lit count / S.
//
// TracedVisibility (the reference: one occlusion ray per point and sample, Embree):
//   light_positions (S, 3) float64 world; the segment from p to l_s is tested from
//   t = eps_rel * z_view / |l_s - p| (skips the surface p lies on: its depth is float32) to
//   1 - 1e-6 (stops just before the light); lit when the segment hits nothing.
//   visibility[v, u] = lit count / S.
//
// Both are multithreaded over image tiles (ibr::ParallelFor2D; S x H x W work); each output
// pixel depends on its inputs only, so results are identical for any thread count. Kernels
// trust their inputs (checked by cpp/bindings/depthwarp.cpp), never throw and never allocate.
#pragma once
#include <cstdint>

#include "ibr/camera.h"
#include "ibr/embree_scene.h"

namespace ibr {

void ShadowMapVisibility(const float* view_depth, const Camera& view, const float* maps, const Camera* cams,
                         int num_samples, float bias, float slope_bias, float* visibility);

void TracedVisibility(const EmbreeScene& scene, const float* view_depth, const Camera& view,
                      const double* light_positions, int num_samples, float eps_rel, float* visibility);

}  // namespace ibr
