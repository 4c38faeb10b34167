// PatchMatch multi-view stereo kernels (patchmatch.h has the contract and the papers).
#include "kernels/mvs/patchmatch.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>

#include "ibr/parallel.h"
#include "ibr/simd.h"

#if defined(IBR_HAVE_AVX2_DISPATCH)
#include <immintrin.h>
#endif

namespace ibr::mvs {
namespace {

constexpr float kMaxCost = 2.0f;
constexpr int kMaxSamples = 256;   // (2 r / step + 1)^2 for r <= 15, step >= 2 (the front checks)
constexpr int kMaxSources = 32;

// splitmix64's finaliser: the counter-based random numbers (determinism, see the header).
inline std::uint64_t Mix(std::uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

struct Rng {
  std::uint64_t state;
  Rng(std::uint64_t seed, std::uint64_t it, std::uint64_t pixel)
      : state(Mix(seed * 0x632be59bd9b4e019ULL ^ Mix(it * 0x8cb92ba72f3d8dd7ULL ^ Mix(pixel)))) {}
  float Uniform() {  // [0, 1)
    state = Mix(state);
    return static_cast<float>(state >> 40) * (1.0f / 16777216.0f);
  }
};

struct V3 {
  float x, y, z;
};
inline float Dot(const V3& a, const V3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline V3 Normalised(const V3& a) {
  const float l = std::sqrt(Dot(a, a));
  return l > 0 ? V3{a.x / l, a.y / l, a.z / l} : V3{0, 0, -1};
}

// n turned to face the camera along `ray`; a grazing one (|cos| < 0.1) becomes fronto-parallel.
V3 FaceCamera(V3 n, const V3& ray) {
  const V3 r = Normalised(ray);
  float c = Dot(n, r);
  if (c > 0) n = V3{-n.x, -n.y, -n.z}, c = -c;
  if (c > -0.1f) return V3{-r.x, -r.y, -r.z};  // grazing: fronto-parallel instead
  return n;
}

struct Offset {
  float dx, dy, w_spatial;
};

// One source view in the reference camera's frame.
struct Source {
  const SourceView* view;
  float A[9];          // K_s R K_r^-1, row-major
  float b[3];          // K_s t
  float R[9], t[3];    // source_from_reference (the geometric term)
  float fx, fy, cx, cy;
  float w, h;
  bool geometric;
};

// The reference window of one pixel: grey values, bilateral weights, weighted mean and variance.
struct Window {
  int n = 0;
  float dx[kMaxSamples], dy[kMaxSamples], g[kMaxSamples], w[kMaxSamples];
  float sw = 0, mean = 0, var = 0;
};

// Samples of a window in whole groups of 8 (the padding has weight 0, grey 0, offset 0).
inline int PaddedSamples(int n) { return (n + 7) & ~7; }

// The source's weighted sums of Photometric over the window: the bilinear grey v_i at the
// homography's image of each sample, ss = sum w_i v_i, sss = sum w_i v_i^2, srs = sum w_i v_i g_i.
// Sample i adds into lane i mod 8 in order and the 8 lanes are summed as ((l0 + l4) + (l2 + l6))
// + ((l1 + l5) + (l3 + l7)), in both versions: the AVX2 one (gathers; no FMA) and the baseline one
// give the same bits (tests/mvs/test_mvs.py compares them). A padding sample adds 0 * v = 0.
struct SampleSums {
  float ss, sss, srs;
};

inline float Reduce8(const float l[8]) {
  const float s0 = l[0] + l[4], s1 = l[1] + l[5], s2 = l[2] + l[6], s3 = l[3] + l[7];
  return (s0 + s2) + (s1 + s3);
}

// max / min as the SSE / AVX instructions define them (a > b ? a : b), so that both versions agree
// on the sign of a zero.
inline float MaxPs(float a, float b) { return a > b ? a : b; }
inline float MinPs(float a, float b) { return a < b ? a : b; }

SampleSums SampleSumsBaseline(const ImageView<const float>& im, const float* h, float hx0, float hy0, float hz0,
                              float xmax, float ymax, const Window& win) {
  float ss[8] = {}, sss[8] = {}, srs[8] = {};
  const float* base = im.Row(0);
  const std::ptrdiff_t stride = im.row_stride;
  const int n = PaddedSamples(win.n);
  for (int i0 = 0; i0 < n; i0 += 8) {
    for (int l = 0; l < 8; ++l) {
      const int i = i0 + l;
      const float dx = win.dx[i], dy = win.dy[i];
      const float inv = 1.0f / ((hz0 + h[6] * dx) + h[7] * dy);
      const float x = MinPs(MaxPs(((hx0 + h[0] * dx) + h[1] * dy) * inv - 0.5f, 0.0f), xmax);
      const float y = MinPs(MaxPs(((hy0 + h[3] * dx) + h[4] * dy) * inv - 0.5f, 0.0f), ymax);
      const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
      const float ax = x - static_cast<float>(x0), ay = y - static_cast<float>(y0);
      const float* r0 = base + std::ptrdiff_t(y0) * stride + x0;
      const float* r1 = r0 + stride;
      const float top = r0[0] + ax * (r0[1] - r0[0]);
      const float bot = r1[0] + ax * (r1[1] - r1[0]);
      const float v = top + ay * (bot - top);
      const float wv = win.w[i] * v;
      ss[l] += wv;
      sss[l] += wv * v;
      srs[l] += wv * win.g[i];
    }
  }
  return {Reduce8(ss), Reduce8(sss), Reduce8(srs)};
}

#if defined(IBR_HAVE_AVX2_DISPATCH)
__attribute__((target("avx2"))) inline float Reduce8Avx2(__m256 v) {
  const __m128 s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));  // l_k + l_k+4
  const __m128 t = _mm_add_ps(s, _mm_movehl_ps(s, s));                                 // s0 + s2, s1 + s3
  return _mm_cvtss_f32(_mm_add_ss(t, _mm_shuffle_ps(t, t, 1)));
}

__attribute__((target("avx2"))) SampleSums SampleSumsAvx2(const ImageView<const float>& im, const float* h, float hx0,
                                                          float hy0, float hz0, float xmax, float ymax,
                                                          const Window& win) {
  const __m256 h0 = _mm256_set1_ps(h[0]), h1 = _mm256_set1_ps(h[1]), h3 = _mm256_set1_ps(h[3]);
  const __m256 h4 = _mm256_set1_ps(h[4]), h6 = _mm256_set1_ps(h[6]), h7 = _mm256_set1_ps(h[7]);
  const __m256 vx0 = _mm256_set1_ps(hx0), vy0 = _mm256_set1_ps(hy0), vz0 = _mm256_set1_ps(hz0);
  const __m256 one = _mm256_set1_ps(1.0f), half = _mm256_set1_ps(0.5f), zero = _mm256_setzero_ps();
  const __m256 vxmax = _mm256_set1_ps(xmax), vymax = _mm256_set1_ps(ymax);
  const float* base = im.Row(0);
  const __m256i stride = _mm256_set1_epi32(static_cast<int>(im.row_stride));
  const __m256i stride1 = _mm256_set1_epi32(static_cast<int>(im.row_stride) + 1), one_i = _mm256_set1_epi32(1);
  __m256 ss = zero, sss = zero, srs = zero;
  const int n = PaddedSamples(win.n);
  for (int i = 0; i < n; i += 8) {
    const __m256 dx = _mm256_loadu_ps(win.dx + i), dy = _mm256_loadu_ps(win.dy + i);
    const __m256 inv = _mm256_div_ps(one, _mm256_add_ps(_mm256_add_ps(vz0, _mm256_mul_ps(h6, dx)), _mm256_mul_ps(h7, dy)));
    const __m256 px = _mm256_add_ps(_mm256_add_ps(vx0, _mm256_mul_ps(h0, dx)), _mm256_mul_ps(h1, dy));
    const __m256 py = _mm256_add_ps(_mm256_add_ps(vy0, _mm256_mul_ps(h3, dx)), _mm256_mul_ps(h4, dy));
    const __m256 x = _mm256_min_ps(_mm256_max_ps(_mm256_sub_ps(_mm256_mul_ps(px, inv), half), zero), vxmax);
    const __m256 y = _mm256_min_ps(_mm256_max_ps(_mm256_sub_ps(_mm256_mul_ps(py, inv), half), zero), vymax);
    const __m256i xi = _mm256_cvttps_epi32(x), yi = _mm256_cvttps_epi32(y);
    const __m256 ax = _mm256_sub_ps(x, _mm256_cvtepi32_ps(xi)), ay = _mm256_sub_ps(y, _mm256_cvtepi32_ps(yi));
    const __m256i idx = _mm256_add_epi32(_mm256_mullo_epi32(yi, stride), xi);
    const __m256 a = _mm256_i32gather_ps(base, idx, 4);
    const __m256 b = _mm256_i32gather_ps(base, _mm256_add_epi32(idx, one_i), 4);
    const __m256 c = _mm256_i32gather_ps(base, _mm256_add_epi32(idx, stride), 4);
    const __m256 d = _mm256_i32gather_ps(base, _mm256_add_epi32(idx, stride1), 4);
    const __m256 top = _mm256_add_ps(a, _mm256_mul_ps(ax, _mm256_sub_ps(b, a)));
    const __m256 bot = _mm256_add_ps(c, _mm256_mul_ps(ax, _mm256_sub_ps(d, c)));
    const __m256 v = _mm256_add_ps(top, _mm256_mul_ps(ay, _mm256_sub_ps(bot, top)));
    const __m256 wv = _mm256_mul_ps(_mm256_loadu_ps(win.w + i), v);
    ss = _mm256_add_ps(ss, wv);
    sss = _mm256_add_ps(sss, _mm256_mul_ps(wv, v));
    srs = _mm256_add_ps(srs, _mm256_mul_ps(wv, _mm256_loadu_ps(win.g + i)));
  }
  return {Reduce8Avx2(ss), Reduce8Avx2(sss), Reduce8Avx2(srs)};
}
#else
inline SampleSums SampleSumsAvx2(const ImageView<const float>& im, const float* h, float hx0, float hy0, float hz0,
                                 float xmax, float ymax, const Window& win) {
  return SampleSumsBaseline(im, h, hx0, hy0, hz0, xmax, ymax, win);
}
#endif

class Matcher {
 public:
  Matcher(const ImageView<const float>& ref, const Camera& cam, const std::vector<SourceView>& sources,
          const PatchMatchOptions& o)
      : ref_(ref), o_(o) {
    fx_ = static_cast<float>(cam.fx), fy_ = static_cast<float>(cam.fy);
    cx_ = static_cast<float>(cam.cx), cy_ = static_cast<float>(cam.cy);
    for (int dy = -o.window_radius; dy <= o.window_radius; dy += o.window_step) {
      for (int dx = -o.window_radius; dx <= o.window_radius; dx += o.window_step) {
        const float d2 = static_cast<float>(dx * dx + dy * dy);
        offsets_.push_back({static_cast<float>(dx), static_cast<float>(dy),
                            -d2 / (2.0f * o.sigma_spatial * o.sigma_spatial)});
      }
    }
    // glm takes columns: K_r^-1 = [[1/fx, 0, -cx/fx], [0, 1/fy, -cy/fy], [0, 0, 1]].
    const glm::dmat3 kr_inv(1.0 / cam.fx, 0, 0, 0, 1.0 / cam.fy, 0, -cam.cx / cam.fx, -cam.cy / cam.fy, 1.0);
    for (const SourceView& sv : sources) {
      const Camera& c = sv.camera;
      Source s{};
      s.view = &sv;
      const glm::dmat3 rot = c.rot * glm::transpose(cam.rot);
      const glm::dvec3 t = c.trans - rot * cam.trans;
      const glm::dmat3 ks = glm::transpose(glm::dmat3(c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1));  // rows given
      const glm::dmat3 a = ks * rot * kr_inv;
      const glm::dvec3 b = ks * t;
      for (int r = 0; r < 3; ++r) {
        for (int k = 0; k < 3; ++k) {
          s.A[r * 3 + k] = static_cast<float>(a[k][r]);
          s.R[r * 3 + k] = static_cast<float>(rot[k][r]);
        }
        s.b[r] = static_cast<float>(b[r]);
        s.t[r] = static_cast<float>(t[r]);
      }
      s.fx = static_cast<float>(c.fx), s.fy = static_cast<float>(c.fy);
      s.cx = static_cast<float>(c.cx), s.cy = static_cast<float>(c.cy);
      s.w = static_cast<float>(c.width), s.h = static_cast<float>(c.height);
      s.geometric = o.geom_weight > 0 && !sv.depth.Empty();
      sources_.push_back(s);
    }
    k_ = std::max(1, std::min(o.best_k, static_cast<int>(sources_.size())));
  }

  V3 Ray(float px, float py) const { return {(px - cx_) / fx_, (py - cy_) / fy_, 1.0f}; }

  // Fills the window of pixel (x, y); false when it is textureless.
  bool BuildWindow(int x, int y, Window* win) const {
    const float gc = ref_.At(y, x);
    const float inv2c = 1.0f / (2.0f * o_.sigma_color * o_.sigma_color);
    double sw = 0, sg = 0, sgg = 0;
    int n = 0;
    for (const Offset& of : offsets_) {
      const int xx = x + static_cast<int>(of.dx), yy = y + static_cast<int>(of.dy);
      if (xx < 0 || yy < 0 || xx >= ref_.width || yy >= ref_.height) continue;
      const float g = ref_.At(yy, xx);
      const float w = std::exp(of.w_spatial - (g - gc) * (g - gc) * inv2c);
      win->dx[n] = of.dx, win->dy[n] = of.dy, win->g[n] = g, win->w[n] = w;
      sw += w, sg += double(w) * g, sgg += double(w) * g * g;
      ++n;
    }
    win->n = n;
    for (int i = n; i < PaddedSamples(n); ++i) win->dx[i] = 0, win->dy[i] = 0, win->g[i] = 0, win->w[i] = 0;
    if (!(sw > 0)) return false;
    const double mean = sg / sw;
    const double var = sgg / sw - mean * mean;
    win->sw = static_cast<float>(sw), win->mean = static_cast<float>(mean), win->var = static_cast<float>(var);
    return var >= o_.min_variance;
  }

  // The aggregated cost of plane (z, n) at pixel (x, y) with window `win`.
  float Cost(int x, int y, const Window& win, float z, const V3& n, std::int64_t* evals) const {
    const float px = x + 0.5f, py = y + 0.5f;
    const V3 ray = Ray(px, py);
    const float c = z * Dot(n, ray);
    if (!(z > 0) || !(c < 0)) return kMaxCost;
    const float m[3] = {n.x / fx_ / c, n.y / fy_ / c, (n.z - n.x * cx_ / fx_ - n.y * cy_ / fy_) / c};
    float costs[kMaxSources];
    const int ns = static_cast<int>(sources_.size());
    for (int si = 0; si < ns; ++si) {
      const Source& s = sources_[si];
      float h[9];
      for (int r = 0; r < 3; ++r) {
        for (int k = 0; k < 3; ++k) h[r * 3 + k] = s.A[r * 3 + k] + s.b[r] * m[k];
      }
      costs[si] = Photometric(s, h, px, py, win);
      if (s.geometric && costs[si] < kMaxCost) {
        costs[si] += o_.geom_weight * Geometric(s, px, py, ray, z);
      }
    }
    *evals += ns;
    // The mean of the best k (insertion sort: a few sources).
    for (int i = 1; i < ns; ++i) {
      const float v = costs[i];
      int j = i - 1;
      while (j >= 0 && costs[j] > v) {
        costs[j + 1] = costs[j];
        --j;
      }
      costs[j + 1] = v;
    }
    float sum = 0;
    for (int i = 0; i < k_; ++i) sum += costs[i];
    return std::min(kMaxCost, sum / static_cast<float>(k_));
  }

  float Photometric(const Source& s, const float* h, float px, float py, const Window& win) const {
    const float hx0 = h[0] * px + h[1] * py + h[2];
    const float hy0 = h[3] * px + h[4] * py + h[5];
    const float hz0 = h[6] * px + h[7] * py + h[8];
    if (!(hz0 > 0)) return kMaxCost;
    const float ux = hx0 / hz0, uy = hy0 / hz0;
    if (!(ux >= 0 && uy >= 0 && ux <= s.w && uy <= s.h)) return kMaxCost;
    // hz is affine in the offset: positive at the window's four corners, positive everywhere in it.
    const float r = static_cast<float>(o_.window_radius);
    for (const float cx : {-r, r}) {
      for (const float cy : {-r, r}) {
        if (!(hz0 + h[6] * cx + h[7] * cy > 0)) return kMaxCost;
      }
    }
    const ImageView<const float>& im = s.view->grey;
    const SampleSums sums = avx2_ ? SampleSumsAvx2(im, h, hx0, hy0, hz0, s.w - 1.001f, s.h - 1.001f, win)
                                  : SampleSumsBaseline(im, h, hx0, hy0, hz0, s.w - 1.001f, s.h - 1.001f, win);
    const float ss = sums.ss, sss = sums.sss, srs = sums.srs;
    const float inv_sw = 1.0f / win.sw;
    const float ms = ss * inv_sw;
    const float vs = sss * inv_sw - ms * ms;
    if (!(vs >= o_.min_variance)) return kMaxCost;
    const float cov = srs * inv_sw - win.mean * ms;
    const float ncc = cov / std::sqrt(win.var * vs);
    return 1.0f - std::min(1.0f, std::max(-1.0f, ncc));
  }

  // min(forward-backward reprojection error in pixels, geom_max_error) of the point at depth z
  // on `ray` through the source's depth map.
  float Geometric(const Source& s, float px, float py, const V3& ray, float z) const {
    const float X[3] = {ray.x * z, ray.y * z, z};
    float Y[3];
    for (int r = 0; r < 3; ++r) Y[r] = s.R[r * 3] * X[0] + s.R[r * 3 + 1] * X[1] + s.R[r * 3 + 2] * X[2] + s.t[r];
    const float cap = o_.geom_max_error;
    if (!(Y[2] > 0)) return cap;
    const float u = s.fx * Y[0] / Y[2] + s.cx, v = s.fy * Y[1] / Y[2] + s.cy;
    if (!(u >= 0 && v >= 0 && u < s.w && v < s.h)) return cap;
    const float d = s.view->depth.At(static_cast<int>(v), static_cast<int>(u));
    if (!(d > 0) || !std::isfinite(d)) return cap;
    const float Ys[3] = {(u - s.cx) / s.fx * d, (v - s.cy) / s.fy * d, d};
    float Xb[3];  // R^T (Ys - t)
    for (int k = 0; k < 3; ++k) {
      Xb[k] = s.R[k] * (Ys[0] - s.t[0]) + s.R[3 + k] * (Ys[1] - s.t[1]) + s.R[6 + k] * (Ys[2] - s.t[2]);
    }
    if (!(Xb[2] > 0)) return cap;
    const float bu = fx_ * Xb[0] / Xb[2] + cx_, bv = fy_ * Xb[1] / Xb[2] + cy_;
    const float e = std::sqrt((bu - px) * (bu - px) + (bv - py) * (bv - py));
    return std::min(e, cap);
  }

 private:
  const ImageView<const float>& ref_;
  const PatchMatchOptions& o_;
  float fx_, fy_, cx_, cy_;
  std::vector<Offset> offsets_;
  std::vector<Source> sources_;
  int k_ = 1;
  bool avx2_ = UseAvx2();
};

// A random unit normal facing the camera along `ray` (not grazing: |cos| >= 0.1).
V3 RandomNormal(Rng& rng, const V3& ray) {
  const float u = rng.Uniform() * 2.0f - 1.0f, phi = rng.Uniform() * 6.2831853f;
  const float r = std::sqrt(std::max(0.0f, 1.0f - u * u));
  V3 n{r * std::cos(phi), r * std::sin(phi), u};
  return FaceCamera(n, ray);
}

}  // namespace

PatchMatchStats PatchMatch(const ImageView<const float>& ref_grey, const Camera& ref_cam,
                           const std::vector<SourceView>& sources, const PatchMatchOptions& o,
                           bool initialised, ImageView<float> depth, ImageView<float> normal,
                           ImageView<float> cost) {
  PatchMatchStats stats;
  const int H = ref_grey.height, W = ref_grey.width;
  const Matcher mt(ref_grey, ref_cam, sources, o);
  const float inv_lo = static_cast<float>(1.0 / o.max_depth), inv_hi = static_cast<float>(1.0 / o.min_depth);
  const float inv_span = inv_hi - inv_lo;
  const std::int64_t grain = std::max<std::int64_t>(1, 4096 / std::max(1, W));
  std::atomic<std::int64_t> evals{0}, textureless{0};

  auto load = [&](int x, int y) -> std::pair<float, V3> {
    const float* n = &normal.At(y, x, 0);
    return {depth.At(y, x), V3{n[0], n[1], n[2]}};
  };
  auto store = [&](int x, int y, float z, const V3& n, float c) {
    depth.At(y, x) = z;
    float* p = &normal.At(y, x, 0);
    p[0] = n.x, p[1] = n.y, p[2] = n.z;
    cost.At(y, x) = c;
  };

  // Start: a hypothesis per pixel (given or random) and its cost; textureless pixels unknown.
  ParallelFor(H, grain, [&](std::int64_t y0, std::int64_t y1) {
    Window win;
    std::int64_t ev = 0, tl = 0;
    for (int y = static_cast<int>(y0); y < y1; ++y) {
      for (int x = 0; x < W; ++x) {
        if (!mt.BuildWindow(x, y, &win)) {
          store(x, y, 0.0f, V3{0, 0, -1}, kMaxCost);
          ++tl;
          continue;
        }
        const V3 ray = mt.Ray(x + 0.5f, y + 0.5f);
        auto [z, n] = load(x, y);
        if (!initialised || !(z > 0) || !std::isfinite(z) || !(Dot(n, ray) < 0)) {
          Rng rng(o.seed, 0xffffffffULL, static_cast<std::uint64_t>(y) * W + x);
          z = 1.0f / (inv_lo + rng.Uniform() * inv_span);
          n = RandomNormal(rng, ray);
        }
        store(x, y, z, n, mt.Cost(x, y, win, z, n, &ev));
      }
    }
    evals += ev;
    textureless += tl;
  });

  static const int kNeighbours[8][2] = {{-1, 0}, {1, 0}, {0, -1}, {0, 1}, {-5, 0}, {5, 0}, {0, -5}, {0, 5}};
  for (int it = 0; it < o.iterations; ++it) {
    // Refinement ranges halve every iteration (Gipuma sec. 3.3): inverse depth, and the normal's
    // perturbation (a random vector of this length added, then normalised).
    const float scale = std::ldexp(1.0f, -std::min(it + o.first_iteration, 30));
    const float d_inv = 0.25f * inv_span * scale, d_n = 0.6f * scale;
    for (int colour = 0; colour < 2; ++colour) {
      ParallelFor(H, grain, [&](std::int64_t y0, std::int64_t y1) {
        Window win;
        std::int64_t ev = 0;
        for (int y = static_cast<int>(y0); y < y1; ++y) {
          for (int x = (y + colour) & 1; x < W; x += 2) {
            if (!(cost.At(y, x) < kMaxCost) && !(depth.At(y, x) > 0)) continue;  // textureless
            if (!mt.BuildWindow(x, y, &win)) continue;
            auto [bz, bn] = load(x, y);
            float bc = cost.At(y, x);
            auto consider = [&](float z, const V3& n) {
              const float c = mt.Cost(x, y, win, z, n, &ev);
              if (c < bc) bz = z, bn = n, bc = c;
            };
            for (int k = 0; k < (o.refine_only ? 4 : 8); ++k) {
              const int xx = x + kNeighbours[k][0], yy = y + kNeighbours[k][1];
              if (xx < 0 || yy < 0 || xx >= W || yy >= H) continue;
              auto [z, n] = load(xx, yy);
              if (z > 0 && cost.At(yy, xx) < kMaxCost) consider(z, n);
            }
            const V3 ray = mt.Ray(x + 0.5f, y + 0.5f);
            Rng rng(o.seed, static_cast<std::uint64_t>(it + o.first_iteration), static_cast<std::uint64_t>(y) * W + x);
            const float z_rand = 1.0f / (inv_lo + rng.Uniform() * inv_span);
            const V3 n_rand = RandomNormal(rng, ray);
            float inv_p = 1.0f / bz + (rng.Uniform() * 2.0f - 1.0f) * d_inv;
            inv_p = std::min(inv_hi, std::max(inv_lo, inv_p));
            const float z_pert = 1.0f / inv_p;
            const V3 jit{(rng.Uniform() * 2 - 1) * d_n, (rng.Uniform() * 2 - 1) * d_n, (rng.Uniform() * 2 - 1) * d_n};
            const V3 cur = bn;
            const float cz = bz;
            const V3 n_pert = FaceCamera(Normalised(V3{cur.x + jit.x, cur.y + jit.y, cur.z + jit.z}), ray);
            if (!o.refine_only) consider(z_rand, cur);
            consider(cz, n_rand);
            consider(z_pert, n_pert);
            consider(z_pert, cur);
            consider(cz, n_pert);
            store(x, y, bz, bn, bc);
          }
        }
        evals += ev;
      });
    }
  }
  stats.evaluations = evals.load();
  stats.textureless = textureless.load();
  return stats;
}

void ConsistentViews(const ImageView<const float>& ref_depth, const Camera& ref_cam,
                     const std::vector<SourceView>& sources, float max_error_px, float max_rel_depth,
                     float min_angle_deg, ImageView<float> count) {
  const int H = ref_depth.height, W = ref_depth.width;
  const double cos_min = std::cos(min_angle_deg * 3.14159265358979323846 / 180.0);
  struct Rel {
    glm::dmat3 rot;
    glm::dvec3 t, centre;  // source_from_reference; the source centre in reference axes
  };
  std::vector<Rel> rel;
  for (const SourceView& s : sources) {
    Rel r;
    r.rot = s.camera.rot * glm::transpose(ref_cam.rot);
    r.t = s.camera.trans - r.rot * ref_cam.trans;
    r.centre = -(glm::transpose(r.rot) * r.t);
    rel.push_back(r);
  }
  ParallelFor(H, std::max<std::int64_t>(1, 16384 / std::max(1, W)), [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < y1; ++y) {
      for (int x = 0; x < W; ++x) {
        const float z = ref_depth.At(y, x);
        float n = 0;
        if (z > 0 && std::isfinite(z)) {
          const glm::dvec3 X = ref_cam.RayInCam(x + 0.5, y + 0.5) * double(z);
          for (std::size_t si = 0; si < sources.size(); ++si) {
            const SourceView& s = sources[si];
            const Rel& r = rel[si];
            const glm::dvec3 Y = r.rot * X + r.t;
            double u = 0, v = 0, d = 0;
            if (!s.camera.ProjectCam(Y, &u, &v, &d)) continue;
            if (!(u >= 0 && v >= 0 && u < s.camera.width && v < s.camera.height)) continue;
            const float ds = s.depth.At(static_cast<int>(v), static_cast<int>(u));
            if (!(ds > 0) || !std::isfinite(ds)) continue;
            const glm::dvec3 Xb = glm::transpose(r.rot) * (s.camera.RayInCam(u, v) * double(ds) - r.t);
            double bu = 0, bv = 0, bd = 0;
            if (!ref_cam.ProjectCam(Xb, &bu, &bv, &bd)) continue;
            const double e = std::hypot(bu - (x + 0.5), bv - (y + 0.5));
            if (!(e <= max_error_px) || !(std::abs(bd - z) <= max_rel_depth * z)) continue;
            const glm::dvec3 a = glm::normalize(X), b = glm::normalize(X - r.centre);
            if (glm::dot(a, b) > cos_min) continue;  // too small a triangulation angle
            n += 1;
          }
        }
        count.At(y, x) = n;
      }
    }
  });
}

}  // namespace ibr::mvs
