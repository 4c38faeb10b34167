// The engine's one triangle rasteriser core. Three shaders draw through it:
//   - the forward warp (cpp/kernels/dibr/forward_warp.cpp): input pixel grids into a target,
//     inclusive edges (DIBR blends every triangle covering a centre);
//   - the G-buffer (cpp/kernels/hybrid/gbuffer_raster.cpp): a mesh's nearest face per pixel,
//     inclusive edges, the nearest 1/z wins;
//   - PVM's candidate lists (cpp/kernels/hybrid/pvm_render.cpp): per-view tile meshes, the
//     top-left rule (a centre on a shared edge goes to exactly one of the two triangles).
// Binning triangles into bands of rows is cpp/ibr/bands.h.
//
// Conventions. Screen coordinates are pixels with centres at i + 0.5 (cpp/ibr/camera.h), y down.
// Vertices are snapped to fixed point, 1/kSubpixel px, rounded half away from zero (ToFixed);
// coverage is decided exactly on the snapped triangle with 64-bit integer edge functions. A
// vertex must lie within kGuardPixels of the origin (CoarseGuard, ClipToGuardBand), so that every
// edge value fits in 64 bits. Edge e of triangle (0, 1, 2) is opposite vertex e, from vertex
// e + 1 to vertex e + 2; with area2 = (X1 - X0) (Y2 - Y0) - (Y1 - Y0) (X2 - X0) > 0 (the shaders
// orient or cull), E_e / area2 is the barycentric weight of vertex e and a centre is inside when
// all three E_e >= 0. The top-left rule subtracts 1 from the edge functions of edges that do not
// own their points (Edges::bias), so "covered" stays E_0, E_1, E_2 >= 0; inclusive edges own all.
//
// Clipping is Sutherland-Hodgman on polygons (ClipPolygon), with each cut point computed from the
// edge's two end points in an order that does not depend on the polygon (the caller's `less`), so
// two polygons sharing an edge get bit-identical cut points and no crack opens between them.
#pragma once

#include <algorithm>
#include <cstdint>

namespace ibr::raster {

constexpr int kSubpixel = 256;  // fixed point: 1/256 pixel
// Largest |coordinate| of a snapped vertex, in pixels: 2^20 px is 2^28 fixed-point units, so edge
// steps are below 2^37 and edge products below 2^58 (room for the row and column steps too).
constexpr double kGuardPixels = 1048576.0;

// Floor / ceil of a / 256 (arithmetic shift: floor for negative a too).
inline std::int64_t FloorSub(std::int64_t a) { return a >> 8; }
inline std::int64_t CeilSub(std::int64_t a) { return -((-a) >> 8); }
inline std::int64_t FloorDiv(std::int64_t a, std::int64_t b) {
  std::int64_t q = a / b;
  if ((a % b != 0) && ((a < 0) != (b < 0))) --q;
  return q;
}
inline std::int64_t CeilDiv(std::int64_t a, std::int64_t b) { return -FloorDiv(-a, b); }

// std::lround(v) without the library call: the same value for |v| < 2^31 (v - trunc(v) is
// exact). Branch-free: the rounding direction is random per vertex, a branch mispredicts.
inline std::int32_t RoundHalfAway(double v) {
  const std::int32_t t = static_cast<std::int32_t>(v);  // truncation
  const double frac = v - double(t);
  return t + std::int32_t(frac >= 0.5) - std::int32_t(frac <= -0.5);
}

// A screen coordinate (|v| <= kGuardPixels) in fixed point.
inline std::int32_t ToFixed(double v) { return RoundHalfAway(v * kSubpixel); }

// True when (x, y) may be snapped (inside the guard band; false for NaN).
inline bool InGuardBand(double x, double y) {
  return x >= -kGuardPixels && x <= kGuardPixels && y >= -kGuardPixels && y <= kGuardPixels;
}

// Twice the signed area of the snapped triangle, in (1/256 px)^2.
inline std::int64_t Area2(const std::int64_t X[3], const std::int64_t Y[3]) {
  return (X[1] - X[0]) * (Y[2] - Y[0]) - (Y[1] - Y[0]) * (X[2] - X[0]);
}

// True when edge a -> b owns its points under the top-left rule (y down, area2 > 0).
inline bool OwnsEdge(std::int64_t dx, std::int64_t dy) { return dy > 0 || (dy == 0 && dx < 0); }

// The pixel centres a triangle may cover: columns [x0, x1], rows [y0, y1].
struct CentreBox {
  int x0, x1, y0, y1;
};

// The centres i + 0.5 within the triangle's bounding box, intersected with columns [x_lo, x_hi]
// and rows [y_lo, y_hi]; false when there is none.
inline bool Centres(const std::int64_t X[3], const std::int64_t Y[3], int x_lo, int x_hi, int y_lo, int y_hi,
                    CentreBox* box) {
  static_assert(kSubpixel == 256, "FloorSub / CeilSub divide by 256");
  const std::int64_t min_x = std::min(X[0], std::min(X[1], X[2])), max_x = std::max(X[0], std::max(X[1], X[2]));
  const std::int64_t min_y = std::min(Y[0], std::min(Y[1], Y[2])), max_y = std::max(Y[0], std::max(Y[1], Y[2]));
  box->x0 = static_cast<int>(std::max<std::int64_t>(x_lo, CeilSub(min_x - kSubpixel / 2)));
  box->x1 = static_cast<int>(std::min<std::int64_t>(x_hi, FloorSub(max_x - kSubpixel / 2)));
  box->y0 = static_cast<int>(std::max<std::int64_t>(y_lo, CeilSub(min_y - kSubpixel / 2)));
  box->y1 = static_cast<int>(std::min<std::int64_t>(y_hi, FloorSub(max_y - kSubpixel / 2)));
  return box->x0 <= box->x1 && box->y0 <= box->y1;
}

// The three edge functions set up at the centre (px0 + 0.5, py0 + 0.5), with their steps per
// column (ex) and per row (ey) and the fill rule's bias (0 or 1, already subtracted in e_row).
struct Edges {
  std::int64_t ex[3], ey[3], e_row[3], bias[3];
};

inline void SetupEdges(const std::int64_t X[3], const std::int64_t Y[3], int px0, int py0, bool inclusive, Edges* E) {
  const std::int64_t sx = std::int64_t(px0) * kSubpixel + kSubpixel / 2;
  const std::int64_t sy = std::int64_t(py0) * kSubpixel + kSubpixel / 2;
  for (int e = 0; e < 3; ++e) {
    const int a = (e + 1) % 3, b = (e + 2) % 3;
    const std::int64_t dx = X[b] - X[a], dy = Y[b] - Y[a];
    const bool owns = inclusive || OwnsEdge(dx, dy);
    E->ex[e] = -dy * kSubpixel;  // step in x
    E->ey[e] = dx * kSubpixel;   // step in y
    E->bias[e] = owns ? 0 : 1;
    E->e_row[e] = dx * (sy - Y[a]) - dy * (sx - X[a]) - E->bias[e];
  }
}

// Calls shade(px, py, e0, e1, e2) for every covered centre of `box` (the box E was set up at), row
// by row, left to right; e_e are the biased edge functions there (add E.bias[e] back for the
// barycentric numerators). Rows of wide triangles (>= 8 candidate columns: long slivers across
// disocclusions, large faces) are cut to the exact span where the three functions are >= 0 (integer
// division) instead of testing every column of the box.
template <class F>
inline void ScanTriangle(const Edges& E, const CentreBox& box, F&& shade) {
  const std::int64_t *ex = E.ex, *ey = E.ey;
  std::int64_t e_row[3] = {E.e_row[0], E.e_row[1], E.e_row[2]};
  const int px0 = box.x0, px1 = box.x1;
  const bool spans = px1 - px0 >= 8;
  for (int py = box.y0; py <= box.y1; ++py, e_row[0] += ey[0], e_row[1] += ey[1], e_row[2] += ey[2]) {
    int xs = px0, xe = px1;
    if (spans) {
      for (int e = 0; e < 3; ++e) {
        const std::int64_t v = e_row[e], st = ex[e];
        if (st > 0) {
          if (v < 0) xs = static_cast<int>(std::max<std::int64_t>(xs, px0 + CeilDiv(-v, st)));
        } else if (st < 0) {
          xe = v < 0 ? px0 - 1 : static_cast<int>(std::min<std::int64_t>(xe, px0 + v / (-st)));
        } else if (v < 0) {
          xe = px0 - 1;
        }
      }
      if (xs > xe) continue;
    }
    std::int64_t e0 = e_row[0] + ex[0] * (xs - px0), e1 = e_row[1] + ex[1] * (xs - px0),
                 e2 = e_row[2] + ex[2] * (xs - px0);
    for (int px = xs; px <= xe; ++px) {
      if ((e0 | e1 | e2) >= 0) shade(px, py, e0, e1, e2);
      e0 += ex[0];
      e1 += ex[1];
      e2 += ex[2];
    }
  }
}

// Sutherland-Hodgman against one half-plane: writes the part of polygon in[0, n) where
// inside(v) holds to out (at most n + 1 vertices) and returns its count. The cut point of an edge
// crossing the boundary is cut(p, q) with p, q its end points ordered by `less` (p the smaller),
// whatever the polygon's winding: two polygons sharing the edge get the same point.
template <class V, class Inside, class Less, class Cut>
inline int ClipPolygon(const V* in, int n, V* out, Inside&& inside, Less&& less, Cut&& cut) {
  int m = 0;
  for (int i = 0; i < n; ++i) {
    const V& a = in[i];
    const V& b = in[(i + 1) % n];
    const bool ina = inside(a), inb = inside(b);
    if (ina) out[m++] = a;
    if (ina != inb) out[m++] = less(b, a) ? cut(b, a) : cut(a, b);
  }
  return m;
}

// A projected polygon vertex: screen position (px) and 1 / z, which is affine in screen
// coordinates over a planar face (so a cut interpolates it linearly, exactly).
struct ScreenVertex {
  double x, y, iz;
};

inline bool ScreenLess(const ScreenVertex& a, const ScreenVertex& b) {
  return a.x < b.x || (a.x == b.x && (a.y < b.y || (a.y == b.y && a.iz < b.iz)));
}

// Clips a convex screen polygon (n <= 4 vertices) to the guard band |x|, |y| <= kGuardPixels.
// out needs n + 4 vertices; returns their count (0 when nothing is left, < 3 degenerate).
inline int ClipToGuardBand(const ScreenVertex* in, int n, ScreenVertex* out) {
  ScreenVertex tmp[8];
  const ScreenVertex* src = in;
  for (int plane = 0; plane < 4; ++plane) {
    const int axis = plane >> 1;
    const double bound = (plane & 1) ? kGuardPixels : -kGuardPixels;
    const double sign = (plane & 1) ? -1.0 : 1.0;  // keep sign * (v - bound) >= 0
    ScreenVertex* dst = (plane & 1) ? out : tmp;
    const auto coord = [axis](const ScreenVertex& v) { return axis == 0 ? v.x : v.y; };
    n = ClipPolygon(
        src, n, dst, [&](const ScreenVertex& v) { return sign * (coord(v) - bound) >= 0.0; }, ScreenLess,
        [&](const ScreenVertex& p, const ScreenVertex& q) {
          const double t = (bound - coord(p)) / (coord(q) - coord(p));
          ScreenVertex c{p.x + t * (q.x - p.x), p.y + t * (q.y - p.y), p.iz + t * (q.iz - p.iz)};
          (axis == 0 ? c.x : c.y) = bound;  // exactly on the boundary, whatever the rounding of t
          return c;
        });
    src = dst;
    if (n == 0) return 0;
  }
  return n;
}

}  // namespace ibr::raster
