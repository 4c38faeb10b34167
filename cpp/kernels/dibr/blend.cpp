#include "kernels/dibr/blend.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>

#include <immintrin.h>  // AVX2: only in target("avx2") functions, called when the CPU has it

#include "ibr/colour.h"
#include "ibr/parallel.h"

namespace ibr {
namespace {
constexpr std::int64_t kRowsPerTask = 16;
}

void ClearBlend(const BlendBuffers& acc) {
  const std::ptrdiff_t w = acc.width;
  ParallelFor(acc.height, kRowsPerTask, [&](std::int64_t y0, std::int64_t y1) {
    for (std::int64_t i = y0 * w; i < y1 * w; ++i) {
      acc.sum_wc[3 * i] = acc.sum_wc[3 * i + 1] = acc.sum_wc[3 * i + 2] = 0.f;
      acc.sum_w[i] = acc.sum_w_invd[i] = acc.sum_q[i] = acc.max_q[i] = 0.f;
    }
  });
}

namespace {

void ResetPixel(const BlendBuffers& acc, std::ptrdiff_t i) {
  acc.sum_wc[3 * i] = acc.sum_wc[3 * i + 1] = acc.sum_wc[3 * i + 2] = 0.f;
  acc.sum_w[i] = acc.sum_w_invd[i] = acc.sum_q[i] = acc.max_q[i] = 0.f;
}

// Whether the fragment (depth d, quality q) joins the sums at pixel i, after resetting them
// when it replaces what they hold ("Visibility across views" in blend.h).
bool Admit(const BlendBuffers& acc, std::ptrdiff_t i, float d, float q) {
  if (!(acc.sum_w[i] > 0.f)) return true;
  if (acc.stretched_quality > 0.f) {
    const bool new_stretched = q < acc.stretched_quality;
    const bool old_stretched = acc.max_q[i] < acc.stretched_quality;
    if (new_stretched && !old_stretched) return false;
    if (!new_stretched && old_stretched) {
      ResetPixel(acc, i);
      return true;
    }
  }
  if (acc.depth_tolerance > 0.f) {
    // Accumulated depth sum_w / sum_w_invd without dividing: compare d * sum_w_invd with
    // sum_w * (1 -/+ tol). Infinite depths (1/d = 0) are handled apart to avoid inf * 0.
    const float s_inv = acc.sum_w_invd[i], s_w = acc.sum_w[i];
    if (std::isinf(d)) return s_inv == 0.f;  // only joins other fragments at infinity
    if (s_inv == 0.f) {                       // sums hold only infinity: a finite surface is nearer
      ResetPixel(acc, i);
      return true;
    }
    const float ratio_num = d * s_inv;         // = d / d_acc * s_w
    if (ratio_num < s_w * (1.f - acc.depth_tolerance)) {
      ResetPixel(acc, i);
      return true;
    }
    if (ratio_num > s_w * (1.f + acc.depth_tolerance)) return false;
  }
  return true;
}

}  // namespace

void AccumulateRow(const float* color, const float* depth, const float* weight, const float* quality,
                   const BlendBuffers& acc, int y) {
  const std::ptrdiff_t w = acc.width, o = std::ptrdiff_t(y) * w;
  const bool visibility = acc.stretched_quality > 0.f || acc.depth_tolerance > 0.f;
  const bool use_mq = acc.stretched_quality > 0.f;
  float *swc = acc.sum_wc + 3 * o, *sw = acc.sum_w + o, *swi = acc.sum_w_invd + o, *sq = acc.sum_q + o,
        *mq = acc.max_q + o;
  if (acc.fresh) {
    // Sums taken as 0 (blend.h): every pixel written; Admit admits every fragment into empty sums.
    for (std::ptrdiff_t x = 0; x < w; ++x) {
      const float wi = weight[x];
      if (!(wi > 0.f)) {
        swc[3 * x] = swc[3 * x + 1] = swc[3 * x + 2] = 0.f;
        sw[x] = swi[x] = sq[x] = 0.f;
        if (use_mq) mq[x] = 0.f;
        continue;
      }
      swc[3 * x] = 0.f + wi * color[3 * x];
      swc[3 * x + 1] = 0.f + wi * color[3 * x + 1];
      swc[3 * x + 2] = 0.f + wi * color[3 * x + 2];
      sw[x] = 0.f + wi;
      swi[x] = 0.f + wi / depth[x];
      sq[x] = 0.f + quality[x];
      if (use_mq) mq[x] = std::max(0.f, quality[x]);
    }
    return;
  }
  for (std::ptrdiff_t x = 0; x < w; ++x) {
    const float wi = weight[x];
    if (!(wi > 0.f)) continue;
    if (visibility && !Admit(acc, o + x, depth[x], quality[x])) continue;
    swc[3 * x] += wi * color[3 * x];
    swc[3 * x + 1] += wi * color[3 * x + 1];
    swc[3 * x + 2] += wi * color[3 * x + 2];
    sw[x] += wi;
    swi[x] += wi / depth[x];  // depth > 0 where covered; +inf gives 0
    sq[x] += quality[x];
    if (use_mq) mq[x] = std::max(mq[x], quality[x]);
  }
}

// A running sum's eight lanes, or 0 for fresh sums (not read).
template <bool kFresh>
__attribute__((target("avx2"))) inline __m256 LoadSum(const float* p) {
  return kFresh ? _mm256_setzero_ps() : _mm256_loadu_ps(p);
}

// fresh (blend.h): the sums are taken as 0 and not read; uncovered pixels get 0, covered ones
// 0 + the view's values (the same bits as adding them to cleared sums). max_q is not kept here
// (no visibility rule: stretched_quality == 0).
template <bool kFresh>
__attribute__((target("avx2"))) inline void AccumulateRowPlainAvx2T(const float* color, const float* depth,
                                                                     const float* weight, const float* quality,
                                                                     const BlendBuffers& acc, int y) {
  const std::ptrdiff_t w = acc.width, o = std::ptrdiff_t(y) * w;
  float *swc = acc.sum_wc + 3 * o, *sw = acc.sum_w + o, *swi = acc.sum_w_invd + o, *sq = acc.sum_q + o;
  // lane k of the three colour vectors holds channel (8 j + k) % 3 of pixel (8 j + k) / 3
  const __m256i p0 = _mm256_setr_epi32(0, 0, 0, 1, 1, 1, 2, 2), p1 = _mm256_setr_epi32(2, 3, 3, 3, 4, 4, 4, 5);
  const __m256i p2 = _mm256_setr_epi32(5, 5, 6, 6, 6, 7, 7, 7);
  const __m256 zero = _mm256_setzero_ps();
  std::ptrdiff_t x = 0;
  for (; x + 8 <= w; x += 8) {
    const __m256 wi = _mm256_loadu_ps(weight + x);
    const __m256 cov = _mm256_cmp_ps(wi, zero, _CMP_GT_OQ);  // !(wi > 0): skipped
    const int m = _mm256_movemask_ps(cov);
    if (m == 0) {
      if (kFresh) {
        _mm256_storeu_ps(sw + x, zero);
        _mm256_storeu_ps(swi + x, zero);
        _mm256_storeu_ps(sq + x, zero);
        for (int j = 0; j < 3; ++j) _mm256_storeu_ps(swc + 3 * x + 8 * j, zero);
      }
      continue;
    }
    const __m256 d = _mm256_loadu_ps(depth + x), q = _mm256_loadu_ps(quality + x);
    const __m256 s_w = LoadSum<kFresh>(sw + x);
    _mm256_storeu_ps(sw + x, _mm256_blendv_ps(s_w, _mm256_add_ps(s_w, wi), cov));
    const __m256 s_i = LoadSum<kFresh>(swi + x);
    _mm256_storeu_ps(swi + x, _mm256_blendv_ps(s_i, _mm256_add_ps(s_i, _mm256_div_ps(wi, d)), cov));
    const __m256 s_q = LoadSum<kFresh>(sq + x);
    _mm256_storeu_ps(sq + x, _mm256_blendv_ps(s_q, _mm256_add_ps(s_q, q), cov));
    const __m256i covi = _mm256_castps_si256(cov);
    const __m256i perm[3] = {p0, p1, p2};
    for (int j = 0; j < 3; ++j) {
      const __m256 wj = _mm256_permutevar8x32_ps(wi, perm[j]);
      const __m256 cj = _mm256_castsi256_ps(_mm256_permutevar8x32_epi32(covi, perm[j]));
      const __m256 s = LoadSum<kFresh>(swc + 3 * x + 8 * j);
      const __m256 c = _mm256_loadu_ps(color + 3 * x + 8 * j);
      _mm256_storeu_ps(swc + 3 * x + 8 * j, _mm256_blendv_ps(s, _mm256_add_ps(s, _mm256_mul_ps(wj, c)), cj));
    }
  }
  for (; x < w; ++x) {
    const float wi = weight[x];
    if (!(wi > 0.f)) {
      if (kFresh) {
        swc[3 * x] = swc[3 * x + 1] = swc[3 * x + 2] = 0.f;
        sw[x] = swi[x] = sq[x] = 0.f;
      }
      continue;
    }
    const float b_wc0 = kFresh ? 0.f : swc[3 * x], b_wc1 = kFresh ? 0.f : swc[3 * x + 1],
                b_wc2 = kFresh ? 0.f : swc[3 * x + 2];
    swc[3 * x] = b_wc0 + wi * color[3 * x];
    swc[3 * x + 1] = b_wc1 + wi * color[3 * x + 1];
    swc[3 * x + 2] = b_wc2 + wi * color[3 * x + 2];
    sw[x] = (kFresh ? 0.f : sw[x]) + wi;
    swi[x] = (kFresh ? 0.f : swi[x]) + wi / depth[x];
    sq[x] = (kFresh ? 0.f : sq[x]) + quality[x];
  }
}

// AccumulateRow without the visibility rules, eight pixels per AVX2 step (the warp calls it from
// its AVX2 clone). Uncovered pixels keep their sums by a select (not by adding 0: the band-local
// colour and depth of an uncovered pixel are stale), covered ones get the scalar loop's
// operations (products, the division, the sums) lane by lane: the same bits.
__attribute__((target("avx2"))) void AccumulateRowPlainAvx2(const float* color, const float* depth,
                                                             const float* weight, const float* quality,
                                                             const BlendBuffers& acc, int y) {
  if (acc.fresh) {
    AccumulateRowPlainAvx2T<true>(color, depth, weight, quality, acc, y);
  } else {
    AccumulateRowPlainAvx2T<false>(color, depth, weight, quality, acc, y);
  }
}

void AccumulateRows(const float* color, const float* depth, const float* weight, const float* quality,
                    const BlendBuffers& acc, int y0, int y1) {
  const std::ptrdiff_t w = acc.width;
  for (int y = y0; y < y1; ++y) {
    const std::ptrdiff_t o = std::ptrdiff_t(y) * w;
    AccumulateRow(color + 3 * o, depth + o, weight + o, quality + o, acc, y);
  }
}

namespace {

// ResolveBlend's pixels [i0, i1), eight per AVX2 step: the scalar loop's operations lane by lane
// (the divisions 1 / sum_w and sum_w / sum_w_invd, the products, the selects): the same bits.
// Returns the first pixel not done.
__attribute__((target("avx2"))) std::ptrdiff_t ResolveAvx2(const BlendBuffers& acc, std::ptrdiff_t i0,
                                                            std::ptrdiff_t i1, float* color, float* depth,
                                                            float* confidence, std::uint8_t* hole) {
  const __m256i p0 = _mm256_setr_epi32(0, 0, 0, 1, 1, 1, 2, 2), p1 = _mm256_setr_epi32(2, 3, 3, 3, 4, 4, 4, 5);
  const __m256i p2 = _mm256_setr_epi32(5, 5, 6, 6, 6, 7, 7, 7);
  const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.f);
  const __m256 inf = _mm256_set1_ps(std::numeric_limits<float>::infinity());
  const __m256 sq_t = _mm256_set1_ps(acc.stretched_quality);
  std::ptrdiff_t i = i0;
  for (; i + 8 <= i1; i += 8) {
    const __m256 sw = _mm256_loadu_ps(acc.sum_w + i);
    __m256 ok = _mm256_cmp_ps(sw, zero, _CMP_GT_OQ);
    if (acc.stretched_holes) ok = _mm256_andnot_ps(_mm256_cmp_ps(_mm256_loadu_ps(acc.max_q + i), sq_t, _CMP_LT_OQ), ok);
    const __m256 inv = _mm256_div_ps(one, sw);
    const __m256i oki = _mm256_castps_si256(ok);
    const __m256i perm[3] = {p0, p1, p2};
    for (int j = 0; j < 3; ++j) {
      const __m256 c = _mm256_mul_ps(_mm256_loadu_ps(acc.sum_wc + 3 * i + 8 * j), _mm256_permutevar8x32_ps(inv, perm[j]));
      _mm256_storeu_ps(color + 3 * i + 8 * j, _mm256_and_ps(c, _mm256_castsi256_ps(_mm256_permutevar8x32_epi32(oki, perm[j]))));
    }
    const __m256 s = _mm256_loadu_ps(acc.sum_w_invd + i);
    const __m256 d = _mm256_blendv_ps(inf, _mm256_div_ps(sw, s), _mm256_cmp_ps(s, zero, _CMP_GT_OQ));
    _mm256_storeu_ps(depth + i, _mm256_and_ps(d, ok));
    _mm256_storeu_ps(confidence + i, _mm256_and_ps(_mm256_loadu_ps(acc.sum_q + i), ok));
    const unsigned holes = ~unsigned(_mm256_movemask_ps(ok));
    for (int k = 0; k < 8; ++k) hole[i + k] = std::uint8_t((holes >> k) & 1u);
  }
  return i;
}

// ResolveBlend's pixels [i0, i1): the AVX2 steps, then the scalar loop for the rest.
void ResolvePixels(const BlendBuffers& acc, std::ptrdiff_t i0, std::ptrdiff_t i1, float* color, float* depth,
                   float* confidence, std::uint8_t* hole, bool avx2) {
  std::ptrdiff_t i = i0;
  if (avx2) i = ResolveAvx2(acc, i, i1, color, depth, confidence, hole);
  for (; i < i1; ++i) {
    const float sw = acc.sum_w[i];
    const bool stretched_only = acc.stretched_holes && acc.max_q[i] < acc.stretched_quality;
    if (sw > 0.f && !stretched_only) {
      const float inv = 1.f / sw;
      color[3 * i] = acc.sum_wc[3 * i] * inv;
      color[3 * i + 1] = acc.sum_wc[3 * i + 1] * inv;
      color[3 * i + 2] = acc.sum_wc[3 * i + 2] * inv;
      const float s = acc.sum_w_invd[i];
      depth[i] = s > 0.f ? sw / s : std::numeric_limits<float>::infinity();
      confidence[i] = acc.sum_q[i];
      hole[i] = 0;
    } else {
      color[3 * i] = color[3 * i + 1] = color[3 * i + 2] = 0.f;
      depth[i] = 0.f;
      confidence[i] = 0.f;
      hole[i] = 1;
    }
  }
}

}  // namespace

void ResolveBlend(const BlendBuffers& acc, float* color, float* depth, float* confidence, std::uint8_t* hole,
                  bool avx2, BlendSpace space) {
  const std::ptrdiff_t w = acc.width;
  ParallelFor(acc.height, kRowsPerTask, [&](std::int64_t y0, std::int64_t y1) {
    if (space == BlendSpace::kLinear) {
      ResolvePixels(acc, y0 * w, y1 * w, color, depth, confidence, hole, avx2);
      return;
    }
    // Decode each row right after resolving it (3 W floats, in L1): no second pass over the image.
    // A hole's 0 decodes to 0 (0 / 12.92).
    for (std::int64_t y = y0; y < y1; ++y) {
      ResolvePixels(acc, y * w, (y + 1) * w, color, depth, confidence, hole, avx2);
      SrgbToLinearTableRun(color + 3 * y * w, 3 * w, avx2);
    }
  });
}

}  // namespace ibr
