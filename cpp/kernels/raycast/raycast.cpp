#include "kernels/raycast/raycast.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include <glm/glm.hpp>

#include "ibr/errors.h"
#include "ibr/parallel.h"

namespace ibr {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

// Primary rays of a camera in world axes (origin shared by all pixels).
struct CameraRays {
  const Camera& cam;
  glm::dmat3 world_from_cam;
  glm::vec3 origin;

  // Pinhole: the world direction is affine in the pixel coordinates,
  // d = world_from_cam * ((x - cx) / fx, (y - cy) / fy, 1) = d0 + x * dx + y * dy.
  bool pinhole;
  glm::dvec3 d0, dx, dy;

  explicit CameraRays(const Camera& c)
      : cam(c), world_from_cam(glm::transpose(c.rot)), origin(glm::vec3(c.CentreInWorld())),
        pinhole(c.model == CameraModel::kPinhole) {
    if (pinhole) {
      dx = world_from_cam[0] / c.fx;
      dy = world_from_cam[1] / c.fy;
      d0 = world_from_cam[2] - c.cx * dx - c.cy * dy;
    }
  }

  // Direction through the centre of pixel (px, py): z_cam = 1 (pinhole) or unit (equirect).
  glm::vec3 Dir(int px, int py) const {
    if (pinhole) return glm::vec3(d0 + (px + 0.5) * dx + (py + 0.5) * dy);
    return glm::vec3(world_from_cam * cam.RayInCam(px + 0.5, py + 0.5));
  }
};

// One primary-ray result, whatever the query width.
struct Hit {
  float t;
  float u, v;
  std::int32_t prim;  // -1 = no hit
  glm::vec3 ng;       // Embree's unnormalised geometric normal (either orientation)
};

// Lane k of a ray packet: a ray from org along dir starting at tnear, no hit yet.
template <typename RayHitN>
inline void SetLane(RayHitN& rh, int k, const glm::vec3& org, const glm::vec3& dir, float tnear) {
  rh.ray.org_x[k] = org.x;
  rh.ray.org_y[k] = org.y;
  rh.ray.org_z[k] = org.z;
  rh.ray.dir_x[k] = dir.x;
  rh.ray.dir_y[k] = dir.y;
  rh.ray.dir_z[k] = dir.z;
  rh.ray.tnear[k] = tnear;
  rh.ray.tfar[k] = kInf;
  rh.ray.time[k] = 0.f;
  rh.ray.mask[k] = 0xFFFFFFFFu;
  rh.ray.id[k] = static_cast<unsigned>(k);
  rh.ray.flags[k] = 0;
  rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
  rh.hit.primID[k] = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
}

// Traces every pixel of the camera, in tiles (ParallelFor2D) and packets of N rays laid out
// as BW x BH pixel blocks, and calls fn(py, px, dir, hit, query) for each pixel. The
// partition depends only on the image size: results do not depend on the thread count.
template <int N, int BW, int BH, typename RayHitN, typename Fn>
void TracePackets(const EmbreeScene& scene, const CameraRays& rays, int tile, Fn& fn) {
  static_assert(BW * BH == N, "packet shape");
  const RTCScene handle = scene.Handle();
  ParallelFor2D(rays.cam.height, rays.cam.width, tile, [&](int y0, int y1, int x0, int x1) {
    RayQuery query(/*coherent=*/true);
    alignas(64) int valid[N];
    alignas(64) float dx[N], dy[N], dz[N];
    RayHitN rh;
    for (int by = y0; by < y1; by += BH) {
      for (int bx = x0; bx < x1; bx += BW) {
        for (int k = 0; k < N; ++k) {
          const int px = bx + k % BW, py = by + k / BW;
          const bool ok = px < x1 && py < y1;
          valid[k] = ok ? -1 : 0;
          const glm::vec3 d = ok ? rays.Dir(px, py) : glm::vec3(0.f, 0.f, 1.f);
          dx[k] = d.x, dy[k] = d.y, dz[k] = d.z;
          SetLane(rh, k, rays.origin, d, 0.f);
        }
        if constexpr (N == 8) query.Intersect8(valid, handle, &rh);
        else query.Intersect16(valid, handle, &rh);
        for (int k = 0; k < N; ++k) {
          if (!valid[k]) continue;
          const bool is_hit = rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID;
          const Hit h{is_hit ? rh.ray.tfar[k] : 0.f, rh.hit.u[k], rh.hit.v[k],
                      is_hit ? static_cast<std::int32_t>(rh.hit.primID[k]) : -1,
                      glm::vec3(rh.hit.Ng_x[k], rh.hit.Ng_y[k], rh.hit.Ng_z[k])};
          fn(by + k / BW, bx + k % BW, glm::vec3(dx[k], dy[k], dz[k]), h, query);
        }
      }
    }
  });
}

// One ray from `org` along `dir`, starting at `tnear`, ready for query.Intersect1.
inline void SetRay1(RTCRayHit& rh, const glm::vec3& org, const glm::vec3& dir, float tnear) {
  rh.ray.org_x = org.x, rh.ray.org_y = org.y, rh.ray.org_z = org.z;
  rh.ray.dir_x = dir.x, rh.ray.dir_y = dir.y, rh.ray.dir_z = dir.z;
  rh.ray.tnear = tnear;
  rh.ray.tfar = kInf;
  rh.ray.time = 0.f;
  rh.ray.mask = 0xFFFFFFFFu;
  rh.ray.id = 0;
  rh.ray.flags = 0;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
}

// The scalar reference path: one rtcIntersect1 per pixel.
template <typename Fn>
void TraceSingle(const EmbreeScene& scene, const CameraRays& rays, int tile, Fn& fn) {
  const RTCScene handle = scene.Handle();
  ParallelFor2D(rays.cam.height, rays.cam.width, tile, [&](int y0, int y1, int x0, int x1) {
    RayQuery query(/*coherent=*/true);
    RTCRayHit rh;
    for (int py = y0; py < y1; ++py) {
      for (int px = x0; px < x1; ++px) {
        const glm::vec3 d = rays.Dir(px, py);
        SetRay1(rh, rays.origin, d, 0.f);
        query.Intersect1(handle, &rh);
        const bool is_hit = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
        const Hit h{is_hit ? rh.ray.tfar : 0.f, rh.hit.u, rh.hit.v,
                    is_hit ? static_cast<std::int32_t>(rh.hit.primID) : -1,
                    glm::vec3(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z)};
        fn(py, px, d, h, query);
      }
    }
  });
}

template <typename Fn>
void Trace(const EmbreeScene& scene, const Camera& camera, const RaycastOptions& options, Fn& fn) {
  const CameraRays rays(camera);
  if (options.packet == 1) TraceSingle(scene, rays, options.tile, fn);
  else if (options.packet == 8) TracePackets<8, 4, 2, RTCRayHit8>(scene, rays, options.tile, fn);
  else TracePackets<16, 4, 4, RTCRayHit16>(scene, rays, options.tile, fn);
}

// Unit geometric normal of the hit face, flipped to face against `dir` (towards the camera).
// Embree's Ng is the face's edge cross product (no vertex fetch: the mesh stays out of the
// cache on a normal-only pass).
glm::vec3 FacingNormal(const glm::vec3& ng, const glm::vec3& dir) {
  const float len = glm::length(ng);
  // A degenerate face cannot be hit by a watertight intersector; keep a defined value anyway.
  if (!(len > 0.f)) return -glm::normalize(dir);
  const glm::vec3 n = ng / len;
  return glm::dot(n, dir) > 0.f ? -n : n;
}

// Bilinear texture lookup, repeat wrap, OBJ uv convention (v up: texel row = (1 - v) * H).
glm::vec3 SampleTexture(const TextureView& tex, float u, float v) {
  const float fx = u * tex.width - 0.5f;
  const float fy = (1.f - v) * tex.height - 0.5f;
  const float flx = std::floor(fx), fly = std::floor(fy);
  const float ax = fx - flx, ay = fy - fly;
  auto wrap = [](long long i, int n) { const long long m = i % n; return static_cast<int>(m < 0 ? m + n : m); };
  const int x0 = wrap(static_cast<long long>(flx), tex.width), x1 = wrap(static_cast<long long>(flx) + 1, tex.width);
  const int y0 = wrap(static_cast<long long>(fly), tex.height), y1 = wrap(static_cast<long long>(fly) + 1, tex.height);
  auto at = [&](int y, int x) {
    const float* p = tex.data + (std::int64_t(y) * tex.width + x) * 3;
    return glm::vec3(p[0], p[1], p[2]);
  };
  return (1.f - ay) * ((1.f - ax) * at(y0, x0) + ax * at(y0, x1)) + ay * ((1.f - ax) * at(y1, x0) + ax * at(y1, x1));
}

glm::vec3 Albedo(const EmbreeScene& scene, const SurfaceView& s, std::int32_t prim, float bu, float bv) {
  const float bw = 1.f - bu - bv;
  if (s.uvs != nullptr && s.num_textures > 0) {
    const int tid = s.texture_ids != nullptr ? s.texture_ids[prim] : 0;
    if (tid >= 0 && tid < s.num_textures) {
      const float* uv = s.uvs + 6 * std::int64_t(prim);
      const float tu = bw * uv[0] + bu * uv[2] + bv * uv[4];
      const float tv = bw * uv[1] + bu * uv[3] + bv * uv[5];
      return SampleTexture(s.textures[tid], tu, tv);
    }
  }
  if (s.vertex_colors != nullptr) {
    const std::int32_t* f = scene.Faces() + 3 * std::int64_t(prim);
    const float* c0 = s.vertex_colors + 3 * std::int64_t(f[0]);
    const float* c1 = s.vertex_colors + 3 * std::int64_t(f[1]);
    const float* c2 = s.vertex_colors + 3 * std::int64_t(f[2]);
    return bw * glm::vec3(c0[0], c0[1], c0[2]) + bu * glm::vec3(c1[0], c1[1], c1[2]) +
           bv * glm::vec3(c2[0], c2[1], c2[2]);
  }
  return glm::vec3(0.8f);
}

// The shading model of raycast.h at one hit.
glm::vec3 Shade(const EmbreeScene& scene, const SurfaceView& s, const ShadingOptions& sh, RayQuery& query,
                const glm::vec3& origin, const glm::vec3& dir, const Hit& h, const glm::vec3& n) {
  const glm::vec3 albedo = Albedo(scene, s, h.prim, h.u, h.v);
  const glm::vec3 p = origin + h.t * dir;
  const glm::vec3 view = -glm::normalize(dir);
  float ks = 0.f, shininess = 0.f;
  const std::int32_t obj = scene.ObjectIds()[h.prim];
  if (s.materials != nullptr && obj >= 0 && obj < s.num_materials) {
    ks = s.materials[2 * obj];
    shininess = s.materials[2 * obj + 1];
  }
  // Shadow-ray offset along the normal: above float rounding of p at this scene's scale.
  const float eps = 1e-5f * (scene.Extent() + glm::length(p));
  const glm::vec3 p_off = p + eps * n;
  glm::vec3 diffuse(sh.ambient);
  glm::vec3 specular(0.f);
  for (int i = 0; i < sh.num_lights; ++i) {
    const Light& light = sh.lights[i];
    const glm::vec3 lc(light.color[0], light.color[1], light.color[2]);
    const glm::vec3 lv(light.vector[0], light.vector[1], light.vector[2]);
    glm::vec3 l;
    glm::vec3 e;
    float t_light;
    if (light.kind == LightKind::kDirectional) {
      l = glm::normalize(lv);
      e = lc;
      t_light = kInf;
    } else {
      const glm::vec3 to = lv - p;
      const float d2 = glm::dot(to, to);
      if (!(d2 > 0.f)) continue;
      const float d = std::sqrt(d2);
      l = to / d;
      e = lc / d2;
      t_light = d - 2.f * eps;
    }
    const float nl = glm::dot(n, l);
    if (!(nl > 0.f)) continue;
    if (light.shadows) {
      RTCRay r;
      r.org_x = p_off.x, r.org_y = p_off.y, r.org_z = p_off.z;
      r.dir_x = l.x, r.dir_y = l.y, r.dir_z = l.z;
      r.tnear = 0.f;
      r.tfar = t_light;
      r.time = 0.f;
      r.mask = 0xFFFFFFFFu;
      r.id = 0;
      r.flags = 0;
      query.Occluded1(scene.Handle(), &r);
      if (r.tfar < 0.f) continue;  // Embree sets tfar = -inf when the ray is blocked
    }
    diffuse += e * nl;
    if (ks > 0.f && shininess > 0.f) {
      const glm::vec3 half = glm::normalize(l + view);
      const float nh = std::max(0.f, glm::dot(n, half));
      specular += ks * std::pow(nh, shininess) * e;
    }
  }
  return albedo * diffuse + specular;
}

}  // namespace

void CheckSurface(const SurfaceView& s, std::int64_t num_faces) {
  if (s.uvs != nullptr) {
    for (std::int64_t i = 0; i < num_faces * 6; ++i) {
      if (!std::isfinite(s.uvs[i])) {
        throw BadValueError("uvs: face " + std::to_string(i / 6) + " has a NaN or infinite uv");
      }
    }
  }
  if (s.texture_ids != nullptr) {
    for (std::int64_t i = 0; i < num_faces; ++i) {
      if (s.texture_ids[i] < -1 || s.texture_ids[i] >= s.num_textures) {
        throw BadValueError("texture_ids: face " + std::to_string(i) + " has texture id " +
                            std::to_string(s.texture_ids[i]) + ", outside [-1, " +
                            std::to_string(s.num_textures) + ")");
      }
    }
  }
  for (int t = 0; t < s.num_textures; ++t) {
    if (s.textures[t].data == nullptr || s.textures[t].width <= 0 || s.textures[t].height <= 0) {
      throw BadValueError("textures[" + std::to_string(t) + "]: empty texture");
    }
  }
  for (int i = 0; i < 2 * s.num_materials; ++i) {
    if (!std::isfinite(s.materials[i]) || s.materials[i] < 0.f) {
      throw BadValueError("materials: object " + std::to_string(i / 2) +
                          " has a negative, NaN or infinite (specular, shininess)");
    }
  }
}

void CheckRaycastOptions(const RaycastOptions& o) {
  if (o.packet != 1 && o.packet != 8 && o.packet != 16) {
    throw BadValueError("packet: expected 1, 8 or 16, got " + std::to_string(o.packet));
  }
}

LightKind LightKindFromName(const std::string& kind, std::size_t index) {
  if (kind == "point") return LightKind::kPoint;
  if (kind == "directional") return LightKind::kDirectional;
  throw BadValueError("lights[" + std::to_string(index) + "]: kind must be 'point' or 'directional', got '" + kind +
                      "'");
}

RTCBuildQuality BuildQualityFromName(const std::string& quality) {
  if (quality == "low") return RTC_BUILD_QUALITY_LOW;
  if (quality == "medium") return RTC_BUILD_QUALITY_MEDIUM;
  if (quality == "high") return RTC_BUILD_QUALITY_HIGH;
  throw BadValueError("quality: expected 'low', 'medium' or 'high', got '" + quality + "'");
}

void CheckShading(const ShadingOptions& sh) {
  if (!std::isfinite(sh.ambient) || sh.ambient < 0.f) {
    throw BadValueError("ambient: expected a finite number >= 0, got " + std::to_string(sh.ambient));
  }
  for (int c = 0; c < 3; ++c) {
    if (!std::isfinite(sh.background[c])) throw BadValueError("background: expected finite colour");
  }
  for (int i = 0; i < sh.num_lights; ++i) {
    const Light& l = sh.lights[i];
    const std::string name = "lights[" + std::to_string(i) + "]";
    float len2 = 0.f;
    for (int c = 0; c < 3; ++c) {
      if (!std::isfinite(l.vector[c])) throw BadValueError(name + ": vector has NaN or infinity");
      if (!std::isfinite(l.color[c]) || l.color[c] < 0.f) {
        throw BadValueError(name + ": colour must be finite and >= 0");
      }
      len2 += l.vector[c] * l.vector[c];
    }
    if (l.kind == LightKind::kDirectional && !(len2 > 0.f)) {
      throw BadValueError(name + ": a directional light needs a non-zero direction");
    }
  }
}

void RaycastCamera(const EmbreeScene& scene, const Camera& camera, const SurfaceView& surface,
                   const ShadingOptions& shading, const RaycastOptions& options,
                   const RaycastOutputs& out) {
  const std::int64_t width = camera.width;
  const glm::vec3 origin(camera.CentreInWorld());
  const std::int32_t* object_ids = scene.ObjectIds();
  const bool need_normal = out.normal != nullptr || out.color != nullptr;
  const bool unit_rays = camera.model == CameraModel::kEquirect;
  auto fn = [&](int py, int px, const glm::vec3& dir, const Hit& h, RayQuery& query) {
    const std::int64_t i = std::int64_t(py) * width + px;
    const bool is_hit = h.prim >= 0;
    if (out.depth) out.depth[i] = h.t;  // t is z (pinhole) or distance (equirect): see raycast.h
    // Equirect rays are unit by construction: their distance is t itself (= depth, exactly).
    if (out.distance) out.distance[i] = is_hit ? (unit_rays ? h.t : h.t * glm::length(dir)) : 0.f;
    if (out.prim_id) out.prim_id[i] = h.prim;
    if (out.object_id) out.object_id[i] = is_hit ? object_ids[h.prim] : -1;
    if (out.hit) out.hit[i] = is_hit ? 1 : 0;
    if (out.bary) {
      out.bary[2 * i] = is_hit ? h.u : 0.f;
      out.bary[2 * i + 1] = is_hit ? h.v : 0.f;
    }
    if (!need_normal) return;
    if (!is_hit) {
      if (out.normal) out.normal[3 * i] = out.normal[3 * i + 1] = out.normal[3 * i + 2] = 0.f;
      if (out.color) {
        for (int c = 0; c < 3; ++c) out.color[3 * i + c] = shading.background[c];
      }
      return;
    }
    const glm::vec3 n = FacingNormal(h.ng, dir);
    if (out.normal) {
      out.normal[3 * i] = n.x, out.normal[3 * i + 1] = n.y, out.normal[3 * i + 2] = n.z;
    }
    if (out.color) {
      const glm::vec3 c = Shade(scene, surface, shading, query, origin, dir, h, n);
      out.color[3 * i] = c.x, out.color[3 * i + 1] = c.y, out.color[3 * i + 2] = c.z;
    }
  };
  Trace(scene, camera, options, fn);
}

void MarkVisibleObjects(const EmbreeScene& scene, const Camera& camera, const RaycastOptions& options,
                        std::atomic<std::uint8_t>* visible) {
  const std::int32_t* object_ids = scene.ObjectIds();
  auto fn = [&](int, int, const glm::vec3&, const Hit& h, RayQuery&) {
    if (h.prim < 0) return;
    const std::int32_t id = object_ids[h.prim];
    // Every writer stores the same value: the result does not depend on the order.
    if (id >= 0) visible[id].store(1, std::memory_order_relaxed);
  };
  Trace(scene, camera, options, fn);
}

std::vector<std::int32_t> VisibleObjects(const EmbreeScene& scene, const Camera& camera,
                                         const RaycastOptions& options) {
  const std::int32_t n = scene.MaxObjectId() + 1;
  std::vector<std::int32_t> ids;
  if (n <= 0) return ids;
  std::vector<std::atomic<std::uint8_t>> visible(static_cast<std::size_t>(n));
  for (auto& v : visible) v.store(0, std::memory_order_relaxed);
  MarkVisibleObjects(scene, camera, options, visible.data());
  scene.ThrowIfError("ray queries");
  for (std::int32_t id = 0; id < n; ++id) {
    if (visible[id].load(std::memory_order_relaxed)) ids.push_back(id);
  }
  return ids;
}

}  // namespace ibr

// ============================================================================================
// Depth peeling (raycast.h "Deep depth buffers")
// ============================================================================================
namespace ibr {
namespace {

// Umbra offset x (Eq. 1) past a quad at depth d on the ray of a pixel whose projector ray has
// lateral slope |r_xy| = rn; see raycast.h for the derivation. 0 = standard peeling.
double UmbraOffset(const PeelOptions& o, double d, double rn, double s) {
  if (o.num_novel <= 0) return 0.0;
  double x = std::numeric_limits<double>::infinity();
  for (int k = 0; k < o.num_novel && x > 0.0; ++k) {
    const double* p = o.novel_in_cam + 3 * k;
    const double c = p[2] + o.novel_radius;  // the nearest the quad the camera may be (smallest D)
    const double dd = d - c;
    if (!(dd > 0.0)) return 0.0;  // a camera at or past the quad's depth: no umbra
    const double e = std::sqrt(p[0] * p[0] + p[1] * p[1]) + o.novel_radius;
    const double h = (std::abs(p[2]) + o.novel_radius) * rn;
    const double spread = e + h - s;
    if (!(spread > 0.0)) continue;  // the whole umbra is infinite for this camera
    x = std::min(x, dd * s / spread);
  }
  return x;
}

}  // namespace

void CheckPeel(const Camera& camera, const PeelOptions& o) {
  if (o.layers < 1) throw BadValueError("layers: expected an integer >= 1, got " + std::to_string(o.layers));
  if (o.num_novel > 0) {
    if (camera.model != CameraModel::kPinhole) {
      throw BadValueError("umbra: generalised umbra culling needs a pinhole source camera");
    }
    if (!std::isfinite(o.novel_radius) || o.novel_radius < 0.0) {
      throw BadValueError("umbra radius: expected a finite number >= 0");
    }
    for (int i = 0; i < 3 * o.num_novel; ++i) {
      if (!std::isfinite(o.novel_in_cam[i])) {
        throw BadValueError("umbra positions: camera " + std::to_string(i / 3) + " has NaN or infinite coordinates");
      }
    }
  }
}

void PeelCamera(const EmbreeScene& scene, const Camera& camera, const PeelOptions& options,
                const PeelOutputs& out) {
  constexpr int N = 16, BW = 4, BH = 4;
  const CameraRays rays(camera);
  const RTCScene handle = scene.Handle();
  const std::int32_t* object_ids = scene.ObjectIds();
  const std::int64_t width = camera.width, plane = std::int64_t(camera.width) * camera.height;
  const int layers = options.layers;
  const float extent_eps = 1e-7f * scene.Extent();
  const bool pinhole = camera.model == CameraModel::kPinhole;
  const double half_pixel = pinhole ? 0.5 / std::max(camera.fx, camera.fy) : 0.0;
  ParallelFor2D(camera.height, camera.width, options.tile, [&](int y0, int y1, int x0, int x1) {
    RayQuery query(/*coherent=*/true);
    alignas(64) int valid[N];
    RTCRayHit16 rh;
    float tnear[N];
    std::int32_t prev_prim[N];
    glm::vec3 dir[N];
    double rn[N];
    std::int64_t pix[N];
    for (int by = y0; by < y1; by += BH) {
      for (int bx = x0; bx < x1; bx += BW) {
        for (int k = 0; k < N; ++k) {
          const int px = bx + k % BW, py = by + k / BW;
          const bool ok = px < x1 && py < y1;
          valid[k] = ok ? -1 : 0;
          dir[k] = ok ? rays.Dir(px, py) : glm::vec3(0.f, 0.f, 1.f);
          pix[k] = ok ? std::int64_t(py) * width + px : 0;
          tnear[k] = 0.f;
          prev_prim[k] = -1;
          rn[k] = pinhole ? std::hypot((px + 0.5 - camera.cx) / camera.fx, (py + 0.5 - camera.cy) / camera.fy) : 0.0;
        }
        for (int layer = 0; layer < layers; ++layer) {
          bool any = false;
          for (int k = 0; k < N; ++k) {
            any |= valid[k] != 0;
            SetLane(rh, k, rays.origin, dir[k], tnear[k]);
          }
          if (any) query.Intersect16(valid, handle, &rh);
          for (int k = 0; k < N; ++k) {
            const int px = bx + k % BW, py = by + k / BW;
            if (px >= x1 || py >= y1) continue;
            const std::int64_t i = layer * plane + pix[k];
            float t = 0.f;
            std::int32_t prim = -1;
            if (valid[k] && rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID) {
              t = rh.ray.tfar[k];
              prim = static_cast<std::int32_t>(rh.hit.primID[k]);
              // The previous layer's triangle again (float rounding only): trace on past it.
              for (int retry = 0; prim == prev_prim[k] && retry < 4; ++retry) {
                RTCRayHit r1;
                SetRay1(r1, rays.origin, dir[k], t + 1e-4f * t + extent_eps);
                query.Intersect1(handle, &r1);
                if (r1.hit.geomID == RTC_INVALID_GEOMETRY_ID) { prim = -1; t = 0.f; break; }
                t = r1.ray.tfar;
                prim = static_cast<std::int32_t>(r1.hit.primID);
              }
              if (prim == prev_prim[k]) { prim = -1; t = 0.f; }
            }
            if (out.depth) out.depth[i] = t;
            if (out.object_id) out.object_id[i] = prim >= 0 ? object_ids[prim] : -1;
            if (prim < 0) {
              valid[k] = 0;
              continue;
            }
            prev_prim[k] = prim;
            const double x = UmbraOffset(options, t, rn[k], half_pixel * t);
            const double next = double(t) + 1e-5 * t + extent_eps + x;
            if (!(next < 3.0e38)) valid[k] = 0;  // infinite umbra: nothing behind is visible
            else tnear[k] = static_cast<float>(next);
          }
        }
      }
    }
  });
}

}  // namespace ibr
