// Reference ray casting of a camera against an EmbreeScene: primary-ray buffers (depth,
// distance, normal, object id, primitive id, barycentrics, hit mask) and a shaded linear
// colour (texture / vertex colour / grey albedo, Lambert + Blinn-Phong, point and directional
// lights, hard shadows by occlusion rays, ambient term).
//
// Rays: one per pixel through its centre (u + 0.5, v + 0.5) (cpp/ibr/camera.h), from the
// camera centre, direction RayInCam rotated to world. Pinhole rays have z_cam = 1, so the hit
// parameter t is the z-depth; equirect rays have unit length, so t is the ray distance. Hence
// "depth" is the scene model's depth convention (cpp/ibr/camera.h: depth_z for pinhole, depth_ray for
// equirect): z for pinhole, distance for equirect; 0 where nothing is hit (unknown).
//
// Output layout (all row-major, C-contiguous; any pointer may be null = not computed):
//   depth     float (H, W)      0 = no hit
//   distance  float (H, W)      distance from the camera centre to the hit; 0 = no hit
//   normal    float (H, W, 3)   unit geometric normal in world axes, flipped to face the
//                                camera; (0, 0, 0) = no hit
//   object_id int32 (H, W)      object id of the hit face; -1 = no hit
//   prim_id   int32 (H, W)      index of the hit face; -1 = no hit
//   bary      float (H, W, 2)   Embree's (u, v): p = (1-u-v) v0 + u v1 + v v2; 0 = no hit
//   hit       uint8 (H, W)      1 = hit, 0 = no hit (numpy bool)
//   color     float (H, W, 3)   linear RGB, `background` where no hit
//
// Shading model (per hit, N = normal facing the camera, V = towards the camera):
//   albedo  A = bilinear texture sample (uv interpolated with the barycentrics; OBJ convention,
//               texel row = (1 - v) * H, column = u * W, repeat wrap), else the barycentric mix of
//               vertex colours, else 0.8 grey.
//   light l: L = unit vector towards the light. Directional: `vector` is the direction towards
//            the light, E = colour. Point: `vector` is the position, E = colour / d^2 (inverse
//            square law, d = distance to the light).
//   colour  = A * (ambient + sum_l E_l max(0, N.L_l) S_l)
//             + sum_l ks E_l max(0, N.H_l)^shininess S_l [N.L_l > 0]      (Blinn 1977)
//   with H_l = normalize(L_l + V), (ks, shininess) = materials[object id] (missing or ks = 0 =
//   diffuse only) and S_l = 0 when the light is blocked (occlusion ray, if the light casts
//   shadows), else 1. There is no 1/pi: a white Lambert surface lit head-on by a directional
//   light of colour c shows A * (ambient + c).
//
// Deterministic: the image is cut into tiles and packets by its size only, so the result is
// identical for any thread count. The kernel never throws nor allocates beyond its stack.
#pragma once
#include <cstddef>
#include <string>
#include <atomic>
#include <cstdint>
#include <vector>

#include "ibr/camera.h"
#include "ibr/embree_scene.h"

namespace ibr {

struct RaycastOutputs {
  float* depth = nullptr;
  float* distance = nullptr;
  float* normal = nullptr;
  std::int32_t* object_id = nullptr;
  std::int32_t* prim_id = nullptr;
  float* bary = nullptr;
  std::uint8_t* hit = nullptr;
  float* color = nullptr;
};

enum class LightKind : int { kPoint = 0, kDirectional = 1 };

struct Light {
  LightKind kind = LightKind::kDirectional;
  float vector[3] = {0.f, 0.f, 1.f};  // point: position; directional: direction towards the light
  float color[3] = {1.f, 1.f, 1.f};   // linear RGB intensity (see the shading model above)
  bool shadows = true;
};

// A texture: float32 linear RGB (H, W, 3), row 0 at the top of the image.
struct TextureView {
  const float* data = nullptr;
  int height = 0;
  int width = 0;
};

// Shading attributes of the mesh (null / 0 = absent); sizes as in python/ibrtools/mesh.py.
struct SurfaceView {
  const float* vertex_colors = nullptr;     // (N, 3)
  const float* uvs = nullptr;               // (M, 3, 2), OBJ convention
  const std::int32_t* texture_ids = nullptr;  // (M,), -1 = untextured; null = all texture 0
  const TextureView* textures = nullptr;
  int num_textures = 0;
  const float* materials = nullptr;         // (K, 2): specular strength, shininess exponent
  int num_materials = 0;
};

struct ShadingOptions {
  const Light* lights = nullptr;
  int num_lights = 0;
  float ambient = 0.15f;
  float background[3] = {0.f, 0.f, 0.f};
};

struct RaycastOptions {
  // Primary rays per Embree query: 1 (rtcIntersect1, the scalar reference path), 8 (4x2 pixel
  // blocks, rtcIntersect8) or 16 (4x4 blocks, rtcIntersect16). 16 measured fastest on AVX-512
  // and AVX2 machines (docs/benchmarks.md).
  int packet = 16;
  // Tile edge in pixels before ParallelFor2D's grain floor enlarges it.
  int tile = 32;
};

// Fronts (they throw BadValueError; the kernels below trust what passes them):
// uvs finite, texture ids in [-1, num_textures), textures non-empty, materials finite and >= 0.
void CheckSurface(const SurfaceView& surface, std::int64_t num_faces);
// Light vectors and colours finite, colours >= 0, directional vectors non-zero, ambient finite.
void CheckShading(const ShadingOptions& shading);
// packet 1, 8 or 16.
void CheckRaycastOptions(const RaycastOptions& options);
// "point" / "directional" (BadValueError naming lights[index] otherwise).
LightKind LightKindFromName(const std::string& name, std::size_t index);
// The BVH build quality "low", "medium" or "high" (BadValueError naming quality otherwise).
RTCBuildQuality BuildQualityFromName(const std::string& name);

// Kernel: fills every non-null output of `out` for camera.width x camera.height pixels.
void RaycastCamera(const EmbreeScene& scene, const Camera& camera, const SurfaceView& surface,
                   const ShadingOptions& shading, const RaycastOptions& options,
                   const RaycastOutputs& out);

// Kernel: sets visible[id] = 1 for every object id hit by a primary ray of the camera.
// `visible` has scene.MaxObjectId() + 1 entries, zeroed by the caller.
void MarkVisibleObjects(const EmbreeScene& scene, const Camera& camera, const RaycastOptions& options,
                        std::atomic<std::uint8_t>* visible);

// Front: the sorted unique object ids (>= 0) hit by any primary ray of the camera (the
// ground truth of visibility culling).
std::vector<std::int32_t> VisibleObjects(const EmbreeScene& scene, const Camera& camera,
                                         const RaycastOptions& options = {});


// --- Deep depth buffers by depth peeling (Lee, Kim, Eisemann 2018, sec. 3.4; Everitt 2001) ---
//
// Layer 0 is the primary-ray hit of every pixel; layer k + 1 continues the same ray past layer
// k's hit: tnear = t_k + eps(t_k) + x(t_k), where eps(t) = 1e-5 t + 1e-7 extent is far above the
// float rounding of a hit parameter (so the same surface, or its neighbour triangle at a shared
// edge, is not hit again at t_k) and x is the umbra offset (0 = standard depth peeling). A hit of
// the very triangle of layer k (possible only through rounding) is skipped by re-tracing past it.
// Hence per pixel the non-empty layers come first and their depths increase strictly.
//
// Generalised umbra culling (Eq. 1): the pixel quad at depth d (the previous layer's hit) is
// taken as an opaque square of half-size s = d / (2 max(fx, fy)) (the disc it contains) in the
// plane z = d of the source camera. A novel camera at o = (ox, oy, c) in source camera axes
// sees a point of the pixel's ray at depth d + x past the quad only if the segment between them
// misses the quad; in the plane z = d that segment is at lateral distance |a| x / (D + x) from
// the ray, D = d - c, |a| = the lateral distance (in the plane z = c) between o and the pixel's
// ray. Hidden while that is <= s:   x <= D s / (|a| - s)   (Eq. 1 with e + h >= |a|: e = |o_xy|,
// the camera's distance to the centre ray (optical axis), h = |c| |r_xy|, the offset of the
// pixel's projector ray r = ((u - cx) / fx, (v - cy) / fy, 1) from the axis at depth c; the
// triangle inequality makes e + h an upper bound of |a|, i.e. a smaller, safe x). A set of
// novel cameras (each also within `novel_radius` of its given position: c + radius, e + radius,
// |c| + radius) skips only what every one of them cannot see: x = min over cameras; x = 0 when
// D <= 0 (the camera is past the quad); x = +inf when e + h <= s for every camera (nothing
// behind the pixel is visible: the pixel's later layers stay empty; this bounds the layers).
// Pinhole source cameras only (the front checks); the peeled depth is z (= t on pinhole rays).
struct PeelOptions {
  int layers = 4;
  // Novel camera centres in the *source camera's* axes, (K, 3) row-major; K = 0: no culling.
  const double* novel_in_cam = nullptr;
  int num_novel = 0;
  double novel_radius = 0.0;
  int tile = 32;
};

// Outputs (L, H, W) row-major, layer-major; either may be null.
//   depth      float   z (pinhole) or ray distance (equirect) of layer k's hit; 0 = empty
//   object_id  int32   object id of the hit face; -1 = empty
struct PeelOutputs {
  float* depth = nullptr;
  std::int32_t* object_id = nullptr;
};

// Front: throws BadValueError for layers < 1, umbra cameras with NaN / infinite coordinates, a
// negative radius, or umbra culling asked of a non-pinhole camera.
void CheckPeel(const Camera& camera, const PeelOptions& options);

// Kernel: fills the L layers for every pixel. Deterministic (partition by image size only).
void PeelCamera(const EmbreeScene& scene, const Camera& camera, const PeelOptions& options,
                const PeelOutputs& out);

}  // namespace ibr
