// Iterative backward depth warping and forward baselines: see depthwarp.h for the contract.
#include "kernels/depthwarp/depthwarp.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <mutex>

#if defined(__SSE2__)
#include <emmintrin.h>
#include <xmmintrin.h>
#endif

#include "ibr/parallel.h"

namespace ibr {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

std::int64_t RowGrain(int width) { return std::max<std::int64_t>(1, kMinPixelsPerTask / std::max(1, width)); }

// Source pixel centre (xi, yi) at depth z -> target image position and z. False when the point
// lands at or behind the target's image plane or moves further than kDepthWarpMaxMotion.
inline bool MovePixel(const DepthWarpMover& m, double xi, double yi, double z, int id, double* xo, double* yo,
                      double* zo) {
  const Camera& s = *m.src;
  const Camera& d = *m.dst;
  const double pcx = (xi - s.cx) / s.fx * z, pcy = (yi - s.cy) / s.fy * z, pcz = z;
  const double* a = m.dst_from_src + 12 * (id + 1);
  const double x = a[0] * pcx + a[1] * pcy + a[2] * pcz + a[3];
  const double y = a[4] * pcx + a[5] * pcy + a[6] * pcz + a[7];
  const double zz = a[8] * pcx + a[9] * pcy + a[10] * pcz + a[11];
  if (!(zz > 0.0)) return false;
  *xo = d.fx * x / zz + d.cx;
  *yo = d.fy * y / zz + d.cy;
  *zo = zz;
  return std::isfinite(*xo) && std::isfinite(*yo) && std::fabs(*xo - xi) < kDepthWarpMaxMotion &&
         std::fabs(*yo - yi) < kDepthWarpMaxMotion;
}

// A motion bound (u0, w0)-(u1, w1) in the layer's rotated axes and zmin, a lower bound of z_dst of
// every valid source pixel it was read from (so of any sample that can converge through it).
struct Bound {
  float u0, w0, u1, w1, zmin;
  bool Valid() const { return u0 <= u1 && w0 <= w1; }
};
constexpr Bound kEmptyBound{kInf, kInf, -kInf, -kInf, kInf};

inline Bound Union(const Bound& a, const Bound& b) {
  return {std::min(a.u0, b.u0), std::min(a.w0, b.w0), std::max(a.u1, b.u1), std::max(a.w1, b.w1),
          std::min(a.zmin, b.zmin)};
}
// The true source is in both regions, so its motion is in both boxes and its z above both zmins.
inline Bound Intersect(const Bound& a, const Bound& b) {
  return {std::max(a.u0, b.u0), std::max(a.w0, b.w0), std::min(a.u1, b.u1), std::min(a.w1, b.w1),
          std::max(a.zmin, b.zmin)};
}

// Texel (ix >> level, iy >> level) of the layer's min-max mipmap; level 0 reads the packed buffer.
inline Bound Texel(const DepthWarpLayer& l, int level, int ix, int iy) {
  if (level == 0) {
    const float* s = l.packed.data + (std::ptrdiff_t(iy) * l.packed.width + ix) * 4;
    if (!(s[2] > 0.0f)) return kEmptyBound;
    const float u = l.rot[0] * s[0] + l.rot[1] * s[1];
    const float w = l.rot[2] * s[0] + l.rot[3] * s[1];
    return {u, w, u, w, s[2]};
  }
  const ImageView<const float>& m = l.mips[level - 1];
  const std::ptrdiff_t at = std::ptrdiff_t(iy >> level) * m.width + (ix >> level);
  const float* t = m.data + at * 4;
  return {t[0], t[1], t[2], t[3], l.zmips[level - 1].data[at]};
}

inline Bound GlobalBound(const DepthWarpLayer& l) {
  return l.n_mips > 0 ? Texel(l, l.n_mips, 0, 0) : Texel(l, 0, 0, 0);
}

// Axis-aligned source region p - R^T B (x0, y0, x1, y1) of the target centres p in
// [px0, px1] x [py0, py1].
struct Region {
  float x0, y0, x1, y1;
};
// The axis-aligned box (x0, y0, x1, y1) of the image-space motions R^T u, u in B.
inline Region MotionBox(const DepthWarpLayer& l, const Bound& b) {
  const float* r = l.rot;
  // v = R^T u: vx = r0 u + r2 w, vy = r1 u + r3 w.
  const float vx_min = (r[0] >= 0 ? r[0] * b.u0 : r[0] * b.u1) + (r[2] >= 0 ? r[2] * b.w0 : r[2] * b.w1);
  const float vx_max = (r[0] >= 0 ? r[0] * b.u1 : r[0] * b.u0) + (r[2] >= 0 ? r[2] * b.w1 : r[2] * b.w0);
  const float vy_min = (r[1] >= 0 ? r[1] * b.u0 : r[1] * b.u1) + (r[3] >= 0 ? r[3] * b.w0 : r[3] * b.w1);
  const float vy_max = (r[1] >= 0 ? r[1] * b.u1 : r[1] * b.u0) + (r[3] >= 0 ? r[3] * b.w1 : r[3] * b.w0);
  return {vx_min, vy_min, vx_max, vy_max};
}
inline Region SourceRegion(const DepthWarpLayer& l, const Bound& b, float px0, float py0, float px1, float py1) {
  const Region v = MotionBox(l, b);
  return {px0 - v.x1, py0 - v.y1, px1 - v.x0, py1 - v.y0};
}

inline bool Overlaps(const DepthWarpLayer& l, const Region& r) {
  return r.x1 >= 0.0f && r.y1 >= 0.0f && r.x0 < float(l.packed.width) && r.y0 < float(l.packed.height);
}

// The four corner texels of Fig. 5 local_motion_bound: level ceil(log2 extent) of the region
// clipped to the source image. False when the region misses the image.
struct Corners {
  int level, ix0, iy0, ix1, iy1;
};
inline bool PixelCorners(const DepthWarpLayer& l, Region r, Corners* c) {
  const int w = l.packed.width, h = l.packed.height;
  if (!Overlaps(l, r)) return false;
  r.x0 = std::max(r.x0, 0.0f);
  r.y0 = std::max(r.y0, 0.0f);
  r.x1 = std::min(r.x1, float(w));
  r.y1 = std::min(r.y1, float(h));
  const float e = std::max(r.x1 - r.x0, r.y1 - r.y0);
  int level = 0;
  if (e > 1.0f) {
    // ceil(log2 e) = bits of (ceil(e) - 1): e <= 2^level <=> ceil(e) <= 2^level.
    const std::uint32_t n = static_cast<std::uint32_t>(std::ceil(std::min(e, 1.0e9f))) - 1u;
    level = 32 - __builtin_clz(n);
  }
  c->level = std::min(level, l.n_mips);
  c->ix0 = std::min(int(r.x0), w - 1), c->ix1 = std::min(int(r.x1), w - 1);
  c->iy0 = std::min(int(r.y0), h - 1), c->iy1 = std::min(int(r.y1), h - 1);
  return true;
}

// The union of the four corner texels (an empty bound when none holds a valid motion).
inline Bound CornersBound(const DepthWarpLayer& l, const Corners& c) {
  Bound b = Texel(l, c.level, c.ix0, c.iy0);
  b = Union(b, Texel(l, c.level, c.ix1, c.iy0));
  b = Union(b, Texel(l, c.level, c.ix0, c.iy1));
  b = Union(b, Texel(l, c.level, c.ix1, c.iy1));
  return b;
}

// Its zmin alone (= CornersBound(l, c).zmin: the minimum does not depend on the order).
inline float TexelZ(const DepthWarpLayer& l, int level, int ix, int iy) {
  if (level == 0) {
    const float z = l.packed.data[(std::ptrdiff_t(iy) * l.packed.width + ix) * 4 + 2];
    return z > 0.0f ? z : kInf;
  }
  const ImageView<const float>& m = l.zmips[level - 1];
  return m.data[std::ptrdiff_t(iy >> level) * m.width + (ix >> level)];
}
inline float CornersZmin(const DepthWarpLayer& l, const Corners& c) {
  return std::min(std::min(TexelZ(l, c.level, c.ix0, c.iy0), TexelZ(l, c.level, c.ix1, c.iy0)),
                  std::min(TexelZ(l, c.level, c.ix0, c.iy1), TexelZ(l, c.level, c.ix1, c.iy1)));
}

// Fig. 5 local_motion_bound. Empty when the region misses the image or holds no valid motion.
inline Bound LocalBound(const DepthWarpLayer& l, const Region& r) {
  Corners c;
  if (!PixelCorners(l, r, &c)) return kEmptyBound;
  return CornersBound(l, c);
}

inline std::uint32_t Hash(std::uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352dU;
  x ^= x >> 15;
  x *= 0x846ca68bU;
  x ^= x >> 16;
  return x;
}
inline float Unit(std::uint32_t x) { return float(x >> 8) * (1.0f / 16777216.0f); }
inline float RadicalInverse2(std::uint32_t k) {
  k = (k << 16) | (k >> 16);
  k = ((k & 0x00ff00ffU) << 8) | ((k & 0xff00ff00U) >> 8);
  k = ((k & 0x0f0f0f0fU) << 4) | ((k & 0xf0f0f0f0U) >> 4);
  k = ((k & 0x33333333U) << 2) | ((k & 0xccccccccU) >> 2);
  k = ((k & 0x55555555U) << 1) | ((k & 0xaaaaaaaaU) >> 1);
  return Unit(k);
}
inline float Frac(float x) { return x - std::floor(x); }

// Silhouette test of a converged sample (not in the paper; DepthWarpOptions::edge_motion): the
// sample of source pixel P (packed entry s at offset `at`, layer jj) moves P's centre to within the
// threshold of p, but its exact preimage w = p - V(P) may lie in another source pixel Q. Then p is
// outside P's moved footprint: accepted when Q's motion (same layer, or the nearest non-empty one
// above) differs from P's by less than edge_motion px - a continuous surface, p is in the crack
// between two moved pixels - and not when the motion jumps (P is a silhouette pixel and p lies
// beyond its edge: accepting it grows every foreground object by up to the threshold). w outside
// the source image: accepted (nothing is known beyond the border).
inline bool EdgeConsistent(const DepthWarpLayer* layers, int jj, std::ptrdiff_t at, const float* s, float wx,
                           float wy, float edge2, int w, int h) {
  if (!(edge2 > 0.0f)) return true;
  if (!(wx >= 0.0f && wy >= 0.0f && wx < float(w) && wy < float(h))) return true;
  const std::ptrdiff_t at_w = (std::ptrdiff_t(int(wy)) * w + int(wx)) * 4;
  if (at_w == at) return true;
  const float* t = layers[jj].packed.data + at_w;
  for (int k = jj - 1; !(t[2] > 0.0f) && k >= 0; --k) t = layers[k].packed.data + at_w;
  if (!(t[2] > 0.0f)) return false;
  const float ex = t[0] - s[0], ey = t[1] - s[1];
  return ex * ex + ey * ey < edge2;
}

// Fig. 3 fixed_point_search with Fig. 6 multi_layer_seed, for target centre (px, py), search
// layer j, seed q. On convergence sets z and the layer the sample came from.
inline bool FixedPointSearch(const DepthWarpLayer* layers, int j, float px, float py, float qx, float qy,
                             int iters, float thr2, float edge2, float* z, int* layer, std::ptrdiff_t* pixel,
                             std::int64_t* lookups) {
  const int w = layers[0].packed.width, h = layers[0].packed.height;
  int empties = 0;
  for (int k = 0;; ++k) {
    if (!(qx >= 0.0f && qy >= 0.0f && qx < float(w) && qy < float(h))) return false;  // rejected, not clamped
    const std::ptrdiff_t at = (std::ptrdiff_t(int(qy)) * w + int(qx)) * 4;
    ++*lookups;
    const float* s = layers[j].packed.data + at;
    int jj = j;
    if (!(s[2] > 0.0f)) {
      if (++empties >= 2) return false;
      for (jj = j - 1; jj >= 0; --jj) {
        s = layers[jj].packed.data + at;
        if (s[2] > 0.0f) break;
      }
      if (jj < 0) return false;
    }
    const float wx = px - s[0], wy = py - s[1];
    const float dx = qx - wx, dy = qy - wy;
    if (dx * dx + dy * dy < thr2 && EdgeConsistent(layers, jj, at, s, wx, wy, edge2, w, h)) {
      *z = s[2];
      *layer = jj;
      *pixel = at / 4;
      return true;
    }
    if (k >= iters) return false;
    qx = wx;
    qy = wy;
  }
}

// Proven occluder depth of a converged sample (depthwarp.h, DepthWarpBackward "proof"). A point of
// surface k at source pixel i is i's sample in the nearest layer whose surface id is k (any layer: a
// surface seen in layer 0 on one side of a silhouette and in a deeper layer behind the occluder on
// the other is one surface). A triangle of three such points of pixels of one 2x2 quad proves the
// target centre p when p lies inside (or on) its moved corners: the bound is its farthest corner z.
// The moved positions carry the motion's float rounding (~1e-4 px at 2000 px; StaticMotion), which
// the test does not widen or shrink for: a gap narrower than that is not resolved (a margin would
// also reject the pixel centres that lie on the shared edge of two proving triangles, measured:
// 1e-3 px cost 15 % of the proven culls on the crowd walk).
// p inside (or on) the triangle of corners (x[i], y[i]) given relative to p: the three edge
// functions (x_a y_b - y_a x_b with p at the origin) have the sign of the area, or are 0. The
// coordinates are a few pixels: float products are exact to ~1e-7 px, far below the motion's rounding.
inline bool InsideTriangle(const float* x, const float* y) {
  const float e0 = x[0] * y[1] - y[0] * x[1], e1 = x[1] * y[2] - y[1] * x[2], e2 = x[2] * y[0] - y[2] * x[0];
  const float area = e0 + e1 + e2;
  if (area > 0.0f) return e0 >= 0.0f && e1 >= 0.0f && e2 >= 0.0f;
  if (area < 0.0f) return e0 <= 0.0f && e1 <= 0.0f && e2 <= 0.0f;
  return false;  // degenerate (or NaN): proves nothing
}

// The quad of pixels (x0, y0) .. (x0 + 1, y0 + 1) for surface `id` (layer `pref` tried first at each
// corner): the two triangles of the diagonal 0-2, then those of 1-3 (a non-convex moved quad, or a
// missing corner). The first proof's bound, or +inf.
inline float QuadBound(const DepthWarpLayer* layers, int num_layers, int pref, std::int32_t id, int x0, int y0,
                       float px, float py) {
  const int w = layers[0].packed.width;
  float cx[4], cy[4], cz[4];
  bool ok[4];
  int n_ok = 0;
  for (int k = 0; k < 4; ++k) {
    const int xx = x0 + (k == 1 || k == 2), yy = y0 + (k >= 2);
    const std::ptrdiff_t i = std::ptrdiff_t(yy) * w + xx;
    const float* t = nullptr;
    if (layers[pref].surface.data[i] == id && layers[pref].packed.data[i * 4 + 2] > 0.0f) {
      t = layers[pref].packed.data + i * 4;
    } else {
      for (int l = 0; l < num_layers && t == nullptr; ++l) {
        if (layers[l].surface.data[i] == id && layers[l].packed.data[i * 4 + 2] > 0.0f) t = layers[l].packed.data + i * 4;
      }
    }
    ok[k] = t != nullptr;
    if (!ok[k]) continue;
    ++n_ok;
    // Moved centre relative to p: (xx + 0.5 - px) is exact (a few pixels), then the motion.
    cx[k] = (float(xx) + 0.5f - px) + t[0], cy[k] = (float(yy) + 0.5f - py) + t[1], cz[k] = t[2];
  }
  if (n_ok < 3) return kInf;
  static constexpr int kTri[4][3] = {{0, 1, 2}, {0, 2, 3}, {0, 1, 3}, {1, 2, 3}};
  for (const auto& tri : kTri) {
    if (!(ok[tri[0]] && ok[tri[1]] && ok[tri[2]])) continue;
    const float tx[3] = {cx[tri[0]], cx[tri[1]], cx[tri[2]]}, ty[3] = {cy[tri[0]], cy[tri[1]], cy[tri[2]]};
    if (InsideTriangle(tx, ty)) return std::max(cz[tri[0]], std::max(cz[tri[1]], cz[tri[2]]));
  }
  return kInf;
}

// The next float up (z > 0, finite): one ulp.
inline float NextUp(float z) {
  std::uint32_t u;
  std::memcpy(&u, &z, 4);
  ++u;
  std::memcpy(&z, &u, 4);
  return z;
}

// Sample of source pixel S (index `pixel`) in layer ls converged at p. First the quad around p's
// preimage p - V(S) for S's surface (the common case: one surface around S); then the four quads
// around S for S's surface; then every surface of those quads' corners in any layer (p beyond S's
// surface's edge: the hidden surface continues behind the occluder, or a neighbour covers p). The
// least bound found at the first stage that finds one, one float ulp up (z_dst is rounded to
// nearest); +inf if none.
inline float ProvenBound(const DepthWarpLayer* layers, int num_layers, int ls, std::ptrdiff_t pixel, float px,
                         float py) {
  const int w = layers[0].packed.width, h = layers[0].packed.height;
  if (w < 2 || h < 2) return kInf;
  const int sx = int(pixel % w), sy = int(pixel / w);
  const std::int32_t own = layers[ls].surface.data[pixel];
  const float* ts = layers[ls].packed.data + pixel * 4;
  const int qx = std::clamp(int(std::floor(px - ts[0] - 0.5f)), 0, w - 2);
  const int qy = std::clamp(int(std::floor(py - ts[1] - 0.5f)), 0, h - 2);
  float best = own >= 0 ? QuadBound(layers, num_layers, ls, own, qx, qy, px, py) : kInf;
  if (best == kInf && own >= 0) {
    for (int oy = -1; oy <= 0; ++oy) {
      for (int ox = -1; ox <= 0; ++ox) {
        const int x0 = sx + ox, y0 = sy + oy;
        if (x0 < 0 || y0 < 0 || x0 + 1 >= w || y0 + 1 >= h || (x0 == qx && y0 == qy)) continue;
        best = std::min(best, QuadBound(layers, num_layers, ls, own, x0, y0, px, py));
      }
    }
  }
  if (best == kInf && own < 0) {
    // Empty or far-plane sample (the sky): another surface can prove p only at its edge, where a
    // corner of the preimage quad carries it in some layer (else nothing is proven: the common case).
    bool any = false;
    for (int k = 0; k < 4 && !any; ++k) {
      const std::ptrdiff_t i = std::ptrdiff_t(qy + (k >> 1)) * w + qx + (k & 1);
      for (int l = 0; l < num_layers && !any; ++l) any = layers[l].surface.data[i] >= 0;
    }
    if (!any) return kInf;
  }
  if (best == kInf) {
    for (int qq = 0; qq < 5; ++qq) {
      const int x0 = qq == 4 ? qx : sx - (qq & 1), y0 = qq == 4 ? qy : sy - (qq >> 1);
      if (x0 < 0 || y0 < 0 || x0 + 1 >= w || y0 + 1 >= h) continue;
      // A triangle holds corner 0 or 2 (of the diagonal pair): their ids are the candidates.
      for (int c = 0; c < 4; c += 2) {
        const std::ptrdiff_t i = std::ptrdiff_t(y0 + (c >> 1)) * w + x0 + (c >> 1);
        for (int l = 0; l < num_layers; ++l) {
          const std::int32_t id = layers[l].surface.data[i];
          if (id < 0 || id == own || !(layers[l].packed.data[i * 4 + 2] > 0.0f)) continue;
          best = std::min(best, QuadBound(layers, num_layers, l, id, x0, y0, px, py));
        }
      }
    }
  }
  return best < kInf ? NextUp(best) : kInf;
}

// DepthWarpSeen: may a sample at depth z be accepted at target pixel centre (px, py)? layer0 is
// the source's layer 0 (its z_dst is the target depth of the surface the source saw at a pixel).
inline bool SeenInFront(const DepthWarpSeen& s, const DepthWarpLayer& layer0, float px, float py, float z) {
  const double* a = s.src_from_dst;
  const double tx = (px - s.dst_cx) / s.dst_fx * z, ty = (py - s.dst_cy) / s.dst_fy * z, tz = z;
  // X and the target centre A (the translation column) in source camera coordinates.
  const double bx = a[0] * tx + a[1] * ty + a[2] * tz + a[3];
  const double by = a[4] * tx + a[5] * ty + a[6] * tz + a[7];
  const double bz = a[8] * tx + a[9] * ty + a[10] * tz + a[11];
  double ax = a[3], ay = a[7], az = a[11];
  if (!(bz > 0.0)) return false;
  double t0 = 0.0;  // A's parameter on the target ray (0 = the target centre, 1 = X)
  const double zc = s.near_fraction * bz;
  if (az < zc) {  // clip the segment at source depth zc (bz > zc > az)
    t0 = (zc - az) / (bz - az);
    ax += t0 * (bx - ax), ay += t0 * (by - ay), az = zc;
  }
  const double W = s.src_width, H = s.src_height;
  const double ua = s.src_fx * ax / az + s.src_cx, va = s.src_fy * ay / az + s.src_cy;
  if (ua >= 0.0 && va >= 0.0 && ua <= W && va <= H) return true;
  // The projected segment leaves the image: where (parameter l from X's end, Liang-Barsky)?
  const double ub = s.src_fx * bx / bz + s.src_cx, vb = s.src_fy * by / bz + s.src_cy;
  const double du = ua - ub, dv = va - vb;
  double l = 1.0;
  if (du < 0.0 && ub + du < 0.0) l = std::min(l, -ub / du);
  if (du > 0.0 && ub + du > W) l = std::min(l, (W - ub) / du);
  if (dv < 0.0 && vb + dv < 0.0) l = std::min(l, -vb / dv);
  if (dv > 0.0 && vb + dv > H) l = std::min(l, (H - vb) / dv);
  l = std::max(0.0, l);
  // Source depth at the exit (inverse depth is affine in screen space), then its target depth
  // (target depth is linear along the target ray: t0 + t (1 - t0) of z).
  const double ze = 1.0 / (l / az + (1.0 - l) / bz);
  const double t = std::fabs(bz - az) > 1e-12 * bz ? (ze - az) / (bz - az) : 1.0 - l;
  const double ze_dst = (t0 + t * (1.0 - t0)) * z;
  const int ix = std::min(int(W) - 1, std::max(0, int(ub + l * du)));
  const int iy = std::min(int(H) - 1, std::max(0, int(vb + l * dv)));
  const float d0 = layer0.packed.data[(std::ptrdiff_t(iy) * layer0.packed.width + ix) * 4 + 2];
  // Seen unless the ray leaves the source's view at (or behind) a fraction of the depth of the
  // surface the source saw at that border pixel: that surface may continue outside the frame.
  return !(d0 > 0.0f) || ze_dst < s.border_fraction * double(d0);
}

inline void AtomicMin(std::uint64_t* p, std::uint64_t v) {
  std::uint64_t cur = __atomic_load_n(p, __ATOMIC_RELAXED);
  while (v < cur && !__atomic_compare_exchange_n(p, &cur, v, true, __ATOMIC_RELAXED, __ATOMIC_RELAXED)) {
  }
}

inline std::uint64_t Key(float z, int layer) {
  std::uint32_t bits;
  std::memcpy(&bits, &z, 4);
  return (std::uint64_t(bits) << 32) | std::uint32_t(layer);
}

struct ScreenVertex {
  double x, y, inv_z;
};

// Depth-tested triangle: pixel centres inside (either orientation; edges included), 1/z affine.
void RasterTriangle(const ScreenVertex& a, const ScreenVertex& b, const ScreenVertex& c, int layer,
                    const ImageView<std::uint64_t>& key) {
  const double area = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
  if (!(std::fabs(area) > 1e-12)) return;
  const double inv_area = 1.0 / area;
  const int x0 = std::max(0, int(std::ceil(std::min({a.x, b.x, c.x}) - 0.5)));
  const int x1 = std::min(key.width - 1, int(std::floor(std::max({a.x, b.x, c.x}) - 0.5)));
  const int y0 = std::max(0, int(std::ceil(std::min({a.y, b.y, c.y}) - 0.5)));
  const int y1 = std::min(key.height - 1, int(std::floor(std::max({a.y, b.y, c.y}) - 0.5)));
  for (int y = y0; y <= y1; ++y) {
    const double py = y + 0.5;
    std::uint64_t* row = key.Row(y);
    for (int x = x0; x <= x1; ++x) {
      const double px = x + 0.5;
      // Barycentrics (normalised by the signed area: all >= 0 inside for either orientation).
      const double l0 = ((b.x - px) * (c.y - py) - (b.y - py) * (c.x - px)) * inv_area;
      const double l1 = ((c.x - px) * (a.y - py) - (c.y - py) * (a.x - px)) * inv_area;
      const double l2 = 1.0 - l0 - l1;
      if (l0 < 0.0 || l1 < 0.0 || l2 < 0.0) continue;
      const double iz = l0 * a.inv_z + l1 * b.inv_z + l2 * c.inv_z;
      if (!(iz > 0.0)) continue;
      AtomicMin(&row[x], Key(float(1.0 / iz), layer));
    }
  }
}

}  // namespace

namespace {
// One row of DepthWarpMotion, per-object transforms: the general per-pixel path (double precision).
void MotionRowObjects(const float* d, const std::int32_t* id, const DepthWarpMover& mover, int y, int w, float* out) {
  for (int x = 0; x < w; ++x) {
    float* o = out + 4 * x;
    o[0] = o[1] = o[2] = o[3] = 0.0f;
    if (!(d[x] > 0.0f)) continue;
    const double xi = x + 0.5, yi = y + 0.5;
    double xo, yo, zo;
    if (!MovePixel(mover, xi, yi, d[x], id[x], &xo, &yo, &zo)) continue;
    o[0] = float(xo - xi);
    o[1] = float(yo - yi);
    o[2] = float(zo);
  }
}

// Static scene: point_in_dst = z * (A * ray) + t with ray = ((x + 0.5 - cx) / fx, ry, 1), i.e.
// z * (c + rx * A0) + t per row; float32 arithmetic, branch-free so that it vectorises (the
// motion's float rounding is ~1e-4 px at 2000 px; z_dst of an identity transform is exact).
struct StaticMotion {
  const DepthWarpMover* mover;
  float a0x, a0y, a0z, tx, ty, tz, fx, fy, cx, cy, scx;
  explicit StaticMotion(const DepthWarpMover& m) : mover(&m) {
    const Camera& s = *m.src;
    const Camera& dcam = *m.dst;
    const double* a = m.dst_from_src;
    a0x = float(a[0] / s.fx), a0y = float(a[4] / s.fx), a0z = float(a[8] / s.fx);
    tx = float(a[3]), ty = float(a[7]), tz = float(a[11]);
    fx = float(dcam.fx), fy = float(dcam.fy), cx = float(dcam.cx), cy = float(dcam.cy);
    scx = float(s.cx);
  }
  void Row(const float* d, int y, int w, float* o) const {
    const Camera& s = *mover->src;
    const double* a = mover->dst_from_src;
    const double ry = (y + 0.5 - s.cy) / s.fy;
    const float cxr = float(a[1] * ry + a[2]), cyr = float(a[5] * ry + a[6]), czr = float(a[9] * ry + a[10]);
    const float yi = float(y) + 0.5f;
    int x = 0;
#if defined(__SSE2__)
    // Four pixels at a time, the scalar loop's operations in the same order (so the same bits;
    // tests/depthwarp/test_depthwarp_speed.py checks against the scalar loop). GCC does not vectorise the
    // scalar loop: with trapping math it keeps the comparisons' control flow.
    {
      const __m128 v_cxr = _mm_set1_ps(cxr), v_cyr = _mm_set1_ps(cyr), v_czr = _mm_set1_ps(czr);
      const __m128 v_a0x = _mm_set1_ps(a0x), v_a0y = _mm_set1_ps(a0y), v_a0z = _mm_set1_ps(a0z);
      const __m128 v_tx = _mm_set1_ps(tx), v_ty = _mm_set1_ps(ty), v_tz = _mm_set1_ps(tz);
      const __m128 v_fx = _mm_set1_ps(fx), v_fy = _mm_set1_ps(fy), v_cx = _mm_set1_ps(cx), v_cy = _mm_set1_ps(cy);
      const __m128 v_scx = _mm_set1_ps(scx), v_yi = _mm_set1_ps(yi), half = _mm_set1_ps(0.5f);
      const __m128 zero = _mm_setzero_ps(), one = _mm_set1_ps(1.0f), big = _mm_set1_ps(kDepthWarpMaxMotion);
      const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
      for (; x + 4 <= w && mover->simd; x += 4) {
        const __m128 z = _mm_loadu_ps(d + x);
        const __m128 xc = _mm_add_ps(_mm_cvtepi32_ps(_mm_setr_epi32(x, x + 1, x + 2, x + 3)), half);
        const __m128 rx = _mm_sub_ps(xc, v_scx);
        const __m128 px = _mm_add_ps(_mm_mul_ps(z, _mm_add_ps(v_cxr, _mm_mul_ps(rx, v_a0x))), v_tx);
        const __m128 py = _mm_add_ps(_mm_mul_ps(z, _mm_add_ps(v_cyr, _mm_mul_ps(rx, v_a0y))), v_ty);
        const __m128 pz = _mm_add_ps(_mm_mul_ps(z, _mm_add_ps(v_czr, _mm_mul_ps(rx, v_a0z))), v_tz);
        const __m128 pos = _mm_cmpgt_ps(pz, zero);
        const __m128 q = _mm_or_ps(_mm_and_ps(pos, pz), _mm_andnot_ps(pos, one));
        const __m128 mx = _mm_sub_ps(_mm_add_ps(_mm_mul_ps(v_fx, _mm_div_ps(px, q)), v_cx), xc);
        const __m128 my = _mm_sub_ps(_mm_add_ps(_mm_mul_ps(v_fy, _mm_div_ps(py, q)), v_cy), v_yi);
        const __m128 ok = _mm_and_ps(_mm_and_ps(_mm_cmpgt_ps(z, zero), pos),
                                     _mm_and_ps(_mm_cmplt_ps(_mm_and_ps(mx, abs_mask), big),
                                                _mm_cmplt_ps(_mm_and_ps(my, abs_mask), big)));
        __m128 r0 = _mm_and_ps(ok, mx), r1 = _mm_and_ps(ok, my), r2 = _mm_and_ps(ok, pz), r3 = zero;
        _MM_TRANSPOSE4_PS(r0, r1, r2, r3);  // -> one (mx, my, z_dst, 0) per pixel
        _mm_storeu_ps(o + 4 * x, r0);
        _mm_storeu_ps(o + 4 * x + 4, r1);
        _mm_storeu_ps(o + 4 * x + 8, r2);
        _mm_storeu_ps(o + 4 * x + 12, r3);
      }
    }
#endif
    for (; x < w; ++x) {
      const float z = d[x];
      const float rx = float(x) + 0.5f - scx;
      const float px = z * (cxr + rx * a0x) + tx;
      const float py = z * (cyr + rx * a0y) + ty;
      const float pz = z * (czr + rx * a0z) + tz;
      // px / q, not px * (1 / q): for z near float max, 1 / q is subnormal and reads as 0
      // when another library in the process has set flush-to-zero (pytest-xdist workers): the
      // motion was then off by the principal-point offset (tests/test_stress.py).
      const float q = pz > 0.0f ? pz : 1.0f;
      const float mx = fx * (px / q) + cx - (float(x) + 0.5f);
      const float my = fy * (py / q) + cy - yi;
      // NaN-safe: every comparison with NaN is false.
      const bool ok = z > 0.0f && pz > 0.0f && std::fabs(mx) < kDepthWarpMaxMotion && std::fabs(my) < kDepthWarpMaxMotion;
      o[4 * x + 0] = ok ? mx : 0.0f;
      o[4 * x + 1] = ok ? my : 0.0f;
      o[4 * x + 2] = ok ? pz : 0.0f;
      o[4 * x + 3] = 0.0f;
    }
  }
};

// Row y of the packed buffer (either path).
inline void MotionRow(const ImageView<const float>& depth, const ImageView<const std::int32_t>* ids,
                      const DepthWarpMover& mover, const StaticMotion& st, int y, const ImageView<float>& packed) {
  if (ids) {
    MotionRowObjects(depth.Row(y), ids->Row(y), mover, y, depth.width, packed.Row(y));
  } else {
    st.Row(depth.Row(y), y, depth.width, packed.Row(y));
  }
}
}  // namespace

void DepthWarpCountBadDepth(const float* depth, std::int64_t n, std::int64_t* nonfinite, std::int64_t* negative) {
  std::atomic<std::int64_t> bad{0}, neg{0};
  ParallelFor(n, std::int64_t(1) << 16, [&](std::int64_t a, std::int64_t b) {
    std::int64_t lb = 0, ln = 0;
    for (std::int64_t i = a; i < b; ++i) {
      const float v = depth[i];
      lb += !(std::fabs(v) <= std::numeric_limits<float>::max());  // NaN or +-inf
      ln += v < 0.0f;
    }
    bad += lb, neg += ln;
  });
  *nonfinite = bad, *negative = neg;
}

void DepthWarpMotion(const ImageView<const float>& depth, const ImageView<const std::int32_t>* ids,
                     const DepthWarpMover& mover, const ImageView<float>& packed) {
  const StaticMotion st(mover);
  ParallelFor(depth.height, RowGrain(depth.width), [&](std::int64_t r0, std::int64_t r1) {
    for (int y = int(r0); y < int(r1); ++y) MotionRow(depth, ids, mover, st, y, packed);
  });
}

DepthWarpAxes DepthWarpChooseAxes(const ImageView<const float>& packed, bool try_oriented, int sample_grid,
                                  float rot[4]) {
  rot[0] = 1, rot[1] = 0, rot[2] = 0, rot[3] = 1;
  if (!try_oriented) return DepthWarpAxes::kAxisAligned;  // no full pass: the mipmap's top is the global box
  const int w = packed.width, h = packed.height;
  // Global axis-aligned box (needed for the area comparison and the empty case).
  std::mutex mu;
  double ax0 = kInf, ay0 = kInf, ax1 = -kInf, ay1 = -kInf;
  ParallelFor(h, RowGrain(w), [&](std::int64_t r0, std::int64_t r1) {
    float lx0 = kInf, ly0 = kInf, lx1 = -kInf, ly1 = -kInf;
    for (int y = int(r0); y < int(r1); ++y) {
      const float* s = packed.Row(y);
      for (int x = 0; x < w; ++x, s += 4) {
        if (!(s[2] > 0.0f)) continue;
        lx0 = std::min(lx0, s[0]), lx1 = std::max(lx1, s[0]);
        ly0 = std::min(ly0, s[1]), ly1 = std::max(ly1, s[1]);
      }
    }
    std::lock_guard<std::mutex> lock(mu);  // min / max: the order of the chunks does not matter
    ax0 = std::min<double>(ax0, lx0), ax1 = std::max<double>(ax1, lx1);
    ay0 = std::min<double>(ay0, ly0), ay1 = std::max<double>(ay1, ly1);
  });
  if (!(ax0 <= ax1)) return DepthWarpAxes::kEmpty;
  // PCA of the motions at a fixed grid of pixels (sec. 3.3: "a small number (e.g., 64) suffices").
  double sx = 0, sy = 0, sxx = 0, sxy = 0, syy = 0;
  int n = 0;
  for (int j = 0; j < sample_grid; ++j) {
    const int y = std::min(h - 1, int((j + 0.5) * h / sample_grid));
    for (int i = 0; i < sample_grid; ++i) {
      const int x = std::min(w - 1, int((i + 0.5) * w / sample_grid));
      const float* s = packed.Row(y) + 4 * x;
      if (!(s[2] > 0.0f)) continue;
      sx += s[0], sy += s[1], sxx += double(s[0]) * s[0], sxy += double(s[0]) * s[1], syy += double(s[1]) * s[1];
      ++n;
    }
  }
  if (n < 2) return DepthWarpAxes::kDegeneratePca;
  const double mx = sx / n, my = sy / n;
  const double a = sxx / n - mx * mx, b = sxy / n - mx * my, c = syy / n - my * my;
  const double half_gap = std::sqrt(0.25 * (a - c) * (a - c) + b * b);  // (lambda1 - lambda2) / 2
  // No principal direction: all sampled motions equal, or an isotropic spread.
  if (!(half_gap > 1e-6 * (0.5 * (a + c)) + 1e-12)) return DepthWarpAxes::kDegeneratePca;
  const double theta = 0.5 * std::atan2(2.0 * b, a - c);
  const float ct = float(std::cos(theta)), st = float(std::sin(theta));
  const float r[4] = {ct, st, -st, ct};  // u = e1 . v, w = e2 . v
  double ou0 = kInf, ow0 = kInf, ou1 = -kInf, ow1 = -kInf;
  ParallelFor(h, RowGrain(w), [&](std::int64_t r0, std::int64_t r1) {
    float lu0 = kInf, lw0 = kInf, lu1 = -kInf, lw1 = -kInf;
    for (int y = int(r0); y < int(r1); ++y) {
      const float* s = packed.Row(y);
      for (int x = 0; x < w; ++x, s += 4) {
        if (!(s[2] > 0.0f)) continue;
        const float u = r[0] * s[0] + r[1] * s[1], v = r[2] * s[0] + r[3] * s[1];
        lu0 = std::min(lu0, u), lu1 = std::max(lu1, u);
        lw0 = std::min(lw0, v), lw1 = std::max(lw1, v);
      }
    }
    std::lock_guard<std::mutex> lock(mu);
    ou0 = std::min<double>(ou0, lu0), ou1 = std::max<double>(ou1, lu1);
    ow0 = std::min<double>(ow0, lw0), ow1 = std::max<double>(ow1, lw1);
  });
  const double aab_area = (ax1 - ax0) * (ay1 - ay0), ob_area = (ou1 - ou0) * (ow1 - ow0);
  if (!(ob_area < aab_area)) return DepthWarpAxes::kOrientedNotSmaller;
  std::copy(r, r + 4, rot);
  return DepthWarpAxes::kOriented;
}

namespace {
// One 2x2 block of the packed buffer into (u0, w0, u1, w1, zmin); Identity: no rotation.
template <bool Identity>
inline void Level1Texel(const float* s, int n, const float* r, float* o, float* oz) {
  float u0 = kInf, w0 = kInf, u1 = -kInf, w1 = -kInf, z0 = kInf;
  for (int k = 0; k < n; ++k, s += 4) {
    const bool ok = s[2] > 0.0f;
    const float u = Identity ? s[0] : r[0] * s[0] + r[1] * s[1];
    const float v = Identity ? s[1] : r[2] * s[0] + r[3] * s[1];
    u0 = std::min(u0, ok ? u : kInf), u1 = std::max(u1, ok ? u : -kInf);
    w0 = std::min(w0, ok ? v : kInf), w1 = std::max(w1, ok ? v : -kInf);
    z0 = std::min(z0, ok ? s[2] : kInf);
  }
  o[0] = std::min(o[0], u0), o[1] = std::min(o[1], w0), o[2] = std::max(o[2], u1), o[3] = std::max(o[3], w1);
  *oz = std::min(*oz, z0);
}

// Texel row j of level 1 from packed rows 2j and 2j + 1 (the last one if it exists).
template <bool Identity>
inline void Level1Row(const ImageView<const float>& packed, const float rot[4], int j, const ImageView<float>& out,
                      const ImageView<float>& out_z) {
  const int w = packed.width, h = packed.height;
  float* o = out.Row(j);
  float* oz = out_z.Row(j);
  for (int i = 0; i < out.width; ++i) {
    o[4 * i + 0] = kInf, o[4 * i + 1] = kInf, o[4 * i + 2] = -kInf, o[4 * i + 3] = -kInf;
    oz[i] = kInf;
  }
  for (int y = 2 * j; y < std::min(h, 2 * j + 2); ++y) {
    const float* s = packed.Row(y);
    const int pairs = w / 2;
    for (int i = 0; i < pairs; ++i) Level1Texel<Identity>(s + 8 * i, 2, rot, o + 4 * i, oz + i);
    if (w & 1) Level1Texel<Identity>(s + 8 * pairs, 1, rot, o + 4 * pairs, oz + pairs);
  }
}

template <bool Identity>
void MipLevel1Impl(const ImageView<const float>& packed, const float rot[4], const ImageView<float>& out,
                   const ImageView<float>& out_z) {
  ParallelFor(out.height, RowGrain(out.width * 2), [&](std::int64_t a, std::int64_t b) {
    for (int j = int(a); j < int(b); ++j) Level1Row<Identity>(packed, rot, j, out, out_z);
  });
}
}  // namespace

void DepthWarpMipLevel1(const ImageView<const float>& packed, const float rot[4], const ImageView<float>& out,
                        const ImageView<float>& out_z) {
  if (rot[0] == 1.0f && rot[1] == 0.0f && rot[2] == 0.0f && rot[3] == 1.0f) {
    MipLevel1Impl<true>(packed, rot, out, out_z);
  } else {
    MipLevel1Impl<false>(packed, rot, out, out_z);
  }
}

void DepthWarpMotionMipLevel1(const ImageView<const float>& depth, const ImageView<const std::int32_t>* ids,
                              const DepthWarpMover& mover, const ImageView<float>& packed, const ImageView<float>& out,
                              const ImageView<float>& out_z) {
  const StaticMotion st(mover);
  const float identity[4] = {1, 0, 0, 1};
  const ImageView<const float> pv(packed.data, packed.height, packed.width, 4);
  // Chunks of level-1 rows: the two packed rows of each are written and then read while in cache.
  ParallelFor(out.height, RowGrain(out.width * 2), [&](std::int64_t a, std::int64_t b) {
    for (int j = int(a); j < int(b); ++j) {
      for (int y = 2 * j; y < std::min(depth.height, 2 * j + 2); ++y) MotionRow(depth, ids, mover, st, y, packed);
      Level1Row<true>(pv, identity, j, out, out_z);
    }
  });
}

void DepthWarpMipDown(const ImageView<const float>& in, const ImageView<const float>& in_z, const ImageView<float>& out,
                      const ImageView<float>& out_z) {
  ParallelFor(out.height, RowGrain(out.width * 2), [&](std::int64_t a, std::int64_t b) {
    for (int j = int(a); j < int(b); ++j) {
      float* o = out.Row(j);
      float* oz = out_z.Row(j);
      const int y0 = 2 * j, y1 = std::min(in.height, 2 * j + 2);
      for (int i = 0; i < out.width; ++i, o += 4) {
        float u0 = kInf, w0 = kInf, u1 = -kInf, w1 = -kInf, z0 = kInf;
        const int x0 = 2 * i, x1 = std::min(in.width, 2 * i + 2);
        for (int y = y0; y < y1; ++y) {
          const float* s = in.Row(y) + 4 * x0;
          const float* sz = in_z.Row(y);
          for (int x = x0; x < x1; ++x, s += 4) {
            u0 = std::min(u0, s[0]), w0 = std::min(w0, s[1]), u1 = std::max(u1, s[2]), w1 = std::max(w1, s[3]);
            z0 = std::min(z0, sz[x]);
          }
        }
        o[0] = u0, o[1] = w0, o[2] = u1, o[3] = w1;
        oz[i] = z0;
      }
    }
  });
}

void DepthWarpBackward(const DepthWarpLayer* layers, int num_layers, const DepthWarpOptions& opt,
                       const ImageView<float>& depth_out, const ImageView<std::int8_t>& layer_out,
                       DepthWarpCounters* counters, const ImageView<float>* proven_out) {
  const int w = depth_out.width, h = depth_out.height;
  constexpr int kMaxT = kDepthWarpMaxTile;
  const int kT = std::max(1, std::min(kMaxT, opt.tile));
  const int tiles_x = (w + kT - 1) / kT, tiles_y = (h + kT - 1) / kT;
  const float thr2 = opt.threshold * opt.threshold;
  const float edge2 = opt.edge_motion > 0.0f ? opt.edge_motion * opt.edge_motion : 0.0f;
  const int n_seeds = std::max(1, opt.seeds);
  const float inv_n = 1.0f / float(n_seeds);
  const bool prove = proven_out != nullptr;
  std::atomic<std::int64_t> converged{0}, early{0}, searched{0}, samples{0}, lookups{0};
  const std::int64_t grain = std::max<std::int64_t>(1, kMinPixelsPerTask / (std::int64_t(kT) * kT * tiles_x));
  ParallelFor(tiles_y, grain, [&](std::int64_t r0, std::int64_t r1) {
    std::int64_t c_conv = 0, c_early = 0, c_search = 0, c_samples = 0, c_lookups = 0;
    float best[kMaxT * kMaxT];
    float proven[kMaxT * kMaxT];  // least proven bound (proven_out only)
    std::int64_t tried[kMaxT * kMaxT];  // the last sample (source pixel, layer) a proof was tried for
    std::int8_t best_layer[kMaxT * kMaxT];
    for (int ty = int(r0); ty < int(r1); ++ty) {
      const int y0 = ty * kT, y1 = std::min(h, y0 + kT);
      for (int tx = 0; tx < tiles_x; ++tx) {
        const int x0 = tx * kT, x1 = std::min(w, x0 + kT);
        std::fill(best, best + kT * kT, kInf);
        if (prove) std::fill(proven, proven + kT * kT, kInf), std::fill(tried, tried + kT * kT, std::int64_t(-1));
        std::fill(best_layer, best_layer + kT * kT, std::int8_t(-1));
        for (int j = 0; j < num_layers; ++j) {
          const DepthWarpLayer& l = layers[j];
          // Fig. 5 for the whole tile: the tile's source region is the union of its pixels'
          // regions, so the tile bound is conservative for each of them.
          Bound bt = GlobalBound(l);
          if (!bt.Valid()) continue;
          const float cx0 = x0 + 0.5f, cy0 = y0 + 0.5f, cx1 = x1 - 0.5f, cy1 = y1 - 0.5f;
          bool empty = false;
          if (opt.tight) {
            for (int k = 0; k < opt.steps && !empty; ++k) {
              bt = Intersect(bt, LocalBound(l, SourceRegion(l, bt, cx0, cy0, cx1, cy1)));
              empty = !bt.Valid();
            }
          } else {
            empty = !Overlaps(l, SourceRegion(l, bt, cx0, cy0, cx1, cy1));
          }
          if (empty) continue;
          if (opt.skip_farther && j > 0) {
            // Every pixel of the tile would skip this layer (bt.zmin >= its depth, first test of the
            // pixel loop): skip it here, before the prefetch of rows that would not be read.
            float farthest = 0.0f;
            for (int k = 0; k < kT * kT; ++k) farthest = std::max(farthest, best[k]);
            if (prove) {  // nor prove a nearer bound (proven depths: see search_from)
              for (int k = 0; k < kT * kT; ++k) farthest = std::max(farthest, proven[k]);
            }
            if (bt.zmin >= farthest) continue;
          }
          const bool tile_one = std::max(bt.u1 - bt.u0, bt.w1 - bt.w0) < opt.early_exit;
          const bool step = opt.tight && !tile_one && opt.steps > 0 && opt.pixel_step;
          const Region mb = MotionBox(l, bt);  // SourceRegion(l, bt, p, p) = p - (x1, y1) .. p - (x0, y0)
          {
            // Prefetch the source rows the searches will read first (the tile shifted by the
            // bound's centre motion): a tile's short row segments in several rows defeat the
            // hardware prefetcher (measured: -8 % warp time, 960x540, L = 3, one thread).
            const float uc = 0.5f * (bt.u0 + bt.u1), wc = 0.5f * (bt.w0 + bt.w1);
            const float vx = l.rot[0] * uc + l.rot[2] * wc, vy = l.rot[1] * uc + l.rot[3] * wc;
            const int sx0 = int(std::floor(x0 - vx)), sx1 = int(std::floor(x1 - vx));
            const int sy0 = int(std::floor(y0 - vy));
            const int pw = l.packed.width, ph = l.packed.height;
            const int ax = std::max(0, sx0), bx = std::min(pw - 1, sx1);
            if (ax <= bx) {
              for (int yy = std::max(0, sy0); yy < std::min(ph, sy0 + (y1 - y0)); ++yy) {
                const float* row = l.packed.Row(yy);
                for (int xx = ax; xx <= bx; xx += 4) __builtin_prefetch(row + 4 * xx);
                __builtin_prefetch(row + 4 * bx);
              }
            }
          }
          // One fixed-point search of pixel (px, py) in layer j from the seed motion (vx, vy): a
          // converged sample nearer than the pixel's best becomes its best (a sample from a deeper
          // layer only if the unseen-space test SeenInFront accepts it). With proven_out, a layer
          // that skip_farther rules out for the depth is still searched where it may prove a nearer
          // bound (its own samples converge there; live = false: the search does not touch the
          // depth, which stays the same as without proven_out).
          auto search_from = [&](float px, float py, int at, float vx, float vy, bool live) {
            float z;
            int from;
            std::ptrdiff_t pixel;
            ++c_samples;
            const bool conv =
                FixedPointSearch(layers, j, px, py, px - vx, py - vy, opt.iters, thr2, edge2, &z, &from, &pixel, &c_lookups);
            if (live && conv && z < best[at] && (from == 0 || opt.seen == nullptr || SeenInFront(*opt.seen, layers[0], px, py, z))) {
              best[at] = z;
              best_layer[at] = std::int8_t(from);
            }
            // A proof bounds the depth by a triangle corner's z >= z: none can beat proven[at] otherwise.
            // No unseen-space test: a proven point is on p's ray whatever lies in front of it.
            // Seeds that converge to a sample already tried at p (the common case) would repeat its proof.
            if (prove && conv && z < proven[at] && tried[at] != std::int64_t(pixel) * 128 + from) {
              tried[at] = std::int64_t(pixel) * 128 + from;
              proven[at] = std::min(proven[at], ProvenBound(layers, num_layers, from, pixel, px, py));
            }
          };
          if (tile_one) {
            // Homogeneous motion over the whole tile: every pixel runs one search from the tile
            // bound's centre (the general loop below with b = bt, one seed; the same arithmetic).
            const float eu = bt.u1 - bt.u0, ew = bt.w1 - bt.w0;
            const float u = bt.u0 + 0.5f * eu, w1 = bt.w0 + 0.5f * ew;
            const float vx = l.rot[0] * u + l.rot[2] * w1, vy = l.rot[1] * u + l.rot[3] * w1;
            for (int y = y0; y < y1; ++y) {
              const float py = y + 0.5f;
              for (int x = x0; x < x1; ++x) {
                const float px = x + 0.5f;
                const int at = (y - y0) * kT + (x - x0);
                const bool live = !(opt.skip_farther && bt.zmin >= best[at]);
                if (!live && !(prove && bt.zmin < proven[at])) continue;
                ++c_search, ++c_early;
                search_from(px, py, at, vx, vy, live);
              }
            }
            continue;
          }
          for (int y = y0; y < y1; ++y) {
            const float py = y + 0.5f;
            for (int x = x0; x < x1; ++x) {
              const float px = x + 0.5f;
              const int at = (y - y0) * kT + (x - x0);
              // No sample of this layer can be nearer than zmin: the result cannot change.
              bool live = !(opt.skip_farther && bt.zmin >= best[at]);
              if (!live && !(prove && bt.zmin < proven[at])) continue;
              Bound b = bt;
              if (step) {
                // One narrowing step of the pixel's own region (Fig. 5) from the tile bound:
                // LocalBound(SourceRegion(bt, p)) with the tile's offsets hoisted, and the four
                // texels' min z read first: a search skip_farther rules out does not need the
                // motion texels (the same result as intersecting first, for less memory traffic).
                Corners c;
                if (!PixelCorners(l, Region{px - mb.x1, py - mb.y1, px - mb.x0, py - mb.y0}, &c)) continue;
                const float zc = std::max(bt.zmin, CornersZmin(l, c));
                live = live && !(opt.skip_farther && zc >= best[at]);
                if (!live && !(prove && zc < proven[at])) continue;
                b = Intersect(b, CornersBound(l, c));
                if (!b.Valid()) continue;
              }
              ++c_search;
              const float eu = b.u1 - b.u0, ew = b.w1 - b.w0;
              const bool one = tile_one || std::max(eu, ew) < opt.early_exit;
              c_early += one;
              const int n = one ? 1 : n_seeds;
              float j1 = 0.0f, j2 = 0.0f;
              if (!one) {
                const std::uint32_t hh = Hash(opt.seed * 0x9e3779b9U ^
                                              Hash(std::uint32_t(x) * 0x85ebca6bU ^ Hash(std::uint32_t(y) ^ (std::uint32_t(j) << 24))));
                j1 = Unit(hh), j2 = Unit(Hash(hh ^ 0x68bc21ebU));
              }
              for (int k = 0; k < n; ++k) {
                float su = 0.5f, sw = 0.5f;
                if (!one) {
                  su = Frac((k + 0.5f) * inv_n + j1);
                  sw = Frac(RadicalInverse2(std::uint32_t(k)) + j2);
                }
                const float u = b.u0 + su * eu, v = b.w0 + sw * ew;
                search_from(px, py, at, l.rot[0] * u + l.rot[2] * v, l.rot[1] * u + l.rot[3] * v, live);
              }
            }
          }
        }
        for (int y = y0; y < y1; ++y) {
          float* dout = depth_out.Row(y);
          std::int8_t* lout = layer_out.Row(y);
          for (int x = x0; x < x1; ++x) {
            const int at = (y - y0) * kT + (x - x0);
            const bool ok = best_layer[at] >= 0;
            dout[x] = ok ? best[at] : 0.0f;
            lout[x] = best_layer[at];
            c_conv += ok;
          }
          if (prove) {
            float* pout = proven_out->Row(y);
            for (int x = x0; x < x1; ++x) {
              const float b = proven[(y - y0) * kT + (x - x0)];
              pout[x] = b < kInf ? b : 0.0f;
            }
          }
        }
      }
    }
    converged += c_conv, early += c_early, searched += c_search, samples += c_samples, lookups += c_lookups;
  });
  counters->converged = converged, counters->early_exit = early, counters->searched = searched;
  counters->samples = samples, counters->lookups = lookups;
}

std::int64_t DepthWarpDilate(const ImageView<const std::int8_t>& lin, int min_neighbors, const ImageView<float>& depth,
                             const ImageView<std::int8_t>& lout) {
  const int w = lin.width, h = lin.height;
  std::atomic<std::int64_t> filled{0};
  // Edge neighbours first, then diagonals: "nearest" neighbour.
  static const int kDx[8] = {-1, 1, 0, 0, -1, 1, -1, 1};
  static const int kDy[8] = {0, 0, -1, 1, -1, -1, 1, 1};
  // In place: holes and neighbours are read from lin (the warp's unmodified layers); a depth is
  // read only where lin is converged, and only holes are written, so no chunk reads what another
  // writes. ~99 % of the pixels are converged: 8 layer bytes are tested at once for a hole.
  ParallelFor(h, RowGrain(w), [&](std::int64_t r0, std::int64_t r1) {
    std::int64_t local = 0;
    for (int y = int(r0); y < int(r1); ++y) {
      const std::int8_t* row = lin.Row(y);
      for (int x = 0; x < w; ++x) {
        if (x + 8 <= w && (x & 7) == 0) {
          std::uint64_t word;
          std::memcpy(&word, row + x, 8);
          if (!(word & 0x8080808080808080ULL)) {  // no negative layer among these 8
            x += 7;
            continue;
          }
        }
        if (row[x] >= 0) continue;
        int count = 0;
        float best_edge = kInf, best_diag = kInf;
        std::int8_t layer_edge = -1, layer_diag = -1;
        for (int k = 0; k < 8; ++k) {
          const int xx = x + kDx[k], yy = y + kDy[k];
          if (xx < 0 || yy < 0 || xx >= w || yy >= h) continue;
          const std::int8_t nl = lin.Row(yy)[xx];
          if (nl < 0) continue;
          ++count;
          const float nd = depth.Row(yy)[xx];
          if (k < 4 && nd < best_edge) best_edge = nd, layer_edge = nl;
          if (k >= 4 && nd < best_diag) best_diag = nd, layer_diag = nl;
        }
        if (count >= min_neighbors) {
          depth.Row(y)[x] = layer_edge >= 0 ? best_edge : best_diag;
          lout.Row(y)[x] = layer_edge >= 0 ? layer_edge : layer_diag;
          ++local;
        }
      }
    }
    filled += local;
  });
  return filled;
}

void DepthWarpForward(DepthWarpForwardKind kind, const ImageView<const float>& depth,
                      const ImageView<const std::int32_t>* ids, const ImageView<const float>& packed,
                      const DepthWarpMover& mover, int layer, const ImageView<std::uint64_t>& key) {
  const int w = packed.width;
  ParallelFor(packed.height, RowGrain(w), [&](std::int64_t r0, std::int64_t r1) {
    for (int y = int(r0); y < int(r1); ++y) {
      const float* s = packed.Row(y);
      for (int x = 0; x < w; ++x, s += 4) {
        if (!(s[2] > 0.0f)) continue;
        if (kind == DepthWarpForwardKind::kAfw) {
          const double px = x + 0.5 + s[0], py = y + 0.5 + s[1];
          // Centres i + 0.5 in [p - 1, p + 1): i in [p - 1.5, p + 0.5).
          const int i0 = std::max(0, int(std::ceil(px - 1.5))), i1 = std::min(key.width - 1, int(std::ceil(px + 0.5)) - 1);
          const int j0 = std::max(0, int(std::ceil(py - 1.5))), j1 = std::min(key.height - 1, int(std::ceil(py + 0.5)) - 1);
          const std::uint64_t k = Key(s[2], layer);
          for (int j = j0; j <= j1; ++j) {
            for (int i = i0; i <= i1; ++i) AtomicMin(&key.Row(j)[i], k);
          }
          continue;
        }
        // VFW: the pixel's footprint expanded by half a pixel, at the pixel's depth.
        const double z = depth.Row(y)[x];
        const int id = ids ? ids->Row(y)[x] : -1;
        static const double kCx[4] = {-0.5, 1.5, 1.5, -0.5};
        static const double kCy[4] = {-0.5, -0.5, 1.5, 1.5};
        ScreenVertex v[4];
        bool ok = true;
        double bx0 = kInf, bx1 = -kInf, by0 = kInf, by1 = -kInf;
        for (int c = 0; c < 4 && ok; ++c) {
          double xo = 0.0, yo = 0.0, zo = 1.0;
          ok = MovePixel(mover, x + kCx[c], y + kCy[c], z, id, &xo, &yo, &zo);
          v[c] = {xo, yo, 1.0 / zo};
          bx0 = std::min(bx0, xo), bx1 = std::max(bx1, xo), by0 = std::min(by0, yo), by1 = std::max(by1, yo);
        }
        if (!ok || bx1 - bx0 > kDepthWarpMaxSplat || by1 - by0 > kDepthWarpMaxSplat) continue;
        if (bx1 < 0 || by1 < 0 || bx0 > key.width || by0 > key.height) continue;
        RasterTriangle(v[0], v[1], v[2], layer, key);
        RasterTriangle(v[0], v[2], v[3], layer, key);
      }
    }
  });
}

void DepthWarpDecodeKeys(const ImageView<const std::uint64_t>& key, const ImageView<float>& depth,
                         const ImageView<std::int8_t>& layer) {
  ParallelFor(key.height, RowGrain(key.width), [&](std::int64_t r0, std::int64_t r1) {
    for (int y = int(r0); y < int(r1); ++y) {
      for (int x = 0; x < key.width; ++x) {
        const std::uint64_t k = key.Row(y)[x];
        if (k == ~std::uint64_t(0)) {
          depth.Row(y)[x] = 0.0f;
          layer.Row(y)[x] = -1;
          continue;
        }
        const std::uint32_t bits = std::uint32_t(k >> 32);
        float z;
        std::memcpy(&z, &bits, 4);
        depth.Row(y)[x] = z;
        layer.Row(y)[x] = std::int8_t(std::uint32_t(k));
      }
    }
  });
}

}  // namespace ibr
