// See harmonise.h.
#include "kernels/hybrid/harmonise.h"

#include <algorithm>
#include <cmath>

#include "ibr/parallel.h"

namespace ibr {
namespace {

// Bilinear read of channel-interleaved RGB at continuous (x, y), as variance.bilinear.
inline void Bilinear(const float* img, int w, int h, double x, double y, float out[3]) {
  const double fx = std::clamp(x - 0.5, 0.0, double(w - 1));
  const double fy = std::clamp(y - 0.5, 0.0, double(h - 1));
  const int x0 = w > 1 ? std::min(static_cast<int>(fx), w - 2) : 0;
  const int y0 = h > 1 ? std::min(static_cast<int>(fy), h - 2) : 0;
  const double ax = w > 1 ? fx - x0 : 0.0;
  const double ay = h > 1 ? fy - y0 : 0.0;
  const int x1 = std::min(x0 + 1, w - 1), y1 = std::min(y0 + 1, h - 1);
  const float* p00 = img + (std::int64_t(y0) * w + x0) * 3;
  const float* p01 = img + (std::int64_t(y0) * w + x1) * 3;
  const float* p10 = img + (std::int64_t(y1) * w + x0) * 3;
  const float* p11 = img + (std::int64_t(y1) * w + x1) * 3;
  for (int c = 0; c < 3; ++c) {
    const double top = p00[c] * (1 - ax) + p01[c] * ax;
    const double bot = p10[c] * (1 - ax) + p11[c] * ax;
    out[c] = static_cast<float>(top * (1 - ay) + bot * ay);
  }
}

}  // namespace

void CrossViewPrediction(const Camera& camera, const float* depth, const std::vector<PredictionSource>& sources,
                         double depth_tol, double quantile, float* pred, std::int32_t* n_seen) {
  const int w = camera.width, h = camera.height;
  const int ns = static_cast<int>(sources.size());
  const glm::dmat3 rt = glm::transpose(camera.rot);
  ParallelFor(h, 8, [&](std::int64_t r0, std::int64_t r1) {
    std::vector<float> samples(static_cast<std::size_t>(std::max(ns, 1)) * 3);
    for (std::int64_t v = r0; v < r1; ++v) {
      for (int u = 0; u < w; ++u) {
        const std::int64_t i = v * w + u;
        float* out = pred + i * 3;
        out[0] = out[1] = out[2] = 0.f;
        n_seen[i] = 0;
        const double d = depth[i];
        if (!(d > 0.0) || !std::isfinite(d)) continue;
        const glm::dvec3 p_cam = camera.RayInCam(u + 0.5, v + 0.5) * d;
        const glm::dvec3 p = rt * (p_cam - camera.trans);
        int n = 0;
        for (const PredictionSource& s : sources) {
          const Camera& ck = *s.camera;
          double x, y, z;
          if (!ck.ProjectCam(ck.CamFromWorld(p), &x, &y, &z)) continue;
          if (!std::isfinite(z) || !(x >= 0.0 && x < ck.width && y >= 0.0 && y < ck.height)) continue;
          const int col = std::min(static_cast<int>(x), ck.width - 1);
          const int row = std::min(static_cast<int>(y), ck.height - 1);
          const double zk = s.depth[std::int64_t(row) * ck.width + col];
          if (!(zk > 0.0) || !(std::abs(zk - z) <= depth_tol * z)) continue;
          float c[3];
          Bilinear(s.image, ck.width, ck.height, x, y, c);
          samples[n] = c[0];
          samples[ns + n] = c[1];
          samples[2 * ns + n] = c[2];
          ++n;
        }
        n_seen[i] = n;
        if (n == 0) continue;
        const double pos = quantile * (n - 1);
        const int lo = static_cast<int>(std::floor(pos));
        const int hi = std::min(lo + 1, n - 1);
        const float frac = static_cast<float>(pos - lo);
        for (int c = 0; c < 3; ++c) {
          float* sc = samples.data() + std::int64_t(c) * ns;
          std::sort(sc, sc + n);
          out[c] = sc[lo] + frac * (sc[hi] - sc[lo]);
        }
      }
    }
  });
}

}  // namespace ibr
