// TM texture atlas reads, float32 and 8-bit sRGB (atlas8.h).
#include "kernels/hybrid/atlas8.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <vector>

#include "ibr/colour.h"
#include "ibr/parallel.h"

namespace ibr {
namespace {



// The one atlas read loop: per pixel, the hit face's UVs interpolated with the barycentrics,
// then a bilinear read (texel centres at +0.5, clamped to the edge texels) of channel c of texel
// (x, y) through `texel(row_y, x, c)` (linear float); black where prim_id < 0, and where the hit's
// barycentrics or its face's uv are not finite (the smallest such pixel index is returned, else -1).
// A large atlas and mesh (lego's 128 MiB atlas, 30 MB of uv) are read at random: neighbouring
// pixels hit faces whose uv and cells lie far apart, so each pixel waited on three cache misses.
// The pixels go in batches through three passes: prefetch the hit faces' uv; compute the taps
// and prefetch their texels (`addr(row_y, x)`: texel (x, y)'s address); read. The same
// arithmetic as one pass per pixel, the same bits (lego's TM shade 14.0-16.6 -> 4.4-5.1 ms at 800x800).
template <class Texel, class RowOf, class Addr>
std::int64_t SampleAtlasBilinear(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels,
                                 const float* uv, int aw, int ah, RowOf row_of, Texel texel, Addr addr, float* out) {
  constexpr int kBatch = 32;
  FirstIndex first_bad;
  ParallelFor(num_pixels, 16384, [&](std::int64_t b, std::int64_t e) {
    struct Tap {
      float* o;
      int x0, x1, y0, y1;
      float ax, ay;
    };
    Tap taps[kBatch];
    for (std::int64_t s = b; s < e; s += kBatch) {
      const std::int64_t se = std::min(e, s + kBatch);
      for (std::int64_t i = s; i < se; ++i) {
        const std::int32_t f = prim_id[i];
        if (f >= 0) {
          __builtin_prefetch(uv + 6 * std::int64_t(f));
          __builtin_prefetch(uv + 6 * std::int64_t(f) + 5);
        }
      }
      int n = 0;
      for (std::int64_t i = s; i < se; ++i) {
        float* o = out + 3 * i;
        const std::int32_t f = prim_id[i];
        if (f < 0) {
          o[0] = o[1] = o[2] = 0.f;
          continue;
        }
        const double u = bary[2 * i], v = bary[2 * i + 1], w = 1.0 - u - v;
        const float* t = uv + 6 * std::int64_t(f);
        const double x = w * t[0] + u * t[2] + v * t[4], y = w * t[1] + u * t[3] + v * t[5];
        if (!std::isfinite(x) || !std::isfinite(y)) {  // non-finite bary or uv: the index would be undefined
          o[0] = o[1] = o[2] = 0.f;
          first_bad.Report(i);
          continue;
        }
        const double fx = std::clamp(x - 0.5, 0.0, double(aw - 1)), fy = std::clamp(y - 0.5, 0.0, double(ah - 1));
        Tap& tp = taps[n++];
        tp.o = o;
        tp.x0 = std::min(static_cast<int>(fx), aw - 1), tp.y0 = std::min(static_cast<int>(fy), ah - 1);
        tp.x1 = std::min(tp.x0 + 1, aw - 1), tp.y1 = std::min(tp.y0 + 1, ah - 1);
        tp.ax = float(fx - tp.x0), tp.ay = float(fy - tp.y0);
        const auto r0 = row_of(tp.y0);
        const auto r1 = row_of(tp.y1);
        __builtin_prefetch(addr(r0, tp.x0));
        __builtin_prefetch(addr(r0, tp.x1));
        __builtin_prefetch(addr(r1, tp.x0));
        __builtin_prefetch(addr(r1, tp.x1));
      }
      for (int k = 0; k < n; ++k) {
        const Tap& tp = taps[k];
        const auto r0 = row_of(tp.y0);
        const auto r1 = row_of(tp.y1);
        for (int c = 0; c < 3; ++c) {
          const float t00 = texel(r0, tp.x0, c), t01 = texel(r0, tp.x1, c), t10 = texel(r1, tp.x0, c),
                      t11 = texel(r1, tp.x1, c);
          const float top = t00 + tp.ax * (t01 - t00);
          const float bot = t10 + tp.ax * (t11 - t10);
          tp.o[c] = top + tp.ay * (bot - top);
        }
      }
    }
  });
  return first_bad.Get();
}

}  // namespace

std::int64_t SampleAtlas(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels, const float* uv,
                         ImageView<const float> atlas, float* out) {
  return SampleAtlasBilinear(
      prim_id, bary, num_pixels, uv, atlas.width, atlas.height, [&](int y) { return atlas.Row(y); },
      [](const float* row, int x, int c) { return row[3 * x + c]; },
      [](const float* row, int x) { return static_cast<const void*>(row + 3 * x); }, out);
}

std::int64_t SampleAtlasSrgb8(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels,
                              const float* uv, ImageView<const std::uint8_t> atlas, float* out) {
  const float* lut = Srgb8ToLinearTable();
  return SampleAtlasBilinear(
      prim_id, bary, num_pixels, uv, atlas.width, atlas.height, [&](int y) { return atlas.Row(y); },
      [lut](const std::uint8_t* row, int x, int c) { return lut[row[4 * x + c]]; },
      [](const std::uint8_t* row, int x) { return static_cast<const void*>(row + 4 * x); }, out);
}

void PointColors(const double* points, const double* normals, std::int64_t n, const UlrInputView* views,
                 int num_views, const PointColorOptions& options, float* color, std::int32_t* seen) {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  const double max_angle = M_PI / 2 - 1e-3;
  constexpr double kMinCos2 = 0.25e-3 * 0.25e-3;  // the facing pre-test's squared cosine
  const int k = std::min(options.k, num_views);
  std::vector<glm::dvec3> centres(num_views);
  for (int i = 0; i < num_views; ++i) centres[i] = views[i].camera.CentreInWorld();
  ParallelFor(n, 4096, [&](std::int64_t b, std::int64_t e) {
    std::vector<float> pen(num_views), dist(num_views), sorted(num_views);
    std::vector<double> px(num_views), py(num_views), pz(num_views), cosv(num_views), rv(num_views);
    std::vector<std::int64_t> at(num_views);
    std::vector<int> kept(num_views);
    for (std::int64_t i = b; i < e; ++i) {
      const glm::dvec3 p(points[3 * i], points[3 * i + 1], points[3 * i + 2]);
      const glm::dvec3 nrm(normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]);
      // Passes over the views, so that the facing, image and depth tests are not a branch each (a
      // view faces a point or not about half the time: such a branch was mispredicted that often).
      // 1: the facing test of every view (without a square root or a division), the views that pass compacted;
      // a cosine <= 0.25e-3 means an angle >= pi/2 - 0.25e-3 > max_angle: it only rejects views
      // the angle test of pass 4 would.
      int n_facing = 0;
      for (int v = 0; v < num_views; ++v) {
        pen[v] = dist[v] = kInf;
        const glm::dvec3 to_cam = centres[v] - p;
        const double dt = glm::dot(to_cam, nrm);
        kept[n_facing] = v;
        n_facing += (dt > 0) & (dt * dt > kMinCos2 * glm::dot(to_cam, to_cam));
      }
      // 2: their cosines and projections; a view that fails reads its depth at pixel (0, 0).
      for (int j = 0; j < n_facing; ++j) {
        const int v = kept[j];
        const glm::dvec3 to_cam = centres[v] - p;
        const double r = glm::length(to_cam);
        cosv[v] = glm::dot(to_cam, nrm) / std::max(r, 1e-12);
        rv[v] = r;
        const Camera& cam = views[v].camera;
        double x = 0, y = 0, z = 0;
        const bool front = cam.ProjectCam(cam.CamFromWorld(p), &x, &y, &z);
        const bool ok = front & std::isfinite(z) & (x >= 0) & (x < cam.width) & (y >= 0) & (y < cam.height);
        const int ix = ok ? std::min(static_cast<int>(x), cam.width - 1) : 0;
        const int iy = ok ? std::min(static_cast<int>(y), cam.height - 1) : 0;
        at[j] = ok ? std::int64_t(iy) * views[v].depth.row_stride + ix : -1;
        px[v] = x;
        py[v] = y;
        pz[v] = z;
      }
      // 3: the depth test; the views that pass, in order, compacted.
      int n_kept = 0;
      for (int j = 0; j < n_facing; ++j) {
        const int v = kept[j];
        const float dz = views[v].depth.data[std::max<std::int64_t>(at[j], 0)];
        const bool ok = (at[j] >= 0) & std::isfinite(dz) & (dz > 0) &
                        (std::abs(pz[v] - double(dz)) <= double(options.depth_tol * dz));
        kept[n_kept] = v;
        n_kept += ok;
      }
      // 4: the angle of the views kept.
      int n_seen = 0;
      float dmin = kInf;
      for (int j = 0; j < n_kept; ++j) {
        const int v = kept[j];
        const double ang = std::acos(std::clamp(cosv[v], -1.0, 1.0));
        if (!(ang < max_angle)) continue;
        pen[v] = static_cast<float>(ang);
        dist[v] = static_cast<float>(rv[v]);
        dmin = std::min(dmin, dist[v]);
        ++n_seen;
      }
      seen[i] = n_seen;
      float* o = color + 3 * i;
      if (n_seen == 0) {
        o[0] = o[1] = o[2] = 0.f;
        continue;
      }
      for (int v = 0; v < num_views; ++v) {
        if (pen[v] < kInf) pen[v] = pen[v] + 0.5f * std::max(0.f, dist[v] / dmin - 1.f);
      }
      float thresh = kInf;
      if (num_views > k) {  // the (k+1)-th smallest penalty (infinite ones included)
        sorted.assign(pen.begin(), pen.end());
        std::nth_element(sorted.begin(), sorted.begin() + k, sorted.end());
        thresh = sorted[k];
      }
      double acc[3] = {0, 0, 0}, wsum = 0;
      for (int v = 0; v < num_views; ++v) {
        if (!(pen[v] < kInf && pen[v] < thresh)) continue;
        float w = 1.f;
        if (thresh < kInf) w = 1.f - pen[v] / (thresh > 0 ? thresh : 1.f);
        w = std::max(w, 1e-3f);
        // Bilinear, centres at +0.5, clamped to the edge (x0 <= w - 2: the right edge reads with tx = 1).
        const ImageView<const float>& img = views[v].color;
        const double xf = std::clamp(px[v] - 0.5, 0.0, double(img.width - 1));
        const double yf = std::clamp(py[v] - 0.5, 0.0, double(img.height - 1));
        const int x0 = std::min(static_cast<int>(xf), img.width > 1 ? img.width - 2 : 0);
        const int y0 = std::min(static_cast<int>(yf), img.height > 1 ? img.height - 2 : 0);
        const int x1 = std::min(x0 + 1, img.width - 1), y1 = std::min(y0 + 1, img.height - 1);
        const double tx = xf - x0, ty = yf - y0;
        const float* r0 = img.Row(y0);
        const float* r1 = img.Row(y1);
        for (int c = 0; c < 3; ++c) {
          const double top = r0[3 * x0 + c] * (1 - tx) + r0[3 * x1 + c] * tx;
          const double bot = r1[3 * x0 + c] * (1 - tx) + r1[3 * x1 + c] * tx;
          acc[c] += w * (top * (1 - ty) + bot * ty);
        }
        wsum += w;
      }
      for (int c = 0; c < 3; ++c) o[c] = wsum > 0 ? static_cast<float>(acc[c] / wsum) : 0.f;
    }
  });
}

void TexelRowStarts(const std::int32_t* face_of_texel, int rows, int width, std::int64_t* row_start) {
  row_start[0] = 0;
  for (int r = 0; r < rows; ++r) {
    const std::int32_t* row = face_of_texel + std::int64_t(r) * width;
    row_start[r + 1] = row_start[r] + std::count_if(row, row + width, [](std::int32_t f) { return f >= 0; });
  }
}

void TexelPoints(const std::int32_t* face_of_texel, const std::int64_t* row_start, int rows, int width, int row0,
                 const float* uv, const float* vertices, const std::int32_t* faces, const float* normals,
                 std::int64_t* ys, std::int64_t* xs, std::int32_t* face, double* bary, double* points,
                 double* unit_normals) {
  // numpy.maximum(x, 0): x when x >= 0 or NaN (so -0.0 stays -0.0), else 0.
  const auto clamp0 = [](double x) { return (x >= 0 || std::isnan(x)) ? x : 0.0; };
  ParallelFor(rows, std::max(1, 16384 / std::max(width, 1)), [&](std::int64_t rb, std::int64_t re) {
    for (std::int64_t r = rb; r < re; ++r) {
      std::int64_t o = row_start[r];
      const std::int32_t* row = face_of_texel + r * width;
      for (int x = 0; x < width; ++x) {
        const std::int32_t f = row[x];
        if (f < 0) continue;
        ys[o] = row0 + r;
        xs[o] = x;
        face[o] = f;
        const double px = x + 0.5, py = double(row0 + r) + 0.5;
        const float* t = uv + 6 * std::int64_t(f);
        const double t0x = t[0], t0y = t[1];
        const double d1x = double(t[2]) - t0x, d1y = double(t[3]) - t0y;
        const double d2x = double(t[4]) - t0x, d2y = double(t[5]) - t0y;
        const double dpx = px - t0x, dpy = py - t0y;
        const double det = d1x * d2y - d1y * d2x;
        const double b1 = (dpx * d2y - dpy * d2x) / det;
        const double b2 = (d1x * dpy - d1y * dpx) / det;
        double w[3] = {clamp0(1 - b1 - b2), clamp0(b1), clamp0(b2)};
        const double s = w[0] + w[1] + w[2];
        for (double& wk : w) wk /= s;
        double* b = bary + 3 * o;
        double* p = points + 3 * o;
        double* nrm = unit_normals + 3 * o;
        const std::int32_t* fv = faces + 3 * std::int64_t(f);
        const float* v0 = vertices + 3 * std::int64_t(fv[0]);
        const float* v1 = vertices + 3 * std::int64_t(fv[1]);
        const float* v2 = vertices + 3 * std::int64_t(fv[2]);
        const float* n0 = normals + 3 * std::int64_t(fv[0]);
        const float* n1 = normals + 3 * std::int64_t(fv[1]);
        const float* n2 = normals + 3 * std::int64_t(fv[2]);
        for (int c = 0; c < 3; ++c) {
          b[c] = w[c];
          p[c] = w[0] * double(v0[c]) + w[1] * double(v1[c]) + w[2] * double(v2[c]);
          nrm[c] = w[0] * double(n0[c]) + w[1] * double(n1[c]) + w[2] * double(n2[c]);
        }
        const double len = std::sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
        const double div = (len >= 1e-12 || std::isnan(len)) ? len : 1e-12;
        for (int c = 0; c < 3; ++c) nrm[c] /= div;
        ++o;
      }
    }
  });
}

}  // namespace ibr
