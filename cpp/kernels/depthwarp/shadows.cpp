// Equations and shapes: shadows.h.
#include "kernels/depthwarp/shadows.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "ibr/parallel.h"

namespace ibr {
namespace {

constexpr int kTile = 32;

glm::dvec3 SurfacePoint(const Camera& view, int u, int v, double z) {
  const glm::dvec3 p_cam = view.RayInCam(u + 0.5, v + 0.5) * z;
  // world = R^T (p_cam - t)
  return glm::transpose(view.rot) * (p_cam - view.trans);
}

// |depth change| per texel towards the flatter neighbour; 0 when no neighbour has a surface.
double Slope(double d, float a, float b) {
  const double da = a > 0.0f ? std::abs(d - a) : std::numeric_limits<double>::infinity();
  const double db = b > 0.0f ? std::abs(d - b) : std::numeric_limits<double>::infinity();
  const double m = std::min(da, db);
  return std::isfinite(m) ? m : 0.0;
}

// The skeleton both visibility images share: at every view pixel with a surface (depth > 0),
// the fraction of the S light samples s for which lit(state, p, z, s) holds; 1 where the view
// sees nothing. make_state() gives each tile task its own state (e.g. an Embree query).
template <class MakeState, class Lit>
void SampleVisibility(const float* view_depth, const Camera& view, int num_samples, float* visibility,
                      MakeState make_state, Lit lit) {
  const int w = view.width, h = view.height;
  const float inv_s = 1.0f / static_cast<float>(num_samples);
  ParallelFor2D(h, w, kTile, [&](int y0, int y1, int x0, int x1) {
    auto state = make_state();
    for (int v = y0; v < y1; ++v) {
      for (int u = x0; u < x1; ++u) {
        const std::int64_t i = static_cast<std::int64_t>(v) * w + u;
        const float z = view_depth[i];
        if (!(z > 0.0f)) {
          visibility[i] = 1.0f;
          continue;
        }
        const glm::dvec3 p = SurfacePoint(view, u, v, z);
        int n = 0;
        for (int s = 0; s < num_samples; ++s) n += lit(state, p, z, s);
        visibility[i] = static_cast<float>(n) * inv_s;
      }
    }
  });
}

}  // namespace

void ShadowMapVisibility(const float* view_depth, const Camera& view, const float* maps, const Camera* cams,
                         int num_samples, float bias, float slope_bias, float* visibility) {
  SampleVisibility(view_depth, view, num_samples, visibility, [] { return 0; },
                   [&](int, const glm::dvec3& p, float, int s) -> bool {
    const Camera& c = cams[s];
    const glm::dvec3 q = c.CamFromWorld(p);
    if (!(q.z > 0.0)) return true;
    const double x = c.fx * q.x / q.z + c.cx, y = c.fy * q.y / q.z + c.cy;
    if (!(x >= 0.0 && x < c.width && y >= 0.0 && y < c.height)) return true;
    const int ix = static_cast<int>(x), iy = static_cast<int>(y);
    const float* row = maps + (static_cast<std::int64_t>(s) * c.height + iy) * c.width;
    const double d = row[ix];
    if (!(d > 0.0)) return true;
    // Receiver slope from the map itself: per axis the smaller of the forward and backward
    // differences (a depth edge on one side does not count), missing neighbours ignored.
    const double sx = Slope(d, ix > 0 ? row[ix - 1] : 0.0f, ix + 1 < c.width ? row[ix + 1] : 0.0f);
    const double sy = Slope(d, iy > 0 ? row[ix - c.width] : 0.0f, iy + 1 < c.height ? row[ix + c.width] : 0.0f);
    return q.z <= d + bias * q.z / c.fx + slope_bias * (sx + sy);
  });
}

void TracedVisibility(const EmbreeScene& scene, const float* view_depth, const Camera& view,
                      const double* light_positions, int num_samples, float eps_rel, float* visibility) {
  RTCScene handle = scene.Handle();
  SampleVisibility(view_depth, view, num_samples, visibility, [] { return RayQuery(false); },
                   [&](RayQuery& query, const glm::dvec3& p, float z, int s) -> bool {
    const glm::dvec3 d(light_positions[s * 3] - p.x, light_positions[s * 3 + 1] - p.y,
                       light_positions[s * 3 + 2] - p.z);
    const double len = glm::length(d);
    if (!(len > 0.0)) return true;
    RTCRay ray;
    ray.org_x = static_cast<float>(p.x);
    ray.org_y = static_cast<float>(p.y);
    ray.org_z = static_cast<float>(p.z);
    ray.dir_x = static_cast<float>(d.x);
    ray.dir_y = static_cast<float>(d.y);
    ray.dir_z = static_cast<float>(d.z);
    ray.tnear = static_cast<float>(eps_rel * z / len);
    ray.tfar = 1.0f - 1e-6f;
    ray.time = 0.0f;
    ray.mask = 0xFFFFFFFFu;
    ray.id = 0;
    ray.flags = 0;
    if (!(ray.tnear < ray.tfar)) return true;
    query.Occluded1(handle, &ray);
    return ray.tfar >= 0.0f;  // Embree sets tfar = -inf when the ray is occluded
  });
}

}  // namespace ibr
