// G-buffer of a triangle mesh by rasterisation (issue 7: TM <= 20 ms at 1280x720): per pixel the
// nearest face hit by the ray through the pixel centre, as the Embree G-buffer
// (cpp/kernels/raycast/raycast.h, ReferenceRenderer outputs depth, prim_id, bary, normal), for pinhole
// cameras.
//
// Two passes. (1) Visibility: every face is transformed into the camera, clipped against the
// plane z = near and the rasteriser's guard band (cpp/ibr/raster.h; a clipped face becomes a
// polygon, fanned into triangles), projected, snapped to 1/256 px and scan-converted band by band
// by the engine's rasteriser core (rows split among the threads; every band walks the faces in
// index order, so the result does not depend on the thread count); a pixel centre is covered when
// the snapped triangle's three edge functions are >= 0 (inclusive edges: shared edges are covered
// by both faces, no cracks) and the nearest face wins by 1/z interpolated linearly in screen
// space (ties: the smaller face index). (2) Attributes: per covered pixel, the ray through its
// centre is intersected with the winning face (Moller-Trumbore, double precision): depth = z
// (the pinhole ray has z = 1, so t is z-depth), bary = (u, v) with p = (1-u-v) v0 + u v1 + v v2
// clamped to the face, normal = the face's unit geometric normal in world axes facing the
// camera. So depth and barycentrics agree with the ray caster to rounding wherever both pick the
// same face; they may pick different faces only at pixel centres within 1/256 px of an edge (the
// snapping).
//
// Conventions (cpp/ibr/camera.h): OpenCV axes, pixel centres at +0.5. No hit: depth 0, prim_id
// -1, bary 0, normal 0. Vertices (N, 3) float32 in world axes, faces (M, 3) int32 with indices
// already checked to lie in [0, N). Pinhole cameras only (the binding checks).
#pragma once
#include <cstdint>

#include "ibr/camera.h"

namespace ibr {

void RasterGBuffer(const Camera& camera, const float* vertices, std::int64_t num_vertices, const std::int32_t* faces,
                   std::int64_t num_faces, float* depth, std::int32_t* prim_id, float* bary, float* normal);

}  // namespace ibr
