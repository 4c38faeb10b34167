// Equations and shapes: culling.h.
#include "kernels/depthwarp/culling.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "ibr/parallel.h"

namespace ibr {

void ObjectBoxes(const float* vertices, const std::int32_t* faces, std::int64_t num_faces,
                 const std::int32_t* object_ids, std::int32_t num_objects, float* boxes) {
  const float inf = std::numeric_limits<float>::infinity();
  for (std::int64_t k = 0; k < num_objects; ++k) {
    for (int c = 0; c < 3; ++c) boxes[k * 6 + c] = inf, boxes[k * 6 + 3 + c] = -inf;
  }
  // One pass over the faces: a few ms for a million faces, not worth a parallel reduction.
  for (std::int64_t f = 0; f < num_faces; ++f) {
    const std::int32_t k = object_ids[f];
    if (k < 0 || k >= num_objects) continue;
    float* b = boxes + static_cast<std::int64_t>(k) * 6;
    for (int i = 0; i < 3; ++i) {
      const float* v = vertices + static_cast<std::int64_t>(faces[f * 3 + i]) * 3;
      for (int c = 0; c < 3; ++c) {
        b[c] = std::min(b[c], v[c]);
        b[3 + c] = std::max(b[3 + c], v[c]);
      }
    }
  }
}

namespace {

void ProjectOne(const float* box, const Camera& cam, const CullOptions& opt, std::uint8_t* state,
                std::int32_t* rect, float* min_z) {
  *state = kCullOutside;
  rect[0] = rect[1] = rect[2] = rect[3] = 0;
  *min_z = 0.0f;
  if (!(box[0] <= box[3] && box[1] <= box[4] && box[2] <= box[5])) return;  // empty (or NaN)
  glm::dvec3 p[8];
  for (int i = 0; i < 8; ++i) {
    const glm::dvec3 w(box[(i & 1) ? 3 : 0], box[(i & 2) ? 4 : 1], box[(i & 4) ? 5 : 2]);
    p[i] = cam.CamFromWorld(w);
  }
  // Frustum planes through the camera centre (and the near plane): outside when all corners
  // are on the negative side of one plane.
  const double w = cam.width, h = cam.height;
  int out_near = 0, out_l = 0, out_r = 0, out_t = 0, out_b = 0;
  for (const auto& q : p) {
    out_near += q.z < opt.near;
    out_l += cam.fx * q.x + cam.cx * q.z < 0.0;
    out_r += (w - cam.cx) * q.z - cam.fx * q.x < 0.0;
    out_t += cam.fy * q.y + cam.cy * q.z < 0.0;
    out_b += (h - cam.cy) * q.z - cam.fy * q.y < 0.0;
  }
  if (out_near == 8 || out_l == 8 || out_r == 8 || out_t == 8 || out_b == 8) return;
  double zmin = std::numeric_limits<double>::infinity();
  for (const auto& q : p) zmin = std::min(zmin, q.z);
  if (zmin <= opt.near) {
    *state = kCullNear;
    return;
  }
  double xmin = std::numeric_limits<double>::infinity(), ymin = xmin, xmax = -xmin, ymax = -xmin;
  for (const auto& q : p) {
    const double x = cam.fx * q.x / q.z + cam.cx, y = cam.fy * q.y / q.z + cam.cy;
    xmin = std::min(xmin, x), xmax = std::max(xmax, x);
    ymin = std::min(ymin, y), ymax = std::max(ymax, y);
  }
  // Pixels u with [u, u + 1) meeting [xmin, xmax]: floor(xmin) .. floor(xmax), then the pad.
  // Clamp in double before converting (a corner just in front of the near plane projects far).
  const double x0 = std::clamp(std::floor(xmin) - opt.pad, 0.0, w);
  const double x1 = std::clamp(std::floor(xmax) + 1.0 + opt.pad, 0.0, w);
  const double y0 = std::clamp(std::floor(ymin) - opt.pad, 0.0, h);
  const double y1 = std::clamp(std::floor(ymax) + 1.0 + opt.pad, 0.0, h);
  if (!(x0 < x1 && y0 < y1)) return;  // projects beside the image: outside the frustum
  *state = kCullTest;
  rect[0] = static_cast<std::int32_t>(x0);
  rect[1] = static_cast<std::int32_t>(y0);
  rect[2] = static_cast<std::int32_t>(x1);
  rect[3] = static_cast<std::int32_t>(y1);
  // Round down so that float(min_z) <= the true least z (the test stays conservative).
  float z = static_cast<float>(zmin);
  if (static_cast<double>(z) > zmin) z = std::nextafter(z, 0.0f);
  *min_z = z;
}

}  // namespace

void ProjectBoxes(const float* boxes, std::int64_t num_boxes, const Camera& camera, const CullOptions& options,
                  std::uint8_t* state, std::int32_t* rect, float* min_z) {
  ParallelFor(num_boxes, 1024, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t k = b; k < e; ++k) ProjectOne(boxes + k * 6, camera, options, state + k, rect + k * 4, min_z + k);
  });
}

}  // namespace ibr

namespace ibr {
namespace {

struct MotionLevel {
  float* data;  // (h, w, 4): min x, min y, max x, max y
  int h, w;
};

constexpr int kMaxLevels = 40;

int NumLevels(int height, int width) {
  int n = 1;
  for (int h = height, w = width; h > 1 || w > 1; h = (h + 1) / 2, w = (w + 1) / 2) ++n;
  return n;
}

}  // namespace

std::int64_t AwocScratchSize(int height, int width) {
  std::int64_t total = 0;
  for (int h = height, w = width;; h = (h + 1) / 2, w = (w + 1) / 2) {
    total += static_cast<std::int64_t>(h) * w * 4;
    if (h == 1 && w == 1) break;
  }
  return total;
}

void AwocFill(const float* motion, const float* dst_depth, int height, int width, int steps,
              const double* sky_from_target, const float* source_depth, float* scratch, float* depth,
              std::uint8_t* hole, int out_height, int out_width) {
  const float inf = std::numeric_limits<float>::infinity();
  const int n = NumLevels(height, width);
  MotionLevel lv[kMaxLevels];  // n <= 33 for int sizes: headers on the stack, the texels in scratch
  float* p = scratch;
  for (int h = height, w = width, l = 0; l < n; ++l, h = (h + 1) / 2, w = (w + 1) / 2) {
    lv[l] = {p, h, w};
    p += static_cast<std::int64_t>(h) * w * 4;
  }
  // Level 0: the valid motions.
  ParallelFor(height, std::max<std::int64_t>(1, kMinPixelsPerTask / std::max(1, width)), [&](std::int64_t y0, std::int64_t y1) {
    for (std::int64_t i = y0 * width; i < y1 * width; ++i) {
      float* t = lv[0].data + i * 4;
      if (dst_depth[i] > 0.0f) {
        t[0] = t[2] = motion[i * 2];
        t[1] = t[3] = motion[i * 2 + 1];
      } else {
        t[0] = t[1] = inf;
        t[2] = t[3] = -inf;
      }
    }
  });
  for (int l = 1; l < n; ++l) {
    const MotionLevel& a = lv[l - 1];
    const MotionLevel& b = lv[l];
    ParallelFor(b.h, std::max<std::int64_t>(1, kMinPixelsPerTask / std::max(1, b.w)), [&](std::int64_t y0, std::int64_t y1) {
      for (std::int64_t y = y0; y < y1; ++y) {
        for (int x = 0; x < b.w; ++x) {
          float r[4] = {inf, inf, -inf, -inf};
          for (int dy = 0; dy < 2; ++dy) {
            const std::int64_t yy = std::min<std::int64_t>(2 * y + dy, a.h - 1);
            for (int dx = 0; dx < 2; ++dx) {
              const int xx = std::min(2 * x + dx, a.w - 1);
              const float* s = a.data + (yy * a.w + xx) * 4;
              r[0] = std::min(r[0], s[0]), r[1] = std::min(r[1], s[1]);
              r[2] = std::max(r[2], s[2]), r[3] = std::max(r[3], s[3]);
            }
          }
          std::copy(r, r + 4, b.data + (y * b.w + x) * 4);
        }
      }
    });
  }
  const float* top = lv[n - 1].data;
  if (!(top[0] <= top[2])) return;  // no valid motion at all
  ParallelFor(out_height, std::max<std::int64_t>(1, kMinPixelsPerTask / std::max(1, out_width)), [&](std::int64_t y0, std::int64_t y1) {
    for (std::int64_t y = y0; y < y1; ++y) {
      for (int x = 0; x < out_width; ++x) {
        const std::int64_t o = y * out_width + x;
        if (!hole[o]) continue;
        if (sky_from_target != nullptr) {
          const double* m = sky_from_target;
          const double px = x + 0.5, py = y + 0.5;
          const double hz = m[6] * px + m[7] * py + m[8];
          bool sky = true;
          if (hz > 0.0) {
            const double qx = (m[0] * px + m[1] * py + m[2]) / hz, qy = (m[3] * px + m[4] * py + m[5]) / hz;
            if (qx >= 0.0 && qx < width && qy >= 0.0 && qy < height) {
              sky = !(source_depth[static_cast<std::int64_t>(qy) * width + static_cast<std::int64_t>(qx)] > 0.0f);
            }
          }
          if (sky) continue;
        }
        // B = [p - Vmax, p - Vmin] in source pixel indices.
        double bx0 = x - top[2], bx1 = x - top[0], by0 = y - top[3], by1 = y - top[1];
        for (int s = 0; s < steps; ++s) {
          // Clip to the image before reading (no solution lies outside it).
          const double cx0 = std::max(bx0, 0.0), cx1 = std::min(bx1, width - 1.0);
          const double cy0 = std::max(by0, 0.0), cy1 = std::min(by1, height - 1.0);
          if (!(cx0 <= cx1 && cy0 <= cy1)) break;
          const double ext = std::max(cx1 - cx0, cy1 - cy0) + 1.0;
          const int l = std::clamp(static_cast<int>(std::ceil(std::log2(ext))), 0, n - 1);
          const MotionLevel& m = lv[l];
          float r[4] = {inf, inf, -inf, -inf};
          const int tx[2] = {static_cast<int>(cx0) >> l, static_cast<int>(cx1) >> l};
          const int ty[2] = {static_cast<int>(cy0) >> l, static_cast<int>(cy1) >> l};
          for (int j = 0; j < 2; ++j) {
            for (int i = 0; i < 2; ++i) {
              const float* t = m.data + (static_cast<std::int64_t>(std::min(ty[j], m.h - 1)) * m.w +
                                         std::min(tx[i], m.w - 1)) * 4;
              r[0] = std::min(r[0], t[0]), r[1] = std::min(r[1], t[1]);
              r[2] = std::max(r[2], t[2]), r[3] = std::max(r[3], t[3]);
            }
          }
          if (!(r[0] <= r[2])) break;  // no valid motion under B: keep the last bound
          bx0 = std::max(cx0, x - static_cast<double>(r[2])), bx1 = std::min(cx1, x - static_cast<double>(r[0]));
          by0 = std::max(cy0, y - static_cast<double>(r[3])), by1 = std::min(cy1, y - static_cast<double>(r[1]));
          if (!(bx0 <= bx1 && by0 <= by1)) break;
        }
        float best = inf;
        const double xs[2] = {bx0, bx1}, ys[2] = {by0, by1};
        for (double qy : ys) {
          for (double qx : xs) {
            if (!std::isfinite(qx) || !std::isfinite(qy)) continue;
            const std::int64_t ix = std::clamp<std::int64_t>(std::llround(qx), 0, width - 1);
            const std::int64_t iy = std::clamp<std::int64_t>(std::llround(qy), 0, height - 1);
            const float d = dst_depth[iy * width + ix];
            if (d > 0.0f) best = std::min(best, d);
          }
        }
        if (best < inf) {
          depth[o] = best;
          hole[o] = 0;
        }
      }
    }
  });
}

}  // namespace ibr
