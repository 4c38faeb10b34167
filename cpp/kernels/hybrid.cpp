// Hybrid IBR rendering kernels: see hybrid.h for the model and the conventions.
#include "kernels/hybrid.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "ibr/parallel.h"
#include "kernels/ulr.h"

namespace ibr {

void InterpolateVertexAttribute(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels,
                                const std::int32_t* faces, const float* attrib, int channels, float* out) {
  ParallelFor(num_pixels, 16384, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t i = b; i < e; ++i) {
      float* o = out + i * channels;
      const std::int32_t f = prim_id[i];
      if (f < 0) {
        for (int c = 0; c < channels; ++c) o[c] = 0.f;
        continue;
      }
      const float u = bary[2 * i], v = bary[2 * i + 1], w = 1.f - u - v;
      const float* a0 = attrib + std::int64_t(faces[3 * f]) * channels;
      const float* a1 = attrib + std::int64_t(faces[3 * f + 1]) * channels;
      const float* a2 = attrib + std::int64_t(faces[3 * f + 2]) * channels;
      for (int c = 0; c < channels; ++c) o[c] = w * a0[c] + u * a1[c] + v * a2[c];
    }
  });
}

namespace {

// Bilinear read of an (h, w, 3) image at continuous pixel position (x, y) (pixel centres at
// +0.5), clamped to the image's edge pixels.
inline glm::vec3 Bilinear3(const ImageView<const float>& img, double x, double y) {
  const double fx = std::clamp(x - 0.5, 0.0, double(img.width - 1));
  const double fy = std::clamp(y - 0.5, 0.0, double(img.height - 1));
  const int x0 = std::min(int(fx), img.width - 1), y0 = std::min(int(fy), img.height - 1);
  const int x1 = std::min(x0 + 1, img.width - 1), y1 = std::min(y0 + 1, img.height - 1);
  const float ax = float(fx - x0), ay = float(fy - y0);
  const float* r0 = img.Row(y0);
  const float* r1 = img.Row(y1);
  glm::vec3 out;
  for (int c = 0; c < 3; ++c) {
    const float top = r0[3 * x0 + c] + ax * (r0[3 * x1 + c] - r0[3 * x0 + c]);
    const float bot = r1[3 * x0 + c] + ax * (r1[3 * x1 + c] - r1[3 * x0 + c]);
    out[c] = top + ay * (bot - top);
  }
  return out;
}

}  // namespace

void SampleAtlas(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels, const float* uv,
                 ImageView<const float> atlas, float* out) {
  ParallelFor(num_pixels, 16384, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t i = b; i < e; ++i) {
      float* o = out + 3 * i;
      const std::int32_t f = prim_id[i];
      if (f < 0) {
        o[0] = o[1] = o[2] = 0.f;
        continue;
      }
      const double u = bary[2 * i], v = bary[2 * i + 1], w = 1.0 - u - v;
      const float* t = uv + 6 * std::int64_t(f);
      const glm::vec3 c = Bilinear3(atlas, w * t[0] + u * t[2] + v * t[4], w * t[1] + u * t[3] + v * t[5]);
      o[0] = c[0];
      o[1] = c[1];
      o[2] = c[2];
    }
  });
}

namespace {

// atan2(y, x) for y >= 0 (an angle in [0, pi]) by a minimax polynomial of atan on [0, 1]
// (Abramowitz and Stegun 4.4.49, 9th order odd polynomial, max error 1e-5 rad): ~4x faster than
// std::atan2 in the per-pixel, per-view penalty loop, and 1e-5 rad is far below any penalty
// difference that matters for ranking (pixels subtend ~1e-3 rad).
inline float FastAtan2Pos(float y, float x) {
  const float ax = std::abs(x);
  const bool swap = y > ax;
  const float num = swap ? ax : y, den = swap ? y : ax;
  if (!(den > 0.f)) return 0.f;
  const float t = num / den, t2 = t * t;
  float r = t * (0.9998660f + t2 * (-0.3302995f + t2 * (0.1801410f + t2 * (-0.0851330f + t2 * 0.0208351f))));
  if (swap) r = 1.57079633f - r;
  if (x < 0.f) r = 3.14159265f - r;
  return r;
}

}  // namespace

// UlrPenalty (ulr.h) with the novel-side vector b = c_novel - p and its length computed once per
// pixel and the fast atan2: agrees with UlrPenalty within 2e-5 (tests/test_hybrid_render.py).
float UlrPenaltyFast(const glm::vec3& p, const glm::vec3& b, float lb, const glm::vec3& c_view,
                     float resolution_weight) {
  const glm::vec3 a = c_view - p;
  const float la = glm::length(a);
  if (!(la > 0.f) || !(lb > 0.f) || !std::isfinite(la) || !std::isfinite(lb)) return INFINITY;
  const float angle = FastAtan2Pos(glm::length(glm::cross(a, b)), glm::dot(a, b));
  const float ratio = la / lb - 1.f;
  const float pen = angle + resolution_weight * (ratio > 0.f ? ratio : 0.f);
  return std::isfinite(pen) ? pen : INFINITY;
}

void UlrBlend(const Camera& novel, ImageView<const float> gbuffer_depth, ImageView<const float> normal,
              const std::uint8_t* pixel_mask, const UlrInputView* views, int num_views, const UlrOptions& options,
              ImageView<float> color_out, ImageView<std::uint8_t> count_out) {
  const int H = gbuffer_depth.height, W = gbuffer_depth.width;
  const glm::dvec3 c_novel_d = novel.CentreInWorld();
  const glm::vec3 c_novel(c_novel_d);
  std::vector<glm::vec3> centres(num_views);
  for (int i = 0; i < num_views; ++i) centres[i] = glm::vec3(views[i].camera.CentreInWorld());
  const int k = std::max(1, std::min(options.k, 64));
  const bool use_normal = !normal.Empty();
  const glm::dmat3 world_from_cam = glm::transpose(novel.rot);
  ParallelFor2D(H, W, 64, [&](int y0, int y1, int x0, int x1) {
    std::vector<float> pen(num_views);
    std::vector<std::uint8_t> tested(num_views);
    std::vector<double> proj(3 * std::size_t(num_views));  // x, y, depth of p in each view
    int index[64];
    float weight[64];
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
          col += weight[j] * Bilinear3(views[i].color, proj[3 * i], proj[3 * i + 1]);
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

void HybridSelect(ImageView<const float> gbuffer_depth, const std::uint8_t* inside_grid, const std::uint8_t* pvm_valid,
                  const float* pvm_depth, const float* vd, const HybridSelectOptions& options,
                  ImageView<std::uint8_t> label_out) {
  const int H = gbuffer_depth.height, W = gbuffer_depth.width;
  ParallelFor(std::int64_t(H) * W, 16384, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t i = b; i < e; ++i) {
      const int y = int(i / W), x = int(i % W);
      const float g = gbuffer_depth.At(y, x);
      const bool hit = g > 0.f && std::isfinite(g);
      std::uint8_t lab;
      if (inside_grid && !inside_grid[i]) {
        lab = hit ? kLabelUlr : kLabelNone;
      } else if (pvm_valid && pvm_valid[i] &&
                 (!hit || !(std::abs(pvm_depth[i] - g) <= options.geo_threshold))) {
        lab = kLabelPvm;
      } else if (!hit) {
        lab = kLabelNone;
      } else if (vd && vd[i] > options.tau_var) {
        lab = kLabelUlr;
      } else {
        lab = kLabelTm;
      }
      label_out.At(y, x) = lab;
    }
  });
}

void BlurSelection(ImageView<const std::uint8_t> label, float sigma, float* scratch, ImageView<float> weights_out) {
  const int H = label.height, W = label.width;
  const int r = sigma > 0.f ? int(std::ceil(3.f * sigma)) : 0;
  std::vector<float> taps(2 * r + 1);
  for (int d = -r; d <= r; ++d) taps[d + r] = r ? std::exp(-0.5f * d * d / (sigma * sigma)) : 1.f;
  // Horizontal pass: one-hot labels -> scratch (H, W, 3).
  ParallelFor(H, 8, [&](std::int64_t b, std::int64_t e) {
    for (int y = int(b); y < int(e); ++y) {
      const std::uint8_t* lrow = label.Row(y);
      float* srow = scratch + std::int64_t(y) * W * 3;
      for (int x = 0; x < W; ++x) {
        float acc[3] = {0.f, 0.f, 0.f};
        for (int d = -r; d <= r; ++d) {
          const int xx = std::clamp(x + d, 0, W - 1);
          const std::uint8_t l = lrow[xx];
          if (l < 3) acc[l] += taps[d + r];
        }
        srow[3 * x] = acc[0];
        srow[3 * x + 1] = acc[1];
        srow[3 * x + 2] = acc[2];
      }
    }
  });
  // Vertical pass and normalisation.
  ParallelFor(H, 8, [&](std::int64_t b, std::int64_t e) {
    for (int y = int(b); y < int(e); ++y) {
      float* orow = weights_out.Row(y);
      for (int x = 0; x < W; ++x) {
        float acc[3] = {0.f, 0.f, 0.f};
        for (int d = -r; d <= r; ++d) {
          const int yy = std::clamp(y + d, 0, H - 1);
          const float* s = scratch + (std::int64_t(yy) * W + x) * 3;
          const float t = taps[d + r];
          acc[0] += t * s[0];
          acc[1] += t * s[1];
          acc[2] += t * s[2];
        }
        const float sum = acc[0] + acc[1] + acc[2];
        const float inv = sum > 0.f ? 1.f / sum : 0.f;
        orow[3 * x] = acc[0] * inv;
        orow[3 * x + 1] = acc[1] * inv;
        orow[3 * x + 2] = acc[2] * inv;
      }
    }
  });
}

void HybridComposite(ImageView<const float> weights, ImageView<const float> tm, const float* ulr,
                     const std::uint8_t* ulr_count, const float* pvm, const std::uint8_t* pvm_valid,
                     ImageView<float> color_out) {
  const int H = weights.height, W = weights.width;
  ParallelFor(std::int64_t(H) * W, 16384, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t i = b; i < e; ++i) {
      const int y = int(i / W), x = int(i % W);
      const float* w = &weights.At(y, x, 0);
      const float* t = &tm.At(y, x, 0);
      const float* u = (ulr && ulr_count && ulr_count[i] > 0) ? ulr + 3 * i : t;
      const float* v = (pvm && pvm_valid && pvm_valid[i]) ? pvm + 3 * i : u;
      float* o = &color_out.At(y, x, 0);
      for (int c = 0; c < 3; ++c) o[c] = w[0] * t[c] + w[1] * u[c] + w[2] * v[c];
    }
  });
}

}  // namespace ibr
