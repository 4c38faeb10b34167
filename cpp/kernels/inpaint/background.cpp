// The background lookup (background.h).
#include "kernels/inpaint/background.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "ibr/parallel.h"

namespace ibr {
namespace {

constexpr std::uint8_t kUndecided = 0, kSurface = 1, kBackground = 2;

inline bool IsPosInf(float d) { return d == std::numeric_limits<float>::infinity(); }

// What input `in` knows of world point p: 0 nothing (outside its image, behind it, unknown
// depth), 1 free (it sees past p: its depth there above p's by more than the tolerance, or
// +inf), 2 on or behind its surface.
int SeesPast(const BackgroundInput& in, const glm::dvec3& p, double tolerance) {
  const Camera& cam = in.camera;
  double x, y, d;
  if (!cam.ProjectCam(cam.CamFromWorld(p), &x, &y, &d)) return 0;
  if (!(x >= 0.0 && x < cam.width && y >= 0.0 && y < cam.height)) return 0;  // NaN too
  const int ix = std::min(static_cast<int>(x), cam.width - 1), iy = std::min(static_cast<int>(y), cam.height - 1);
  const float at = in.depth.At(iy, ix);
  if (!(at > 0.0f)) return 0;
  return static_cast<double>(at) > d * (1.0 + tolerance) ? 1 : 2;  // +inf is free
}

// Whether every sample of the target's ray origin + t dir (t in `ts`, kRaySamples of them) that
// some input sees is free in one of them (background.h: free space is what any input sees past).
bool RayIsFree(const BackgroundInput* inputs, int num_inputs, const glm::dvec3& origin, const glm::dvec3& dir,
               const double* ts, double tolerance) {
  for (int k = 0; k < BackgroundRay::kRaySamples; ++k) {
    const glm::dvec3 p = origin + ts[k] * dir;
    bool seen = false, free = false;
    for (int i = 0; i < num_inputs && !free; ++i) {
      const int s = SeesPast(inputs[i], p, tolerance);
      seen |= s != 0;
      free = s == 1;
    }
    if (seen && !free) return false;
  }
  return true;
}

// Asks one input about world direction `dir`: kUndecided, kSurface, or kBackground with rgb set.
std::uint8_t Ask(const BackgroundInput& in, const glm::dvec3& dir, float rgb[3]) {
  const Camera& cam = in.camera;
  const glm::dvec3 p = cam.rot * dir;  // the camera at the origin: a direction projects as a point
  double x, y, unused;
  if (!cam.ProjectCam(p, &x, &y, &unused)) return kUndecided;
  const int w = cam.width, h = cam.height;
  if (!(x >= 0.0 && x < w && y >= 0.0 && y < h)) return kUndecided;  // NaN fails too
  const int ix = std::min(static_cast<int>(x), w - 1), iy = std::min(static_cast<int>(y), h - 1);
  const float at = in.depth.At(iy, ix);
  if (!(at > 0.0f)) return kUndecided;  // unknown depth: no decision
  if (!(IsPosInf(at) && in.clear.At(iy, ix))) return kSurface;
  const double gx = x - 0.5, gy = y - 0.5;
  const double x0 = std::floor(gx), y0 = std::floor(gy);
  const double fx = gx - x0, fy = gy - y0;
  const double weights[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
  const int dxs[4] = {0, 1, 0, 1}, dys[4] = {0, 0, 1, 1};
  double acc[3] = {0.0, 0.0, 0.0}, wsum = 0.0;
  for (int k = 0; k < 4; ++k) {
    const int cx = std::clamp(static_cast<int>(x0) + dxs[k], 0, w - 1);
    const int cy = std::clamp(static_cast<int>(y0) + dys[k], 0, h - 1);
    const double wt = IsPosInf(in.depth.At(cy, cx)) ? weights[k] : 0.0;
    for (int c = 0; c < 3; ++c) acc[c] += wt * static_cast<double>(in.color.At(cy, cx, c));
    wsum += wt;
  }
  const double norm = std::max(wsum, 1e-12);
  for (int c = 0; c < 3; ++c) rgb[c] = static_cast<float>(acc[c] / norm);
  return kBackground;
}

}  // namespace

void BackgroundLookupKernel(const Camera& target, const BackgroundInput* inputs, int num_inputs,
                            const BackgroundRay& ray, const ImageView<const std::uint8_t>& hole,
                            const ImageView<float>& color, const ImageView<std::uint8_t>& state) {
  const glm::dvec3 origin = target.CentreInWorld();
  // The ray's sample depths, the same for every pixel: geometric steps from near to far.
  double ts[BackgroundRay::kRaySamples] = {};
  if (ray.Active()) {
    const double step = std::log(ray.far / ray.near) / (BackgroundRay::kRaySamples - 1);
    for (int k = 0; k < BackgroundRay::kRaySamples; ++k) ts[k] = ray.near * std::exp(step * k);
  }
  ParallelFor(hole.height, 8, [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const std::uint8_t* hrow = hole.Row(y);
      std::uint8_t* srow = state.Row(y);
      for (int x = 0; x < hole.width; ++x) {
        if (!hrow[x]) {
          srow[x] = kUndecided;
          continue;
        }
        const glm::dvec3 dir = target.WorldFromCamDir(target.RayInCam(x + 0.5, y + 0.5));
        std::uint8_t s = kUndecided;
        float rgb[3];
        for (int i = 0; i < num_inputs && s == kUndecided; ++i) s = Ask(inputs[i], dir, rgb);
        if (s == kBackground && ray.Active() && !RayIsFree(inputs, num_inputs, origin, dir, ts, ray.tolerance)) {
          s = kUndecided;
        }
        srow[x] = s;
        if (s == kBackground) {
          for (int c = 0; c < 3; ++c) color.At(y, x, c) = rgb[c];
        }
      }
    }
  });
}

}  // namespace ibr
