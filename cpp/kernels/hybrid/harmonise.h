// Harmonisation kernels (Prakash et al. 2021 sec. 4.2; python/ibrtools/hybrid/harmonise.py,
// docs/harmonise.md): the cross-view diffuse prediction of the view-dependent mask's data term.
//
// For every pixel (u, v) of the target view with a surface (depth > 0 and finite): the surface
// point p = world_from_cam(RayInCam(u + 0.5, v + 0.5) * depth) (depth is z for pinhole, the
// ray distance for equirect, as the renderer writes it); for each source view k, in the given
// order: p projected (ProjectCam), kept when inside the image (0 <= x < W, 0 <= y < H) and when
// the source's own depth at the pixel containing it, zk = depth_k[floor y, floor x], satisfies
// zk > 0 and |zk - z| <= depth_tol * z (the point is the surface that view sees, not occluded);
// the source image is then read bilinearly (pixel centres at +0.5, coordinates clamped to
// [0.5, W - 0.5] x [0.5, H - 0.5]). The prediction is, per channel independently, the quantile
// `quantile` of the kept samples (sorted, linear interpolation at position q * (n - 1), as
// numpy's default); n_seen = the number of kept samples. Pixels without a surface or with no
// kept sample get prediction 0 and n_seen 0.
//
// Same arithmetic as the numpy reference (double projection and bilinear weights, float32
// samples and quantile), so results agree to float rounding; the loop runs over rows with
// ParallelFor (deterministic: each pixel is computed independently).
#pragma once
#include <cstdint>
#include <vector>

#include "ibr/camera.h"

namespace ibr {

struct PredictionSource {
  const Camera* camera = nullptr;  // its width / height give the size of depth and image
  const float* depth = nullptr;    // (H, W): the mesh's depth in that view (<= 0, NaN or inf: no surface)
  const float* image = nullptr;    // (H, W, 3) float32 colour
};

// pred: (height, width, 3) of `camera`; n_seen: (height, width). Never throws, never allocates
// beyond per-chunk scratch of sources.size() * 3 floats.
void CrossViewPrediction(const Camera& camera, const float* depth, const std::vector<PredictionSource>& sources,
                         double depth_tol, double quantile, float* pred, std::int32_t* n_seen);

}  // namespace ibr
