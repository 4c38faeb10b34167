// G-buffer by rasterisation (gbuffer_raster.h).
#include "kernels/hybrid/gbuffer_raster.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <glm/glm.hpp>

#include "ibr/bands.h"
#include "ibr/parallel.h"
#include "ibr/raster.h"
#include "ibr/simd.h"

namespace ibr {
namespace {

constexpr int kBandRows = 16;

// A triangle to draw: snapped vertices (cpp/ibr/raster.h; 32-bit inside the guard band), oriented
// so that area2 > 0. 80 bytes (104 with 64-bit coordinates: the bins are walked once per band).
struct ScreenTri {
  std::int32_t X[3], Y[3];
  double iz[3];  // 1 / z at the vertices
  std::int64_t area2;
  std::int32_t prim;
  raster::CentreBox box;  // candidate centres in the image
};

// A vertex projected once for all the faces that share it: snapped screen position and 1 / z;
// `ok` when it is in front of the near plane and inside the guard band (a face of three such
// vertices needs no clipping: the common case, which then projects nothing per face).
struct ScreenPoint {
  std::int32_t X, Y;
  double iz;
  bool ok;
};

// The projection of camera-space p (z >= near) to the screen, as every path computes it (a vertex
// shared by a clipped and an unclipped face snaps to the same point).
inline raster::ScreenVertex Project(const Camera& cam, const glm::dvec3& p) {
  const double iz = 1.0 / p.z;
  return {cam.fx * p.x * iz + cam.cx, cam.fy * p.y * iz + cam.cy, iz};
}

inline bool Finite(const raster::ScreenVertex& s) {
  return std::isfinite(s.x) && std::isfinite(s.y) && std::isfinite(s.iz);
}

// Appends triangle (X, Y, iz) of face `prim` when it has area and covers a pixel centre.
void Emit(const Camera& cam, const std::int32_t X[3], const std::int32_t Y[3], const double iz[3], std::int32_t prim,
          std::vector<ScreenTri>* out) {
  ScreenTri t;
  std::copy(X, X + 3, t.X);
  std::copy(Y, Y + 3, t.Y);
  std::copy(iz, iz + 3, t.iz);
  std::int64_t X64[3] = {X[0], X[1], X[2]}, Y64[3] = {Y[0], Y[1], Y[2]};
  t.area2 = raster::Area2(X64, Y64);
  if (t.area2 == 0) return;
  if (t.area2 < 0) {  // either winding: the G-buffer draws both sides
    std::swap(X64[1], X64[2]);
    std::swap(Y64[1], Y64[2]);
    std::swap(t.X[1], t.X[2]);
    std::swap(t.Y[1], t.Y[2]);
    std::swap(t.iz[1], t.iz[2]);
    t.area2 = -t.area2;
  }
  if (!raster::Centres(X64, Y64, 0, cam.width - 1, 0, cam.height - 1, &t.box)) return;
  t.prim = prim;
  out->push_back(t);
}

// Appends the screen triangles of face `prim` (camera-space vertices p) clipped to z >= near and to
// the rasteriser's guard band: the faces whose vertices are not all ScreenPoint::ok.
void SetUp(const Camera& cam, const glm::dvec3 p[3], double near, std::int32_t prim, std::vector<ScreenTri>* out) {
  glm::dvec3 poly[4];
  const bool in_front = p[0].z >= near && p[1].z >= near && p[2].z >= near;
  if (in_front) std::copy(p, p + 3, poly);
  const int n = in_front ? 3 : raster::ClipPolygon(
      p, 3, poly, [near](const glm::dvec3& v) { return v.z >= near; },
      [](const glm::dvec3& a, const glm::dvec3& b) {
        return a.x < b.x || (a.x == b.x && (a.y < b.y || (a.y == b.y && a.z < b.z)));
      },
      [near](const glm::dvec3& a, const glm::dvec3& b) {
        const double t = (near - a.z) / (b.z - a.z);
        glm::dvec3 c = a + t * (b - a);
        c.z = near;
        return c;
      });
  if (n < 3) return;
  raster::ScreenVertex sv[8];
  bool in_band = true;
  for (int i = 0; i < n; ++i) {
    sv[i] = Project(cam, poly[i]);
    if (!Finite(sv[i])) return;
    in_band = in_band && raster::InGuardBand(sv[i].x, sv[i].y);
  }
  raster::ScreenVertex clipped[8];
  const raster::ScreenVertex* v = sv;
  int m = n;
  if (!in_band) {  // a face reaching far outside the image (next to the near plane)
    m = raster::ClipToGuardBand(sv, n, clipped);
    v = clipped;
  }
  for (int k = 1; k + 1 < m; ++k) {
    const int idx[3] = {0, k, k + 1};
    std::int32_t X[3], Y[3];
    double iz[3];
    for (int j = 0; j < 3; ++j) {
      X[j] = raster::ToFixed(v[idx[j]].x);
      Y[j] = raster::ToFixed(v[idx[j]].y);
      iz[j] = v[idx[j]].iz;
    }
    Emit(cam, X, Y, iz, prim, out);
  }
}

// Scan-converts t into rows [r0, r1] of the band (the core's inclusive edges: a centre on an edge
// shared by two faces is covered by both, no cracks): nearest 1/z wins (ties: smaller prim). 1/z
// is interpolated with the snapped triangle's barycentric weights.
void Raster(const ScreenTri& t, int r0, int r1, int width, float* best_iz, std::int32_t* prim) {
  raster::CentreBox box = t.box;
  box.y0 = std::max(box.y0, r0);
  box.y1 = std::min(box.y1, r1);
  if (box.y0 > box.y1) return;
  const std::int64_t X[3] = {t.X[0], t.X[1], t.X[2]}, Y[3] = {t.Y[0], t.Y[1], t.Y[2]};
  raster::Edges E;
  raster::SetupEdges(X, Y, box.x0, box.y0, /*inclusive=*/true, &E);
  const double inv = 1.0 / static_cast<double>(t.area2);
  raster::ScanTriangle(E, box, [&](int x, int y, std::int64_t e0, std::int64_t e1, std::int64_t e2) {
    const float iz = static_cast<float>(
        (static_cast<double>(e0) * t.iz[0] + static_cast<double>(e1) * t.iz[1] + static_cast<double>(e2) * t.iz[2]) * inv);
    const std::int64_t i = static_cast<std::int64_t>(y) * width + x;
    if (iz > best_iz[i] || (iz == best_iz[i] && t.prim < prim[i])) {
      best_iz[i] = iz;
      prim[i] = t.prim;
    }
  });
}

// Rows [r0, r1] of the visibility pass: cleared, then the triangles reaching them (`tris`, the
// band's bin, in face order) scan-converted. This and AttributeRow, the per-pixel loops, run through
// ParallelForIsa (cpp/ibr/simd.h: built for AVX2 and the baseline, the same bits): G-buffer 8.0 ->
// 6.9 ms at 1280x720 on a Zen 3 EPYC (bench_hybrid's scene, 2 threads).
void RasterBand(const ScreenTri* const* tris, std::int64_t count, int r0, int r1, int width, float* best_iz,
                std::int32_t* prim) {
  std::fill(best_iz + static_cast<std::int64_t>(r0) * width, best_iz + static_cast<std::int64_t>(r1 + 1) * width, 0.f);
  std::fill(prim + static_cast<std::int64_t>(r0) * width, prim + static_cast<std::int64_t>(r1 + 1) * width, -1);
  for (std::int64_t i = 0; i < count; ++i) Raster(*tris[i], r0, r1, width, best_iz, prim);
}

// Per-face constants of the attribute pass (RasterGBuffer): with the ray origin at the camera
// centre (0 in camera axes) and d = ((x - cx) / fx, (y - cy) / fy, 1), Moller-Trumbore's
// u = s.(d x e2) / e1.(d x e2), v = d.(s x e1) / e1.(d x e2), t = e2.(s x e1) / e1.(d x e2) (s = -p0)
// are ratios of dot products of d with per-face vectors (triple product identities):
// u = d.A / d.C, v = d.B / d.C, t = T / d.C with A = e2 x s, B = s x e1, C = e2 x e1, T = e2.B.
struct FaceRay {
  glm::dvec3 a, b, c, n_world;
  double t;
};

FaceRay MakeFaceRay(const Camera& camera, const std::vector<glm::dvec3>& pc, const std::int32_t* fv) {
  const glm::dvec3 &p0 = pc[fv[0]], &p1 = pc[fv[1]], &p2 = pc[fv[2]];
  const glm::dvec3 e1 = p1 - p0, e2 = p2 - p0, s = -p0;
  FaceRay r;
  r.a = glm::cross(e2, s);
  r.b = glm::cross(s, e1);
  r.c = glm::cross(e2, e1);
  r.t = glm::dot(e2, r.b);
  glm::dvec3 n = glm::cross(e1, e2);
  const double len = glm::length(n);
  n = len > 0 ? n / len : glm::dvec3(0.0);
  if (glm::dot(n, p0) > 0) n = -n;  // facing the camera (the camera is at 0)
  r.n_world = camera.WorldFromCamDir(n);
  return r;
}

// Row y of the attribute pass: depth (from 1/z to the ray's t), barycentrics and normal at each
// covered pixel centre, zeros elsewhere.
// The face's constants are made at the pixels that show it (a run of pixels of one face makes them
// once): a frame shows fewer faces than a large mesh has in view (1.27 M-face lego mesh at 800x800).
void AttributeRow(const Camera& camera, const std::vector<glm::dvec3>& pc, const std::int32_t* faces, std::int64_t y,
                  float* depth, const std::int32_t* prim_id, float* bary, float* normal) {
  const int w = camera.width;
  const double dy = (static_cast<double>(y) + 0.5 - camera.cy) / camera.fy;
  FaceRay r{};
  std::int32_t r_face = -1;
  for (int x = 0; x < w; ++x) {
    const std::int64_t i = y * w + x;
    float* bo = bary + 2 * i;
    const std::int32_t f = prim_id[i];
    if (f < 0) {
      depth[i] = 0.f;
      bo[0] = bo[1] = 0.f;
      if (normal) normal[3 * i] = normal[3 * i + 1] = normal[3 * i + 2] = 0.f;
      continue;
    }
    if (f != r_face) {
      r = MakeFaceRay(camera, pc, faces + 3 * static_cast<std::int64_t>(f));
      r_face = f;
    }
    const glm::dvec3 d((static_cast<double>(x) + 0.5 - camera.cx) / camera.fx, dy, 1.0);
    const double det = glm::dot(d, r.c);
    double u = 0, v = 0, t = 0;
    if (std::abs(det) > 0) {
      const double id = 1.0 / det;
      u = glm::dot(d, r.a) * id;
      v = glm::dot(d, r.b) * id;
      t = r.t * id;
    }
    // Clamp to the face (pixel centres on an edge may land a rounding error outside).
    u = std::max(0.0, u);
    v = std::max(0.0, v);
    if (u + v > 1.0) {
      const double k = 1.0 / (u + v);
      u *= k;
      v *= k;
    }
    if (!(t > 0.0) || !std::isfinite(t)) {  // grazing face: depth from the clamped point
      const std::int32_t* fv = faces + 3 * static_cast<std::int64_t>(f);
      t = ((1.0 - u - v) * pc[fv[0]] + u * pc[fv[1]] + v * pc[fv[2]]).z;
    }
    depth[i] = static_cast<float>(t);
    bo[0] = static_cast<float>(u);
    bo[1] = static_cast<float>(v);
    if (normal) {
      normal[3 * i] = static_cast<float>(r.n_world.x);
      normal[3 * i + 1] = static_cast<float>(r.n_world.y);
      normal[3 * i + 2] = static_cast<float>(r.n_world.z);
    }
  }
}

}  // namespace

void RasterGBuffer(const Camera& camera, const float* vertices, std::int64_t num_vertices, const std::int32_t* faces,
                   std::int64_t num_faces, float* depth, std::int32_t* prim_id, float* bary, float* normal) {
  const int w = camera.width, h = camera.height;
  // Camera-space vertices.
  std::vector<glm::dvec3> pc(static_cast<std::size_t>(num_vertices));
  ParallelFor(num_vertices, 16384, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t i = b; i < e; ++i) {
      pc[i] = camera.CamFromWorld(glm::dvec3(vertices[3 * i], vertices[3 * i + 1], vertices[3 * i + 2]));
    }
  });
  double zmax = 0.0;
  for (const auto& p : pc) zmax = std::max(zmax, std::abs(p.z));
  const double near = std::max(zmax * 1e-7, std::numeric_limits<double>::min());
  // Every vertex projected once (most faces then only gather their three points).
  std::vector<ScreenPoint> sp(static_cast<std::size_t>(num_vertices));
  ParallelFor(num_vertices, 16384, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t i = b; i < e; ++i) {
      ScreenPoint& q = sp[i];
      q = {0, 0, 0.0, false};
      if (!(pc[i].z >= near)) continue;
      const raster::ScreenVertex s = Project(camera, pc[i]);
      if (!Finite(s) || !raster::InGuardBand(s.x, s.y)) continue;
      q = {raster::ToFixed(s.x), raster::ToFixed(s.y), s.iz, true};
    }
  });
  // Screen triangles, set up in chunks (in parallel) and concatenated in face order.
  const std::int64_t chunk = 4096;
  const std::int64_t nchunks = (num_faces + chunk - 1) / chunk;
  std::vector<std::vector<ScreenTri>> parts(static_cast<std::size_t>(nchunks));
  ParallelFor(nchunks, 1, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t c = b; c < e; ++c) {
      auto& out = parts[c];
      out.reserve(static_cast<std::size_t>(chunk));  // a clipped face may give up to 6 (then it regrows)
      for (std::int64_t f = c * chunk; f < std::min(num_faces, (c + 1) * chunk); ++f) {
        const std::int32_t* fv = faces + 3 * f;
        const ScreenPoint &a = sp[fv[0]], &b = sp[fv[1]], &d = sp[fv[2]];
        if (a.ok && b.ok && d.ok) {
          const std::int32_t X[3] = {a.X, b.X, d.X}, Y[3] = {a.Y, b.Y, d.Y};
          const double iz[3] = {a.iz, b.iz, d.iz};
          Emit(camera, X, Y, iz, static_cast<std::int32_t>(f), &out);
          continue;
        }
        const glm::dvec3 p[3] = {pc[fv[0]], pc[fv[1]], pc[fv[2]]};
        if (p[0].z < near && p[1].z < near && p[2].z < near) continue;
        SetUp(camera, p, near, static_cast<std::int32_t>(f), &out);
      }
    }
  });
  // The triangles binned by band of rows, each bin in face order (a counting sort; a band used to
  // walk every triangle: 351 -> 218 ms for a 1.27 M-face mesh at 800x800, 127 ms with AttributeRow's
  // per-pixel face constants; the same output).
  const int nbands = (h + kBandRows - 1) / kBandRows;
  std::vector<std::int64_t> start;
  std::vector<const ScreenTri*> binned;
  BinByBand<const ScreenTri*>(nbands, kBandRows, [&](auto&& emit) {
    for (const auto& part : parts) {
      for (const ScreenTri& t : part) emit(&t, t.box.y0, t.box.y1);
    }
  }, start, binned);
  // Visibility, band by band: depth holds 1/z meanwhile (0 = nothing).
  ParallelForIsa(nbands, 1, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t band = b; band < e; ++band) {
      const int r0 = static_cast<int>(band) * kBandRows;
      RasterBand(binned.data() + start[band], start[band + 1] - start[band], r0, std::min(h - 1, r0 + kBandRows - 1),
                 w, depth, prim_id);
    }
  });
  // Attributes by ray-face intersection at each covered pixel centre (FaceRay, AttributeRow).
  ParallelForIsa(h, 8, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t y = b; y < e; ++y) AttributeRow(camera, pc, faces, y, depth, prim_id, bary, normal);
  });
}

}  // namespace ibr
