// Unstructured Lumigraph Rendering view ranking and blending weights (Buehler et al. 2001,
// "Unstructured Lumigraph Rendering", Sec. 4-5; Prakash et al. 2021, "Hybrid Image-based
// Rendering for Free-view Synthesis", Sec. 3.3). Header-only: shared by the per-pixel ULR
// kernel (cpp/kernels/hybrid/hybrid.h) and the PVM renderer, so both rank views identically.
//
// Penalty of input view i for the surface point p seen from the novel camera centre c_novel:
//   angle(c_view - p, c_novel - p)                          [radians, 0 .. pi]
//   + resolution_weight * max(0, |c_view - p| / |c_novel - p| - 1)
// The first term is Buehler's angular penalty; the second is his resolution penalty (an input
// view farther from p than the novel camera sees p at lower resolution). +infinity when either
// distance is 0 or not finite (p at a camera centre, or a non-finite point). It is the penalty
// of the texture stage (python/ibrtools/hybrid/globalmesh.py), which uses 0.5 as the weight.
//
// Selection (Buehler's k-nearest blending, Sec. 5.1): keep the k smallest finite penalties and
// weight them w_i = max(0, 1 - p_i / p_thresh), where p_thresh is the k-th smallest penalty when
// at least k are finite, so the weights fall smoothly to zero at the k-th view (it is returned
// with weight 0: with k = 4 three views carry the blend, as in the paper); with fewer than k
// finite penalties, p_thresh = 1.01 * the largest finite + 1e-6 so every kept view keeps a
// positive weight. If all kept weights are zero (e.g. several equal penalties at the threshold)
// the kept views are weighted uniformly. Weights are normalised to sum 1. Never NaN.
#pragma once
#include <cmath>
#include <limits>

#include <glm/glm.hpp>

namespace ibr {

// angle_out: where given, receives the angle term (0 when the penalty is infinite for a degenerate p).
inline float UlrPenalty(const glm::vec3& p, const glm::vec3& c_novel, const glm::vec3& c_view,
                        float resolution_weight = 0.5f, float* angle_out = nullptr) {
  const glm::vec3 a = c_view - p;
  const glm::vec3 b = c_novel - p;
  const float la = glm::length(a), lb = glm::length(b);
  if (angle_out != nullptr) *angle_out = 0.f;
  if (!(la > 0.f) || !(lb > 0.f) || !std::isfinite(la) || !std::isfinite(lb))
    return std::numeric_limits<float>::infinity();
  // atan2(|a x b|, a . b) is accurate for small angles, where acos of the normalised dot is not.
  const float angle = std::atan2(glm::length(glm::cross(a, b)), glm::dot(a, b));
  if (angle_out != nullptr) *angle_out = angle;
  const float ratio = la / lb - 1.f;
  const float pen = angle + resolution_weight * (ratio > 0.f ? ratio : 0.f);
  return std::isfinite(pen) ? pen : std::numeric_limits<float>::infinity();
}

// index[0..m), weight[0..m) must hold k entries; returns m = min(k, number of finite penalties)
// (0 when k <= 0 or none is finite). Insertion into a sorted list of k: O(n k), k is small (4).
inline int UlrSelect(const float* penalty, int n, int k, int* index, float* weight) {
  if (k <= 0 || n <= 0) return 0;
  int m = 0;
  for (int i = 0; i < n; ++i) {
    const float p = penalty[i];
    if (!std::isfinite(p)) continue;
    // Strictly smaller moves ahead: equal penalties keep the lower index first.
    int pos = m;
    while (pos > 0 && weight[pos - 1] > p) --pos;
    if (pos >= k) continue;
    const int last = m < k ? m : k - 1;
    for (int j = last; j > pos; --j) {
      index[j] = index[j - 1];
      weight[j] = weight[j - 1];
    }
    index[pos] = i;
    weight[pos] = p;  // weight[] holds the sorted penalties until the end
    if (m < k) ++m;
  }
  if (m == 0) return 0;
  const float thresh = m >= k ? weight[m - 1] : 1.01f * weight[m - 1] + 1e-6f;
  float sum = 0.f;
  for (int j = 0; j < m; ++j) {
    float w = thresh > 0.f ? 1.f - weight[j] / thresh : 0.f;
    w = w > 0.f ? w : 0.f;
    weight[j] = w;
    sum += w;
  }
  if (!(sum > 0.f) || !std::isfinite(sum)) {
    for (int j = 0; j < m; ++j) weight[j] = 1.f / static_cast<float>(m);
  } else {
    for (int j = 0; j < m; ++j) weight[j] /= sum;
  }
  return m;
}

// atan(t) on [0, 1] by a minimax polynomial (Abramowitz and Stegun 4.4.49, 9th order odd
// polynomial, max error 1e-5 rad): t * (kAtan1 + t^2 (kAtan3 + t^2 (kAtan5 + t^2 (kAtan7 + t^2 kAtan9)))).
// FastAtan2Pos below and the SSE2 / AVX2 / AVX-512 atan2 of the ULR kernel (hybrid.cpp) all evaluate it
// in this Horner order (the same bits).
constexpr float kAtan1 = 0.9998660f, kAtan3 = -0.3302995f, kAtan5 = 0.1801410f, kAtan7 = -0.0851330f,
                kAtan9 = 0.0208351f;

inline float AtanPoly01(float t) {
  const float t2 = t * t;
  return t * (kAtan1 + t2 * (kAtan3 + t2 * (kAtan5 + t2 * (kAtan7 + t2 * kAtan9))));
}

// atan2(y, x) for y >= 0 (an angle in [0, pi]) by AtanPoly01: ~4x faster than std::atan2 in the
// per-pixel, per-view penalty loop, and 1e-5 rad is far below any penalty difference that
// matters for ranking (pixels subtend ~1e-3 rad).
inline float FastAtan2Pos(float y, float x) {
  const float ax = std::abs(x);
  const bool swap = y > ax;
  const float num = swap ? ax : y, den = swap ? y : ax;
  if (!(den > 0.f)) return 0.f;
  float r = AtanPoly01(num / den);
  if (swap) r = 1.57079633f - r;
  if (x < 0.f) r = 3.14159265f - r;
  return r;
}

// UlrPenalty with the novel-side vector b = c_novel - p and its length lb computed once per point
// and the fast atan2: agrees with UlrPenalty within 2e-5 (tests/hybrid/test_hybrid_render.py). The ULR
// kernel's scalar path and PVM's cluster & blend (inline there: it runs per candidate).
inline float UlrPenaltyFast(const glm::vec3& p, const glm::vec3& b, float lb, const glm::vec3& c_view,
                            float resolution_weight) {
  const glm::vec3 a = c_view - p;
  const float la = glm::length(a);
  constexpr float kInf = std::numeric_limits<float>::infinity();
  if (!(la > 0.f) || !(lb > 0.f) || !std::isfinite(la) || !std::isfinite(lb)) return kInf;
  const float angle = FastAtan2Pos(glm::length(glm::cross(a, b)), glm::dot(a, b));
  const float ratio = la / lb - 1.f;
  const float pen = angle + resolution_weight * (ratio > 0.f ? ratio : 0.f);
  return std::isfinite(pen) ? pen : kInf;
}

}  // namespace ibr
