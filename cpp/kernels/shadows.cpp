// Equations and shapes: shadows.h.
#include "kernels/shadows.h"

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

}  // namespace

void ShadowMapVisibility(const float* view_depth, const Camera& view, const float* maps, const Camera* cams,
                         int num_samples, float bias, float* visibility) {
  const int w = view.width, h = view.height;
  const float inv_s = 1.0f / static_cast<float>(num_samples);
  ParallelFor2D(h, w, kTile, [&](int y0, int y1, int x0, int x1) {
    for (int v = y0; v < y1; ++v) {
      for (int u = x0; u < x1; ++u) {
        const std::int64_t i = static_cast<std::int64_t>(v) * w + u;
        const float z = view_depth[i];
        if (!(z > 0.0f)) {
          visibility[i] = 1.0f;
          continue;
        }
        const glm::dvec3 p = SurfacePoint(view, u, v, z);
        int lit = 0;
        for (int s = 0; s < num_samples; ++s) {
          const Camera& c = cams[s];
          const glm::dvec3 q = c.CamFromWorld(p);
          if (!(q.z > 0.0)) { ++lit; continue; }
          const double x = c.fx * q.x / q.z + c.cx, y = c.fy * q.y / q.z + c.cy;
          if (!(x >= 0.0 && x < c.width && y >= 0.0 && y < c.height)) { ++lit; continue; }
          const std::int64_t t = (static_cast<std::int64_t>(s) * c.height + static_cast<int>(y)) * c.width +
                                 static_cast<int>(x);
          const double d = maps[t];
          lit += !(d > 0.0) || q.z <= d + bias * q.z / c.fx;
        }
        visibility[i] = static_cast<float>(lit) * inv_s;
      }
    }
  });
}

void TracedVisibility(const EmbreeScene& scene, const float* view_depth, const Camera& view,
                      const double* light_positions, int num_samples, float eps_rel, float* visibility) {
  const int w = view.width, h = view.height;
  const float inv_s = 1.0f / static_cast<float>(num_samples);
  RTCScene handle = scene.Handle();
  ParallelFor2D(h, w, kTile, [&](int y0, int y1, int x0, int x1) {
    RayQuery query(false);
    for (int v = y0; v < y1; ++v) {
      for (int u = x0; u < x1; ++u) {
        const std::int64_t i = static_cast<std::int64_t>(v) * w + u;
        const float z = view_depth[i];
        if (!(z > 0.0f)) {
          visibility[i] = 1.0f;
          continue;
        }
        const glm::dvec3 p = SurfacePoint(view, u, v, z);
        int lit = 0;
        for (int s = 0; s < num_samples; ++s) {
          const glm::dvec3 d(light_positions[s * 3] - p.x, light_positions[s * 3 + 1] - p.y,
                             light_positions[s * 3 + 2] - p.z);
          const double len = glm::length(d);
          if (!(len > 0.0)) { ++lit; continue; }
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
          if (!(ray.tnear < ray.tfar)) { ++lit; continue; }
          query.Occluded1(handle, &ray);
          // Embree sets tfar = -inf when the ray is occluded.
          lit += ray.tfar >= 0.0f;
        }
        visibility[i] = static_cast<float>(lit) * inv_s;
      }
    }
  });
}

}  // namespace ibr
