#include "kernels/dibr/forward_warp.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>
#include <type_traits>

#include <emmintrin.h>  // SSE2: part of x86-64, no build option needed
#include <immintrin.h>  // AVX2: only in target("avx2") functions, called when the CPU has it

#include "ibr/parallel.h"
#include "ibr/raster.h"
#include "ibr/simd.h"

namespace ibr {
namespace {

// The rasteriser core (cpp/ibr/raster.h): fixed point, edge functions and their fill rule, the
// candidate centres and the span scan.
using raster::CeilSub;
using raster::Edges;
using raster::FloorSub;
using raster::kSubpixel;
using raster::RoundHalfAway;
using raster::SetupEdges;

constexpr int kSegCols = 16;     // input quads per column segment (y-range culling unit)
constexpr int kBandRows = 32;    // target rows per rasterisation task
constexpr float kGuardPixels = 16384.f;
constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr std::int32_t kInvalid = std::numeric_limits<std::int32_t>::min();

// Instruction-set dispatch (forward_warp.h): the hot loops run through
// CallAvx2 / UseAvx2 (cpp/ibr/simd.h), which compile them for AVX2 (no FMA: the same IEEE
// operations in the same order, so the same bits; tests/dibr/test_forward_warp_isa.py compares both
// paths) and follow the engine's process-wide switch.

// The three input pixels (linear indices) of triangle `id` of an input of width w.
inline void TriangleVertices(std::uint32_t id, int w, std::int64_t v[3]) {
  const std::int64_t a = id >> 1;  // the block's top-left pixel
  if ((id & 1u) == 0) {
    v[0] = a; v[1] = a + 1; v[2] = a + w;
  } else {
    v[0] = a + 1; v[1] = a + w + 1; v[2] = a + w;
  }
}

// Inverse depth of a finite vertex, clamped to [1e-30, 1e30] (depth 1e-30 .. 1e30): 1 / depth of
// a denormal depth overflows float to +inf (then inf / inf = NaN colours), and 1 / depth of a
// depth near float max is a denormal whose reciprocal in the perspective-correct interpolation
// overflows (inf colours); both found by tests/test_stress.py. No metric depth is near either
// bound; infinite depth keeps its own rule (inverse 0, affine interpolation).
constexpr double kMinInvDepth = 1e-30, kMaxInvDepth = 1e30;
inline float InvDepth(double ip) { return static_cast<float>(std::min(std::max(ip, kMinInvDepth), kMaxInvDepth)); }

inline float ClampDepth(float d) { return std::min(std::max(d, kMinWeightDepth), kMaxWeightDepth); }

inline float Weight(float q, float d, float p) {
  const float x = q / ClampDepth(d);
  float w;
  if (p == 5.f) {
    const float x2 = x * x;
    w = x2 * x2 * x;
  } else if (p == 3.f) {
    w = x * x * x;
  } else {
    w = std::pow(x, p);
  }
  return std::min(std::max(w, 1e-30f), 1e30f);
}

// WarpOptions::view_weight on a row of fragment weights (0 stays 0: not covered). Weights are
// in [1e-30, 1e30] and the factor in [1e-6, 1], so the product stays a finite, positive, normal
// float (floored at 1e-36). The same scalar multiply on every ISA path (bit-identical).
inline void ScaleRow(float* w, int n, float factor) {
  for (int x = 0; x < n; ++x) w[x] = w[x] > 0.f ? std::max(w[x] * factor, 1e-36f) : 0.f;
}

// Coverage of the nx x ny (each 1 or 2) centres from the set-up corner: bit 2 * j + i set when
// centre (px0 + i, py0 + j) is inside.
inline unsigned SmallCoverage(const Edges& E, int nx, int ny) {
  unsigned mask = 0;
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      const std::int64_t e0 = E.e_row[0] + E.ex[0] * i + E.ey[0] * j, e1 = E.e_row[1] + E.ex[1] * i + E.ey[1] * j,
                         e2 = E.e_row[2] + E.ex[2] * i + E.ey[2] * j;
      if ((e0 | e1 | e2) >= 0) mask |= 1u << (2 * j + i);
    }
  }
  return mask;
}

struct Context {
  const ImageView<const float>* color;
  const ImageView<const float>* depth;
  const Camera* source;
  const Camera* target;
  const WarpOptions* options;
  const WarpVertex* verts;
  float side_t;
  bool equirect_target;
  int tw, th;
};

// q = 1 - L / T (before the floor), L = longest side in target pixels.
inline float SideQuality(const float x[3], const float y[3], float side_t) {
  float l2 = 0.f;
  for (int e = 0; e < 3; ++e) {
    const int f = (e + 1) % 3;
    const float dx = x[f] - x[e], dy = y[f] - y[e];
    l2 = std::max(l2, dx * dx + dy * dy);
  }
  return 1.f - std::sqrt(l2) / side_t;
}

// Quality of a triangle (forward_warp.h); returns <= 0 when the triangle is to be dropped.
float TriangleQuality(const Context& cx, const std::int64_t vi[3], const float x[3], const float y[3],
                      double area_px) {
  const WarpOptions& o = *cx.options;
  float q = 1.f;
  switch (o.quality) {
    case WarpQuality::kSide:
      q = SideQuality(x, y, cx.side_t);
      break;
    case WarpQuality::kShape: {
      float s2 = 0.f;
      for (int e = 0; e < 3; ++e) {
        const int f = (e + 1) % 3;
        const float dx = x[f] - x[e], dy = y[f] - y[e];
        s2 += dx * dx + dy * dy;
      }
      // 4 sqrt(3) A / sum e^2, relative to the grid triangle's 4 sqrt(3) (1/2) / 4 = 0.866.
      q = s2 > 0.f ? static_cast<float>(4.0 * std::sqrt(3.0) * area_px / s2 / 0.8660254037844386) : 0.f;
      break;
    }
    case WarpQuality::kDepth: {
      const float* d = cx.depth->data;
      const float d0 = d[vi[0]], d1 = d[vi[1]], d2 = d[vi[2]];
      const float lo = std::min(d0, std::min(d1, d2)), hi = std::max(d0, std::max(d1, d2));
      q = std::isinf(hi) ? (std::isinf(lo) ? 1.f : 0.f) : 1.f - (hi - lo) / (kDepthVariation * lo);
      break;
    }
    case WarpQuality::kNormal: {
      const float* d = cx.depth->data;
      const int w = cx.depth->width;
      glm::dvec3 p[3];
      for (int k = 0; k < 3; ++k) {
        const double dk = d[vi[k]];
        if (std::isinf(dk)) return 1.f;  // sky: a direction, no surface to be edge-on
        const double u = double(vi[k] % w) + 0.5, v = double(vi[k] / w) + 0.5;
        p[k] = cx.source->RayInCam(u, v) * dk;
      }
      const glm::dvec3 n = glm::cross(p[1] - p[0], p[2] - p[0]);
      const glm::dvec3 c = (p[0] + p[1] + p[2]) / 3.0;
      const double nn = glm::length(n) * glm::length(c);
      q = nn > 0.0 ? static_cast<float>(std::abs(glm::dot(n, c)) / nn) : 0.f;
      break;
    }
  }
  if (q <= 0.f && o.discard_stretched) return 0.f;
  return std::min(1.f, std::max(q, kQualityFloor));
}

// Perspective-correct interpolation over one triangle, shared by both shaders: barycentric e of
// a centre is (E_e + bias_e) / area2 (the tie-rule bias removed again); 1 / d and c / d are
// linear in screen space (forward_warp.h). affine = every vertex at infinity (sky).
struct TriangleInterp {
  float inv_area;
  float a_inv[3], a_c[3][3];
  std::int64_t bias[3];
  bool affine;

  // inv: 1 / depth of the vertices (all 0 = affine sky); col: their colours.
  // inverse_area: float(1 / area2) (see SmallQuadTriangle for a cheaper equal form).
  void SetupInterp(float inverse_area, const std::int64_t b[3], const float inv[3], const float* const col[3],
                   bool all_inf) {
    affine = all_inf;
    inv_area = inverse_area;
    for (int k = 0; k < 3; ++k) {
      bias[k] = b[k];
      const float m = affine ? 1.f : inv[k];
      a_inv[k] = inv[k];
      for (int c = 0; c < 3; ++c) a_c[k][c] = col[k][c] * m;
    }
  }
  inline void Bary(std::int64_t e0, std::int64_t e1, std::int64_t e2, float b[3]) const {
    b[0] = float(e0 + bias[0]) * inv_area;
    b[1] = float(e1 + bias[1]) * inv_area;
    b[2] = float(e2 + bias[2]) * inv_area;
  }
  // Interpolated 1 / d (0 for sky).
  inline float InvDepth(const float b[3]) const {
    return affine ? 0.f : b[0] * a_inv[0] + b[1] * a_inv[1] + b[2] * a_inv[2];
  }
  // Colour at barycentrics b, with m = d (perspective) or 1 (affine).
  inline void Color(const float b[3], float m, float* c) const {
    for (int ch = 0; ch < 3; ++ch) c[ch] = (b[0] * a_c[0][ch] + b[1] * a_c[1][ch] + b[2] * a_c[2][ch]) * m;
  }
};

// One triangle's per-centre shading + depth test (DIBR). Every path (small quad, small triangle,
// span scan) shades through this, so a centre gets the same bits whichever path covers it.
struct Shader : TriangleInterp {
  float q;
  bool combined;
  int tw;
  int row0 = 0;  // target row of score[0] etc. (the band's first row with band-local buffers)
  float *score, *oc, *od, *oq;

  // RasterBlockRowAvx2 may set up 8 quads at once (BeginQuad is a no-op here).
  static constexpr bool kQuadSimd = true;
  // Inclusive edges: a centre exactly on an edge shared by two triangles of the view is offered
  // to both and the depth test keeps one (forward_warp.h): one fragment per pixel per view.
  static constexpr bool kInclusiveEdges = true;

  // Per-quad state: none for DIBR (triangles are judged alone, by their quality).
  inline void BeginQuad(const WarpVertex&, const WarpVertex&, const WarpVertex&, const WarpVertex&) {}

  void Setup(float inverse_area, const std::int64_t b[3], float quality, const float inv[3],
             const float* const col[3], bool all_inf) {
    q = quality;
    SetupInterp(inverse_area, b, inv, col, all_inf);
  }

  inline void Shade(int px, int py, std::int64_t e0, std::int64_t e1, std::int64_t e2) const {
    float b[3];
    Bary(e0, e1, e2, b);
    // 1 / d interpolated (0 for sky); the score q / d^3 (d clamped) is q (1/d)^3 with 1/d
    // clamped to [1 / kMaxWeightDepth, 1 / kMinWeightDepth]: no division unless the fragment
    // wins. kNearest ranks by 1/d (larger = nearer), the same order as -d.
    const float id = InvDepth(b);
    float s;
    if (combined) {
      const float ic = std::min(std::max(id, 1.f / kMaxWeightDepth), 1.f / kMinWeightDepth);
      s = q * (ic * ic * ic);
    } else {
      s = std::max(id, 1.f / kMaxWeightDepth);
    }
    const std::ptrdiff_t i = std::ptrdiff_t(py - row0) * tw + px;
    if (s > score[i]) {
      score[i] = s;
      const float d = affine ? kInf : 1.f / id;
      const float m = affine ? 1.f : d;
      Color(b, m, oc + 3 * i);
      od[i] = d;
      oq[i] = q;
    }
  }
};

// Rasterises triangle `id` into rows [band_y0, band_y1) of the outputs (any size, any quality).
template <class Sh>
void RasterTriangle(const Context& cx, std::uint32_t id, int band_y0, int band_y1, Sh& sh) {
  std::int64_t vi[3];
  TriangleVertices(id, cx.depth->width, vi);
  float x[3], y[3], inv[3];
  std::int64_t X[3], Y[3];
  for (int k = 0; k < 3; ++k) {
    const WarpVertex& vk = cx.verts[vi[k]];
    X[k] = vk.x;
    Y[k] = vk.y;
    inv[k] = vk.inv;
    x[k] = float(X[k]) * (1.f / kSubpixel);
    y[k] = float(Y[k]) * (1.f / kSubpixel);
  }
  if (X[0] == kInvalid || X[1] == kInvalid || X[2] == kInvalid) return;
  const std::int64_t area2 = raster::Area2(X, Y);
  if (area2 <= 0) return;  // back-facing or degenerate
  const std::int64_t min_x = std::min(X[0], std::min(X[1], X[2])), max_x = std::max(X[0], std::max(X[1], X[2]));
  if (cx.equirect_target && max_x - min_x > std::int64_t(cx.tw) * kSubpixel / 2) return;  // straddles the seam
  raster::CentreBox box;
  if (!raster::Centres(X, Y, 0, cx.tw - 1, band_y0, band_y1 - 1, &box)) return;
  const int px0 = box.x0, px1 = box.x1, py0 = box.y0, py1 = box.y1;

  Edges E;
  SetupEdges(X, Y, px0, py0, Sh::kInclusiveEdges, &E);
  const std::int64_t *ex = E.ex, *ey = E.ey, *e_row = E.e_row;
  // Small triangles (<= 2 x 2 candidate centres): test them directly.
  const bool small = px1 - px0 <= 1 && py1 - py0 <= 1;
  const unsigned mask = small ? SmallCoverage(E, px1 - px0 + 1, py1 - py0 + 1) : 0u;
  if (small && mask == 0) return;

  const int n_inf = (inv[0] == 0.f) + (inv[1] == 0.f) + (inv[2] == 0.f);
  if (n_inf != 0 && n_inf != 3) return;  // mixed sky / surface: stretched across a silhouette

  const double area_px = double(area2) / (2.0 * kSubpixel * kSubpixel);
  const float q = TriangleQuality(cx, vi, x, y, area_px);
  if (q <= 0.f) return;
  const float* col = cx.color->data;
  const float* cols[3] = {col + 3 * vi[0], col + 3 * vi[1], col + 3 * vi[2]};
  sh.Setup(static_cast<float>(1.0 / double(area2)), E.bias, q, inv, cols, n_inf == 3);
  if (small) {
    for (int j = 0; j <= py1 - py0; ++j) {
      for (int i = 0; i <= px1 - px0; ++i) {
        if (mask & (1u << (2 * j + i))) {
          sh.Shade(px0 + i, py0 + j, e_row[0] + ex[0] * i + ey[0] * j, e_row[1] + ex[1] * i + ey[1] * j,
                   e_row[2] + ex[2] * i + ey[2] * j);
        }
      }
    }
    return;
  }
  raster::ScanTriangle(E, box, [&](int px, int py, std::int64_t e0, std::int64_t e1, std::int64_t e2) {
    sh.Shade(px, py, e0, e1, e2);
  });
}

// Shades one triangle of a small quad whose covered candidate centres are `mask` (bit 4 j + i:
// centre (px0 + i, py0 + j)); er / ex / ey / bias are its 32-bit edge functions (SmallQuad).
template <class Sh>
inline void ShadeSmallTriangle(const Context& cx, const WarpVertex& v0, const WarpVertex& v1, const WarpVertex& v2,
                               const float* c0, const float* c1, const float* c2, std::int32_t area2,
                               const std::int32_t er[3], const std::int32_t ex[3], const std::int32_t ey[3],
                               const std::int64_t bias[3], unsigned mask, int px0, int py0, Sh& sh) {
  const float x[3] = {float(v0.x) * (1.f / kSubpixel), float(v1.x) * (1.f / kSubpixel), float(v2.x) * (1.f / kSubpixel)};
  const float y[3] = {float(v0.y) * (1.f / kSubpixel), float(v1.y) * (1.f / kSubpixel), float(v2.y) * (1.f / kSubpixel)};
  float q = SideQuality(x, y, cx.side_t);
  if (q <= 0.f && cx.options->discard_stretched) return;
  q = std::min(1.f, std::max(q, kQualityFloor));
  const float inv[3] = {v0.inv, v1.inv, v2.inv};
  const float* cols[3] = {c0, c1, c2};
  // area2 < 2^24 is exact in float, and the double quotient rounded to float is the correctly
  // rounded float quotient (53 >= 2 * 24 + 2: double rounding is innocuous for division), so
  // this equals float(1.0 / double(area2)) of the general path, bit for bit.
  sh.Setup(1.f / float(area2), bias, q, inv, cols, false);
  do {
    const int bit = __builtin_ctz(mask);
    mask &= mask - 1;
    const int i = bit & 3, j = bit >> 2;
    sh.Shade(px0 + i, py0 + j, er[0] + ex[0] * i + ey[0] * j, er[1] + ex[1] * i + ey[1] * j,
             er[2] + ex[2] * i + ey[2] * j);
  } while (mask != 0);
}

// Edge function of the edge from p to q (32 bits, 1/256 px) set up at centre (sx, sy) / 256,
// tie-rule bias included (as SetupEdges).
inline void SmallEdge(const WarpVertex& p, const WarpVertex& q, std::int32_t sx, std::int32_t sy, bool inclusive,
                      std::int32_t* ex, std::int32_t* ey, std::int32_t* er, std::int64_t* bias) {
  const std::int32_t dx = q.x - p.x, dy = q.y - p.y;
  const bool owns = inclusive || raster::OwnsEdge(dx, dy);
  *ex = -dy * kSubpixel;
  *ey = dx * kSubpixel;
  *bias = owns ? 0 : 1;
  *er = dx * (sy - p.y) - dy * (sx - p.x) - std::int32_t(*bias);
}

// Both triangles of a small quad A B / C D (fast path: quality 'side', finite depths, every
// vertex valid): triangle 0 = (A, B, C), triangle 1 = (B, D, C), in that order. The candidate
// centres are the quad's, px0 + i, py0 + j for i < nx, j < ny (nx, ny <= 4, already clipped to
// the band and the image). A centre outside a triangle's own bounding box fails an edge test
// anyway, so this covers exactly what RasterTriangle covers. Coordinates span < 5 px (1280
// units), so every edge value fits in 32 bits. The diagonal B -> C is edge 0 of triangle 0;
// edge 1 of triangle 1 is C -> B, whose biased value is -e - 1 = ~e (exactly one of the two
// owns a non-degenerate edge; a degenerate one makes both areas 0): one evaluation decides
// which triangle may own each centre. Quality and shading set-up only for a triangle that
// covers a centre.
template <class Sh>
inline void SmallQuad(const Context& cx, const WarpVertex& A, const WarpVertex& B, const WarpVertex& C,
                      const WarpVertex& D, const float* ca, const float* cb, const float* cc, const float* cd,
                      int px0, int py0, int nx, int ny, Sh& sh) {
  const std::int32_t area0 = (B.x - A.x) * (C.y - A.y) - (B.y - A.y) * (C.x - A.x);
  const std::int32_t area1 = (D.x - B.x) * (C.y - B.y) - (D.y - B.y) * (C.x - B.x);
  if (area0 <= 0 && area1 <= 0) return;  // back-facing or degenerate
  const std::int32_t sx = px0 * kSubpixel + kSubpixel / 2, sy = py0 * kSubpixel + kSubpixel / 2;
  // Triangle 0: edge e opposite vertex e (B -> C, C -> A, A -> B); triangle 1: D -> C, C -> B,
  // B -> D. The four edges B -> C, C -> A, A -> B, D -> C side by side (SSE2 lanes), the fifth
  // (B -> D) scalar as SmallEdge. The products dx (sy - p.y) and dy (sx - p.x) have factors below
  // 1280 (coordinates span < 5 px), so they and every edge value at the <= 4 x 4 centres (below
  // 2^23) are integers that float holds exactly: float arithmetic gives the same integers as
  // 32-bit integer arithmetic (SSE2 has no 32-bit multiply), and the same signs (-0 == 0).
  const __m128i pxv = _mm_setr_epi32(B.x, C.x, A.x, D.x), pyv = _mm_setr_epi32(B.y, C.y, A.y, D.y);
  const __m128i qxv = _mm_setr_epi32(C.x, A.x, B.x, C.x), qyv = _mm_setr_epi32(C.y, A.y, B.y, C.y);
  const __m128i dxv = _mm_sub_epi32(qxv, pxv), dyv = _mm_sub_epi32(qyv, pyv);
  const __m128i zero = _mm_setzero_si128();
  // owns = dy > 0 || (dy == 0 && dx < 0); bias = 1 where the edge does not own its points.
  const __m128i owns = _mm_or_si128(_mm_cmpgt_epi32(dyv, zero),
                                    _mm_and_si128(_mm_cmpeq_epi32(dyv, zero), _mm_cmpgt_epi32(zero, dxv)));
  const __m128i biasv = Sh::kInclusiveEdges ? zero : _mm_andnot_si128(owns, _mm_set1_epi32(1));
  const __m128 fer = _mm_sub_ps(
      _mm_sub_ps(_mm_mul_ps(_mm_cvtepi32_ps(dxv), _mm_cvtepi32_ps(_mm_sub_epi32(_mm_set1_epi32(sy), pyv))),
                 _mm_mul_ps(_mm_cvtepi32_ps(dyv), _mm_cvtepi32_ps(_mm_sub_epi32(_mm_set1_epi32(sx), pxv)))),
      _mm_cvtepi32_ps(biasv));
  const __m128i exv = _mm_slli_epi32(_mm_sub_epi32(zero, dyv), 8), eyv = _mm_slli_epi32(dxv, 8);  // * kSubpixel
  alignas(16) std::int32_t er4[4], ex4[4], ey4[4], b4[4];
  _mm_store_si128(reinterpret_cast<__m128i*>(er4), _mm_cvtps_epi32(fer));
  _mm_store_si128(reinterpret_cast<__m128i*>(ex4), exv);
  _mm_store_si128(reinterpret_cast<__m128i*>(ey4), eyv);
  _mm_store_si128(reinterpret_cast<__m128i*>(b4), biasv);
  std::int32_t ex0[3] = {ex4[0], ex4[1], ex4[2]}, ey0[3] = {ey4[0], ey4[1], ey4[2]}, er0[3] = {er4[0], er4[1], er4[2]};
  std::int32_t ex1[3], ey1[3], er1[3];
  std::int64_t bias0[3] = {b4[0], b4[1], b4[2]}, bias1[3];
  ex1[0] = ex4[3];
  ey1[0] = ey4[3];
  er1[0] = er4[3];
  bias1[0] = b4[3];
  SmallEdge(B, D, sx, sy, Sh::kInclusiveEdges, &ex1[2], &ey1[2], &er1[2], &bias1[2]);
  ex1[1] = -ex0[0];
  ey1[1] = -ey0[0];
  // C -> B: exclusive, -e - 1 = ~e of the biased B -> C; inclusive (no bias), -e.
  er1[1] = Sh::kInclusiveEdges ? -er0[0] : ~er0[0];
  bias1[1] = Sh::kInclusiveEdges ? 0 : 1 - bias0[0];
  unsigned m0 = 0, m1 = 0;  // bit 4 j + i: centre (px0 + i, py0 + j) covered
  if (nx <= 2 && ny <= 2) {
    // Branch-free 2 x 2 (the common case); centres beyond nx / ny masked off afterwards. Per
    // centre, the sign bits of the four lane edges: triangle 0 needs B -> C, C -> A, A -> B >= 0;
    // triangle 1 needs B -> C < 0 (its C -> B = ~(B -> C) >= 0; inclusive: B -> C <= 0, its
    // C -> B = -(B -> C) >= 0), D -> C >= 0 and B -> D >= 0.
    const __m128 fex = _mm_cvtepi32_ps(exv), fey = _mm_cvtepi32_ps(eyv), fz = _mm_setzero_ps();
    const __m128 e00 = fer, e10 = _mm_add_ps(fer, fex), e01 = _mm_add_ps(fer, fey), e11 = _mm_add_ps(e10, fey);
    const unsigned n00 = unsigned(_mm_movemask_ps(_mm_cmplt_ps(e00, fz))), n10 = unsigned(_mm_movemask_ps(_mm_cmplt_ps(e10, fz)));
    const unsigned n01 = unsigned(_mm_movemask_ps(_mm_cmplt_ps(e01, fz))), n11 = unsigned(_mm_movemask_ps(_mm_cmplt_ps(e11, fz)));
    const std::int32_t bd = er1[2], bdx = ex1[2], bdy = ey1[2];
    const unsigned c00 = (n00 & 7u) == 0, c10 = (n10 & 7u) == 0, c01 = (n01 & 7u) == 0, c11 = (n11 & 7u) == 0;
    // Bit 0 of z: B -> C excludes the centre from triangle 0's side (< 0, or inclusive <= 0).
    unsigned z00 = n00, z10 = n10, z01 = n01, z11 = n11;
    if constexpr (Sh::kInclusiveEdges) {
      z00 = ~unsigned(_mm_movemask_ps(_mm_cmpgt_ps(e00, fz)));
      z10 = ~unsigned(_mm_movemask_ps(_mm_cmpgt_ps(e10, fz)));
      z01 = ~unsigned(_mm_movemask_ps(_mm_cmpgt_ps(e01, fz)));
      z11 = ~unsigned(_mm_movemask_ps(_mm_cmpgt_ps(e11, fz)));
    }
    const unsigned d00 = (z00 & 1u) && !(n00 & 8u) && bd >= 0, d10 = (z10 & 1u) && !(n10 & 8u) && bd + bdx >= 0;
    const unsigned d01 = (z01 & 1u) && !(n01 & 8u) && bd + bdy >= 0, d11 = (z11 & 1u) && !(n11 & 8u) && bd + bdx + bdy >= 0;
    m0 = c00 | (c10 << 1) | (c01 << 4) | (c11 << 5);
    m1 = d00 | (d10 << 1) | (d01 << 4) | (d11 << 5);
    const unsigned valid = (nx == 2 ? 3u : 1u) * (ny == 2 ? 0x11u : 1u);
    m0 &= valid;
    m1 &= valid;
  } else {
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        const std::int32_t d = er0[0] + ex0[0] * i + ey0[0] * j;
        const std::int32_t a1 = er0[1] + ex0[1] * i + ey0[1] * j, a2 = er0[2] + ex0[2] * i + ey0[2] * j;
        const std::int32_t b0 = er1[0] + ex1[0] * i + ey1[0] * j, b2 = er1[2] + ex1[2] * i + ey1[2] * j;
        m0 |= unsigned((d | a1 | a2) >= 0) << (4 * j + i);
        m1 |= unsigned(((Sh::kInclusiveEdges ? -d : ~d) | b0 | b2) >= 0) << (4 * j + i);
      }
    }
  }
  if (area0 > 0 && m0 != 0) ShadeSmallTriangle(cx, A, B, C, ca, cb, cc, area0, er0, ex0, ey0, bias0, m0, px0, py0, sh);
  if (area1 > 0 && m1 != 0) ShadeSmallTriangle(cx, B, D, C, cb, cd, cc, area1, er1, ex1, ey1, bias1, m1, px0, py0, sh);
}

// Rasterises every triangle of input block row r, columns [u0, u1), into band rows [y0, y1), in
// input order (triangle 0 then 1 of each quad).
template <class Sh>
void RasterBlockRow(const Context& cx, int r, int u0, int u1, int y0, int y1, bool fast, Sh& sh) {
  const int w = cx.depth->width;
  const WarpVertex* top = cx.verts + std::int64_t(r) * w;
  const WarpVertex* bot = top + w;
  const float* ctop = cx.color->data + 3 * (std::int64_t(r) * w);
  const float* cbot = ctop + 3 * std::int64_t(w);
  for (int u = u0; u < u1; ++u) {
    const WarpVertex &A = top[u], &B = top[u + 1], &C = bot[u], &D = bot[u + 1];
    if (B.x == kInvalid || C.x == kInvalid) continue;  // both triangles touch B and C
    sh.BeginQuad(A, B, C, D);
    if (A.x != kInvalid && D.x != kInvalid) {
      // Both triangles lie in the quad's bounding box: no centre of it in the band (or the
      // image), nothing to do.
      const std::int32_t mny = std::min(std::min(A.y, B.y), std::min(C.y, D.y));
      const std::int32_t mxy = std::max(std::max(A.y, B.y), std::max(C.y, D.y));
      int qy0 = static_cast<int>(CeilSub(mny - kSubpixel / 2)), qy1 = static_cast<int>(FloorSub(mxy - kSubpixel / 2));
      if (qy0 > qy1 || qy1 < y0 || qy0 >= y1) continue;
      const std::int32_t mnx = std::min(std::min(A.x, B.x), std::min(C.x, D.x));
      const std::int32_t mxx = std::max(std::max(A.x, B.x), std::max(C.x, D.x));
      int qx0 = static_cast<int>(CeilSub(mnx - kSubpixel / 2)), qx1 = static_cast<int>(FloorSub(mxx - kSubpixel / 2));
      if (qx0 > qx1 || qx1 < 0 || qx0 >= cx.tw) continue;
      if (fast && qx1 - qx0 <= 3 && qy1 - qy0 <= 3 && (!cx.equirect_target || mxx - mnx <= cx.tw * (kSubpixel / 2)) &&
          A.inv != 0.f && B.inv != 0.f && C.inv != 0.f && D.inv != 0.f) {
        {
          qx0 = std::max(qx0, 0);
          qx1 = std::min(qx1, cx.tw - 1);
          qy0 = std::max(qy0, y0);
          qy1 = std::min(qy1, y1 - 1);
          const int nx = qx1 - qx0 + 1, ny = qy1 - qy0 + 1;
          const float *ca = ctop + 3 * u, *cb = ca + 3, *cc = cbot + 3 * u, *cd = cc + 3;
          SmallQuad(cx, A, B, C, D, ca, cb, cc, cd, qx0, qy0, nx, ny, sh);
          continue;
        }
      }
    }
    const std::uint32_t id = static_cast<std::uint32_t>(2 * (std::int64_t(r) * w + u));
    RasterTriangle(cx, id, y0, y1, sh);
    RasterTriangle(cx, id + 1, y0, y1, sh);
  }
}


// RasterBlockRow for the DIBR shader, eight quads per AVX2 step (the target("avx2") clone only).
// Per lane (quad), the same integer decisions as RasterBlockRow + SmallQuad: validity, bounding
// box against the band and the image, the small-path conditions, both areas, the five edge
// functions (32-bit integers: exact, as the scalar code), the <= 4 x 4 coverage masks of both
// triangles, and the side quality's sqrt and division (IEEE lanes: the same floats as scalar;
// the longest squared side is the integer dX^2 + dY^2 / 65536, exact in float below 2^24, which
// the scalar float differences also give exactly for coordinates that span < 5 px). Then, quad
// by quad in input order, the scalar shading of the covered centres (ShadeSmallTriangle's body)
// or the general path (RasterTriangle) for quads the small path does not take: every fragment
// arrives in the same order with the same values, so the outputs are bit-identical.
__attribute__((target("avx2"))) inline __m256i CeilSub8(__m256i a) {
  return _mm256_sub_epi32(_mm256_setzero_si256(), _mm256_srai_epi32(_mm256_sub_epi32(_mm256_setzero_si256(), a), 8));
}

// Eight consecutive records of three 32-bit fields (WarpVertex: x, y, inv; an RGB pixel: r, g,
// b) as three lanes vectors: three loads, two blends and one permutation per field.
__attribute__((target("avx2"))) inline void Deinterleave8x3(const void* v, __m256i* f0, __m256i* f1, __m256i* f2) {
  const __m256i* p = reinterpret_cast<const __m256i*>(v);
  const __m256i a = _mm256_loadu_si256(p), b = _mm256_loadu_si256(p + 1), c = _mm256_loadu_si256(p + 2);
  // a = x0 y0 i0 x1 y1 i1 x2 y2, b = i2 x3 y3 i3 x4 y4 i4 x5, c = y5 i5 x6 y6 i6 x7 y7 i7
  *f0 = _mm256_permutevar8x32_epi32(_mm256_blend_epi32(_mm256_blend_epi32(a, b, 0x92), c, 0x24),
                                    _mm256_setr_epi32(0, 3, 6, 1, 4, 7, 2, 5));
  *f1 = _mm256_permutevar8x32_epi32(_mm256_blend_epi32(_mm256_blend_epi32(a, b, 0x24), c, 0x49),
                                    _mm256_setr_epi32(1, 4, 7, 2, 5, 0, 3, 6));
  *f2 = _mm256_permutevar8x32_epi32(_mm256_blend_epi32(_mm256_blend_epi32(a, b, 0x49), c, 0x92),
                                    _mm256_setr_epi32(2, 5, 0, 3, 6, 1, 4, 7));
}

__attribute__((target("avx2"))) inline void Deinterleave8(const WarpVertex* v, __m256i* x, __m256i* y, __m256* inv) {
  static_assert(sizeof(WarpVertex) == 12, "WarpVertex: three 32-bit fields");
  __m256i i;
  Deinterleave8x3(v, x, y, &i);
  *inv = _mm256_castsi256_ps(i);
}

// Eight consecutive RGB pixels (24 floats) as r, g, b lanes.
__attribute__((target("avx2"))) inline void DeinterleaveRgb8(const float* c, __m256* r, __m256* g, __m256* b) {
  __m256i x, y, z;
  Deinterleave8x3(c, &x, &y, &z);
  *r = _mm256_castsi256_ps(x);
  *g = _mm256_castsi256_ps(y);
  *b = _mm256_castsi256_ps(z);
}

// One triangle of each of the eight quads of a step, shaded in lanes at its first covered centre
// (Shader::Shade's operations, lane by lane, in the same order and without FMA: the same bits):
// the score, 1 / d and the colour, stored for the in-order depth test of RasterBlockRowAvx2.
struct FirstFragments {
  alignas(32) float s[8], d[8], q[8], r[8], g[8], b[8];
  alignas(32) std::int32_t pix[8];  // the centre's index in the band buffers, (y - row0) tw + x
};

__attribute__((target("avx2"))) inline void ShadeFirst8(__m256i mask, const __m256i er[3], const __m256i ex[3],
                                                        const __m256i ey[3], __m256 inv_area, __m256 q,
                                                        const __m256 inv[3], const __m256 col[3][3], bool combined,
                                                        __m256i x0, __m256i y0_band, __m256i tw, FirstFragments* out) {
  // First covered centre: bit = log2(lowest set bit) from the float exponent (exact: <= 2^15).
  const __m256i lsb = _mm256_and_si256(mask, _mm256_sub_epi32(_mm256_setzero_si256(), mask));
  const __m256i bit = _mm256_sub_epi32(_mm256_srli_epi32(_mm256_castps_si256(_mm256_cvtepi32_ps(lsb)), 23),
                                       _mm256_set1_epi32(127));
  const __m256i i = _mm256_and_si256(bit, _mm256_set1_epi32(3)), j = _mm256_srai_epi32(bit, 2);
  // x0, y0_band: the set-up corner (y relative to the band's first row); the band buffers are
  // < 2^31 floats, so the 32-bit index is exact.
  _mm256_store_si256(reinterpret_cast<__m256i*>(out->pix),
                     _mm256_add_epi32(_mm256_mullo_epi32(_mm256_add_epi32(y0_band, j), tw), _mm256_add_epi32(x0, i)));
  __m256 b[3];
  for (int e = 0; e < 3; ++e) {
    const __m256i v = _mm256_add_epi32(_mm256_add_epi32(er[e], _mm256_mullo_epi32(ex[e], i)), _mm256_mullo_epi32(ey[e], j));
    b[e] = _mm256_mul_ps(_mm256_cvtepi32_ps(v), inv_area);
  }
  // TriangleInterp::InvDepth: b0 a0 + b1 a1 + b2 a2, left to right
  const __m256 id = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(b[0], inv[0]), _mm256_mul_ps(b[1], inv[1])),
                                  _mm256_mul_ps(b[2], inv[2]));
  __m256 s;
  if (combined) {
    const __m256 ic = _mm256_min_ps(_mm256_max_ps(id, _mm256_set1_ps(1.f / kMaxWeightDepth)),
                                    _mm256_set1_ps(1.f / kMinWeightDepth));
    s = _mm256_mul_ps(q, _mm256_mul_ps(_mm256_mul_ps(ic, ic), ic));
  } else {
    s = _mm256_max_ps(id, _mm256_set1_ps(1.f / kMaxWeightDepth));
  }
  const __m256 d = _mm256_div_ps(_mm256_set1_ps(1.f), id);
  _mm256_store_ps(out->s, s);
  _mm256_store_ps(out->d, d);
  _mm256_store_ps(out->q, q);
  float* dst[3] = {out->r, out->g, out->b};
  for (int ch = 0; ch < 3; ++ch) {
    // SetupInterp's a_c = colour * (1 / d) per vertex, then Color: (b0 a_c0 + b1 a_c1 + b2 a_c2) d
    const __m256 c = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(b[0], _mm256_mul_ps(col[0][ch], inv[0])),
                                                 _mm256_mul_ps(b[1], _mm256_mul_ps(col[1][ch], inv[1]))),
                                   _mm256_mul_ps(b[2], _mm256_mul_ps(col[2][ch], inv[2])));
    _mm256_store_ps(dst[ch], _mm256_mul_ps(c, d));
  }
}

template <class Sh>
__attribute__((target("avx2"))) void RasterBlockRowAvx2(const Context& cx, int r, int u0, int u1, int y0, int y1,
                                                         Sh& sh) {
  const int w = cx.depth->width;
  const WarpVertex* top = cx.verts + std::int64_t(r) * w;
  const WarpVertex* bot = top + w;
  const float* ctop = cx.color->data + 3 * (std::int64_t(r) * w);
  const float* cbot = ctop + 3 * std::int64_t(w);
  const __m256i zero = _mm256_setzero_si256(), one = _mm256_set1_epi32(1), invalid = _mm256_set1_epi32(kInvalid);
  const __m256i half = _mm256_set1_epi32(kSubpixel / 2), three = _mm256_set1_epi32(3);
  const __m256i vy0 = _mm256_set1_epi32(y0), vy1m = _mm256_set1_epi32(y1 - 1), vtwm = _mm256_set1_epi32(cx.tw - 1);
  const __m256i seam = _mm256_set1_epi32(cx.equirect_target ? cx.tw * (kSubpixel / 2) : std::numeric_limits<std::int32_t>::max());
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256 fzero = _mm256_setzero_ps(), fone = _mm256_set1_ps(1.f), side_t = _mm256_set1_ps(cx.side_t);
  const __m256 inv65536 = _mm256_set1_ps(1.f / float(kSubpixel * kSubpixel));
  const bool discard = cx.options->discard_stretched;
  // Per step: class (0 skip, 1 small, 2 general), coverage masks, the set-up corner, the edges
  // (0 B->C, 1 C->A, 2 A->B, 3 D->C, 4 B->D: er at the corner, steps ex / ey, tie bias), the
  // raw side qualities and 1 / area of both triangles.
  alignas(32) std::int32_t cls[8], m0[8], m1[8], qx0[8], qy0[8], er[5][8], ex[5][8], ey[5][8], bias[5][8];
  alignas(32) std::int32_t a0s[8], a1s[8];
  alignas(32) float q0s[8], q1s[8], ia0[8], ia1[8];
  FirstFragments first[2];  // per triangle (0, 1) of each quad: its first covered centre, shaded
  // Covered centres `rest` (bit 4 j + i) of triangle t of quad k after its first: scalar shading
  // (ShadeSmallTriangle's), in bit order.
  const auto shade_rest = [&](int u, int k, int t, unsigned rest) {
    const int uk = u + k;
    const WarpVertex &A = top[uk], &B = top[uk + 1], &C = bot[uk], &D = bot[uk + 1];
    const float *ca = ctop + 3 * uk, *cb = ca + 3, *cc = cbot + 3 * uk, *cd = cc + 3;
    // triangle 0 = (A, B, C): edges B->C, C->A, A->B; triangle 1 = (B, D, C): D->C, C->B, B->D
    std::int32_t te_r[3], te_x[3], te_y[3];
    std::int64_t tb[3];
    if (t == 0) {
      for (int e = 0; e < 3; ++e) {
        te_r[e] = er[e][k];
        te_x[e] = ex[e][k];
        te_y[e] = ey[e][k];
        tb[e] = bias[e][k];
      }
    } else {
      te_r[0] = er[3][k], te_x[0] = ex[3][k], te_y[0] = ey[3][k], tb[0] = bias[3][k];
      te_r[1] = Sh::kInclusiveEdges ? -er[0][k] : ~er[0][k], te_x[1] = -ex[0][k], te_y[1] = -ey[0][k];
      tb[1] = Sh::kInclusiveEdges ? 0 : 1 - bias[0][k];
      te_r[2] = er[4][k], te_x[2] = ex[4][k], te_y[2] = ey[4][k], tb[2] = bias[4][k];
    }
    const float inv[3] = {t == 0 ? A.inv : B.inv, t == 0 ? B.inv : D.inv, C.inv};
    const float* cols[3] = {t == 0 ? ca : cb, t == 0 ? cb : cd, cc};
    sh.Setup(t == 0 ? ia0[k] : ia1[k], tb, t == 0 ? q0s[k] : q1s[k], inv, cols, false);
    const int px0 = qx0[k], py0 = qy0[k];
    do {
      const int bit = __builtin_ctz(rest);
      rest &= rest - 1;
      const int i = bit & 3, j = bit >> 2;
      sh.Shade(px0 + i, py0 + j, te_r[0] + te_x[0] * i + te_y[0] * j, te_r[1] + te_x[1] * i + te_y[1] * j,
               te_r[2] + te_x[2] * i + te_y[2] * j);
    } while (rest != 0);
  };
  for (int u = u0; u < u1; u += 8) {
    const int n = std::min(8, u1 - u);
    // Vertices u .. u + 8 of both rows as x, y, 1/d lanes (A, C: u + k; B, D: u + k + 1). A
    // short group (the segment's end) copies its vertices first (lanes past the end repeat the
    // last quad and are skipped): the full-width loads would read past the last row.
    const WarpVertex *tv = top + u, *bv = bot + u;
    const float *tc = ctop + 3 * u, *bc = cbot + 3 * u;
    WarpVertex pad[2][9];
    float cpad[2][27];
    if (n < 8) {
      for (int k = 0; k < 9; ++k) {
        const int kk = std::min(k, n);
        pad[0][k] = top[u + kk];
        pad[1][k] = bot[u + kk];
        for (int ch = 0; ch < 3; ++ch) {
          cpad[0][3 * k + ch] = ctop[3 * (u + kk) + ch];
          cpad[1][3 * k + ch] = cbot[3 * (u + kk) + ch];
        }
      }
      tv = pad[0];
      bv = pad[1];
      tc = cpad[0];
      bc = cpad[1];
    }
    __m256i Ax, Ay, Bx, By, Cx, Cy, Dx, Dy;
    __m256 Ai, Bi, Ci, Di;
    Deinterleave8(tv, &Ax, &Ay, &Ai);
    Deinterleave8(tv + 1, &Bx, &By, &Bi);
    Deinterleave8(bv, &Cx, &Cy, &Ci);
    Deinterleave8(bv + 1, &Dx, &Dy, &Di);
    const __m256i in_seg = _mm256_cmpgt_epi32(_mm256_set1_epi32(n), lane);
    const __m256i bc_ok = _mm256_andnot_si256(_mm256_or_si256(_mm256_cmpeq_epi32(Bx, invalid), _mm256_cmpeq_epi32(Cx, invalid)), in_seg);
    const __m256i ad_ok = _mm256_andnot_si256(_mm256_or_si256(_mm256_cmpeq_epi32(Ax, invalid), _mm256_cmpeq_epi32(Dx, invalid)), bc_ok);
    // Bounding box (RasterBlockRow).
    const __m256i mny = _mm256_min_epi32(_mm256_min_epi32(Ay, By), _mm256_min_epi32(Cy, Dy));
    const __m256i mxy = _mm256_max_epi32(_mm256_max_epi32(Ay, By), _mm256_max_epi32(Cy, Dy));
    const __m256i mnx = _mm256_min_epi32(_mm256_min_epi32(Ax, Bx), _mm256_min_epi32(Cx, Dx));
    const __m256i mxx = _mm256_max_epi32(_mm256_max_epi32(Ax, Bx), _mm256_max_epi32(Cx, Dx));
    __m256i by0 = CeilSub8(_mm256_sub_epi32(mny, half)), by1 = _mm256_srai_epi32(_mm256_sub_epi32(mxy, half), 8);
    __m256i bx0 = CeilSub8(_mm256_sub_epi32(mnx, half)), bx1 = _mm256_srai_epi32(_mm256_sub_epi32(mxx, half), 8);
    // culled: qy0 > qy1 || qy1 < y0 || qy0 >= y1 || qx0 > qx1 || qx1 < 0 || qx0 >= tw
    __m256i culled = _mm256_or_si256(_mm256_cmpgt_epi32(by0, by1), _mm256_cmpgt_epi32(vy0, by1));
    culled = _mm256_or_si256(culled, _mm256_cmpgt_epi32(by0, vy1m));
    culled = _mm256_or_si256(culled, _mm256_or_si256(_mm256_cmpgt_epi32(bx0, bx1), _mm256_cmpgt_epi32(zero, bx1)));
    culled = _mm256_or_si256(culled, _mm256_cmpgt_epi32(bx0, vtwm));
    // small: extent <= 3 centres each way, the seam rule, every corner finite (inv != 0)
    __m256i small = _mm256_andnot_si256(_mm256_cmpgt_epi32(_mm256_sub_epi32(bx1, bx0), three),
                                        _mm256_andnot_si256(_mm256_cmpgt_epi32(_mm256_sub_epi32(by1, by0), three),
                                                            _mm256_andnot_si256(_mm256_cmpgt_epi32(_mm256_sub_epi32(mxx, mnx), seam), ad_ok)));
    const __m256 inf_any = _mm256_or_ps(_mm256_or_ps(_mm256_cmp_ps(Ai, fzero, _CMP_EQ_OQ), _mm256_cmp_ps(Bi, fzero, _CMP_EQ_OQ)),
                                        _mm256_or_ps(_mm256_cmp_ps(Ci, fzero, _CMP_EQ_OQ), _mm256_cmp_ps(Di, fzero, _CMP_EQ_OQ)));
    small = _mm256_andnot_si256(_mm256_or_si256(culled, _mm256_castps_si256(inf_any)), small);
    // class: skip (B or C invalid, or A, D valid and culled), small, else general
    const __m256i skip = _mm256_or_si256(_mm256_andnot_si256(bc_ok, _mm256_set1_epi32(-1)), _mm256_and_si256(ad_ok, culled));
    const __m256i cl = _mm256_andnot_si256(skip, _mm256_blendv_epi8(_mm256_set1_epi32(2), one, small));
    _mm256_store_si256(reinterpret_cast<__m256i*>(cls), cl);
    if (_mm256_testz_si256(small, small)) {
      if (_mm256_testz_si256(cl, cl)) continue;
    } else {
      // Clip the candidate centres to the band and the image.
      bx0 = _mm256_max_epi32(bx0, zero);
      bx1 = _mm256_min_epi32(bx1, vtwm);
      by0 = _mm256_max_epi32(by0, vy0);
      by1 = _mm256_min_epi32(by1, vy1m);
      const __m256i nx = _mm256_sub_epi32(bx1, bx0), ny = _mm256_sub_epi32(by1, by0);  // count - 1
      _mm256_store_si256(reinterpret_cast<__m256i*>(qx0), bx0);
      _mm256_store_si256(reinterpret_cast<__m256i*>(qy0), by0);
      const __m256i area0 = _mm256_sub_epi32(_mm256_mullo_epi32(_mm256_sub_epi32(Bx, Ax), _mm256_sub_epi32(Cy, Ay)),
                                             _mm256_mullo_epi32(_mm256_sub_epi32(By, Ay), _mm256_sub_epi32(Cx, Ax)));
      const __m256i area1 = _mm256_sub_epi32(_mm256_mullo_epi32(_mm256_sub_epi32(Dx, Bx), _mm256_sub_epi32(Cy, By)),
                                             _mm256_mullo_epi32(_mm256_sub_epi32(Dy, By), _mm256_sub_epi32(Cx, Bx)));
      _mm256_store_si256(reinterpret_cast<__m256i*>(a0s), area0);
      _mm256_store_si256(reinterpret_cast<__m256i*>(a1s), area1);
      const __m256i sx = _mm256_add_epi32(_mm256_slli_epi32(bx0, 8), half), sy = _mm256_add_epi32(_mm256_slli_epi32(by0, 8), half);
      const __m256i px[5] = {Bx, Cx, Ax, Dx, Bx}, py[5] = {By, Cy, Ay, Dy, By};
      const __m256i qxv[5] = {Cx, Ax, Bx, Cx, Dx}, qyv[5] = {Cy, Ay, By, Cy, Dy};
      __m256i e_r[5], e_x[5], e_y[5], l2[5];
      for (int e = 0; e < 5; ++e) {
        const __m256i dx = _mm256_sub_epi32(qxv[e], px[e]), dy = _mm256_sub_epi32(qyv[e], py[e]);
        const __m256i owns = _mm256_or_si256(_mm256_cmpgt_epi32(dy, zero),
                                             _mm256_and_si256(_mm256_cmpeq_epi32(dy, zero), _mm256_cmpgt_epi32(zero, dx)));
        const __m256i b = Sh::kInclusiveEdges ? zero : _mm256_andnot_si256(owns, one);
        e_x[e] = _mm256_slli_epi32(_mm256_sub_epi32(zero, dy), 8);
        e_y[e] = _mm256_slli_epi32(dx, 8);
        e_r[e] = _mm256_sub_epi32(_mm256_sub_epi32(_mm256_mullo_epi32(dx, _mm256_sub_epi32(sy, py[e])),
                                                   _mm256_mullo_epi32(dy, _mm256_sub_epi32(sx, px[e]))), b);
        l2[e] = _mm256_add_epi32(_mm256_mullo_epi32(dx, dx), _mm256_mullo_epi32(dy, dy));
        _mm256_store_si256(reinterpret_cast<__m256i*>(er[e]), e_r[e]);
        _mm256_store_si256(reinterpret_cast<__m256i*>(ex[e]), e_x[e]);
        _mm256_store_si256(reinterpret_cast<__m256i*>(ey[e]), e_y[e]);
        _mm256_store_si256(reinterpret_cast<__m256i*>(bias[e]), b);
      }
      // Coverage of the candidate centres (i, j), i <= nx, j <= ny: triangle 0 needs B->C, C->A,
      // A->B >= 0; triangle 1 needs B->C < 0 (its C->B = ~(B->C) >= 0; inclusive: B->C <= 0,
      // C->B = -(B->C) >= 0), D->C >= 0, B->D >= 0.
      const int max_nx = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_and_si256(_mm256_cmpgt_epi32(nx, one), small))) ? 3 :
                         _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_and_si256(_mm256_cmpgt_epi32(nx, zero), small))) ? 1 : 0;
      const int max_ny = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_and_si256(_mm256_cmpgt_epi32(ny, one), small))) ? 3 :
                         _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_and_si256(_mm256_cmpgt_epi32(ny, zero), small))) ? 1 : 0;
      __m256i c0 = zero, c1 = zero;
      __m256i row[5] = {e_r[0], e_r[1], e_r[2], e_r[3], e_r[4]};
      for (int j = 0; j <= max_ny; ++j) {
        __m256i v[5] = {row[0], row[1], row[2], row[3], row[4]};
        const __m256i jok = _mm256_cmpgt_epi32(_mm256_set1_epi32(j), ny);  // j > ny: outside
        for (int i = 0; i <= max_nx; ++i) {
          const __m256i out = _mm256_or_si256(jok, _mm256_cmpgt_epi32(_mm256_set1_epi32(i), nx));
          const __m256i t0 = _mm256_or_si256(_mm256_or_si256(v[0], v[1]), v[2]);
          const __m256i cb = Sh::kInclusiveEdges ? _mm256_sub_epi32(zero, v[0]) : _mm256_xor_si256(v[0], _mm256_set1_epi32(-1));
          const __m256i t1 = _mm256_or_si256(_mm256_or_si256(cb, v[3]), v[4]);
          const __m256i bit = _mm256_set1_epi32(1 << (4 * j + i));
          // sign bit clear = covered
          c0 = _mm256_or_si256(c0, _mm256_andnot_si256(_mm256_or_si256(_mm256_srai_epi32(t0, 31), out), bit));
          c1 = _mm256_or_si256(c1, _mm256_andnot_si256(_mm256_or_si256(_mm256_srai_epi32(t1, 31), out), bit));
          for (int e = 0; e < 5; ++e) v[e] = _mm256_add_epi32(v[e], e_x[e]);
        }
        for (int e = 0; e < 5; ++e) row[e] = _mm256_add_epi32(row[e], e_y[e]);
      }
      c0 = _mm256_and_si256(c0, _mm256_and_si256(small, _mm256_cmpgt_epi32(area0, zero)));
      c1 = _mm256_and_si256(c1, _mm256_and_si256(small, _mm256_cmpgt_epi32(area1, zero)));
      // Side quality 1 - L / T (before the floor) of triangle 0 (AB, BC, CA) and 1 (BD, DC, CB),
      // and float(1 / area): SmallQuad / ShadeSmallTriangle's values.
      const __m256i l2t0 = _mm256_max_epi32(_mm256_max_epi32(l2[2], l2[0]), l2[1]);
      const __m256i l2t1 = _mm256_max_epi32(_mm256_max_epi32(l2[4], l2[3]), l2[0]);
      const __m256 L0 = _mm256_mul_ps(_mm256_cvtepi32_ps(l2t0), inv65536), L1 = _mm256_mul_ps(_mm256_cvtepi32_ps(l2t1), inv65536);
      const __m256 rq0 = _mm256_sub_ps(fone, _mm256_div_ps(_mm256_sqrt_ps(L0), side_t));
      const __m256 rq1 = _mm256_sub_ps(fone, _mm256_div_ps(_mm256_sqrt_ps(L1), side_t));
      const __m256 iav0 = _mm256_div_ps(fone, _mm256_cvtepi32_ps(area0));
      const __m256 iav1 = _mm256_div_ps(fone, _mm256_cvtepi32_ps(area1));
      _mm256_store_ps(ia0, iav0);
      _mm256_store_ps(ia1, iav1);
      // Paper Eq. 1 option: a triangle whose quality reaches 0 draws nothing. Then the floored
      // quality min(1, max(q, kQualityFloor)) (no NaN: max / min give std::max / std::min's value).
      if (discard) {
        c0 = _mm256_andnot_si256(_mm256_castps_si256(_mm256_cmp_ps(rq0, fzero, _CMP_LE_OQ)), c0);
        c1 = _mm256_andnot_si256(_mm256_castps_si256(_mm256_cmp_ps(rq1, fzero, _CMP_LE_OQ)), c1);
      }
      const __m256 floor_q = _mm256_set1_ps(kQualityFloor);
      const __m256 q0 = _mm256_min_ps(_mm256_max_ps(rq0, floor_q), fone), q1 = _mm256_min_ps(_mm256_max_ps(rq1, floor_q), fone);
      _mm256_store_ps(q0s, q0);
      _mm256_store_ps(q1s, q1);
      _mm256_store_si256(reinterpret_cast<__m256i*>(m0), c0);
      _mm256_store_si256(reinterpret_cast<__m256i*>(m1), c1);
      // Each triangle's first covered centre shaded in lanes (its further centres, rare, are
      // shaded one by one below). Colours of A, B (top row) and C, D (bottom row) as lanes.
      const bool any0 = !_mm256_testz_si256(c0, c0), any1 = !_mm256_testz_si256(c1, c1);
      if (any0 || any1) {
        __m256 cA[3], cB[3], cC[3], cD[3];
        const __m256i yb0 = _mm256_sub_epi32(by0, _mm256_set1_epi32(sh.row0)), vtw = _mm256_set1_epi32(sh.tw);
        DeinterleaveRgb8(tc, &cA[0], &cA[1], &cA[2]);
        DeinterleaveRgb8(tc + 3, &cB[0], &cB[1], &cB[2]);
        DeinterleaveRgb8(bc, &cC[0], &cC[1], &cC[2]);
        DeinterleaveRgb8(bc + 3, &cD[0], &cD[1], &cD[2]);
        if (any0) {
          // triangle 0 = (A, B, C): edges B->C, C->A, A->B
          const __m256 inv[3] = {Ai, Bi, Ci};
          const __m256 col[3][3] = {{cA[0], cA[1], cA[2]}, {cB[0], cB[1], cB[2]}, {cC[0], cC[1], cC[2]}};
          ShadeFirst8(c0, e_r, e_x, e_y, iav0, q0, inv, col, sh.combined, bx0, yb0, vtw, &first[0]);
        }
        if (any1) {
          // triangle 1 = (B, D, C): edges D->C, C->B (inclusive: -(B->C)), B->D
          static_assert(Sh::kInclusiveEdges, "the lanes of C->B assume the inclusive rule (no bias)");
          const __m256i t_r[3] = {e_r[3], _mm256_sub_epi32(zero, e_r[0]), e_r[4]};
          const __m256i t_x[3] = {e_x[3], _mm256_sub_epi32(zero, e_x[0]), e_x[4]};
          const __m256i t_y[3] = {e_y[3], _mm256_sub_epi32(zero, e_y[0]), e_y[4]};
          const __m256 inv[3] = {Bi, Di, Ci};
          const __m256 col[3][3] = {{cB[0], cB[1], cB[2]}, {cD[0], cD[1], cD[2]}, {cC[0], cC[1], cC[2]}};
          ShadeFirst8(c1, t_r, t_x, t_y, iav1, q1, inv, col, sh.combined, bx0, yb0, vtw, &first[1]);
        }
      }
      // The fragments in input order: quad by quad, triangle 0 before 1 (bit 2 k + t of `order`;
      // a quad for the general path is an event at bit 2 k). Each triangle's first covered
      // centre takes the lane values through a depth test whose writes go to a dummy slot when
      // the fragment loses (GCC compiles these selects into a jump; a mask-selected branch-free
      // form measured no faster, docs/dibr.md); a later fragment at the same pixel reads what an
      // earlier one wrote, as in Shader::Shade. Further centres of the same triangle (rare) are
      // shaded one by one right after it. Per event, nothing is loaded but the fragment and the
      // kept score (the band pointers and the event masks stay in registers: 3 % less CPU).
      const auto spread = [](unsigned x) {  // bit k -> bit 2 k (k < 8)
        x = (x | (x << 4)) & 0x0f0fu;
        x = (x | (x << 2)) & 0x3333u;
        return (x | (x << 1)) & 0x5555u;
      };
      const __m256i general = _mm256_cmpeq_epi32(cl, _mm256_set1_epi32(2));
      unsigned order =
          spread(unsigned(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_or_si256(_mm256_cmpgt_epi32(c0, zero), general))))) |
          (spread(unsigned(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(c1, zero))))) << 1);
      // In registers rather than loaded per event: the quads for the general path (bit k) and
      // the triangles with further covered centres (bit 2 k + t: mask & (mask - 1) != 0).
      const unsigned gen = unsigned(_mm256_movemask_ps(_mm256_castsi256_ps(general)));
      // (a lambda would not be compiled for AVX2)
      const unsigned several0 = unsigned(_mm256_movemask_ps(_mm256_castsi256_ps(
                                    _mm256_cmpeq_epi32(_mm256_and_si256(c0, _mm256_sub_epi32(c0, one)), zero)))) ^ 0xffu;
      const unsigned several1 = unsigned(_mm256_movemask_ps(_mm256_castsi256_ps(
                                    _mm256_cmpeq_epi32(_mm256_and_si256(c1, _mm256_sub_epi32(c1, one)), zero)))) ^ 0xffu;
      const unsigned multi = spread(several0) | (spread(several1) << 1);
      float *const score = sh.score, *const oc = sh.oc, *const od = sh.od, *const oq = sh.oq;
      alignas(32) float dummy[4];
      while (order != 0) {
        const int bo = __builtin_ctz(order);
        order &= order - 1;
        const int k = bo >> 1, t = bo & 1;
        if ((gen >> k) & 1u) {
          const std::uint32_t id = static_cast<std::uint32_t>(2 * (std::int64_t(r) * w + u + k));
          RasterTriangle(cx, id, y0, y1, sh);
          RasterTriangle(cx, id + 1, y0, y1, sh);
          continue;
        }
        const FirstFragments& f = first[t];
        const std::ptrdiff_t i = f.pix[k];
        const bool win = f.s[k] > score[i];
        *(win ? score + i : dummy) = f.s[k];
        float* const c = win ? oc + 3 * i : dummy;
        c[0] = f.r[k];
        c[1] = f.g[k];
        c[2] = f.b[k];
        *(win ? od + i : dummy) = f.d[k];
        *(win ? oq + i : dummy) = f.q[k];
        if ((multi >> bo) & 1u) {
          const unsigned mask = unsigned(t == 0 ? m0[k] : m1[k]);
          shade_rest(u, k, t, mask & (mask - 1));
        }
      }
      continue;
    }
    // No quad for the small path in this step: only the general path (or nothing).
    for (int k = 0; k < n; ++k) {
      if (cls[k] != 2) continue;
      const std::uint32_t id = static_cast<std::uint32_t>(2 * (std::int64_t(r) * w + u + k));
      RasterTriangle(cx, id, y0, y1, sh);
      RasterTriangle(cx, id + 1, y0, y1, sh);
    }
  }
}

// Target y and x ranges (1/256 px) of a row's valid vertices per column segment (vertices u0 ..
// u0 + kSegCols inclusive: the segment's quads).
void RowSegmentRanges(const WarpVertex* vrow, int w, int num_segs, YRange* ry) {
  for (int s = 0; s < num_segs; ++s) {
    YRange g = {std::numeric_limits<std::int32_t>::max(), std::numeric_limits<std::int32_t>::min(),
                std::numeric_limits<std::int32_t>::max(), std::numeric_limits<std::int32_t>::min()};
    const int u1 = std::min(w - 1, (s + 1) * kSegCols);
    for (int u = s * kSegCols; u <= u1; ++u) {
      if (vrow[u].x == kInvalid) continue;
      g.lo = std::min(g.lo, vrow[u].y);
      g.hi = std::max(g.hi, vrow[u].y);
      g.x_lo = std::min(g.x_lo, vrow[u].x);
      g.x_hi = std::max(g.x_hi, vrow[u].x);
    }
    ry[s] = g;
  }
}

inline int NumSegments(int w) { return (std::max(1, w - 1) + kSegCols - 1) / kSegCols; }

// RowSegmentRanges, 16 vertices per AVX2 step (two Deinterleave8) plus the segment's last
// vertex; integer min / max, so the same ranges. A short last segment goes the scalar way.
__attribute__((target("avx2"))) inline std::int32_t HMin8(__m256i v) {
  __m128i m = _mm_min_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
  m = _mm_min_epi32(m, _mm_shuffle_epi32(m, 0x4e));
  m = _mm_min_epi32(m, _mm_shuffle_epi32(m, 0xb1));
  return _mm_cvtsi128_si32(m);
}

__attribute__((target("avx2"))) inline std::int32_t HMax8(__m256i v) {
  __m128i m = _mm_max_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
  m = _mm_max_epi32(m, _mm_shuffle_epi32(m, 0x4e));
  m = _mm_max_epi32(m, _mm_shuffle_epi32(m, 0xb1));
  return _mm_cvtsi128_si32(m);
}

__attribute__((target("avx2"))) void RowSegmentRangesAvx2(const WarpVertex* vrow, int w, int num_segs, YRange* ry) {
  const __m256i inval = _mm256_set1_epi32(kInvalid), imax = _mm256_set1_epi32(std::numeric_limits<std::int32_t>::max());
  const __m256i imin = _mm256_set1_epi32(std::numeric_limits<std::int32_t>::min());
  for (int s = 0; s < num_segs; ++s) {
    const int u0 = s * kSegCols;
    if (std::min(w - 1, u0 + kSegCols) != u0 + kSegCols) {
      RowSegmentRanges(vrow + u0, w - u0, 1, ry + s);  // the short last segment
      continue;
    }
    __m256i x0, y0, x1, y1;
    __m256 i0, i1;
    Deinterleave8(vrow + u0, &x0, &y0, &i0);
    Deinterleave8(vrow + u0 + 8, &x1, &y1, &i1);
    const __m256i bad0 = _mm256_cmpeq_epi32(x0, inval), bad1 = _mm256_cmpeq_epi32(x1, inval);
    // Invalid vertices (x = INT32_MIN, y = 0) get the neutral element of each reduction.
    const __m256i lo = _mm256_min_epi32(_mm256_blendv_epi8(y0, imax, bad0), _mm256_blendv_epi8(y1, imax, bad1));
    const __m256i hi = _mm256_max_epi32(_mm256_blendv_epi8(y0, imin, bad0), _mm256_blendv_epi8(y1, imin, bad1));
    const __m256i xlo = _mm256_min_epi32(_mm256_blendv_epi8(x0, imax, bad0), _mm256_blendv_epi8(x1, imax, bad1));
    const __m256i xhi = _mm256_max_epi32(x0, x1);  // INT32_MIN is already max's neutral element
    YRange g = {HMin8(lo), HMax8(hi), HMin8(xlo), HMax8(xhi)};
    const WarpVertex& last = vrow[u0 + kSegCols];
    if (last.x != kInvalid) {
      g.lo = std::min(g.lo, last.y);
      g.hi = std::max(g.hi, last.y);
      g.x_lo = std::min(g.x_lo, last.x);
      g.x_hi = std::max(g.x_hi, last.x);
    }
    ry[s] = g;
  }
}

// Pinhole -> pinhole projection of one input row, four vertices per step (AVX2 doubles; the
// target("avx2") clone of ProjectVertices' SSE2 pair loop): the very same operations in the
// same order (no FMA), so the same bits as the scalar branch. RoundHalfAway, the bounds test
// and InvDepth's clamp in lanes too (integer truncation of values below 2^31, exact compares;
// max / min equal std::max / std::min for the non-NaN values of front lanes). Groups of four
// with a depth that is not finite and > 0 go through the scalar rules. Returns the first
// column not done (the caller finishes the row).
struct PinholeProjection {
  double rot[3][3], trans[3], fx, fy, cx, cy;
  float lo_x, hi_x, lo_y, hi_y;
};

// RoundHalfAway of four doubles (|v| < 2^31 where the result is used): t = trunc(v), frac = v - t
// (exact), t + (frac >= 0.5) - (frac <= -0.5). In doubles (every value an exact integer below
// 2^31) with one conversion at the end: the same integers as truncating to int32 first, with
// one float -> int conversion instead of three.
__attribute__((target("avx2"))) inline __m128i RoundHalfAway4(__m256d v) {
  const __m256d one = _mm256_set1_pd(1.0);
  const __m256d t = _mm256_round_pd(v, _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC);
  const __m256d frac = _mm256_sub_pd(v, t);
  const __m256d up = _mm256_and_pd(_mm256_cmp_pd(frac, _mm256_set1_pd(0.5), _CMP_GE_OQ), one);
  const __m256d dn = _mm256_and_pd(_mm256_cmp_pd(frac, _mm256_set1_pd(-0.5), _CMP_LE_OQ), one);
  return _mm256_cvtpd_epi32(_mm256_sub_pd(_mm256_add_pd(t, up), dn));
}

template <class ScalarVertex>
__attribute__((target("avx2"))) int ProjectPinholeRowAvx2(const float* drow, const double* ray_x, double ray_y,
                                                            int w, const PinholeProjection& k, WarpVertex* vrow,
                                                            std::int64_t& my_valid, ScalarVertex& scalar_vertex) {
  const __m256d r02 = _mm256_set1_pd(k.rot[0][2]), r12 = _mm256_set1_pd(k.rot[1][2]), r22 = _mm256_set1_pd(k.rot[2][2]);
  const __m256d r00 = _mm256_set1_pd(k.rot[0][0]), r10 = _mm256_set1_pd(k.rot[1][0]), r20 = _mm256_set1_pd(k.rot[2][0]);
  const __m256d r01 = _mm256_set1_pd(k.rot[0][1]), r11 = _mm256_set1_pd(k.rot[1][1]), r21 = _mm256_set1_pd(k.rot[2][1]);
  const __m256d tx = _mm256_set1_pd(k.trans[0]), ty = _mm256_set1_pd(k.trans[1]), tz = _mm256_set1_pd(k.trans[2]);
  const __m256d fx = _mm256_set1_pd(k.fx), fy = _mm256_set1_pd(k.fy);
  const __m256d tcx = _mm256_set1_pd(k.cx), tcy = _mm256_set1_pd(k.cy), ryv = _mm256_set1_pd(ray_y);
  const __m256d one = _mm256_set1_pd(1.0), zero = _mm256_setzero_pd(), sub = _mm256_set1_pd(double(kSubpixel));
  const __m256d lox = _mm256_set1_pd(double(k.lo_x)), hix = _mm256_set1_pd(double(k.hi_x));
  const __m256d loy = _mm256_set1_pd(double(k.lo_y)), hiy = _mm256_set1_pd(double(k.hi_y));
  const __m256d min_inv = _mm256_set1_pd(kMinInvDepth), max_inv = _mm256_set1_pd(kMaxInvDepth);
  const __m128 finf = _mm_set1_ps(kInf), fzero = _mm_setzero_ps();
  int u = 0;
  for (; u + 4 <= w; u += 4) {
    const __m128 d4 = _mm_loadu_ps(drow + u);
    if (_mm_movemask_ps(_mm_and_ps(_mm_cmpgt_ps(d4, fzero), _mm_cmplt_ps(d4, finf))) != 15) {
      for (int j = 0; j < 4; ++j) scalar_vertex(u + j);
      continue;
    }
    const __m256d dd = _mm256_cvtps_pd(d4);
    const __m256d rx = _mm256_mul_pd(_mm256_loadu_pd(ray_x + u), dd), ry = _mm256_mul_pd(ryv, dd), rz = dd;
    const __m256d pz = _mm256_add_pd(_mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(r02, rx), _mm256_mul_pd(r12, ry)), _mm256_mul_pd(r22, rz)), tz);
    const __m256d px = _mm256_add_pd(_mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(r00, rx), _mm256_mul_pd(r10, ry)), _mm256_mul_pd(r20, rz)), tx);
    const __m256d py = _mm256_add_pd(_mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(r01, rx), _mm256_mul_pd(r11, ry)), _mm256_mul_pd(r21, rz)), ty);
    const __m256d ipz = _mm256_div_pd(one, pz);
    const __m256d x = _mm256_add_pd(_mm256_mul_pd(_mm256_mul_pd(fx, px), ipz), tcx);
    const __m256d y = _mm256_add_pd(_mm256_mul_pd(_mm256_mul_pd(fy, py), ipz), tcy);
    my_valid += 4;
    // front && x > lo_x && x < hi_x && y > lo_y && y < hi_y (ordered compares: false for NaN)
    __m256d ok = _mm256_cmp_pd(pz, zero, _CMP_GT_OQ);
    ok = _mm256_and_pd(ok, _mm256_and_pd(_mm256_cmp_pd(x, lox, _CMP_GT_OQ), _mm256_cmp_pd(x, hix, _CMP_LT_OQ)));
    ok = _mm256_and_pd(ok, _mm256_and_pd(_mm256_cmp_pd(y, loy, _CMP_GT_OQ), _mm256_cmp_pd(y, hiy, _CMP_LT_OQ)));
    const int okm = _mm256_movemask_pd(ok);
    if (okm == 0) {
      for (int j = 0; j < 4; ++j) vrow[u + j] = WarpVertex{kInvalid, 0, 0.f};
      continue;
    }
    // RoundHalfAway(v * 256): t = trunc, frac = v - t, t + (frac >= 0.5) - (frac <= -0.5); the
    // compare masks are -1 / 0, so t - mask(frac >= 0.5) + mask(frac <= -0.5).
    // Invalid lanes: x = kInvalid, y = 0, inv = 0 (as the scalar rules); then the four
    // vertices interleaved into 48 bytes (x0 y0 i0 x1 y1 i1 x2 y2 | i2 x3 y3 i3).
    const __m128i okv = _mm256_castsi256_si128(
        _mm256_permutevar8x32_epi32(_mm256_castpd_si256(ok), _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6)));
    const __m128i X = _mm_blendv_epi8(_mm_set1_epi32(kInvalid), RoundHalfAway4(_mm256_mul_pd(x, sub)), okv);
    const __m128i Y = _mm_and_si128(RoundHalfAway4(_mm256_mul_pd(y, sub)), okv);
    const __m128i I = _mm_and_si128(_mm_castps_si128(_mm256_cvtpd_ps(_mm256_min_pd(_mm256_max_pd(ipz, min_inv), max_inv))), okv);
    const __m256i xy = _mm256_set_m128i(Y, X), ii = _mm256_set_m128i(I, I);
    const __m256i out0 = _mm256_blend_epi32(_mm256_permutevar8x32_epi32(xy, _mm256_setr_epi32(0, 4, 0, 1, 5, 1, 2, 6)),
                                            _mm256_permutevar8x32_epi32(ii, _mm256_setr_epi32(0, 0, 0, 0, 0, 1, 0, 0)), 0x24);
    const __m256i out1 = _mm256_blend_epi32(_mm256_permutevar8x32_epi32(xy, _mm256_setr_epi32(0, 3, 7, 0, 0, 0, 0, 0)),
                                            _mm256_permutevar8x32_epi32(ii, _mm256_setr_epi32(2, 0, 0, 3, 0, 0, 0, 0)), 0x09);
    static_assert(sizeof(WarpVertex) == 12, "WarpVertex: three 32-bit fields");
    char* dst = reinterpret_cast<char*>(vrow + u);
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(dst), out0);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(dst + 32), _mm256_castsi256_si128(out1));
  }
  return u;
}

// Weight() of a band row, eight pixels per AVX2 step, for p = 5 or 3 (the products of Weight in
// its order; max / min give std::max / std::min's values for these non-NaN operands): w = 0 where
// q <= 0 (not covered; the depth there is stale). Adds the covered pixels to `covered`; returns
// the first column not done.
__attribute__((target("avx2"))) int WeightRowAvx2(const float* q, const float* d, float* w, int n, float p,
                                                  std::int64_t& covered) {
  const __m256 zero = _mm256_setzero_ps(), dlo = _mm256_set1_ps(kMinWeightDepth), dhi = _mm256_set1_ps(kMaxWeightDepth);
  const __m256 wlo = _mm256_set1_ps(1e-30f), whi = _mm256_set1_ps(1e30f);
  const bool five = p == 5.f;
  int x = 0;
  for (; x + 8 <= n; x += 8) {
    const __m256 qv = _mm256_loadu_ps(q + x);
    const __m256 cov = _mm256_cmp_ps(qv, zero, _CMP_GT_OQ);
    const int m = _mm256_movemask_ps(cov);
    if (m == 0) {
      _mm256_storeu_ps(w + x, zero);
      continue;
    }
    covered += __builtin_popcount(unsigned(m));
    const __m256 xv = _mm256_div_ps(qv, _mm256_min_ps(_mm256_max_ps(_mm256_loadu_ps(d + x), dlo), dhi));
    const __m256 x2 = _mm256_mul_ps(xv, xv);
    const __m256 wv = five ? _mm256_mul_ps(_mm256_mul_ps(x2, x2), xv) : _mm256_mul_ps(x2, xv);
    _mm256_storeu_ps(w + x, _mm256_and_ps(_mm256_min_ps(_mm256_max_ps(wv, wlo), whi), cov));
  }
  return x;
}

// Pass 1 of the mesh warp: every input pixel projected into the target (scratch.verts) and the
// per-row segment y ranges (scratch.seg_y). Counts valid and bad depths.
// Non-finite values (exponent bits all set) among n floats, eight per AVX2 step.
__attribute__((target("avx2"))) std::int64_t CountNonFiniteAvx2(const float* p, std::ptrdiff_t n) {
  const __m256i e = _mm256_set1_epi32(0x7f800000);
  std::int64_t bad = 0;
  std::ptrdiff_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const __m256i v = _mm256_and_si256(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(p + i)), e);
    bad += __builtin_popcount(unsigned(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(v, e)))));
  }
  for (; i < n; ++i) bad += !std::isfinite(p[i]);
  return bad;
}

std::int64_t CountNonFinite(const float* p, std::ptrdiff_t n) {
  std::int64_t bad = 0;
  for (std::ptrdiff_t i = 0; i < n; ++i) {
    std::uint32_t u;
    std::memcpy(&u, p + i, sizeof u);
    bad += (u & 0x7f800000u) == 0x7f800000u;
  }
  return bad;
}

// check_color: colour (H, W, 3) rows counted for NaN / inf values in the same row tasks
// (counts.bad_colors).
WarpCounts ProjectVertices(const ImageView<const float>& depth, const Camera& source, const Camera& target,
                           WarpScratch& scratch, const ImageView<const float>* check_color = nullptr) {
  WarpCounts counts;
  const int h = depth.height, w = depth.width;
  const int th = target.height, tw = target.width;
  (void)th;
  const std::int64_t n = std::int64_t(h) * w;
  const int num_segs = (std::max(1, w - 1) + kSegCols - 1) / kSegCols;
  scratch.verts.resize(n);
  scratch.seg_y.resize(std::size_t(h) * num_segs);

  // Pass 1: vertices. target_from_source = (R_t, t_t) o (R_s, t_s)^-1.
  const glm::dmat3 rot = target.rot * glm::transpose(source.rot);
  const glm::dvec3 trans = target.trans - rot * source.trans;
  const float lo_x = -kGuardPixels, hi_x = float(tw) + kGuardPixels;
  const float lo_y = -kGuardPixels, hi_y = float(th) + kGuardPixels;
  const bool pinholes = source.model == CameraModel::kPinhole && target.model == CameraModel::kPinhole;
  WarpVertex* verts = scratch.verts.data();
  YRange* seg_y = scratch.seg_y.data();
  // Pinhole source: the ray's x per column, (u + 0.5 - cx) / fx, once per view (same doubles).
  if (pinholes) {
    scratch.ray_x.resize(w);
    for (int u = 0; u < w; ++u) scratch.ray_x[u] = (u + 0.5 - source.cx) / source.fx;
  }
  const double* ray_x = scratch.ray_x.data();
  // Equirect source: Camera::RayInCam's longitude terms per column (its latitude terms once per
  // row below), the same operations in the same order, so the same doubles: 2 sines and cosines
  // per row and column instead of 4 per vertex.
  const bool equirect_source = source.model == CameraModel::kEquirect;
  if (equirect_source) {
    scratch.lon_sin.resize(w);
    scratch.lon_cos.resize(w);
    for (int u = 0; u < w; ++u) {
      const double lon = source.lon_min + ((u + 0.5) / source.width) * (source.lon_max - source.lon_min);
      scratch.lon_sin[u] = std::sin(lon);
      scratch.lon_cos[u] = std::cos(lon);
    }
  }
  const double* lon_sin = scratch.lon_sin.data();
  const double* lon_cos = scratch.lon_cos.data();
  const bool avx2 = UseAvx2();
  std::atomic<std::int64_t> valid{0}, bad{0}, bad_colors{0};
  ParallelFor(h, 8, [&](std::int64_t r0, std::int64_t r1) {
    std::int64_t my_valid = 0, my_bad = 0;
    if (check_color != nullptr) {
      const std::ptrdiff_t n_c = std::ptrdiff_t(check_color->width) * check_color->channels;
      std::int64_t my_bad_colors = 0;
      for (std::int64_t r = r0; r < r1; ++r) {
        const float* crow = check_color->Row(static_cast<int>(r));
        my_bad_colors += avx2 ? CountNonFiniteAvx2(crow, n_c) : CountNonFinite(crow, n_c);
      }
      bad_colors += my_bad_colors;
    }
    for (std::int64_t r = r0; r < r1; ++r) {
      const float* drow = depth.Row(static_cast<int>(r));
      WarpVertex* vrow = verts + r * w;
      // Pinhole -> pinhole (the common case): Camera::RayInCam, the glm rotation and
      // Camera::ProjectCam written out with the very same operations in the same order (so the
      // same doubles, bit for bit), without the per-pixel model branches or divisions for the
      // ray (its x comes from a per-column table, its y is computed once per row).
      const double ray_y = (double(r) + 0.5 - source.cy) / source.fy;
      double lat_cos = 0.0, lat_sin = 0.0;
      if (equirect_source) {
        const double lat = source.lat_max - ((double(r) + 0.5) / source.height) * (source.lat_max - source.lat_min);
        lat_cos = std::cos(lat);
        lat_sin = std::sin(lat);
      }
      const auto scalar_vertex = [&](int u) {
        const float d = drow[u];
        WarpVertex& o = vrow[u];
        o.x = kInvalid;
        o.y = 0;
        o.inv = 0.f;
        if (!(d > 0.f)) {
          if (d != 0.f) ++my_bad;  // NaN or negative
          return;
        }
        ++my_valid;
        double x, y, dt;
        if (pinholes && !std::isinf(d)) {
          const double dd = double(d);
          const double rx = ray_x[u] * dd, ry = ray_y * dd, rz = dd;
          const double pz = rot[0][2] * rx + rot[1][2] * ry + rot[2][2] * rz + trans.z;
          if (!(pz > 0.0)) return;
          const double px = rot[0][0] * rx + rot[1][0] * ry + rot[2][0] * rz + trans.x;
          const double py = rot[0][1] * rx + rot[1][1] * ry + rot[2][1] * rz + trans.y;
          // One division: x = fx px / pz + cx as fx px (1 / pz) + cx (differs from
          // Camera::ProjectCam by an ulp or so, far below the 1/256 px snap).
          const double ipz = 1.0 / pz;
          x = target.fx * px * ipz + target.cx;
          y = target.fy * py * ipz + target.cy;
          dt = pz;
          if (x > lo_x && x < hi_x && y > lo_y && y < hi_y) {
            o.x = RoundHalfAway(x * kSubpixel);
            o.y = RoundHalfAway(y * kSubpixel);
            o.inv = InvDepth(ipz);
          }
          return;
        } else {
          const glm::dvec3 ray = equirect_source
                                     ? glm::dvec3(lat_cos * lon_sin[u], -lat_sin, lat_cos * lon_cos[u])
                                     : source.RayInCam(u + 0.5, double(r) + 0.5);
          glm::dvec3 p;
          if (std::isinf(d)) {
            p = rot * ray;  // a direction: rotation only
          } else {
            p = rot * (ray * double(d)) + trans;
          }
          if (!target.ProjectCam(p, &x, &y, &dt)) return;
        }
        if (!(x > lo_x && x < hi_x && y > lo_y && y < hi_y)) return;
        // Snap to 1/256 px, rounding half away from zero (one rule for every vertex).
        o.x = RoundHalfAway(x * kSubpixel);
        o.y = RoundHalfAway(y * kSubpixel);
        o.inv = std::isinf(d) ? 0.f : InvDepth(1.0 / dt);
      };
      int u = 0;
      if (pinholes && avx2) {
        PinholeProjection k;
        for (int a = 0; a < 3; ++a) {
          for (int b = 0; b < 3; ++b) k.rot[a][b] = rot[a][b];
          k.trans[a] = trans[a];
        }
        k.fx = target.fx;
        k.fy = target.fy;
        k.cx = target.cx;
        k.cy = target.cy;
        k.lo_x = lo_x;
        k.hi_x = hi_x;
        k.lo_y = lo_y;
        k.hi_y = hi_y;
        u = ProjectPinholeRowAvx2(drow, ray_x, ray_y, w, k, vrow, my_valid, scalar_vertex);
      }
      if (pinholes) {
        // Two vertices per step (SSE2 doubles): the very same operations as the scalar pinhole
        // branch, in the same order (no FMA), so the same bits. Pairs with a depth that is not
        // finite and > 0 go through the scalar rules.
        const __m128d r02 = _mm_set1_pd(rot[0][2]), r12 = _mm_set1_pd(rot[1][2]), r22 = _mm_set1_pd(rot[2][2]);
        const __m128d r00 = _mm_set1_pd(rot[0][0]), r10 = _mm_set1_pd(rot[1][0]), r20 = _mm_set1_pd(rot[2][0]);
        const __m128d r01 = _mm_set1_pd(rot[0][1]), r11 = _mm_set1_pd(rot[1][1]), r21 = _mm_set1_pd(rot[2][1]);
        const __m128d tx = _mm_set1_pd(trans.x), ty = _mm_set1_pd(trans.y), tz = _mm_set1_pd(trans.z);
        const __m128d fx = _mm_set1_pd(target.fx), fy = _mm_set1_pd(target.fy);
        const __m128d tcx = _mm_set1_pd(target.cx), tcy = _mm_set1_pd(target.cy), ryv = _mm_set1_pd(ray_y);
        const __m128d one = _mm_set1_pd(1.0);
        alignas(16) double xs[2], ys[2], ip[2];
        for (; u + 2 <= w; u += 2) {
          const float d0 = drow[u], d1 = drow[u + 1];
          if (!(d0 > 0.f && d1 > 0.f && d0 < kInf && d1 < kInf)) {
            scalar_vertex(u);
            scalar_vertex(u + 1);
            continue;
          }
          const __m128d dd = _mm_cvtps_pd(_mm_castsi128_ps(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(drow + u))));
          const __m128d rx = _mm_mul_pd(_mm_loadu_pd(ray_x + u), dd), ry = _mm_mul_pd(ryv, dd), rz = dd;
          const __m128d pz = _mm_add_pd(_mm_add_pd(_mm_add_pd(_mm_mul_pd(r02, rx), _mm_mul_pd(r12, ry)), _mm_mul_pd(r22, rz)), tz);
          const __m128d px = _mm_add_pd(_mm_add_pd(_mm_add_pd(_mm_mul_pd(r00, rx), _mm_mul_pd(r10, ry)), _mm_mul_pd(r20, rz)), tx);
          const __m128d py = _mm_add_pd(_mm_add_pd(_mm_add_pd(_mm_mul_pd(r01, rx), _mm_mul_pd(r11, ry)), _mm_mul_pd(r21, rz)), ty);
          const __m128d ipz = _mm_div_pd(one, pz);
          _mm_store_pd(xs, _mm_add_pd(_mm_mul_pd(_mm_mul_pd(fx, px), ipz), tcx));
          _mm_store_pd(ys, _mm_add_pd(_mm_mul_pd(_mm_mul_pd(fy, py), ipz), tcy));
          _mm_store_pd(ip, ipz);
          const int front = _mm_movemask_pd(_mm_cmpgt_pd(pz, _mm_setzero_pd()));
          my_valid += 2;
          for (int k = 0; k < 2; ++k) {
            WarpVertex& o = vrow[u + k];
            const double x = xs[k], y = ys[k];
            if (((front >> k) & 1) && x > lo_x && x < hi_x && y > lo_y && y < hi_y) {
              o.x = RoundHalfAway(x * kSubpixel);
              o.y = RoundHalfAway(y * kSubpixel);
              o.inv = InvDepth(ip[k]);
            } else {
              o.x = kInvalid;
              o.y = 0;
              o.inv = 0.f;
            }
          }
        }
      }
      for (; u < w; ++u) scalar_vertex(u);
      // Target y range of the row's valid vertices per column segment.
      if (avx2) {
        RowSegmentRangesAvx2(vrow, w, num_segs, seg_y + r * num_segs);
      } else {
        RowSegmentRanges(vrow, w, num_segs, seg_y + r * num_segs);
      }
    }
    valid += my_valid;
    bad += my_bad;
  });
  counts.valid_vertices = valid;
  counts.bad_depths = bad;
  counts.bad_colors = bad_colors;
  return counts;
}

// Pass 1 of the flow form: vertex (u, v) moves to (u + 0.5 + flow_x, v + 0.5 + flow_y); 1 / depth
// orders fragments. Depth 0 = unknown (vertex invalid); NaN / negative depth or a non-finite
// flow vector are counted as bad (the front rejects them).
WarpCounts FlowVertices(const ImageView<const float>& depth, const float* flow, WarpScratch& scratch) {
  const int h = depth.height, w = depth.width;
  const int num_segs = NumSegments(w);
  scratch.verts.resize(std::int64_t(h) * w);
  scratch.seg_y.resize(std::size_t(h) * num_segs);
  WarpVertex* verts = scratch.verts.data();
  YRange* seg_y = scratch.seg_y.data();
  std::atomic<std::int64_t> valid{0}, bad{0}, bad_flow{0};
  ParallelFor(h, 8, [&](std::int64_t r0, std::int64_t r1) {
    std::int64_t my_valid = 0, my_bad = 0, my_bad_flow = 0;
    for (std::int64_t r = r0; r < r1; ++r) {
      const float* drow = depth.Row(static_cast<int>(r));
      const float* frow = flow + 2 * r * w;
      WarpVertex* vrow = verts + r * w;
      for (int u = 0; u < w; ++u) {
        const float d = drow[u], fx = frow[2 * u], fy = frow[2 * u + 1];
        WarpVertex& o = vrow[u];
        o.x = kInvalid;
        o.y = 0;
        o.inv = 0.f;
        if (!std::isfinite(fx) || !std::isfinite(fy)) {
          ++my_bad_flow;
          continue;
        }
        if (!(d > 0.f)) {
          if (d != 0.f) ++my_bad;
          continue;
        }
        ++my_valid;
        const double x = double(u) + 0.5 + double(fx), y = double(r) + 0.5 + double(fy);
        if (!(x > -kGuardPixels && x < double(w) + kGuardPixels && y > -kGuardPixels && y < double(h) + kGuardPixels)) {
          continue;
        }
        o.x = RoundHalfAway(x * kSubpixel);
        o.y = RoundHalfAway(y * kSubpixel);
        o.inv = std::isinf(d) ? 0.f : std::min(std::max(1.f / d, float(kMinInvDepth)), float(kMaxInvDepth));
      }
      RowSegmentRanges(vrow, w, num_segs, seg_y + r * num_segs);
    }
    valid += my_valid;
    bad += my_bad;
    bad_flow += my_bad_flow;
  });
  WarpCounts counts;
  counts.valid_vertices = valid;
  counts.bad_depths = bad;
  counts.bad_flow = bad_flow;
  return counts;
}

// Per target band of kBandRows rows, the (block row, column segment) pairs whose vertices' y
// range reaches it and whose x range reaches a centre column of the target (tw wide)
// (scratch.band_start / band_segs). Returns the number of bands. A counting sort, in parallel
// over chunks of kListRows block rows (the chunks depend on the sizes only): per chunk, each
// segment's band range and the chunk's count per band; then the offsets of (band, chunk) in
// band order, chunk order; then each chunk writes its ids. Per band the ids stay in input order.
constexpr int kListRows = 64;

int BuildBandLists(WarpScratch& scratch, int h, int w, int th, int tw) {
  const int num_segs = NumSegments(w);
  const int block_rows = std::max(0, h - 1);
  const int num_bands = (th + kBandRows - 1) / kBandRows;
  const int num_chunks = (block_rows + kListRows - 1) / kListRows;
  const YRange* seg_y = scratch.seg_y.data();
  // Centre rows of a y range: [CeilSub(lo - 128), FloorSub(hi - 128)].
  std::vector<std::uint32_t>& band_start = scratch.band_start;
  std::vector<std::uint32_t>& band_segs = scratch.band_segs;
  std::vector<std::uint32_t>& seg_bands = scratch.seg_bands;
  std::vector<std::uint32_t>& fill = scratch.band_fill;  // per chunk, per band: count, then offset
  band_start.assign(std::size_t(num_bands) + 1, 0u);
  seg_bands.resize(2 * std::size_t(block_rows) * num_segs);
  fill.assign(std::size_t(num_chunks) * num_bands, 0u);
  ParallelFor(num_chunks, 1, [&](std::int64_t c0_, std::int64_t c1_) {
    for (std::int64_t c = c0_; c < c1_; ++c) {
      std::uint32_t* count = fill.data() + c * num_bands;
      const int r_end = std::min<int>(block_rows, int(c + 1) * kListRows);
      for (int r = int(c) * kListRows; r < r_end; ++r) {
        const YRange* ya = seg_y + std::int64_t(r) * num_segs;
        const YRange* yb = ya + num_segs;
        std::uint32_t* sb = seg_bands.data() + 2 * std::int64_t(r) * num_segs;
        for (int s = 0; s < num_segs; ++s) {
          const std::int32_t lo = std::min(ya[s].lo, yb[s].lo), hi = std::max(ya[s].hi, yb[s].hi);
          sb[2 * s] = 1u;  // no band (first > last)
          sb[2 * s + 1] = 0u;
          if (lo > hi) continue;
          // Every triangle of the segment lies in its vertices' x range: none covers a centre
          // column of the target when that range holds none (RasterBlockRow / RasterTriangle
          // clip to it).
          const std::int32_t xlo = std::min(ya[s].x_lo, yb[s].x_lo), xhi = std::max(ya[s].x_hi, yb[s].x_hi);
          if (FloorSub(std::int64_t(xhi) - kSubpixel / 2) < 0 || CeilSub(std::int64_t(xlo) - kSubpixel / 2) > tw - 1) {
            continue;
          }
          const std::int64_t c0 = std::max<std::int64_t>(0, CeilSub(std::int64_t(lo) - kSubpixel / 2));
          const std::int64_t c1 = std::min<std::int64_t>(th - 1, FloorSub(std::int64_t(hi) - kSubpixel / 2));
          if (c0 > c1) continue;
          const std::uint32_t b_lo = static_cast<std::uint32_t>(c0 / kBandRows), b_hi = static_cast<std::uint32_t>(c1 / kBandRows);
          sb[2 * s] = b_lo;
          sb[2 * s + 1] = b_hi;
          for (std::uint32_t b = b_lo; b <= b_hi; ++b) ++count[b];
        }
      }
    }
  });
  std::uint32_t total = 0;
  for (int b = 0; b < num_bands; ++b) {
    band_start[b] = total;
    for (int c = 0; c < num_chunks; ++c) {
      const std::uint32_t n = fill[std::size_t(c) * num_bands + b];
      fill[std::size_t(c) * num_bands + b] = total;
      total += n;
    }
  }
  band_start[num_bands] = total;
  band_segs.resize(total);
  ParallelFor(num_chunks, 1, [&](std::int64_t c0_, std::int64_t c1_) {
    for (std::int64_t c = c0_; c < c1_; ++c) {
      std::uint32_t* off = fill.data() + c * num_bands;
      const std::uint32_t id0 = static_cast<std::uint32_t>(c * kListRows * num_segs);
      const std::uint32_t id1 = static_cast<std::uint32_t>(std::min<std::int64_t>(block_rows, (c + 1) * kListRows) * num_segs);
      for (std::uint32_t id = id0; id < id1; ++id) {
        for (std::uint32_t b = seg_bands[2 * id]; b <= seg_bands[2 * id + 1]; ++b) band_segs[off[b]++] = id;
      }
    }
  });
  // Pass 2 takes the bands with the most segments first, so that the last tasks of a view are
  // short ones and no thread waits long for the others at its end (bands own their pixels: the
  // order changes no result).
  std::vector<std::uint32_t>& order = scratch.band_order;
  order.resize(num_bands);
  for (int b = 0; b < num_bands; ++b) order[b] = static_cast<std::uint32_t>(b);
  std::sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) {
    const std::uint32_t na = band_start[a + 1] - band_start[a], nb = band_start[b + 1] - band_start[b];
    return na != nb ? na > nb : a < b;
  });
  return num_bands;
}

// Pass 2: rasterise each target band (bands own their pixels; in parallel) from its segment
// list, triangles in input order. Per task a shader is made by make(); per band, init(sh, y0,
// y1) clears the band, finish(sh, y0, y1) post-processes it.
template <class MakeShader, class Init, class Finish>
void RasterBands(const Context& cx, const WarpScratch& scratch, int num_bands, bool fast, MakeShader&& make,
                 Init&& init, Finish&& finish) {
  const int w = cx.depth->width, th = cx.th;
  const int num_segs = NumSegments(w);
  const std::uint32_t* band_start = scratch.band_start.data();
  const std::uint32_t* band_segs = scratch.band_segs.data();
  const std::uint32_t* band_order = scratch.band_order.data();
  const bool avx2 = UseAvx2();
  ParallelFor(num_bands, 1, [&](std::int64_t i0, std::int64_t i1) {
    auto sh = make();
    const auto bands = [&](auto simd) {
    for (std::int64_t i = i0; i < i1; ++i) {
      const std::int64_t b = band_order[i];
      const int y0 = static_cast<int>(b) * kBandRows, y1 = std::min(th, y0 + kBandRows);
      init(sh, y0, y1);
      for (std::uint32_t k = band_start[b]; k < band_start[b + 1]; ++k) {
        const std::uint32_t id = band_segs[k];
        if (k + 1 < band_start[b + 1]) {
          // The next segment is elsewhere in the input (another block row): fetch its two vertex
          // rows (16 + 1 vertices of 12 bytes each) and colour rows while this one is drawn.
          const std::uint32_t nid = band_segs[k + 1];
          const std::int64_t nr = nid / std::uint32_t(num_segs), nu = std::int64_t(nid % std::uint32_t(num_segs)) * kSegCols;
          const char* v0 = reinterpret_cast<const char*>(cx.verts + nr * w + nu);
          const char* c0 = reinterpret_cast<const char*>(cx.color->data + 3 * (nr * w + nu));
          for (int line = 0; line < 4; ++line) {
            __builtin_prefetch(v0 + 64 * line);
            __builtin_prefetch(v0 + 12 * std::int64_t(w) + 64 * line);
            __builtin_prefetch(c0 + 64 * line);
            __builtin_prefetch(c0 + 12 * std::int64_t(w) + 64 * line);
          }
        }
        const int r = static_cast<int>(id / std::uint32_t(num_segs)), s = static_cast<int>(id % std::uint32_t(num_segs));
        const int u0 = s * kSegCols, u1 = std::min(w - 1, (s + 1) * kSegCols);
        if constexpr (decltype(simd)::value && std::decay_t<decltype(sh)>::kQuadSimd) {
          if (fast) {
            RasterBlockRowAvx2(cx, r, u0, u1, y0, y1, sh);
            continue;
          }
        }
        RasterBlockRow(cx, r, u0, u1, y0, y1, fast, sh);
      }
      finish(sh, y0, y1);
    }
    };
    if (avx2) {
      CallAvx2([&] { bands(std::true_type{}); });
    } else {
      bands(std::false_type{});
    }
  });
}

}  // namespace

float SideThreshold(const WarpOptions& options, const Camera& target) {
  if (options.side_threshold > 0.f) return options.side_threshold;
  return static_cast<float>(std::max(kMinAutoSide, 10.0 * std::sqrt(double(target.width) * target.height / (1920.0 * 1080.0))));
}

WarpCounts ForwardWarp(const ImageView<const float>& color, const ImageView<const float>& depth,
                       const Camera& source, const Camera& target, const WarpOptions& options,
                       WarpScratch& scratch, const ImageView<float>& out_color,
                       const ImageView<float>& out_depth, const ImageView<float>& out_weight,
                       float* out_quality, const BlendBuffers* accumulate, bool check_color) {
  const int h = depth.height, w = depth.width;
  const int th = target.height, tw = target.width;
  WarpCounts counts = ProjectVertices(depth, source, target, scratch, check_color ? &color : nullptr);
  // A view the front will reject (bad or no depth, non-finite colour) never reaches the sums.
  const BlendBuffers* acc =
      counts.bad_depths == 0 && counts.valid_vertices > 0 && counts.bad_colors == 0 ? accumulate : nullptr;

  const int num_bands = BuildBandLists(scratch, h, w, th, tw);
  const bool equirect_target = target.model == CameraModel::kEquirect;
  Context cx{&color, &depth, &source, &target, &options, scratch.verts.data(),
             SideThreshold(options, target), equirect_target, tw, th};
  const bool fast = options.quality == WarpQuality::kSide;
  const float p = options.blend_exponent;
  const float vw = options.view_weight;
  std::atomic<std::int64_t> covered{0};
  if (out_color.data == nullptr) {
    // Band-local mode (accumulate only, forward_warp.h): each task draws its band into a
    // thread's own band buffers (score, colour, depth, quality; a few MB, kept in cache) and adds
    // it to the sums row by row. Colour and depth need no clearing: they are read only where the
    // quality is > 0, i.e. where a fragment of this band wrote them.
    if (acc == nullptr) return counts;  // a view the front rejects: nothing to draw into
    const std::ptrdiff_t band_px = std::ptrdiff_t(kBandRows) * tw;
    const bool plain_avx2 = UseAvx2() && !(acc->stretched_quality > 0.f) && !(acc->depth_tolerance > 0.f);
    const bool avx2_weights = UseAvx2() && (p == 5.f || p == 3.f);
    RasterBands(
        cx, scratch, num_bands, fast,
        [&] {
          thread_local std::vector<float> band;  // grown once per thread, reused by every view
          if (band.size() < std::size_t(7 * band_px)) band.resize(std::size_t(7 * band_px));
          Shader sh;
          sh.combined = options.depth_test == DepthTest::kCombined;
          sh.tw = tw;
          sh.score = band.data();
          sh.oq = sh.score + band_px;
          sh.od = sh.oq + band_px;
          sh.oc = sh.od + band_px;  // 3 * band_px; then one row of weights
          return sh;
        },
        [&](Shader& sh, int y0, int y1) {
          sh.row0 = y0;
          const std::ptrdiff_t n = std::ptrdiff_t(y1 - y0) * tw;
          std::fill(sh.score, sh.score + n, -kInf);
          std::fill(sh.oq, sh.oq + n, 0.f);
        },
        [&](Shader& sh, int y0, int y1) {
          float* wrow = sh.oc + 3 * band_px;
          std::int64_t my_covered = 0;
          for (int y = y0; y < y1; ++y) {
            const std::ptrdiff_t o = std::ptrdiff_t(y - y0) * tw;
            const float *qrow = sh.oq + o, *drow = sh.od + o;
            int x = 0;
            if (avx2_weights) x = WeightRowAvx2(qrow, drow, wrow, tw, p, my_covered);
            for (; x < tw; ++x) {
              const float q = qrow[x];
              if (q > 0.f) {
                wrow[x] = Weight(q, drow[x], p);
                ++my_covered;
              } else {
                wrow[x] = 0.f;
              }
            }
            if (vw != 1.f) ScaleRow(wrow, tw, vw);
            if (plain_avx2) {
              AccumulateRowPlainAvx2(sh.oc + 3 * o, drow, wrow, qrow, *acc, y);
            } else {
              AccumulateRow(sh.oc + 3 * o, drow, wrow, qrow, *acc, y);
            }
          }
          covered += my_covered;
        });
    counts.covered_pixels = covered;
    return counts;
  }
  scratch.score.resize(std::int64_t(th) * tw);
  float* score = scratch.score.data();
  RasterBands(
      cx, scratch, num_bands, fast,
      [&] {
        Shader sh;
        sh.combined = options.depth_test == DepthTest::kCombined;
        sh.tw = tw;
        sh.score = score;
        sh.oc = out_color.data;
        sh.od = out_depth.data;
        sh.oq = out_quality;
        return sh;
      },
      [&](Shader&, int y0, int y1) {
        for (std::ptrdiff_t i = std::ptrdiff_t(y0) * tw; i < std::ptrdiff_t(y1) * tw; ++i) {
          score[i] = -kInf;
          out_quality[i] = 0.f;
          out_depth.data[i] = 0.f;
          out_color.data[3 * i] = out_color.data[3 * i + 1] = out_color.data[3 * i + 2] = 0.f;
        }
      },
      [&](Shader&, int y0, int y1) {
        // Row by row: the weights of a row, then its accumulation while the row is in L1/L2
        // (the same per-pixel operations as a band-wide pass, one read of the row instead of two).
        std::int64_t my_covered = 0;
        for (int y = y0; y < y1; ++y) {
          for (std::ptrdiff_t i = std::ptrdiff_t(y) * tw; i < std::ptrdiff_t(y + 1) * tw; ++i) {
            const float q = out_quality[i];
            if (q > 0.f) {
              out_weight.data[i] = Weight(q, out_depth.data[i], p);
              ++my_covered;
            } else {
              out_weight.data[i] = 0.f;
            }
          }
          if (vw != 1.f) ScaleRow(out_weight.data + std::ptrdiff_t(y) * tw, tw, vw);
          if (acc) AccumulateRows(out_color.data, out_depth.data, out_weight.data, out_quality, *acc, y, y + 1);
        }
        covered += my_covered;
      });
  counts.covered_pixels = covered;
  return counts;
}

// ---- Warp with background-depth holes (dos Anjos et al. sec. 3.1; forward_warp.h) ----
namespace {

// Shader of the hole mode: plain z-buffer on the re-partitioned depth of Eq. 1 (smaller wins).
// Unstretched quads: interpolated colour and depth as in DIBR, key 0.5 d. Stretched quads: one
// flat background depth for the whole quad, key 1 - 0.5 d, colour 0, mask kMaskDisoccluded.
struct HoleShader : TriangleInterp {
  static constexpr bool kQuadSimd = false;  // needs BeginQuad per quad: the scalar block-row loop
  static constexpr bool kInclusiveEdges = false;  // the exclusive tie rule (forward_warp.h)
  int tw;
  float stretch2;    // squared stretch threshold, px^2
  float depth_jump1; // 1 + HoleWarpOptions::depth_jump
  bool stretched;    // of the current quad
  float bg_depth;    // of the current quad: the farthest corner (metric; +inf for sky)
  double bg_key;     // 1 - 0.5 d(bg_depth), kept above 0.5
  double* key;
  float *oc, *od;
  std::uint8_t* om;

  // d of Eq. 1: metric depth z mapped monotonically onto [0, 1] (larger = farther) by
  // d = z / (1 + z) = 1 / (1 + 1/z); +inf -> 1. Double: distinct depths stay distinct keys.
  static inline double NormDepth(float inv) { return inv > 0.f ? 1.0 / (1.0 + double(inv)) : 1.0; }

  inline void BeginQuad(const WarpVertex& A, const WarpVertex& B, const WarpVertex& C, const WarpVertex& D) {
    // The quad's edges: AB, AC, BC (triangle 0) and BD, DC (triangle 1); corners B and C are
    // valid here (RasterBlockRow), A and D may not be.
    const WarpVertex* v[4] = {&A, &B, &C, &D};
    static constexpr int kEdges[5][2] = {{0, 1}, {0, 2}, {1, 2}, {1, 3}, {3, 2}};
    const float s = 1.f / kSubpixel;
    float l2 = 0.f;
    for (const auto& e : kEdges) {
      const WarpVertex &p = *v[e[0]], &q = *v[e[1]];
      if (p.x == kInvalid || q.x == kInvalid) continue;
      const float dx = float(q.x - p.x) * s, dy = float(q.y - p.y) * s;
      l2 = std::max(l2, dx * dx + dy * dy);
    }
    stretched = false;
    if (!(l2 > stretch2)) return;
    // "The minimum of the depth of all four vertices" in the paper's reversed-Z buffer (larger =
    // nearer) is the farthest corner: the smallest 1 / z here (0 = infinite).
    float inv = kInf, inv_hi = 0.f;
    for (const WarpVertex* c : v) {
      if (c->x != kInvalid) {
        inv = std::min(inv, c->inv);
        inv_hi = std::max(inv_hi, c->inv);
      }
    }
    // ... and connects foreground and background: nearest / farthest corner depth ratio above
    // 1 + depth_jump (0 = the stretch alone decides).
    stretched = inv_hi > inv * depth_jump1 || (depth_jump1 <= 1.f);
    if (!stretched) return;
    bg_depth = inv > 0.f ? 1.f / inv : kInf;
    // Eq. 1, stretched: 1 - 0.5 d in (0.5, 1]. d = 1 (infinite background) would give 0.5, the
    // key of unstretched sky; the smallest double above 0.5 keeps the two ranges disjoint.
    bg_key = std::max(1.0 - 0.5 * NormDepth(inv), std::nextafter(0.5, 1.0));
  }

  void Setup(float inverse_area, const std::int64_t b[3], float, const float inv[3], const float* const col[3],
             bool all_inf) {
    SetupInterp(inverse_area, b, inv, col, all_inf);
  }

  inline void Shade(int px, int py, std::int64_t e0, std::int64_t e1, std::int64_t e2) const {
    const std::ptrdiff_t i = std::ptrdiff_t(py) * tw + px;
    if (stretched) {
      // No interpolation: the quad's background depth everywhere, a hole in colour.
      if (bg_key < key[i]) {
        key[i] = bg_key;
        od[i] = bg_depth;
        oc[3 * i] = oc[3 * i + 1] = oc[3 * i + 2] = 0.f;
        om[i] = kMaskDisoccluded;
      }
      return;
    }
    float b[3];
    Bary(e0, e1, e2, b);
    const float id = InvDepth(b);
    const double k = 0.5 * NormDepth(id);  // Eq. 1, unstretched: 0.5 d in [0, 0.5]
    if (k < key[i]) {
      key[i] = k;
      const bool far = affine || !(id > 0.f);
      const float d = far ? kInf : 1.f / id;
      const float m = affine ? 1.f : d;
      Color(b, m, oc + 3 * i);
      od[i] = d;
      om[i] = kMaskSurface;
    }
  }
};

// Pass 2 of both hole-mode entry points (vertices already in scratch).
WarpCounts RasterHoles(const ImageView<const float>& color, const ImageView<const float>& depth,
                       const Camera* source, const Camera* target, bool equirect_target, int th, int tw,
                       const HoleWarpOptions& options, WarpScratch& scratch, WarpCounts counts,
                       const ImageView<float>& out_color, const ImageView<float>& out_depth,
                       std::uint8_t* out_mask) {
  // The shared rasteriser runs with quality 'side' (its fast small-quad path) and never discards:
  // the HoleShader ignores the triangle quality, stretch is judged per quad in BeginQuad.
  WarpOptions wo;
  wo.quality = WarpQuality::kSide;
  wo.discard_stretched = false;
  const float t = options.stretch_threshold;
  const int num_bands = BuildBandLists(scratch, depth.height, depth.width, th, tw);
  Context cx{&color, &depth, source, target, &wo, scratch.verts.data(), t, equirect_target, tw, th};
  scratch.depth_key.resize(std::size_t(th) * tw);
  double* key = scratch.depth_key.data();
  std::atomic<std::int64_t> covered{0}, disoccluded{0};
  RasterBands(
      cx, scratch, num_bands, true,
      [&] {
        HoleShader sh;
        sh.tw = tw;
        sh.stretch2 = t * t;
        sh.depth_jump1 = 1.f + options.depth_jump;
        sh.stretched = false;
        sh.key = key;
        sh.oc = out_color.data;
        sh.od = out_depth.data;
        sh.om = out_mask;
        return sh;
      },
      [&](HoleShader&, int y0, int y1) {
        for (std::ptrdiff_t i = std::ptrdiff_t(y0) * tw; i < std::ptrdiff_t(y1) * tw; ++i) {
          key[i] = std::numeric_limits<double>::infinity();
          out_depth.data[i] = 0.f;
          out_mask[i] = kMaskUncovered;
          out_color.data[3 * i] = out_color.data[3 * i + 1] = out_color.data[3 * i + 2] = 0.f;
        }
      },
      [&](HoleShader&, int y0, int y1) {
        std::int64_t c = 0, d = 0;
        for (std::ptrdiff_t i = std::ptrdiff_t(y0) * tw; i < std::ptrdiff_t(y1) * tw; ++i) {
          c += out_mask[i] == kMaskSurface;
          d += out_mask[i] == kMaskDisoccluded;
        }
        covered += c;
        disoccluded += d;
      });
  counts.covered_pixels = covered;
  counts.disoccluded_pixels = disoccluded;
  return counts;
}

}  // namespace

WarpCounts WarpWithHoles(const ImageView<const float>& color, const ImageView<const float>& depth,
                         const Camera& source, const Camera& target, const HoleWarpOptions& options,
                         WarpScratch& scratch, const ImageView<float>& out_color,
                         const ImageView<float>& out_depth, std::uint8_t* out_mask) {
  const WarpCounts counts = ProjectVertices(depth, source, target, scratch);
  return RasterHoles(color, depth, &source, &target, target.model == CameraModel::kEquirect, target.height,
                     target.width, options, scratch, counts, out_color, out_depth, out_mask);
}

WarpCounts WarpFlowWithHoles(const ImageView<const float>& color, const ImageView<const float>& depth,
                             const float* flow, const HoleWarpOptions& options, WarpScratch& scratch,
                             const ImageView<float>& out_color, const ImageView<float>& out_depth,
                             std::uint8_t* out_mask) {
  const WarpCounts counts = FlowVertices(depth, flow, scratch);
  return RasterHoles(color, depth, nullptr, nullptr, false, depth.height, depth.width, options, scratch, counts,
                     out_color, out_depth, out_mask);
}

}  // namespace ibr
