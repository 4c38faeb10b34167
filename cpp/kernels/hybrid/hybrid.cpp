// Hybrid IBR rendering kernels: see hybrid.h for the model and the conventions.
#include "kernels/hybrid/hybrid.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <vector>

#include "ibr/parallel.h"
#include "ibr/simd.h"
#include "ibr/resample.h"
#include "kernels/hybrid/ulr.h"

#if defined(__SSE2__)
#include <immintrin.h>  // SSE2; AVX2 only inside target("avx2") functions, called when the CPU has it
#endif

namespace ibr {

std::int64_t InterpolateVertexAttribute(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels,
                                        const std::int32_t* faces, const float* attrib, std::int64_t num_vertices,
                                        int channels, float* out) {
  // A dense mesh's faces and vertices are hit at random (lego: 1.27 M faces, 668 k vertices), so
  // the pixels go in batches: prefetch the hit faces, then their vertices' attributes, then
  // interpolate (the same arithmetic as one pass per pixel; as the TM atlas read, atlas8.cpp).
  constexpr int kBatch = 32;
  FirstIndex first_bad;
  ParallelFor(num_pixels, 16384, [&](std::int64_t b, std::int64_t e) {
    const std::int32_t* face_of[kBatch];  // each pixel's hit face, nullptr: a miss or a bad face
    for (std::int64_t s = b; s < e; s += kBatch) {
      const std::int64_t se = std::min(e, s + kBatch);
      for (std::int64_t i = s; i < se; ++i) {
        if (prim_id[i] >= 0) __builtin_prefetch(faces + 3 * std::int64_t(prim_id[i]));
      }
      for (std::int64_t i = s; i < se; ++i) {
        const std::int32_t f = prim_id[i];
        const std::int32_t* fv = f >= 0 ? faces + 3 * std::int64_t(f) : nullptr;
        if (fv != nullptr && !(fv[0] >= 0 && fv[0] < num_vertices && fv[1] >= 0 && fv[1] < num_vertices &&
                               fv[2] >= 0 && fv[2] < num_vertices)) {
          first_bad.Report(i);  // a vertex index out of range: not read
          fv = nullptr;
        }
        face_of[i - s] = fv;
        if (fv == nullptr) {
          for (int c = 0; c < channels; ++c) out[i * channels + c] = 0.f;
          continue;
        }
        for (int k = 0; k < 3; ++k) __builtin_prefetch(attrib + std::int64_t(fv[k]) * channels);
      }
      for (std::int64_t i = s; i < se; ++i) {
        const std::int32_t* fv = face_of[i - s];
        if (fv == nullptr) continue;
        float* o = out + i * channels;
        const float u = bary[2 * i], v = bary[2 * i + 1], w = 1.f - u - v;
        const float* a0 = attrib + std::int64_t(fv[0]) * channels;
        const float* a1 = attrib + std::int64_t(fv[1]) * channels;
        const float* a2 = attrib + std::int64_t(fv[2]) * channels;
        for (int c = 0; c < channels; ++c) o[c] = w * a0[c] + u * a1[c] + v * a2[c];
      }
    }
  });
  return first_bad.Get();
}

namespace {

// The scalar reference path of UlrBlend (double projections through Camera::ProjectCam, one view
// at a time): used for input views that are not all pinhole, and with options.reference.
void UlrBlendScalar(const Camera& novel, ImageView<const float> gbuffer_depth, ImageView<const float> normal,
                    const std::uint8_t* pixel_mask, const UlrInputView* views, int num_views,
                    const UlrOptions& options, ImageView<float> color_out, ImageView<std::uint8_t> count_out) {
  const int H = gbuffer_depth.height, W = gbuffer_depth.width;
  const glm::dvec3 c_novel_d = novel.CentreInWorld();
  const glm::vec3 c_novel(c_novel_d);
  std::vector<glm::vec3> centres(num_views);
  for (int i = 0; i < num_views; ++i) centres[i] = glm::vec3(views[i].camera.CentreInWorld());
  const int k = std::max(1, std::min(options.k, UlrOptions::kMaxK));
  const bool use_normal = !normal.Empty();
  const glm::dmat3 world_from_cam = glm::transpose(novel.rot);
  ParallelFor2D(H, W, 64, [&](int y0, int y1, int x0, int x1) {
    std::vector<float> pen(num_views);
    std::vector<std::uint8_t> tested(num_views);
    std::vector<double> proj(3 * std::size_t(num_views));  // x, y, depth of p in each view
    int index[UlrOptions::kMaxK];
    float weight[UlrOptions::kMaxK];
    for (int y = y0; y < y1; ++y) {
      const float* drow = gbuffer_depth.Row(y);
      float* crow = color_out.Row(y);
      std::uint8_t* nrow = count_out.Row(y);
      for (int x = x0; x < x1; ++x) {
        crow[3 * x] = crow[3 * x + 1] = crow[3 * x + 2] = 0.f;
        nrow[x] = 0;
        const float t = drow[x];
        if (!(t > 0.f) || !std::isfinite(t)) continue;
        if (pixel_mask && !pixel_mask[std::int64_t(y) * W + x]) continue;
        const glm::dvec3 p_cam = novel.RayInCam(x + 0.5, y + 0.5) * double(t);
        const glm::dvec3 p_world_d = world_from_cam * p_cam + c_novel_d;
        const glm::vec3 p(p_world_d);
        glm::vec3 n(0.f);
        if (use_normal) n = glm::vec3(normal.At(y, x, 0), normal.At(y, x, 1), normal.At(y, x, 2));
        const glm::vec3 b = c_novel - p;
        const float lb = glm::length(b);
        // Penalties, with the cheap visibility tests done for every view at once (behind the
        // surface, behind the camera, outside the image): views failing them would otherwise
        // trigger a re-selection each. The depth test (a read in the view's depth map) is lazy.
        for (int i = 0; i < num_views; ++i) {
          tested[i] = 0;
          pen[i] = INFINITY;
          if (use_normal && !(glm::dot(n, centres[i] - p) > 0.f)) continue;  // sees the back
          const float pi = UlrPenaltyFast(p, b, lb, centres[i], options.resolution_weight);
          if (!std::isfinite(pi)) continue;
          const UlrInputView& v = views[i];
          double vx, vy, vd;
          if (!v.camera.ProjectCam(v.camera.CamFromWorld(p_world_d), &vx, &vy, &vd) || !(vx >= 0.0) ||
              !(vy >= 0.0) || !(vx < v.depth.width) || !(vy < v.depth.height)) {
            continue;
          }
          proj[3 * i] = vx;
          proj[3 * i + 1] = vy;
          proj[3 * i + 2] = vd;
          pen[i] = pi;
        }
        // Lazy occlusion test: only views that would be selected are tested.
        int m = 0;
        glm::vec3 col(0.f);
        for (;;) {
          m = UlrSelect(pen.data(), num_views, k, index, weight);
          bool all_ok = true;
          for (int j = 0; j < m; ++j) {
            const int i = index[j];
            if (tested[i]) continue;
            tested[i] = 1;
            const UlrInputView& v = views[i];
            const double vx = proj[3 * i], vy = proj[3 * i + 1], vd = proj[3 * i + 2];
            const float dv = v.depth.At(std::min(int(vy), v.depth.height - 1), std::min(int(vx), v.depth.width - 1));
            if (!(dv > 0.f && std::isfinite(dv) && std::abs(vd - double(dv)) <= double(options.depth_tol) * dv)) {
              pen[i] = INFINITY;
              all_ok = false;
            }
          }
          if (all_ok) break;
        }
        int used = 0;
        for (int j = 0; j < m; ++j) {
          if (!(weight[j] > 0.f)) continue;
          const int i = index[j];
          const ImageView<const float>& img = views[i].color;
          float c[3];
          ReadRgb(img.data, img.row_stride, img.width, img.height, proj[3 * i], proj[3 * i + 1], options.cubic, c);
          col += weight[j] * glm::vec3(c[0], c[1], c[2]);
          ++used;
        }
        if (used > 0) {
          crow[3 * x] = col.x;
          crow[3 * x + 1] = col.y;
          crow[3 * x + 2] = col.z;
          nrow[x] = std::uint8_t(std::min(used, 255));
        }
      }
    }
  });
}

// BilinearRgb (resample.h) in float, accumulated: acc += weight * bilinear(img at (x, y)). The same clamping
// (positions come from the in-image test, x in [0, w), y in [0, h)). acc holds 4 floats: the
// three channels are interpolated at once in SSE2 (the same operations per lane as the scalar
// loop, so the same bits; the fourth lane reads the next pixel's red, acc[3] is unused), except
// at the image's last pixel, whose fourth float is past the end.
inline void Bilinear3Add(const ImageView<const float>& img, float x, float y, float weight, float* acc) {
  const float fx = std::min(std::max(x - 0.5f, 0.f), float(img.width - 1));
  const float fy = std::min(std::max(y - 0.5f, 0.f), float(img.height - 1));
  const int x0 = int(fx), y0 = int(fy);
  const int x1 = std::min(x0 + 1, img.width - 1), y1 = std::min(y0 + 1, img.height - 1);
  const float ax = fx - float(x0), ay = fy - float(y0);
  const float* a = img.Row(y0) + 3 * x0;
  const float* b = img.Row(y0) + 3 * x1;
  const float* c = img.Row(y1) + 3 * x0;
  const float* d = img.Row(y1) + 3 * x1;
#if defined(__SSE2__)
  if (y1 < img.height - 1 || x1 < img.width - 1) {
    const __m128 A = _mm_loadu_ps(a), B = _mm_loadu_ps(b), C = _mm_loadu_ps(c), D = _mm_loadu_ps(d);
    const __m128 AX = _mm_set1_ps(ax);
    const __m128 top = _mm_add_ps(A, _mm_mul_ps(AX, _mm_sub_ps(B, A)));
    const __m128 bot = _mm_add_ps(C, _mm_mul_ps(AX, _mm_sub_ps(D, C)));
    const __m128 v = _mm_add_ps(top, _mm_mul_ps(_mm_set1_ps(ay), _mm_sub_ps(bot, top)));
    _mm_storeu_ps(acc, _mm_add_ps(_mm_loadu_ps(acc), _mm_mul_ps(_mm_set1_ps(weight), v)));
    return;
  }
#endif
  for (int k = 0; k < 3; ++k) {
    const float top = a[k] + ax * (b[k] - a[k]);
    const float bot = c[k] + ax * (d[k] - c[k]);
    acc[k] += weight * (top + ay * (bot - top));
  }
}

// FastAtan2Pos without branches (selects only), so that the per-view loop below vectorises; the
// same polynomial and the same result (den = 0 only when y = x = 0, where t = 0 gives 0 as well).
inline float FastAtan2PosSelect(float y, float x) {
  const float ax = std::fabs(x);
  const bool swap = y > ax;
  const float num = swap ? ax : y, den = swap ? y : ax;
  float r = AtanPoly01(num / (den > 0.f ? den : 1.f));
  r = swap ? 1.57079633f - r : r;
  return x < 0.f ? 3.14159265f - r : r;
}

// Per-view constants of the fast path, one array per quantity (structure of arrays: the loop over
// views reads each contiguously, SIMD over views). The projection folds the intrinsics into the
// pose: (x z, y z, z) = P (p, 1) with P's rows fx R0 + cx R2, fy R1 + cy R2 and R2 (and the same
// combination of t), in float. The depth maps' pointers, strides and last column / row for the
// branch-free depth test.
struct UlrViewTable {
  int n = 0;
  int n4 = 0;  // n rounded up to a multiple of 4: where the SIMD loops end
  std::vector<float> cx, cy, cz, w, h, wlast, hlast;
  std::vector<float> m[12];
  std::vector<const float*> depth;
  std::vector<std::ptrdiff_t> depth_stride;
  std::vector<std::int64_t> depth_addr;     // the depth maps' addresses, for the AVX-512 gathers
  std::vector<std::int32_t> depth_stride32;  // their row strides
  bool offsets32 = true;                     // every depth texel offset fits in int32
  // For the AVX2 gathers (one base address for all lanes): the lowest depth map's address and each
  // map's distance from it in floats; rel32 when every texel of every map is within int32 floats.
  std::uintptr_t depth_base = 0;
  std::vector<std::int32_t> depth_rel32;
  bool rel32 = true;
  // Padded to a multiple of 16 views with views of size 0 x 0 (every point is outside them).
  explicit UlrViewTable(const UlrInputView* views, int num_views) : n(num_views) {
    n4 = (num_views + 3) / 4 * 4;
    const int padded = (num_views + 15) / 16 * 16;
    for (auto* a : {&cx, &cy, &cz, &w, &h, &wlast, &hlast}) a->assign(padded, 0.f);
    for (auto& a : m) a.assign(padded, 0.f);
    depth.assign(padded, nullptr);
    depth_stride.assign(padded, 0);
    depth_addr.assign(padded, 0);
    depth_stride32.assign(padded, 0);
    depth_rel32.assign(padded, 0);
    for (int i = 0; i < n; ++i) {
      const std::uintptr_t a = reinterpret_cast<std::uintptr_t>(views[i].depth.data);
      depth_base = i == 0 ? a : std::min(depth_base, a);
    }
    for (int i = 0; i < n; ++i) {
      const std::uintptr_t rel = reinterpret_cast<std::uintptr_t>(views[i].depth.data) - depth_base;
      const double last = double(rel / sizeof(float)) + double(views[i].depth.row_stride) * views[i].depth.height;
      rel32 = rel32 && rel % sizeof(float) == 0 && last < 2147483647.0;
      depth_rel32[i] = rel32 ? std::int32_t(rel / sizeof(float)) : 0;
    }
    for (int i = 0; i < n; ++i) {
      const Camera& c = views[i].camera;
      const glm::dvec3 o = c.CentreInWorld();
      cx[i] = float(o.x), cy[i] = float(o.y), cz[i] = float(o.z);
      w[i] = float(views[i].depth.width), h[i] = float(views[i].depth.height);
      wlast[i] = float(views[i].depth.width - 1), hlast[i] = float(views[i].depth.height - 1);
      depth[i] = views[i].depth.data;
      depth_stride[i] = views[i].depth.row_stride;
      depth_addr[i] = std::int64_t(reinterpret_cast<std::uintptr_t>(views[i].depth.data));
      depth_stride32[i] = std::int32_t(std::min<std::ptrdiff_t>(views[i].depth.row_stride, INT32_MAX));
      offsets32 = offsets32 && double(views[i].depth.row_stride) * views[i].depth.height < 2147483647.0;
      for (int j = 0; j < 3; ++j) {  // glm is column-major: rot[col][row]
        m[j][i] = float(c.fx * c.rot[j][0] + c.cx * c.rot[j][2]);
        m[4 + j][i] = float(c.fy * c.rot[j][1] + c.cy * c.rot[j][2]);
        m[8 + j][i] = float(c.rot[j][2]);
      }
      m[3][i] = float(c.fx * c.trans.x + c.cx * c.trans.z);
      m[7][i] = float(c.fy * c.trans.y + c.cy * c.trans.z);
      m[11][i] = float(c.trans.z);
    }
  }
};

// One G-buffer point of the fast path: p, b = c_novel - p, |b|, the normal (0 without one).
struct UlrPoint {
  float px, py, pz, bx, by, bz, lb, nx, ny, nz;
};

// Outputs of the per-view loop: penalty (+inf when a cheap test fails), projection (x, y) in
// pixels and z of p in every view.
struct UlrViewOut {
  float* pen;
  float* qx;
  float* qy;
  float* qz;
};

// Penalties and cheap tests of all views, scalar: the reference for the SIMD versions (the same
// float operations in the same order, so the same bits) and the loop on CPUs without SSE2.
inline void UlrViewsScalar(const UlrPoint& q, const UlrViewTable& t, bool use_normal, float rw, int i0,
                           const UlrViewOut& o) {
  for (int i = i0; i < t.n; ++i) {
    const float ax = t.cx[i] - q.px, ay = t.cy[i] - q.py, az = t.cz[i] - q.pz;
    const float la = std::sqrt(ax * ax + ay * ay + az * az);
    const float crx = ay * q.bz - az * q.by, cry = az * q.bx - ax * q.bz, crz = ax * q.by - ay * q.bx;
    const float cr = std::sqrt(crx * crx + cry * cry + crz * crz);
    const float dt = ax * q.bx + ay * q.by + az * q.bz;
    const float ratio = la / q.lb - 1.f;
    const float pn = FastAtan2PosSelect(cr, dt) + rw * (ratio > 0.f ? ratio : 0.f);
    const float X = t.m[0][i] * q.px + t.m[1][i] * q.py + t.m[2][i] * q.pz + t.m[3][i];
    const float Y = t.m[4][i] * q.px + t.m[5][i] * q.py + t.m[6][i] * q.pz + t.m[7][i];
    const float Z = t.m[8][i] * q.px + t.m[9][i] * q.py + t.m[10][i] * q.pz + t.m[11][i];
    const float iz = 1.f / (Z > 0.f ? Z : 1.f);
    const float vx = X * iz, vy = Y * iz;
    const float facing = q.nx * ax + q.ny * ay + q.nz * az;
    const int ok = (!use_normal | (facing > 0.f)) & (la > 0.f) & (la <= 3.4e38f) & (pn <= 3.4e38f) & (Z > 0.f) &
                   (vx >= 0.f) & (vy >= 0.f) & (vx < t.w[i]) & (vy < t.h[i]);
    o.pen[i] = ok ? pn : INFINITY;
    o.qx[i] = vx;
    o.qy[i] = vy;
    o.qz[i] = Z;
  }
}

#if defined(__SSE2__)
// Views i0 .. i0 + 3 in SSE2 (part of x86-64): UlrViewsScalar's operations, four lanes at a time.
inline void UlrViews4(const UlrPoint& q, const UlrViewTable& t, bool use_normal, float rw, int i0,
                      const UlrViewOut& o) {
  const __m128 Px = _mm_set1_ps(q.px), Py = _mm_set1_ps(q.py), Pz = _mm_set1_ps(q.pz);
  const __m128 Bx = _mm_set1_ps(q.bx), By = _mm_set1_ps(q.by), Bz = _mm_set1_ps(q.bz), Lb = _mm_set1_ps(q.lb);
  const __m128 Nx = _mm_set1_ps(q.nx), Ny = _mm_set1_ps(q.ny), Nz = _mm_set1_ps(q.nz);
  const __m128 zero = _mm_setzero_ps(), one = _mm_set1_ps(1.f), big = _mm_set1_ps(3.4e38f);
  const __m128 inf = _mm_set1_ps(INFINITY), Rw = _mm_set1_ps(rw), sign = _mm_set1_ps(-0.f);
  const __m128 half_pi = _mm_set1_ps(1.57079633f), pi = _mm_set1_ps(3.14159265f);
  const __m128 facing_any = use_normal ? zero : _mm_castsi128_ps(_mm_set1_epi32(-1));
  const __m128 ax = _mm_sub_ps(_mm_loadu_ps(&t.cx[i0]), Px);
  const __m128 ay = _mm_sub_ps(_mm_loadu_ps(&t.cy[i0]), Py);
  const __m128 az = _mm_sub_ps(_mm_loadu_ps(&t.cz[i0]), Pz);
  const __m128 la = _mm_sqrt_ps(_mm_add_ps(_mm_add_ps(_mm_mul_ps(ax, ax), _mm_mul_ps(ay, ay)), _mm_mul_ps(az, az)));
  const __m128 crx = _mm_sub_ps(_mm_mul_ps(ay, Bz), _mm_mul_ps(az, By));
  const __m128 cry = _mm_sub_ps(_mm_mul_ps(az, Bx), _mm_mul_ps(ax, Bz));
  const __m128 crz = _mm_sub_ps(_mm_mul_ps(ax, By), _mm_mul_ps(ay, Bx));
  const __m128 cr = _mm_sqrt_ps(_mm_add_ps(_mm_add_ps(_mm_mul_ps(crx, crx), _mm_mul_ps(cry, cry)), _mm_mul_ps(crz, crz)));
  const __m128 dt = _mm_add_ps(_mm_add_ps(_mm_mul_ps(ax, Bx), _mm_mul_ps(ay, By)), _mm_mul_ps(az, Bz));
  // FastAtan2PosSelect(cr, dt)
  const __m128 adt = _mm_andnot_ps(sign, dt);
  const __m128 swap = _mm_cmpgt_ps(cr, adt);
  const __m128 num = _mm_or_ps(_mm_and_ps(swap, adt), _mm_andnot_ps(swap, cr));
  const __m128 den = _mm_or_ps(_mm_and_ps(swap, cr), _mm_andnot_ps(swap, adt));
  const __m128 denpos = _mm_cmpgt_ps(den, zero);
  const __m128 tt = _mm_div_ps(num, _mm_or_ps(_mm_and_ps(denpos, den), _mm_andnot_ps(denpos, one)));
  const __m128 t2 = _mm_mul_ps(tt, tt);
  __m128 r = _mm_add_ps(_mm_set1_ps(kAtan7), _mm_mul_ps(t2, _mm_set1_ps(kAtan9)));
  r = _mm_add_ps(_mm_set1_ps(kAtan5), _mm_mul_ps(t2, r));
  r = _mm_add_ps(_mm_set1_ps(kAtan3), _mm_mul_ps(t2, r));
  r = _mm_add_ps(_mm_set1_ps(kAtan1), _mm_mul_ps(t2, r));
  r = _mm_mul_ps(tt, r);
  r = _mm_or_ps(_mm_and_ps(swap, _mm_sub_ps(half_pi, r)), _mm_andnot_ps(swap, r));
  const __m128 neg = _mm_cmplt_ps(dt, zero);
  r = _mm_or_ps(_mm_and_ps(neg, _mm_sub_ps(pi, r)), _mm_andnot_ps(neg, r));
  const __m128 ratio = _mm_sub_ps(_mm_div_ps(la, Lb), one);
  const __m128 pn = _mm_add_ps(r, _mm_mul_ps(Rw, _mm_max_ps(ratio, zero)));
  const __m128 X = _mm_add_ps(_mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_loadu_ps(&t.m[0][i0]), Px), _mm_mul_ps(_mm_loadu_ps(&t.m[1][i0]), Py)),
                                         _mm_mul_ps(_mm_loadu_ps(&t.m[2][i0]), Pz)), _mm_loadu_ps(&t.m[3][i0]));
  const __m128 Y = _mm_add_ps(_mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_loadu_ps(&t.m[4][i0]), Px), _mm_mul_ps(_mm_loadu_ps(&t.m[5][i0]), Py)),
                                         _mm_mul_ps(_mm_loadu_ps(&t.m[6][i0]), Pz)), _mm_loadu_ps(&t.m[7][i0]));
  const __m128 Z = _mm_add_ps(_mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_loadu_ps(&t.m[8][i0]), Px), _mm_mul_ps(_mm_loadu_ps(&t.m[9][i0]), Py)),
                                         _mm_mul_ps(_mm_loadu_ps(&t.m[10][i0]), Pz)), _mm_loadu_ps(&t.m[11][i0]));
  const __m128 zpos = _mm_cmpgt_ps(Z, zero);
  const __m128 iz = _mm_div_ps(one, _mm_or_ps(_mm_and_ps(zpos, Z), _mm_andnot_ps(zpos, one)));
  const __m128 vx = _mm_mul_ps(X, iz), vy = _mm_mul_ps(Y, iz);
  const __m128 facing = _mm_add_ps(_mm_add_ps(_mm_mul_ps(Nx, ax), _mm_mul_ps(Ny, ay)), _mm_mul_ps(Nz, az));
  __m128 ok = _mm_or_ps(facing_any, _mm_cmpgt_ps(facing, zero));
  ok = _mm_and_ps(ok, _mm_cmpgt_ps(la, zero));
  ok = _mm_and_ps(ok, _mm_cmple_ps(la, big));
  ok = _mm_and_ps(ok, _mm_cmple_ps(pn, big));
  ok = _mm_and_ps(ok, zpos);
  ok = _mm_and_ps(ok, _mm_cmpge_ps(vx, zero));
  ok = _mm_and_ps(ok, _mm_cmpge_ps(vy, zero));
  ok = _mm_and_ps(ok, _mm_cmplt_ps(vx, _mm_loadu_ps(&t.w[i0])));
  ok = _mm_and_ps(ok, _mm_cmplt_ps(vy, _mm_loadu_ps(&t.h[i0])));
  _mm_storeu_ps(o.pen + i0, _mm_or_ps(_mm_and_ps(ok, pn), _mm_andnot_ps(ok, inf)));
  _mm_storeu_ps(o.qx + i0, vx);
  _mm_storeu_ps(o.qy + i0, vy);
  _mm_storeu_ps(o.qz + i0, Z);
}

void UlrViewsSse2(const UlrPoint& q, const UlrViewTable& t, bool use_normal, float rw, const UlrViewOut& o) {
  for (int i0 = 0; i0 < t.n4; i0 += 4) UlrViews4(q, t, use_normal, rw, i0, o);
}

#if defined(__GNUC__)
#define IBR_ULR_AVX2 1
// Eight views per step in AVX2 (without FMA: the same IEEE operations as UlrViews4 lane for lane,
// so the same bits; the comparisons are the ordered, non-signalling forms of SSE's, false on NaN
// as there), the rest (up to 4 views) by UlrViews4. Called when the CPU has AVX2 (UlrBlendFast):
// 12 views take one 8-wide and one 4-wide step instead of three 4-wide ones.
__attribute__((target("avx2"))) void UlrViewsAvx2(const UlrPoint& q, const UlrViewTable& t, bool use_normal,
                                                   float rw, const UlrViewOut& o) {
  const __m256 Px = _mm256_set1_ps(q.px), Py = _mm256_set1_ps(q.py), Pz = _mm256_set1_ps(q.pz);
  const __m256 Bx = _mm256_set1_ps(q.bx), By = _mm256_set1_ps(q.by), Bz = _mm256_set1_ps(q.bz);
  const __m256 Lb = _mm256_set1_ps(q.lb);
  const __m256 Nx = _mm256_set1_ps(q.nx), Ny = _mm256_set1_ps(q.ny), Nz = _mm256_set1_ps(q.nz);
  const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.f), big = _mm256_set1_ps(3.4e38f);
  const __m256 inf = _mm256_set1_ps(INFINITY), Rw = _mm256_set1_ps(rw), sign = _mm256_set1_ps(-0.f);
  const __m256 half_pi = _mm256_set1_ps(1.57079633f), pi = _mm256_set1_ps(3.14159265f);
  const __m256 facing_any = use_normal ? zero : _mm256_castsi256_ps(_mm256_set1_epi32(-1));
  int i0 = 0;
  for (; i0 + 8 <= t.n4; i0 += 8) {
    const __m256 ax = _mm256_sub_ps(_mm256_loadu_ps(&t.cx[i0]), Px);
    const __m256 ay = _mm256_sub_ps(_mm256_loadu_ps(&t.cy[i0]), Py);
    const __m256 az = _mm256_sub_ps(_mm256_loadu_ps(&t.cz[i0]), Pz);
    const __m256 la = _mm256_sqrt_ps(
        _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(ax, ax), _mm256_mul_ps(ay, ay)), _mm256_mul_ps(az, az)));
    const __m256 crx = _mm256_sub_ps(_mm256_mul_ps(ay, Bz), _mm256_mul_ps(az, By));
    const __m256 cry = _mm256_sub_ps(_mm256_mul_ps(az, Bx), _mm256_mul_ps(ax, Bz));
    const __m256 crz = _mm256_sub_ps(_mm256_mul_ps(ax, By), _mm256_mul_ps(ay, Bx));
    const __m256 cr = _mm256_sqrt_ps(
        _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(crx, crx), _mm256_mul_ps(cry, cry)), _mm256_mul_ps(crz, crz)));
    const __m256 dt = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(ax, Bx), _mm256_mul_ps(ay, By)), _mm256_mul_ps(az, Bz));
    const __m256 adt = _mm256_andnot_ps(sign, dt);
    const __m256 swap = _mm256_cmp_ps(cr, adt, _CMP_GT_OQ);
    const __m256 num = _mm256_blendv_ps(cr, adt, swap);
    const __m256 den = _mm256_blendv_ps(adt, cr, swap);
    const __m256 denpos = _mm256_cmp_ps(den, zero, _CMP_GT_OQ);
    const __m256 tt = _mm256_div_ps(num, _mm256_blendv_ps(one, den, denpos));
    const __m256 t2 = _mm256_mul_ps(tt, tt);
    __m256 r = _mm256_add_ps(_mm256_set1_ps(kAtan7), _mm256_mul_ps(t2, _mm256_set1_ps(kAtan9)));
    r = _mm256_add_ps(_mm256_set1_ps(kAtan5), _mm256_mul_ps(t2, r));
    r = _mm256_add_ps(_mm256_set1_ps(kAtan3), _mm256_mul_ps(t2, r));
    r = _mm256_add_ps(_mm256_set1_ps(kAtan1), _mm256_mul_ps(t2, r));
    r = _mm256_mul_ps(tt, r);
    r = _mm256_blendv_ps(r, _mm256_sub_ps(half_pi, r), swap);
    const __m256 neg = _mm256_cmp_ps(dt, zero, _CMP_LT_OQ);
    r = _mm256_blendv_ps(r, _mm256_sub_ps(pi, r), neg);
    const __m256 ratio = _mm256_sub_ps(_mm256_div_ps(la, Lb), one);
    const __m256 pn = _mm256_add_ps(r, _mm256_mul_ps(Rw, _mm256_max_ps(ratio, zero)));
    const __m256 X = _mm256_add_ps(
        _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(_mm256_loadu_ps(&t.m[0][i0]), Px), _mm256_mul_ps(_mm256_loadu_ps(&t.m[1][i0]), Py)),
                      _mm256_mul_ps(_mm256_loadu_ps(&t.m[2][i0]), Pz)),
        _mm256_loadu_ps(&t.m[3][i0]));
    const __m256 Y = _mm256_add_ps(
        _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(_mm256_loadu_ps(&t.m[4][i0]), Px), _mm256_mul_ps(_mm256_loadu_ps(&t.m[5][i0]), Py)),
                      _mm256_mul_ps(_mm256_loadu_ps(&t.m[6][i0]), Pz)),
        _mm256_loadu_ps(&t.m[7][i0]));
    const __m256 Z = _mm256_add_ps(
        _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(_mm256_loadu_ps(&t.m[8][i0]), Px), _mm256_mul_ps(_mm256_loadu_ps(&t.m[9][i0]), Py)),
                      _mm256_mul_ps(_mm256_loadu_ps(&t.m[10][i0]), Pz)),
        _mm256_loadu_ps(&t.m[11][i0]));
    const __m256 zpos = _mm256_cmp_ps(Z, zero, _CMP_GT_OQ);
    const __m256 iz = _mm256_div_ps(one, _mm256_blendv_ps(one, Z, zpos));
    const __m256 vx = _mm256_mul_ps(X, iz), vy = _mm256_mul_ps(Y, iz);
    const __m256 facing = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(Nx, ax), _mm256_mul_ps(Ny, ay)), _mm256_mul_ps(Nz, az));
    __m256 ok = _mm256_or_ps(facing_any, _mm256_cmp_ps(facing, zero, _CMP_GT_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(la, zero, _CMP_GT_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(la, big, _CMP_LE_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(pn, big, _CMP_LE_OQ));
    ok = _mm256_and_ps(ok, zpos);
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(vx, zero, _CMP_GE_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(vy, zero, _CMP_GE_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(vx, _mm256_loadu_ps(&t.w[i0]), _CMP_LT_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(vy, _mm256_loadu_ps(&t.h[i0]), _CMP_LT_OQ));
    _mm256_storeu_ps(o.pen + i0, _mm256_blendv_ps(inf, pn, ok));
    _mm256_storeu_ps(o.qx + i0, vx);
    _mm256_storeu_ps(o.qy + i0, vy);
    _mm256_storeu_ps(o.qz + i0, Z);
  }
  if (i0 < t.n4) UlrViews4(q, t, use_normal, rw, i0, o);
}

// UlrBlendFast's depth test of views 0 .. nv - 1 in AVX2 (its scalar loop's operations lane for
// lane: the same views pass), eight per step: the texel offsets in int32, the depths gathered
// from one base address (the table checked every map is within int32 floats of it; lanes past nv
// masked: no read). Writes the offsets to off[] (the prefetch's predictor) and +inf to o.pen where
// the test fails, and +inf past nv: a plain store (the arrays hold the table's padding to 16 views),
// not a masked one, which is microcoded on Zen (ulr_blend 1-thread median 124 -> 120 ms). For CPUs
// with AVX2 and without AVX-512 (ulr_blend 85 -> 80 ms per 1280x720 frame on a Zen 3 EPYC, 2 threads).
__attribute__((target("avx2"))) void UlrDepthTestAvx2(const UlrViewTable& t, int nv, float tol, const UlrViewOut& o,
                                                       std::ptrdiff_t* off) {
  const __m256 zero = _mm256_setzero_ps(), inf = _mm256_set1_ps(INFINITY), Tol = _mm256_set1_ps(tol);
  const __m256 fmax = _mm256_set1_ps(3.4028235e38f), sign = _mm256_set1_ps(-0.f);
  const float* base = reinterpret_cast<const float*>(t.depth_base);
  const __m256i lane_id = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  for (int i0 = 0; i0 < nv; i0 += 8) {
    const __m256i lanes = _mm256_cmpgt_epi32(_mm256_set1_epi32(nv - i0), lane_id);
    const __m256 fx = _mm256_min_ps(_mm256_max_ps(_mm256_loadu_ps(o.qx + i0), zero), _mm256_loadu_ps(&t.wlast[i0]));
    const __m256 fy = _mm256_min_ps(_mm256_max_ps(_mm256_loadu_ps(o.qy + i0), zero), _mm256_loadu_ps(&t.hlast[i0]));
    const __m256i o32 = _mm256_add_epi32(
        _mm256_mullo_epi32(_mm256_cvttps_epi32(fy), _mm256_loadu_si256(reinterpret_cast<const __m256i*>(&t.depth_stride32[i0]))),
        _mm256_cvttps_epi32(fx));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(off + i0), _mm256_cvtepi32_epi64(_mm256_castsi256_si128(o32)));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(off + i0 + 4), _mm256_cvtepi32_epi64(_mm256_extracti128_si256(o32, 1)));
    const __m256i idx = _mm256_add_epi32(o32, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(&t.depth_rel32[i0])));
    const __m256 dv = _mm256_mask_i32gather_ps(zero, base, idx, _mm256_castsi256_ps(lanes), 4);
    const __m256 pen = _mm256_loadu_ps(o.pen + i0);
    __m256 ok = _mm256_and_ps(_mm256_cmp_ps(pen, inf, _CMP_LT_OQ), _mm256_cmp_ps(dv, zero, _CMP_GT_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(dv, fmax, _CMP_LE_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(_mm256_andnot_ps(sign, _mm256_sub_ps(_mm256_loadu_ps(o.qz + i0), dv)),
                                         _mm256_mul_ps(Tol, dv), _CMP_LE_OQ));
    _mm256_storeu_ps(o.pen + i0, _mm256_blendv_ps(inf, pen, ok));
  }
}

// Sixteen views per step in AVX-512F (UlrViewsAvx2's operations lane for lane: the same bits; the
// compares as mask registers, blends by mask): 9-16 views in one step instead of an 8-wide and a
// 4-wide one. Called when the CPU has AVX-512F (UlrBlendFast); the table is padded to 16 views.
// AVX-512F brings FMA, which GCC would contract mul + add into (other bits): contraction off here.
__attribute__((target("avx512f"), optimize("fp-contract=off"))) void UlrViewsAvx512(const UlrPoint& q, const UlrViewTable& t, bool use_normal,
                                                       float rw, const UlrViewOut& o) {
  const __m512 Px = _mm512_set1_ps(q.px), Py = _mm512_set1_ps(q.py), Pz = _mm512_set1_ps(q.pz);
  const __m512 Bx = _mm512_set1_ps(q.bx), By = _mm512_set1_ps(q.by), Bz = _mm512_set1_ps(q.bz);
  const __m512 Lb = _mm512_set1_ps(q.lb);
  const __m512 Nx = _mm512_set1_ps(q.nx), Ny = _mm512_set1_ps(q.ny), Nz = _mm512_set1_ps(q.nz);
  const __m512 zero = _mm512_setzero_ps(), one = _mm512_set1_ps(1.f), big = _mm512_set1_ps(3.4e38f);
  const __m512 inf = _mm512_set1_ps(INFINITY), Rw = _mm512_set1_ps(rw);
  const __m512 half_pi = _mm512_set1_ps(1.57079633f), pi = _mm512_set1_ps(3.14159265f);
  for (int i0 = 0; i0 < t.n4; i0 += 16) {
    const __m512 ax = _mm512_sub_ps(_mm512_loadu_ps(&t.cx[i0]), Px);
    const __m512 ay = _mm512_sub_ps(_mm512_loadu_ps(&t.cy[i0]), Py);
    const __m512 az = _mm512_sub_ps(_mm512_loadu_ps(&t.cz[i0]), Pz);
    const __m512 la = _mm512_sqrt_ps(
        _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(ax, ax), _mm512_mul_ps(ay, ay)), _mm512_mul_ps(az, az)));
    const __m512 crx = _mm512_sub_ps(_mm512_mul_ps(ay, Bz), _mm512_mul_ps(az, By));
    const __m512 cry = _mm512_sub_ps(_mm512_mul_ps(az, Bx), _mm512_mul_ps(ax, Bz));
    const __m512 crz = _mm512_sub_ps(_mm512_mul_ps(ax, By), _mm512_mul_ps(ay, Bx));
    const __m512 cr = _mm512_sqrt_ps(
        _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(crx, crx), _mm512_mul_ps(cry, cry)), _mm512_mul_ps(crz, crz)));
    const __m512 dt = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(ax, Bx), _mm512_mul_ps(ay, By)), _mm512_mul_ps(az, Bz));
    const __m512 adt = _mm512_abs_ps(dt);
    const __mmask16 swap = _mm512_cmp_ps_mask(cr, adt, _CMP_GT_OQ);
    const __m512 num = _mm512_mask_blend_ps(swap, cr, adt);
    const __m512 den = _mm512_mask_blend_ps(swap, adt, cr);
    const __mmask16 denpos = _mm512_cmp_ps_mask(den, zero, _CMP_GT_OQ);
    const __m512 tt = _mm512_div_ps(num, _mm512_mask_blend_ps(denpos, one, den));
    const __m512 t2 = _mm512_mul_ps(tt, tt);
    __m512 r = _mm512_add_ps(_mm512_set1_ps(kAtan7), _mm512_mul_ps(t2, _mm512_set1_ps(kAtan9)));
    r = _mm512_add_ps(_mm512_set1_ps(kAtan5), _mm512_mul_ps(t2, r));
    r = _mm512_add_ps(_mm512_set1_ps(kAtan3), _mm512_mul_ps(t2, r));
    r = _mm512_add_ps(_mm512_set1_ps(kAtan1), _mm512_mul_ps(t2, r));
    r = _mm512_mul_ps(tt, r);
    r = _mm512_mask_blend_ps(swap, r, _mm512_sub_ps(half_pi, r));
    r = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(dt, zero, _CMP_LT_OQ), r, _mm512_sub_ps(pi, r));
    const __m512 ratio = _mm512_sub_ps(_mm512_div_ps(la, Lb), one);
    const __m512 pn = _mm512_add_ps(r, _mm512_mul_ps(Rw, _mm512_max_ps(ratio, zero)));
    const __m512 X = _mm512_add_ps(
        _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(_mm512_loadu_ps(&t.m[0][i0]), Px), _mm512_mul_ps(_mm512_loadu_ps(&t.m[1][i0]), Py)),
                      _mm512_mul_ps(_mm512_loadu_ps(&t.m[2][i0]), Pz)),
        _mm512_loadu_ps(&t.m[3][i0]));
    const __m512 Y = _mm512_add_ps(
        _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(_mm512_loadu_ps(&t.m[4][i0]), Px), _mm512_mul_ps(_mm512_loadu_ps(&t.m[5][i0]), Py)),
                      _mm512_mul_ps(_mm512_loadu_ps(&t.m[6][i0]), Pz)),
        _mm512_loadu_ps(&t.m[7][i0]));
    const __m512 Z = _mm512_add_ps(
        _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(_mm512_loadu_ps(&t.m[8][i0]), Px), _mm512_mul_ps(_mm512_loadu_ps(&t.m[9][i0]), Py)),
                      _mm512_mul_ps(_mm512_loadu_ps(&t.m[10][i0]), Pz)),
        _mm512_loadu_ps(&t.m[11][i0]));
    const __mmask16 zpos = _mm512_cmp_ps_mask(Z, zero, _CMP_GT_OQ);
    const __m512 iz = _mm512_div_ps(one, _mm512_mask_blend_ps(zpos, one, Z));
    const __m512 vx = _mm512_mul_ps(X, iz), vy = _mm512_mul_ps(Y, iz);
    const __m512 facing = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(Nx, ax), _mm512_mul_ps(Ny, ay)), _mm512_mul_ps(Nz, az));
    __mmask16 ok = use_normal ? _mm512_cmp_ps_mask(facing, zero, _CMP_GT_OQ) : __mmask16(0xFFFF);
    ok &= _mm512_cmp_ps_mask(la, zero, _CMP_GT_OQ) & _mm512_cmp_ps_mask(la, big, _CMP_LE_OQ);
    ok &= _mm512_cmp_ps_mask(pn, big, _CMP_LE_OQ) & zpos;
    ok &= _mm512_cmp_ps_mask(vx, zero, _CMP_GE_OQ) & _mm512_cmp_ps_mask(vy, zero, _CMP_GE_OQ);
    ok &= _mm512_cmp_ps_mask(vx, _mm512_loadu_ps(&t.w[i0]), _CMP_LT_OQ);
    ok &= _mm512_cmp_ps_mask(vy, _mm512_loadu_ps(&t.h[i0]), _CMP_LT_OQ);
    _mm512_storeu_ps(o.pen + i0, _mm512_mask_blend_ps(ok, inf, pn));
    _mm512_storeu_ps(o.qx + i0, vx);
    _mm512_storeu_ps(o.qy + i0, vy);
    _mm512_storeu_ps(o.qz + i0, Z);
  }
}

// UlrBlendFast's depth test of views 0 .. nv - 1 (its scalar loop's operations lane for lane: the
// same views pass), sixteen per step: the texel offsets in int32 (the table checked they fit), the
// depths gathered from each view's map by address (lanes past nv masked: no read). Writes the
// offsets to off[] (the prefetch's predictor) and +inf to o.pen where the test fails.
__attribute__((target("avx512f"), optimize("fp-contract=off"))) void UlrDepthTestAvx512(
    const UlrViewTable& t, int nv, float tol, const UlrViewOut& o, std::ptrdiff_t* off) {
  const __m512 zero = _mm512_setzero_ps(), inf = _mm512_set1_ps(INFINITY), Tol = _mm512_set1_ps(tol);
  const __m512 fmax = _mm512_set1_ps(3.4028235e38f);
  for (int i0 = 0; i0 < nv; i0 += 16) {
    const __mmask16 lanes = nv - i0 >= 16 ? __mmask16(0xFFFF) : __mmask16((1u << (nv - i0)) - 1u);
    const __m512 fx = _mm512_min_ps(_mm512_max_ps(_mm512_loadu_ps(o.qx + i0), zero), _mm512_loadu_ps(&t.wlast[i0]));
    const __m512 fy = _mm512_min_ps(_mm512_max_ps(_mm512_loadu_ps(o.qy + i0), zero), _mm512_loadu_ps(&t.hlast[i0]));
    const __m512i o32 = _mm512_add_epi32(
        _mm512_mullo_epi32(_mm512_cvttps_epi32(fy), _mm512_loadu_si512(&t.depth_stride32[i0])), _mm512_cvttps_epi32(fx));
    const __m512i olo = _mm512_cvtepi32_epi64(_mm512_castsi512_si256(o32));
    const __m512i ohi = _mm512_cvtepi32_epi64(_mm256_castpd_si256(_mm512_extractf64x4_pd(_mm512_castsi512_pd(o32), 1)));
    _mm512_storeu_si512(off + i0, olo);
    _mm512_storeu_si512(off + i0 + 8, ohi);
    const __m512i alo = _mm512_add_epi64(_mm512_loadu_si512(&t.depth_addr[i0]), _mm512_slli_epi64(olo, 2));
    const __m512i ahi = _mm512_add_epi64(_mm512_loadu_si512(&t.depth_addr[i0 + 8]), _mm512_slli_epi64(ohi, 2));
    const __m256 dlo = _mm512_mask_i64gather_ps(_mm256_setzero_ps(), __mmask8(lanes & 0xFF), alo, nullptr, 1);
    const __m256 dhi = _mm512_mask_i64gather_ps(_mm256_setzero_ps(), __mmask8(lanes >> 8), ahi, nullptr, 1);
    const __m512 dv = _mm512_castpd_ps(
        _mm512_insertf64x4(_mm512_castpd256_pd512(_mm256_castps_pd(dlo)), _mm256_castps_pd(dhi), 1));
    const __m512 pen = _mm512_loadu_ps(o.pen + i0);
    __mmask16 ok = _mm512_cmp_ps_mask(pen, inf, _CMP_LT_OQ) & _mm512_cmp_ps_mask(dv, zero, _CMP_GT_OQ);
    ok &= _mm512_cmp_ps_mask(dv, fmax, _CMP_LE_OQ);
    ok &= _mm512_cmp_ps_mask(_mm512_abs_ps(_mm512_sub_ps(_mm512_loadu_ps(o.qz + i0), dv)), _mm512_mul_ps(Tol, dv),
                             _CMP_LE_OQ);
    _mm512_mask_storeu_ps(o.pen + i0, lanes, _mm512_mask_blend_ps(ok, inf, pen));
  }
}

// CubicRgbAdd's position clamp, tap origin and Catmull-Rom weights (CatmullRomWeights4) of n
// reads at once, eight per AVX2 step, the same operations per read (no FMA), so the same values:
// read r at (x[r], y[r]) in an image whose last column / row is wlast[r] / hlast[r] gets its tap
// origin x0[r], y0[r] and its weights wx[4 r .. 4 r + 4), wy[..] (the layout CatmullRomWeights4
// returns). The arrays hold n rounded up to 8 (lanes past n are computed from whatever they hold).
__attribute__((target("avx2"))) void CubicWeightsAvx2(int n, const float* x, const float* y, const float* wlast,
                                                       const float* hlast, int* x0, int* y0, float* wx, float* wy) {
  const __m256 half = _mm256_set1_ps(0.5f), zero = _mm256_setzero_ps();
  const float a[4] = {-1.f, 3.f, -3.f, 1.f}, b[4] = {2.f, -5.f, 4.f, -1.f}, c[4] = {-1.f, 0.f, 1.f, 0.f};
  const float d[4] = {0.f, 2.f, 0.f, 0.f};
  for (int r0 = 0; r0 < n; r0 += 8) {
    for (int axis = 0; axis < 2; ++axis) {
      const float* pos = axis ? y + r0 : x + r0;
      const __m256 f = _mm256_min_ps(_mm256_max_ps(_mm256_sub_ps(_mm256_loadu_ps(pos), half), zero),
                                     _mm256_loadu_ps(axis ? hlast + r0 : wlast + r0));
      const __m256i i0 = _mm256_cvttps_epi32(f);
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(axis ? y0 + r0 : x0 + r0), i0);
      const __m256 t = _mm256_sub_ps(f, _mm256_cvtepi32_ps(i0));
      const __m256 t2 = _mm256_mul_ps(t, t), t3 = _mm256_mul_ps(t2, t);
      __m256 w[4];
      for (int k = 0; k < 4; ++k) {
        __m256 v = _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(a[k]), t3), _mm256_mul_ps(_mm256_set1_ps(b[k]), t2));
        v = _mm256_add_ps(v, _mm256_mul_ps(_mm256_set1_ps(c[k]), t));
        v = _mm256_add_ps(v, _mm256_set1_ps(d[k]));
        w[k] = _mm256_mul_ps(half, v);
      }
      // Transpose to four weights per read: reads 0-3 from the low halves, 4-7 from the high.
      const __m256 t0 = _mm256_unpacklo_ps(w[0], w[1]), t1 = _mm256_unpackhi_ps(w[0], w[1]);
      const __m256 u0 = _mm256_unpacklo_ps(w[2], w[3]), u1 = _mm256_unpackhi_ps(w[2], w[3]);
      const __m256 e0 = _mm256_shuffle_ps(t0, u0, 0x44), e1 = _mm256_shuffle_ps(t0, u0, 0xEE);
      const __m256 e2 = _mm256_shuffle_ps(t1, u1, 0x44), e3 = _mm256_shuffle_ps(t1, u1, 0xEE);
      float* out = (axis ? wy : wx) + 4 * r0;
      _mm256_storeu_ps(out, _mm256_permute2f128_ps(e0, e1, 0x20));
      _mm256_storeu_ps(out + 8, _mm256_permute2f128_ps(e2, e3, 0x20));
      _mm256_storeu_ps(out + 16, _mm256_permute2f128_ps(e0, e1, 0x31));
      _mm256_storeu_ps(out + 24, _mm256_permute2f128_ps(e2, e3, 0x31));
    }
  }
}

// Pixels a group of UlrBlendFast's loop holds: the per-view work runs pixel by pixel, then the
// selection of the whole group at once (UlrSelect4x8Avx2), then the blends pixel by pixel.
constexpr int kUlrGroup = 8;

// UlrSelect (cpp/kernels/hybrid/ulr.h) with k = 4 for the eight pixels of a group at once, one per AVX2
// lane: pixel g's penalty of view v at pen[v * 8 + g], v < nv (lanes not in `live` select nothing;
// the per-pixel loop stores this layout as it goes, one store per view: 4 % faster than gathering
// it from the per-pixel rows). The insertion into a sorted list of 4 without branches: each view's
// penalty passes down the four slots, each slot keeping the strictly smaller of itself and it (so
// equal penalties keep the lower index first, as the insertion does; non-finite penalties are +inf,
// never kept), then Buehler's weights with UlrSelect's operations in its order (no FMA), so the
// same indices and weights bit for bit (tests/hybrid/test_ulr_fast.py compares with simd="sse2", which
// selects pixel by pixel). Writes index[j * 8 + g], weight[j * 8 + g] for j < m[g], and m[g].
// The per-pixel insertion over 12 views had 15 % of the loop's samples; this took ulr_blend's
// 1-thread median 150 -> 136 ms (a branch-free insertion per pixel gained nothing).
__attribute__((target("avx2"))) void UlrSelect4x8Avx2(const float* pen, int nv, unsigned live,
                                                       int* index, float* weight, int* m) {
  const __m256 inf = _mm256_set1_ps(INFINITY), zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.f);
  const __m256 sign = _mm256_set1_ps(-0.f);
  const __m256i lane_bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
  const __m256 live_mask = _mm256_castsi256_ps(
      _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(int(live)), lane_bit), lane_bit));
  __m256 s[4] = {inf, inf, inf, inf};
  __m256i id[4] = {_mm256_setzero_si256(), _mm256_setzero_si256(), _mm256_setzero_si256(), _mm256_setzero_si256()};
  for (int v = 0; v < nv; ++v) {
    __m256 p = _mm256_loadu_ps(pen + 8 * v);
    p = _mm256_blendv_ps(inf, p, _mm256_and_ps(live_mask, _mm256_cmp_ps(_mm256_andnot_ps(sign, p), inf, _CMP_LT_OQ)));
    __m256i iv = _mm256_set1_epi32(v);
    for (int j = 0; j < 4; ++j) {
      const __m256 less = _mm256_cmp_ps(p, s[j], _CMP_LT_OQ);
      const __m256 sj = s[j];
      s[j] = _mm256_blendv_ps(sj, p, less);
      p = _mm256_blendv_ps(p, sj, less);
      const __m256i idj = id[j];
      id[j] = _mm256_castps_si256(_mm256_blendv_ps(_mm256_castsi256_ps(idj), _mm256_castsi256_ps(iv), less));
      iv = _mm256_castps_si256(_mm256_blendv_ps(_mm256_castsi256_ps(iv), _mm256_castsi256_ps(idj), less));
    }
  }
  // UlrSelect's weights: the finite slots are a prefix of m; thresh = the 4th penalty, or 1.01 x
  // the largest + 1e-6 when fewer than 4 are finite.
  __m256 fin[4];
  __m256i count = _mm256_setzero_si256();
  __m256 last = s[0];
  for (int j = 0; j < 4; ++j) {
    fin[j] = _mm256_cmp_ps(s[j], inf, _CMP_LT_OQ);
    count = _mm256_sub_epi32(count, _mm256_castps_si256(fin[j]));
    last = _mm256_blendv_ps(last, s[j], fin[j]);
  }
  const __m256 thresh =
      _mm256_blendv_ps(_mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(1.01f), last), _mm256_set1_ps(1e-6f)), s[3], fin[3]);
  const __m256 tpos = _mm256_cmp_ps(thresh, zero, _CMP_GT_OQ);
  __m256 w[4];
  __m256 sum = zero;
  for (int j = 0; j < 4; ++j) {
    w[j] = _mm256_and_ps(tpos, _mm256_sub_ps(one, _mm256_div_ps(s[j], thresh)));
    w[j] = _mm256_and_ps(_mm256_and_ps(w[j], _mm256_cmp_ps(w[j], zero, _CMP_GT_OQ)), fin[j]);
    sum = _mm256_add_ps(sum, w[j]);  // + 0 past the finite slots: the same sum
  }
  const __m256 sum_ok = _mm256_and_ps(_mm256_cmp_ps(sum, zero, _CMP_GT_OQ), _mm256_cmp_ps(sum, inf, _CMP_LT_OQ));
  const __m256 uniform = _mm256_div_ps(one, _mm256_cvtepi32_ps(count));
  for (int j = 0; j < 4; ++j) {
    _mm256_storeu_ps(weight + 8 * j, _mm256_blendv_ps(uniform, _mm256_div_ps(w[j], sum), sum_ok));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(index + 8 * j), id[j]);
  }
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(m), count);
}
#endif  // __GNUC__
#endif  // __SSE2__

// Software prefetch of base[offset] (offset in floats; any value: the address is computed as an
// integer and a prefetch never faults, so a wrong guess costs a wasted line fill, nothing else).
inline void PrefetchAt(const float* base, std::ptrdiff_t offset) {
#if defined(__GNUC__)
  const std::uintptr_t a = reinterpret_cast<std::uintptr_t>(base) + std::uintptr_t(offset) * sizeof(float);
  __builtin_prefetch(reinterpret_cast<const void*>(a));
#else
  (void)base, (void)offset;
#endif
}

// The depth and colour texels a pixel will read, predicted kPrefetchAhead pixels ahead along the
// row from the last two pixels' texels in each view (the projection of the G-buffer moves
// steadily across a view along a row of the target, but in any direction: for a view turned 90
// degrees from the target a row of the target walks down a column of the view, a new cache line
// per pixel, which the hardware prefetchers do not follow across 12 views at once). Measured:
// the depth test's reads were the loop's largest stall (perf); 2 pixels ahead: ulr_blend min
// 103.6 -> 90.7 ms, median 106.4 -> 97.6 per frame (single-thread CPU, 6 rounds interleaved
// in one process, load ~10); 1 and 4 pixels ahead did less.
constexpr std::ptrdiff_t kPrefetchAhead = 2;

// The fast path of UlrBlend for pinhole input views: penalties, back-face, behind-the-camera and
// outside-the-image tests of all views in one branch-free float loop (SIMD over views: AVX2 when
// the CPU has it, else SSE2), then the depth test of every view that passed them (branch-free),
// pixel by pixel for a group of 8 pixels; then the group's selection (with AVX2: all 8 at once)
// and the blends. Differences from the scalar path: float instead of double
// projections (positions agree within ~1e-4 px at the synthetic scenes' scale), so a depth test
// exactly at its tolerance may flip (tests/hybrid/test_ulr_fast.py bounds it).
void UlrBlendFast(const Camera& novel, ImageView<const float> gbuffer_depth, ImageView<const float> normal,
                  const std::uint8_t* pixel_mask, const UlrInputView* views, int num_views, const UlrOptions& options,
                  ImageView<float> color_out, ImageView<std::uint8_t> count_out) {
  const int H = gbuffer_depth.height, W = gbuffer_depth.width;
  const glm::dvec3 c_novel_d = novel.CentreInWorld();
  const glm::vec3 c_novel(c_novel_d);
  const UlrViewTable vt(views, num_views);
  const int k = std::max(1, std::min(options.k, UlrOptions::kMaxK));
  const bool use_normal = !normal.Empty();
  const float rw = options.resolution_weight, tol = options.depth_tol;
  const bool cubic = options.cubic;
  const glm::dmat3 world_from_cam = glm::transpose(novel.rot);
  const int nv = num_views;
  const bool novel_pinhole = novel.model == CameraModel::kPinhole;
  const glm::vec3 col_step(world_from_cam * glm::dvec3(1.0 / novel.fx, 0.0, 0.0));
  const float cnx = c_novel.x, cny = c_novel.y, cnz = c_novel.z;
  using ViewsFn = void (*)(const UlrPoint&, const UlrViewTable&, bool, float, const UlrViewOut&);
  ViewsFn views_fn = nullptr;
  using DepthFn = void (*)(const UlrViewTable&, int, float, const UlrViewOut&, std::ptrdiff_t*);
  DepthFn depth_fn = nullptr;
  // The instruction sets: kAuto follows the engine's switch (UseAvx2: set_warp_isa; AVX-512 when
  // the CPU has it and the switch is not at the baseline), kAvx2 and kSse2 force theirs.
  bool avx2 = false, avx512 = false;
#if defined(IBR_ULR_AVX2)
  avx2 = options.simd == UlrSimd::kAuto ? UseAvx2() : options.simd == UlrSimd::kAvx2 && CpuHasAvx2();
  avx512 = options.simd == UlrSimd::kAuto && avx2 && CpuHasAvx512f();
#endif
#if defined(__SSE2__)
  views_fn = UlrViewsSse2;
#if defined(IBR_ULR_AVX2)
  if (avx2) views_fn = UlrViewsAvx2;
  if (avx512) views_fn = UlrViewsAvx512;
  // The depth test in the same ISA where the table's offsets fit int32 (else the scalar loop below).
  if (avx512 && vt.offsets32) {
    depth_fn = UlrDepthTestAvx512;
  } else if (views_fn == UlrViewsAvx2 && vt.rel32) {
    depth_fn = UlrDepthTestAvx2;
  }
#endif
#endif
  // With AVX2: the selection of a group's pixels at once for the default k = 4 (else UlrSelect
  // pixel by pixel: the same result), and the cubic reads' weights eight at a time.
  const bool select_avx2 = avx2 && k == 4;
  const bool cubic_avx2 = avx2 && cubic;
  ParallelFor2D(H, W, 64, [&](int y0, int y1, int x0, int x1) {
    const std::size_t nvp = vt.w.size();  // per-pixel row length of the group's arrays
    // Per pixel g of a group: the views' penalties, projections and z (row g of each), the colour
    // texel to prefetch per view; then the selection.
    std::vector<float> pen(kUlrGroup * nvp), qx(kUlrGroup * nvp), qy(kUlrGroup * nvp), qz(kUlrGroup * nvp);
    std::vector<std::ptrdiff_t> ahead(kUlrGroup * nvp), off16(nvp, 0);
    std::vector<float> pen_by_view(kUlrGroup * nvp);  // pen[view][g]: the selection's layout
    const float* const* DP = vt.depth.data();
    const std::ptrdiff_t* DS = vt.depth_stride.data();
    const float* WL = vt.wlast.data();
    const float* HL = vt.hlast.data();
    int index[kUlrGroup * UlrOptions::kMaxK];  // [j * kUlrGroup + g]
    float weight[kUlrGroup * UlrOptions::kMaxK];
    int selected[kUlrGroup];
    // The group's colour reads (at most k per pixel; padded to a multiple of 8): pixel, view,
    // weight, position; and the cubic reads' tap origins and weights.
    constexpr int kMaxReads = kUlrGroup * UlrOptions::kMaxK + 8;
    int read_g[kMaxReads], read_view[kMaxReads];
    float read_w[kMaxReads];
    alignas(32) float read_x[kMaxReads] = {}, read_y[kMaxReads] = {};
    alignas(32) float read_wlast[kMaxReads] = {}, read_hlast[kMaxReads] = {};
    alignas(32) int read_x0[kMaxReads], read_y0[kMaxReads];
    alignas(32) float read_wx[4 * kMaxReads], read_wy[4 * kMaxReads];
    int one_index[64];
    float one_weight[64];
    // Each view's depth texel offset at the last pixel computed (the prefetch's predictor).
    std::vector<std::ptrdiff_t> prev_off(nvp, 0);
    for (int y = y0; y < y1; ++y) {
      const float* drow = gbuffer_depth.Row(y);
      float* crow = color_out.Row(y);
      std::uint8_t* nrow = count_out.Row(y);
      // World direction of pixel (0, y)'s ray (camera z = 1) and its change per column.
      const glm::vec3 row_dir(world_from_cam * novel.RayInCam(0.5, y + 0.5));
      for (int xg = x0; xg < x1; xg += kUlrGroup) {
        const int gn = std::min(kUlrGroup, x1 - xg);
        unsigned live = 0;
        for (int g = 0; g < gn; ++g) {
          const int x = xg + g;
          crow[3 * x] = crow[3 * x + 1] = crow[3 * x + 2] = 0.f;
          nrow[x] = 0;
          const float t = drow[x];
          if (!(t > 0.f) || !std::isfinite(t)) continue;
          if (pixel_mask && !pixel_mask[std::int64_t(y) * W + x]) continue;
          // p = centre + t * (world direction of the pixel's ray), the direction affine in x along
          // the row (pinhole novel camera; equirect: per pixel, as the scalar path).
          UlrPoint q;
          if (novel_pinhole) {
            const float fxp = float(x);
            q.px = cnx + t * (row_dir.x + fxp * col_step.x);
            q.py = cny + t * (row_dir.y + fxp * col_step.y);
            q.pz = cnz + t * (row_dir.z + fxp * col_step.z);
          } else {
            const glm::vec3 p(world_from_cam * (novel.RayInCam(x + 0.5, y + 0.5) * double(t)) + c_novel_d);
            q.px = p.x, q.py = p.y, q.pz = p.z;
          }
          q.nx = q.ny = q.nz = 0.f;
          if (use_normal) q.nx = normal.At(y, x, 0), q.ny = normal.At(y, x, 1), q.nz = normal.At(y, x, 2);
          q.bx = c_novel.x - q.px, q.by = c_novel.y - q.py, q.bz = c_novel.z - q.pz;
          q.lb = std::sqrt(q.bx * q.bx + q.by * q.by + q.bz * q.bz);
          if (!(q.lb > 0.f) || !std::isfinite(q.lb)) continue;  // every penalty is +inf
          live |= 1u << g;
          const UlrViewOut vo{pen.data() + g * nvp, qx.data() + g * nvp, qy.data() + g * nvp, qz.data() + g * nvp};
          if (views_fn) {
            views_fn(q, vt, use_normal, rw, vo);
          } else {
            UlrViewsScalar(q, vt, use_normal, rw, 0, vo);
          }
          // The depth test of every view, before any selection and without branches: the views'
          // depth reads are independent loads the CPU overlaps, where the lazy scheme (test the
          // selected views, drop failures, select again; the scalar path) waits for each in turn,
          // and a branch per view mispredicts. Views that failed the cheap tests read a clamped
          // texel and stay at +inf. The same views pass as with the lazy test, so the selection and
          // the blend are the lazy scheme's, bit for bit (measured again with this loop: the lazy
          // scheme 107 ms against 104.5 per frame, single-thread CPU, min of 8, load ~9).
          std::ptrdiff_t* ahead_g = ahead.data() + g * nvp;
          if (depth_fn) {  // the same test, 16 or 8 views a step; then the prefetches by view
            depth_fn(vt, nv, tol, vo, off16.data());
          } else {
            for (int i = 0; i < nv; ++i) {
              float fx = vo.qx[i] > 0.f ? vo.qx[i] : 0.f;  // NaN -> 0
              float fy = vo.qy[i] > 0.f ? vo.qy[i] : 0.f;
              fx = fx < WL[i] ? fx : WL[i];
              fy = fy < HL[i] ? fy : HL[i];
              const std::ptrdiff_t off = std::ptrdiff_t(int(fy)) * DS[i] + int(fx);
              off16[std::size_t(i)] = off;
              const float dv = DP[i][off];
              const bool ok = (vo.pen[i] < INFINITY) & (dv > 0.f) & (dv <= 3.4028235e38f) &
                              (std::abs(vo.qz[i] - dv) <= tol * dv);
              vo.pen[i] = ok ? vo.pen[i] : INFINITY;
            }
          }
          for (int i = 0; i < nv; ++i) {
            const std::ptrdiff_t off = off16[std::size_t(i)];
            const std::ptrdiff_t step = kPrefetchAhead * (off - prev_off[i]);
            PrefetchAt(DP[i], off + step);
            ahead_g[i] = off + step;  // the depth texel's offset and step, for the colour read below
            prev_off[i] = off;
            pen_by_view[std::size_t(i) * kUlrGroup + g] = vo.pen[i];
          }
        }
        if (!live) continue;
#if defined(IBR_ULR_AVX2)
        if (select_avx2) {
          UlrSelect4x8Avx2(pen_by_view.data(), nv, live, index, weight, selected);
        } else
#endif
        {
          for (int g = 0; g < gn; ++g) {
            selected[g] = live >> g & 1u ? UlrSelect(pen.data() + g * nvp, nv, k, one_index, one_weight) : 0;
            for (int j = 0; j < selected[g]; ++j) {
              index[j * kUlrGroup + g] = one_index[j];
              weight[j * kUlrGroup + g] = one_weight[j];
            }
          }
        }
        // The group's colour reads (each kept view with a positive weight, pixel by pixel, in
        // selection order: the blend's order); with cubic_avx2 their Catmull-Rom positions and
        // weights computed eight reads at once.
        int reads = 0;
        for (int g = 0; g < gn; ++g) {
          for (int j = 0; j < (live >> g & 1u ? selected[g] : 0); ++j) {
            if (!(weight[j * kUlrGroup + g] > 0.f)) continue;
            const int i = index[j * kUlrGroup + g];
            read_g[reads] = g;
            read_view[reads] = i;
            read_w[reads] = weight[j * kUlrGroup + g];
            read_x[reads] = qx[g * nvp + i];
            read_y[reads] = qy[g * nvp + i];
            read_wlast[reads] = float(views[i].color.width - 1);
            read_hlast[reads] = float(views[i].color.height - 1);
            ++reads;
          }
        }
#if defined(IBR_ULR_AVX2)
        if (cubic_avx2) CubicWeightsAvx2(reads, read_x, read_y, read_wlast, read_hlast, read_x0, read_y0, read_wx, read_wy);
#endif
        float col[kUlrGroup][4] = {};
        int used[kUlrGroup] = {};
        for (int r = 0; r < reads; ++r) {
          const int g = read_g[r], i = read_view[r];
          const ImageView<const float>& img = views[i].color;
          // CubicRgbAdd with the weights computed above (and, like it, per channel at a view's
          // last pixel).
#if defined(IBR_ULR_AVX2)
          if (cubic_avx2 && (read_y0[r] + 2 < img.height - 1 || read_x0[r] + 2 < img.width - 1)) {
            const float* rows[4];
            int taps[4];
            CubicRgbTaps(img.data, img.row_stride, img.width, img.height, read_x0[r], read_y0[r], taps, rows);
            CubicRgbTapsAdd(rows, taps, _mm_loadu_ps(read_wx + 4 * r), _mm_loadu_ps(read_wy + 4 * r), read_w[r], col[g]);
          } else
#endif
          if (cubic) {
            CubicRgbAdd(img.data, img.row_stride, img.width, img.height, read_x[r], read_y[r], read_w[r], col[g]);
          } else {
            Bilinear3Add(img, read_x[r], read_y[r], read_w[r], col[g]);
          }
          // The texels this view's colour read will want kPrefetchAhead pixels on (its depth
          // texel's offset and step, in the colour image: 3 floats a pixel), rows y and y + 1.
          const std::ptrdiff_t ahead_i = ahead[g * nvp + i];
          PrefetchAt(img.data, 3 * ahead_i);
          PrefetchAt(img.data, 3 * ahead_i + img.row_stride);
          ++used[g];
        }
        for (int g = 0; g < gn; ++g) {
          if (used[g] == 0) continue;
          const int x = xg + g;
          crow[3 * x] = col[g][0];
          crow[3 * x + 1] = col[g][1];
          crow[3 * x + 2] = col[g][2];
          nrow[x] = std::uint8_t(std::min(used[g], 255));
        }
      }
    }
  });
}

}  // namespace

void UlrBlend(const Camera& novel, ImageView<const float> gbuffer_depth, ImageView<const float> normal,
              const std::uint8_t* pixel_mask, const UlrInputView* views, int num_views, const UlrOptions& options,
              ImageView<float> color_out, ImageView<std::uint8_t> count_out) {
  bool pinhole = true;
  for (int i = 0; i < num_views; ++i) pinhole = pinhole && views[i].camera.model == CameraModel::kPinhole;
  if (pinhole && !options.reference) {
    UlrBlendFast(novel, gbuffer_depth, normal, pixel_mask, views, num_views, options, color_out, count_out);
  } else {
    UlrBlendScalar(novel, gbuffer_depth, normal, pixel_mask, views, num_views, options, color_out, count_out);
  }
}

void HybridSelect(ImageView<const float> gbuffer_depth, const std::uint8_t* inside_grid, const std::uint8_t* pvm_valid,
                  const float* pvm_depth, const float* vd, const HybridSelectOptions& options,
                  ImageView<std::uint8_t> label_out) {
  const int H = gbuffer_depth.height, W = gbuffer_depth.width;
  // By rows (no division per pixel to find its row and column).
  ParallelFor(H, 8, [&](std::int64_t b, std::int64_t e) {
    for (int y = int(b); y < int(e); ++y) {
      const float* grow = gbuffer_depth.Row(y);
      std::uint8_t* lrow = label_out.Row(y);
      for (int x = 0; x < W; ++x) {
        const std::int64_t i = std::int64_t(y) * W + x;
        const float g = grow[x];
        const bool hit = g > 0.f && std::isfinite(g);
        std::uint8_t lab;
        if (inside_grid && !inside_grid[i]) {
          lab = hit ? kLabelUlr : kLabelNone;
        } else if (pvm_valid && pvm_valid[i] &&
                   (!hit || !(std::abs(pvm_depth[i] - g) <= options.geo_threshold))) {
          lab = kLabelPvm;
        } else if (!hit) {
          lab = kLabelNone;
        } else if ((vd ? vd[i] : 0.f) > options.tau_var) {  // no vd: 0 (tau_var < 0: always ULR)
          lab = kLabelUlr;
        } else {
          lab = kLabelTm;
        }
        lrow[x] = lab;
      }
    }
  });
}

namespace {

#if defined(IBR_ULR_AVX2)
// BlurSelection's two passes in AVX2, eight columns per register and the sum over the taps kept
// in registers (no store per tap): each output is the same sum in the same order (tap -r first,
// starting from 0; mul then add, no FMA) as the SSE2 / scalar loops, so the same bits.
// Vertical: a_c[x] = sum_d taps[d] * (label(clamp(y + d - r), x) == c) for the labels c with
// has[c], written to planes[c] + x.
__attribute__((target("avx2"))) void BlurVerticalAvx2(const std::uint8_t* const* rows, const float* taps, int ntaps,
                                                      int W, const bool* has, float* const* planes) {
  const __m256i l0 = _mm256_set1_epi32(0), l1 = _mm256_set1_epi32(1), l2 = _mm256_set1_epi32(2);
  int x = 0;
  for (; x + 8 <= W; x += 8) {
    __m256 a0 = _mm256_setzero_ps(), a1 = _mm256_setzero_ps(), a2 = _mm256_setzero_ps();
    for (int d = 0; d < ntaps; ++d) {
      const __m256i lab = _mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(rows[d] + x)));
      const __m256 t = _mm256_set1_ps(taps[d]);
      a0 = _mm256_add_ps(a0, _mm256_and_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(lab, l0)), t));
      a1 = _mm256_add_ps(a1, _mm256_and_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(lab, l1)), t));
      a2 = _mm256_add_ps(a2, _mm256_and_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(lab, l2)), t));
    }
    if (has[0]) _mm256_storeu_ps(planes[0] + x, a0);
    if (has[1]) _mm256_storeu_ps(planes[1] + x, a1);
    if (has[2]) _mm256_storeu_ps(planes[2] + x, a2);
  }
  for (; x < W; ++x) {
    float a[3] = {0.f, 0.f, 0.f};
    for (int d = 0; d < ntaps; ++d) {
      const std::uint8_t l = rows[d][x];
      for (int c = 0; c < 3; ++c) a[c] += l == c ? taps[d] : 0.f;
    }
    for (int c = 0; c < 3; ++c)
      if (has[c]) planes[c][x] = a[c];
  }
}

// Horizontal: out[x] = sum_d taps[d] * pad[x + d].
__attribute__((target("avx2"))) void BlurHorizontalAvx2(const float* pad, const float* taps, int ntaps, int W,
                                                        float* out) {
  int x = 0;
  for (; x + 32 <= W; x += 32) {
    __m256 a0 = _mm256_setzero_ps(), a1 = _mm256_setzero_ps(), a2 = _mm256_setzero_ps(), a3 = _mm256_setzero_ps();
    for (int d = 0; d < ntaps; ++d) {
      const __m256 t = _mm256_set1_ps(taps[d]);
      const float* in = pad + x + d;
      a0 = _mm256_add_ps(a0, _mm256_mul_ps(t, _mm256_loadu_ps(in)));
      a1 = _mm256_add_ps(a1, _mm256_mul_ps(t, _mm256_loadu_ps(in + 8)));
      a2 = _mm256_add_ps(a2, _mm256_mul_ps(t, _mm256_loadu_ps(in + 16)));
      a3 = _mm256_add_ps(a3, _mm256_mul_ps(t, _mm256_loadu_ps(in + 24)));
    }
    _mm256_storeu_ps(out + x, a0);
    _mm256_storeu_ps(out + x + 8, a1);
    _mm256_storeu_ps(out + x + 16, a2);
    _mm256_storeu_ps(out + x + 24, a3);
  }
  for (; x + 8 <= W; x += 8) {
    __m256 a0 = _mm256_setzero_ps();
    for (int d = 0; d < ntaps; ++d) a0 = _mm256_add_ps(a0, _mm256_mul_ps(_mm256_set1_ps(taps[d]), _mm256_loadu_ps(pad + x + d)));
    _mm256_storeu_ps(out + x, a0);
  }
  for (; x < W; ++x) {
    float a = 0.f;
    for (int d = 0; d < ntaps; ++d) a += taps[d] * pad[x + d];
    out[x] = a;
  }
}
#endif  // IBR_ULR_AVX2

// The blurred weights (w0, w1, w2) of one pixel normalised to sum 1 (all 0 where none is
// positive), then min_weight applied (BlurSelection), into out[0..3).
inline void StoreSelectionWeights(float w0, float w1, float w2, float min_weight, float* out) {
  const float sum = w0 + w1 + w2;
  const float inv = sum > 0.f ? 1.f / sum : 0.f;
  float a = w0 * inv, b = w1 * inv, c = w2 * inv;
  if (min_weight > 0.f && sum > 0.f && (a < min_weight || b < min_weight || c < min_weight)) {
    const float ka = a < min_weight ? 0.f : a, kb = b < min_weight ? 0.f : b, kc = c < min_weight ? 0.f : c;
    // >= 1/3 but for rounding (three equal weights at min_weight = 1/3): then all are kept
    const float kept = ka + kb + kc;
    if (kept > 0.f) a = ka / kept, b = kb / kept, c = kc / kept;
  }
  out[0] = a;
  out[1] = b;
  out[2] = c;
}

#if defined(IBR_ULR_AVX2)
// StoreSelectionWeights over W pixels of planar weights, eight per step in AVX2: its operations
// lane for lane, the branches as selects (the divisions of the lanes not taken are discarded), so
// the same bits; the interleaved stores through a small buffer.
__attribute__((target("avx2"))) void StoreSelectionWeightsAvx2(const float* w0, const float* w1, const float* w2, int W,
                                                               float min_weight, float* out) {
  const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.f), mw = _mm256_set1_ps(min_weight);
  const bool clip = min_weight > 0.f;
  alignas(32) float abc[3][8];
  int x = 0;
  for (; x + 8 <= W; x += 8) {
    const __m256 A = _mm256_loadu_ps(w0 + x), B = _mm256_loadu_ps(w1 + x), C = _mm256_loadu_ps(w2 + x);
    const __m256 sum = _mm256_add_ps(_mm256_add_ps(A, B), C);
    const __m256 pos = _mm256_cmp_ps(sum, zero, _CMP_GT_OQ);
    const __m256 inv = _mm256_and_ps(pos, _mm256_div_ps(one, sum));
    __m256 a = _mm256_mul_ps(A, inv), b = _mm256_mul_ps(B, inv), c = _mm256_mul_ps(C, inv);
    if (clip) {
      const __m256 la = _mm256_cmp_ps(a, mw, _CMP_LT_OQ), lb = _mm256_cmp_ps(b, mw, _CMP_LT_OQ);
      const __m256 lc = _mm256_cmp_ps(c, mw, _CMP_LT_OQ);
      const __m256 ka = _mm256_andnot_ps(la, a), kb = _mm256_andnot_ps(lb, b), kc = _mm256_andnot_ps(lc, c);
      const __m256 kept = _mm256_add_ps(_mm256_add_ps(ka, kb), kc);
      const __m256 upd = _mm256_and_ps(_mm256_and_ps(pos, _mm256_or_ps(_mm256_or_ps(la, lb), lc)),
                                       _mm256_cmp_ps(kept, zero, _CMP_GT_OQ));
      a = _mm256_blendv_ps(a, _mm256_div_ps(ka, kept), upd);
      b = _mm256_blendv_ps(b, _mm256_div_ps(kb, kept), upd);
      c = _mm256_blendv_ps(c, _mm256_div_ps(kc, kept), upd);
    }
    _mm256_store_ps(abc[0], a);
    _mm256_store_ps(abc[1], b);
    _mm256_store_ps(abc[2], c);
    float* o = out + 3 * x;
    for (int i = 0; i < 8; ++i) o[3 * i] = abc[0][i], o[3 * i + 1] = abc[1][i], o[3 * i + 2] = abc[2][i];
  }
  for (; x < W; ++x) StoreSelectionWeights(w0[x], w1[x], w2[x], min_weight, out + 3 * x);
}
#endif

// StoreSelectionWeights over a row of W pixels of planar weights w0, w1, w2 (AVX2 when avx2: the
// same bits).
void StoreSelectionWeightsRow(const float* w0, const float* w1, const float* w2, int W, float min_weight, bool avx2,
                              float* out) {
#if defined(IBR_ULR_AVX2)
  if (avx2) {
    StoreSelectionWeightsAvx2(w0, w1, w2, W, min_weight, out);
    return;
  }
#endif
  (void)avx2;
  for (int x = 0; x < W; ++x) StoreSelectionWeights(w0[x], w1[x], w2[x], min_weight, out + 3 * x);
}

// One row of a separable blur, edge-clamped: out[x] = sum_d taps[d] src[clamp(x + d - r)] for x < W
// (taps of length 2 r + 1), through pad (W + 2 r floats); AVX2 when avx2 (BlurHorizontalAvx2: the
// same sums in the same order, so the same bits).
void BlurRowClamped(const float* src, int W, const std::vector<float>& taps, bool avx2, float* pad, float* out) {
  const int r = int(taps.size() / 2);
  for (int x = 0; x < r; ++x) pad[x] = src[0], pad[W + r + x] = src[W - 1];
  std::copy(src, src + W, pad + r);
#if defined(IBR_ULR_AVX2)
  if (avx2) {
    BlurHorizontalAvx2(pad, taps.data(), int(taps.size()), W, out);
    return;
  }
#endif
  (void)avx2;
  for (int x = 0; x < W; ++x) out[x] = 0.f;
  for (int d = 0; d <= 2 * r; ++d) {
    const float t = taps[std::size_t(d)];
    const float* in = pad + d;
    for (int x = 0; x < W; ++x) out[x] += t * in[x];
  }
}

// Separable Gaussian taps of standard deviation sigma, radius ceil(3 sigma) (one tap of 1 at 0).
std::vector<float> GaussTaps(float sigma) {
  const int r = sigma > 0.f ? int(std::ceil(3.f * sigma)) : 0;
  std::vector<float> taps(2 * r + 1);
  for (int d = -r; d <= r; ++d) taps[d + r] = r ? std::exp(-0.5f * d * d / (sigma * sigma)) : 1.f;
  return taps;
}

// BlurSelection's decimated form (see hybrid.h): the one-hot planes averaged over f x f blocks of
// the label image edge-replicated by a margin M beyond the blur's reach (the full blur's edge
// clamp: the edge pixels' labels, not their blocks' means, continue past the edge), blurred at
// 1 / f of the resolution with a Gaussian whose variance plus the block mean's ((f^2 - 1) / 12
// px^2) and the bilinear upsampling's (~(f^2 - 1) / 6) is sigma^2, and read back bilinearly at
// each pixel (block centres at f j + (f - 1) / 2 - M).
void BlurSelectionDecimated(ImageView<const std::uint8_t> label, float sigma, float min_weight, int f,
                            ImageView<float> weights_out) {
  const int H = label.height, W = label.width;
  const int margin = (int(std::ceil(3.f * sigma / float(f))) + 1) * f;
  const int hl = (H + 2 * margin + f - 1) / f, wl = (W + 2 * margin + f - 1) / f;
  const std::size_t plane = std::size_t(hl) * wl;
  std::vector<float> lo(3 * plane), tmp(3 * plane);
  const float block = 1.f / float(f * f);
  ParallelFor(hl, 4, [&](std::int64_t b, std::int64_t e) {
    for (int by = int(b); by < int(e); ++by) {
      for (int bx = 0; bx < wl; ++bx) {
        int n[4] = {0, 0, 0, 0};
        for (int y = by * f - margin; y < by * f + f - margin; ++y) {
          const std::uint8_t* lrow = label.Row(std::clamp(y, 0, H - 1));
          for (int x = bx * f - margin; x < bx * f + f - margin; ++x) ++n[lrow[std::clamp(x, 0, W - 1)] & 3];
        }
        for (int c = 0; c < 3; ++c) lo[c * plane + std::size_t(by) * wl + bx] = float(n[c]) * block;
      }
    }
  });
  const float var = sigma * sigma - float(f * f - 1) / 4.f;
  const std::vector<float> taps = GaussTaps(std::sqrt(std::max(var, 0.f)) / float(f));
  const int r = int(taps.size() / 2);
  ParallelFor(3 * std::int64_t(hl), 8, [&](std::int64_t b, std::int64_t e) {  // vertical, lo -> tmp
    for (std::int64_t cy = b; cy < e; ++cy) {
      const std::size_t c = std::size_t(cy / hl);
      const int y = int(cy % hl);
      float* out = tmp.data() + c * plane + std::size_t(y) * wl;
      std::fill(out, out + wl, 0.f);
      for (int d = -r; d <= r; ++d) {
        const float* in = lo.data() + c * plane + std::size_t(std::clamp(y + d, 0, hl - 1)) * wl;
        const float t = taps[std::size_t(d + r)];
        for (int x = 0; x < wl; ++x) out[x] += t * in[x];
      }
    }
  });
  const bool avx2 = UseAvx2();
  ParallelFor(3 * std::int64_t(hl), 8, [&](std::int64_t b, std::int64_t e) {  // horizontal, tmp -> lo
    std::vector<float> pad(std::size_t(wl) + 2 * r);
    for (std::int64_t cy = b; cy < e; ++cy)  // plane c, row y: consecutive rows of tmp and lo
      BlurRowClamped(tmp.data() + std::size_t(cy) * wl, wl, taps, avx2, pad.data(), lo.data() + std::size_t(cy) * wl);
  });
  // Bilinear read-back: low-resolution coordinate u = (x + M - (f - 1) / 2) / f (clamped).
  const auto axis = [f, margin](int n, int nl, std::vector<int>& i0, std::vector<float>& frac) {
    i0.resize(std::size_t(n)), frac.resize(std::size_t(n));
    for (int x = 0; x < n; ++x) {
      const float u = (float(x + margin) - 0.5f * float(f - 1)) / float(f);
      int j = int(std::floor(u));
      float t = u - float(j);
      if (j < 0) j = 0, t = 0.f;
      if (j >= nl - 1) j = nl - 1, t = 0.f;
      i0[std::size_t(x)] = j, frac[std::size_t(x)] = t;
    }
  };
  std::vector<int> x0, y0;
  std::vector<float> fx, fy;
  axis(W, wl, x0, fx);
  axis(H, hl, y0, fy);
  // The low-resolution rows the output rows read (y0 and y0 + 1; y0 grows with y), each read back
  // along x once into hz (plane c, row j - j0) for the ~f output rows that share it: the same
  // values as interpolating at every output pixel, a fraction of the work.
  const int j0 = y0.front(), j1 = std::min(y0.back() + 1, hl - 1), nr = j1 - j0 + 1;
  std::vector<float> hz(3 * std::size_t(nr) * std::size_t(W));
  ParallelFor(3 * std::int64_t(nr), 4, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t cj = b; cj < e; ++cj) {
      const float* q = lo.data() + std::size_t(cj / nr) * plane + std::size_t(j0 + cj % nr) * wl;
      float* o = hz.data() + std::size_t(cj) * W;
      for (int x = 0; x < W; ++x) {
        const std::size_t ca = std::size_t(x0[std::size_t(x)]);
        const std::size_t cb = std::min(ca + 1, std::size_t(wl - 1));
        o[x] = q[ca] + fx[std::size_t(x)] * (q[cb] - q[ca]);
      }
    }
  });
  ParallelFor(H, 8, [&](std::int64_t b, std::int64_t e) {
    std::vector<float> wv(3 * std::size_t(W));
    for (int y = int(b); y < int(e); ++y) {
      const int ra = y0[std::size_t(y)] - j0, rb = std::min(y0[std::size_t(y)] + 1, hl - 1) - j0;
      const float ty = fy[std::size_t(y)];
      for (int c = 0; c < 3; ++c) {
        const float* top = hz.data() + (std::size_t(c) * nr + std::size_t(ra)) * W;
        const float* bot = hz.data() + (std::size_t(c) * nr + std::size_t(rb)) * W;
        float* w = wv.data() + std::size_t(c) * W;
        for (int x = 0; x < W; ++x) w[x] = std::max(top[x] + ty * (bot[x] - top[x]), 0.f);  // >= 0 (rounding)
      }
      StoreSelectionWeightsRow(wv.data(), wv.data() + W, wv.data() + 2 * std::size_t(W), W, min_weight, avx2,
                               weights_out.Row(y));
    }
  });
}

}  // namespace

void FloorPvmWeight(ImageView<float> weights, float floor) {
  if (!(floor > 0.f)) return;
  const int W = weights.width;
  ParallelFor(weights.height, 16, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t y = b; y < e; ++y) {
      float* w = weights.Row(int(y));
      for (int x = 0; x < W; ++x, w += 3) {
        const float pvm = w[2];
        if (!(pvm < floor) || !(w[0] + w[1] + pvm > 0.f)) continue;
        // pvm < floor <= 1: the divisor is > 0.
        const float s = (1.f - floor) / (1.f - pvm);
        w[0] *= s;
        w[1] *= s;
        w[2] = floor;
      }
    }
  });
}

int BlurSelectionFactor(float sigma) { return sigma >= 8.f ? std::min(4, int(sigma / 4.f)) : 1; }

void BlurSelection(ImageView<const std::uint8_t> label, float sigma, float min_weight, float* scratch,
                   ImageView<float> weights_out, bool decimate) {
  const int f = decimate ? BlurSelectionFactor(sigma) : 1;
  if (f > 1) {
    BlurSelectionDecimated(label, sigma, min_weight, f, weights_out);
    return;
  }
  const int H = label.height, W = label.width;
  const std::vector<float> taps = GaussTaps(sigma);
  const int r = int(taps.size() / 2);
  // Vertical pass first, on the one-hot planes, into scratch as three planes (TM, ULR, PVM) of
  // H x W: the inner loops run along rows (contiguous, vectorised), unlike a horizontal pass over
  // interleaved channels. Sums of non-negative terms: a weight is 0 exactly where no label of its
  // kind lies in the window, whatever the order of the passes (the support, which decides where
  // ULR and PVM are computed, is the same as the horizontal-first order's; values agree to float
  // rounding).
  const std::int64_t plane = std::int64_t(H) * W;
  // Labels present anywhere: a method no pixel chose has weight 0 everywhere (exactly what its
  // convolution would give) and its passes are skipped (e.g. ULR when the photometric test never
  // fires; at sigma_blur 16 each pass is 97 taps).
  bool has[3] = {false, false, false};
  for (int y = 0; y < H && !(has[0] && has[1] && has[2]); ++y) {
    const std::uint8_t* lrow = label.Row(y);
    for (int x = 0; x < W; ++x)
      if (lrow[x] < 3) has[lrow[x]] = true;
  }
  // AVX2 when the engine's switch allows (UseAvx2: the CPU has it, unless set_warp_isa asked for
  // the baseline; the same bits, BlurVerticalAvx2 / BlurHorizontalAvx2): the sums over the taps in
  // registers, eight columns at a time.
  const bool avx2 = UseAvx2();
  const int ntaps = 2 * r + 1;
  ParallelFor(H, 8, [&](std::int64_t b, std::int64_t e) {
#if defined(IBR_ULR_AVX2)
    if (avx2) {
      std::vector<const std::uint8_t*> rows(static_cast<std::size_t>(ntaps));
      for (int y = int(b); y < int(e); ++y) {
        for (int d = -r; d <= r; ++d) rows[std::size_t(d + r)] = label.Row(std::clamp(y + d, 0, H - 1));
        float* planes[3];
        for (int c = 0; c < 3; ++c) planes[c] = scratch + c * plane + std::int64_t(y) * W;
        BlurVerticalAvx2(rows.data(), taps.data(), ntaps, W, has, planes);
      }
      return;
    }
#endif
    for (int y = int(b); y < int(e); ++y) {
      float* a0 = scratch + std::int64_t(y) * W;
      float* a1 = a0 + plane;
      float* a2 = a1 + plane;
      for (int x = 0; x < W; ++x) a0[x] = a1[x] = a2[x] = 0.f;
      for (int d = -r; d <= r; ++d) {
        const std::uint8_t* lrow = label.Row(std::clamp(y + d, 0, H - 1));
        const float t = taps[d + r];
        // One channel per sweep (measured faster than three selects per element in one sweep).
        for (int c = 0; c < 3; ++c) {
          if (!has[c]) continue;
          float* a = scratch + c * plane + std::int64_t(y) * W;
          const std::uint8_t lc = std::uint8_t(c);
          for (int x = 0; x < W; ++x) a[x] += lrow[x] == lc ? t : 0.f;
        }
      }
    }
  });
  // Horizontal pass (edge-clamped through a padded copy of the row), normalisation, interleave.
  ParallelFor(H, 8, [&](std::int64_t b, std::int64_t e) {
    std::vector<float> pad(std::size_t(W) + 2 * r), acc(3 * std::size_t(W));
    for (int y = int(b); y < int(e); ++y) {
      for (int c = 0; c < 3; ++c) {
        if (!has[c]) {
          std::fill(acc.begin() + std::size_t(c) * W, acc.begin() + std::size_t(c + 1) * W, 0.f);
          continue;
        }
        BlurRowClamped(scratch + c * plane + std::int64_t(y) * W, W, taps, avx2, pad.data(),
                       acc.data() + std::size_t(c) * W);
      }
      StoreSelectionWeightsRow(acc.data(), acc.data() + W, acc.data() + 2 * std::size_t(W), W, min_weight, avx2,
                               weights_out.Row(y));
    }
  });
}

void HybridNeeds(ImageView<const float> weights, const std::uint8_t* pvm_valid, std::uint8_t* need_ulr,
                 std::uint8_t* need_pvm, std::int64_t counts[2]) {
  const int H = weights.height, W = weights.width;
  std::atomic<std::int64_t> n_ulr{0}, n_pvm{0};
  ParallelFor(H, 8, [&](std::int64_t b, std::int64_t e) {
    std::int64_t nu = 0, np = 0;
    for (int y = int(b); y < int(e); ++y) {
      const float* wrow = weights.Row(y);
      for (int x = 0; x < W; ++x) {
        const std::int64_t i = std::int64_t(y) * W + x;
        const bool pvm = wrow[3 * x + 2] > 0.f, valid = pvm_valid[i] != 0;
        const bool u = wrow[3 * x + 1] > 0.f || (pvm && !valid), p = pvm && valid;
        need_ulr[i] = u;
        need_pvm[i] = p;
        nu += u, np += p;
      }
    }
    n_ulr += nu;
    n_pvm += np;
  });
  counts[0] = n_ulr, counts[1] = n_pvm;
}

void HybridFrameOutputs(ImageView<const std::uint8_t> label, ImageView<const float> weights, const float* gbuffer_depth,
                        const float* pvm_depth, std::uint8_t* hole, float* depth, float* selection,
                        std::int64_t counts[4]) {
  const int H = label.height, W = label.width;
  std::atomic<std::int64_t> total[4] = {{0}, {0}, {0}, {0}};
  ParallelFor(H, 8, [&](std::int64_t b, std::int64_t e) {
    std::int64_t n[4] = {0, 0, 0, 0};
    for (int y = int(b); y < int(e); ++y) {
      const std::uint8_t* lrow = label.Row(y);
      const float* wrow = weights.Row(y);
      for (int x = 0; x < W; ++x) {
        const std::int64_t i = std::int64_t(y) * W + x;
        static constexpr float kNoWeight[3] = {0.f, 0.f, 0.f};
        const std::uint8_t l = lrow[x];
        const bool none = l == kLabelNone;
        const float* wt = none ? kNoWeight : wrow + 3 * x;  // a hole shows no weight
        ++n[l];  // 0..3 (the binding checks)
        hole[i] = none;
        depth[i] = l == kLabelPvm ? pvm_depth[i] : gbuffer_depth[i];
        float* s = selection + 3 * i;
        s[0] = wt[2], s[1] = wt[0], s[2] = wt[1];
      }
    }
    for (int c = 0; c < 4; ++c) total[c] += n[c];
  });
  for (int c = 0; c < 4; ++c) counts[c] = total[c];
}

void HybridComposite(ImageView<const float> weights, ImageView<const float> tm, const float* ulr,
                     const std::uint8_t* ulr_count, const float* pvm, const std::uint8_t* pvm_valid,
                     ImageView<float> color_out) {
  const int H = weights.height, W = weights.width;
  // By rows (no division per pixel to find its row and column).
  ParallelFor(H, 8, [&](std::int64_t b, std::int64_t e) {
    for (int y = int(b); y < int(e); ++y) {
      const float* wrow = weights.Row(y);
      const float* trow = tm.Row(y);
      float* orow = color_out.Row(y);
      for (int x = 0; x < W; ++x) {
        const std::int64_t i = std::int64_t(y) * W + x;
        const float* w = wrow + 3 * x;
        const float* t = trow + 3 * x;
        const float* u = (ulr && ulr_count && ulr_count[i] > 0) ? ulr + 3 * i : t;
        const float* v = (pvm && pvm_valid && pvm_valid[i]) ? pvm + 3 * i : u;
        float* o = orow + 3 * x;
        for (int c = 0; c < 3; ++c) o[c] = w[0] * t[c] + w[1] * u[c] + w[2] * v[c];
      }
    }
  });
}

}  // namespace ibr
