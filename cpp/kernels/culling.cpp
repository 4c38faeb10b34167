// Equations and shapes: culling.h.
#include "kernels/culling.h"

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
