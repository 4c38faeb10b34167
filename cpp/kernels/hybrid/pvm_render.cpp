// PVM rendering with clustered depth filtering: see pvm_render.h for the contract.
#include "kernels/hybrid/pvm_render.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>

#if defined(__SSE2__)
#include <immintrin.h>  // SSE2; AVX2 only inside target("avx2") functions, called when the CPU has it
#endif

#include "ibr/bands.h"
#include "ibr/fastmath.h"
#include "ibr/parallel.h"
#include "ibr/raster.h"
#include "ibr/resample.h"
#include "ibr/simd.h"
#include "kernels/hybrid/ulr.h"

namespace ibr {
namespace {

inline std::int64_t CoarseCount(const PvmGrid& g) {
  return static_cast<std::int64_t>(g.coarse) * g.coarse * g.coarse;
}

// Coarse cell index along one axis of a world coordinate (outer cells extend to infinity).
inline int CoarseAxis(const PvmGrid& g, int a, double x) {
  const double f = (x - g.origin[a]) / (g.cell[a] * g.sub);
  if (!(f >= 0.0)) return 0;  // also NaN
  if (f >= g.coarse - 1) return g.coarse - 1;
  return static_cast<int>(f);
}

inline glm::vec3 Centre(const Camera& c) { return glm::vec3(c.CentreInWorld()); }

// exp(-x) for x >= 0 (0 beyond 87): 2^(-x log2 e) as an exponent in the float's bits times a
// degree-5 polynomial for the fraction (relative error < 2e-7, as std::exp's float rounding);
// the spatial filter evaluates it 4 times per neighbour. The constants serve the scalar, SSE2 and
// AVX2 forms (same Horner order in each, so the same bits).
constexpr float kExpCut = 87.f, kLog2e = 1.44269504f;
constexpr float kExp1 = 0.693147182f, kExp2 = 0.240226507f, kExp3 = 0.0555041087f, kExp4 = 0.00961812911f,
                kExp5 = 0.00133335581f;
inline float ExpNeg(float x) {
  if (!(x < kExpCut)) return 0.f;
  const float y = -x * kLog2e;
  const float n = std::floor(y);
  const float f = y - n;
  const float p = 1.f + f * (kExp1 + f * (kExp2 + f * (kExp3 + f * (kExp4 + f * kExp5))));
  const std::int32_t bits = (static_cast<std::int32_t>(n) + 127) << 23;
  float scale;
  std::memcpy(&scale, &bits, sizeof scale);
  return p * scale;
}

#if defined(__SSE2__)
// ExpNeg of four lanes (x >= 0; 0 where x >= 87 or NaN): the same steps as ExpNeg.
inline __m128 ExpNeg4(__m128 x) {
  const __m128 ok = _mm_cmplt_ps(x, _mm_set1_ps(kExpCut));
  const __m128 y = _mm_mul_ps(x, _mm_set1_ps(-kLog2e));
  __m128 n = _mm_cvtepi32_ps(_mm_cvttps_epi32(y));                  // trunc toward 0 (y <= 0)
  n = _mm_sub_ps(n, _mm_and_ps(_mm_cmpgt_ps(n, y), _mm_set1_ps(1.f)));  // floor
  const __m128 f = _mm_sub_ps(y, n);
  __m128 p = _mm_add_ps(_mm_set1_ps(kExp4), _mm_mul_ps(f, _mm_set1_ps(kExp5)));
  p = _mm_add_ps(_mm_set1_ps(kExp3), _mm_mul_ps(f, p));
  p = _mm_add_ps(_mm_set1_ps(kExp2), _mm_mul_ps(f, p));
  p = _mm_add_ps(_mm_set1_ps(kExp1), _mm_mul_ps(f, p));
  p = _mm_add_ps(_mm_set1_ps(1.f), _mm_mul_ps(f, p));
  const __m128i bits = _mm_slli_epi32(_mm_add_epi32(_mm_cvttps_epi32(n), _mm_set1_epi32(127)), 23);
  return _mm_and_ps(ok, _mm_mul_ps(p, _mm_castsi128_ps(bits)));
}

#if defined(__GNUC__)
#define IBR_PVM_AVX2 1
// ExpNeg4 in eight lanes (AVX2, no FMA): the same operations lane for lane, so the same bits.
__attribute__((target("avx2"))) inline __m256 ExpNeg8(__m256 x) {
  const __m256 ok = _mm256_cmp_ps(x, _mm256_set1_ps(kExpCut), _CMP_LT_OQ);
  const __m256 y = _mm256_mul_ps(x, _mm256_set1_ps(-kLog2e));
  __m256 n = _mm256_cvtepi32_ps(_mm256_cvttps_epi32(y));
  n = _mm256_sub_ps(n, _mm256_and_ps(_mm256_cmp_ps(n, y, _CMP_GT_OQ), _mm256_set1_ps(1.f)));
  const __m256 f = _mm256_sub_ps(y, n);
  __m256 p = _mm256_add_ps(_mm256_set1_ps(kExp4), _mm256_mul_ps(f, _mm256_set1_ps(kExp5)));
  p = _mm256_add_ps(_mm256_set1_ps(kExp3), _mm256_mul_ps(f, p));
  p = _mm256_add_ps(_mm256_set1_ps(kExp2), _mm256_mul_ps(f, p));
  p = _mm256_add_ps(_mm256_set1_ps(kExp1), _mm256_mul_ps(f, p));
  p = _mm256_add_ps(_mm256_set1_ps(1.f), _mm256_mul_ps(f, p));
  const __m256i bits = _mm256_slli_epi32(_mm256_add_epi32(_mm256_cvttps_epi32(n), _mm256_set1_epi32(127)), 23);
  return _mm256_and_ps(ok, _mm256_mul_ps(p, _mm256_castsi256_ps(bits)));
}

// PvmFilter's Eq. 1 sums over np (a multiple of 4) window pairs: the exponentials of eight pairs
// per step (ExpNeg8), accumulated into the four-lane sums as two four-pair steps in pair order,
// so l0 / l1 get exactly the SSE2 loop's bits.
__attribute__((target("avx2"))) void PairSumsAvx2(const float* pw, const float* pd, int np, float alpha, float di0,
                                                  float di1, float* l0, float* l1) {
  const __m256 A = _mm256_set1_ps(alpha), D0 = _mm256_set1_ps(di0), D1 = _mm256_set1_ps(di1);
  const __m256 sign = _mm256_set1_ps(-0.f);
  __m128 s0 = _mm_setzero_ps(), s1 = _mm_setzero_ps();
  int k = 0;
  for (; k + 8 <= np; k += 8) {
    const __m256 wt = _mm256_loadu_ps(pw + k), d = _mm256_loadu_ps(pd + k);
    const __m256 e0 = _mm256_mul_ps(wt, ExpNeg8(_mm256_mul_ps(A, _mm256_andnot_ps(sign, _mm256_sub_ps(d, D0)))));
    const __m256 e1 = _mm256_mul_ps(wt, ExpNeg8(_mm256_mul_ps(A, _mm256_andnot_ps(sign, _mm256_sub_ps(d, D1)))));
    s0 = _mm_add_ps(_mm_add_ps(s0, _mm256_castps256_ps128(e0)), _mm256_extractf128_ps(e0, 1));
    s1 = _mm_add_ps(_mm_add_ps(s1, _mm256_castps256_ps128(e1)), _mm256_extractf128_ps(e1, 1));
  }
  if (k < np) {
    const __m128 A4 = _mm_set1_ps(alpha), sign4 = _mm_set1_ps(-0.f);
    const __m128 wt = _mm_loadu_ps(pw + k), d = _mm_loadu_ps(pd + k);
    s0 = _mm_add_ps(s0, _mm_mul_ps(wt, ExpNeg4(_mm_mul_ps(A4, _mm_andnot_ps(sign4, _mm_sub_ps(d, _mm_set1_ps(di0)))))));
    s1 = _mm_add_ps(s1, _mm_mul_ps(wt, ExpNeg4(_mm_mul_ps(A4, _mm_andnot_ps(sign4, _mm_sub_ps(d, _mm_set1_ps(di1)))))));
  }
  _mm_storeu_ps(l0, s0);
  _mm_storeu_ps(l1, s1);
}

#endif  // __GNUC__
#endif

// Clips [t0, t1] to where the ray o + t dir is inside the box [lo, hi] (slabs); a ray parallel
// to a slab and outside it empties the interval (t1 = -1).
inline void ClipRayToBox(const glm::dvec3& o, const glm::dvec3& dir, const double* lo, const double* hi, double& t0,
                         double& t1) {
  for (int a = 0; a < 3; ++a) {
    if (dir[a] == 0.0) {
      if (o[a] < lo[a] || o[a] > hi[a]) t1 = -1.0;
      continue;
    }
    double ta = (lo[a] - o[a]) / dir[a], tb = (hi[a] - o[a]) / dir[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
}

}  // namespace

void PvmFaceSourceLog2Area(const PvmTileArrays& tiles, const Camera* cameras, float* out) {
  ParallelFor(tiles.num_tiles, 256, [&](std::int64_t t0, std::int64_t t1) {
    std::vector<double> px, py;
    std::vector<std::uint8_t> ok;
    for (std::int64_t t = t0; t < t1; ++t) {
      const Camera& cam = cameras[tiles.tile_view[t]];
      const std::int64_t v0 = tiles.vertex_offsets[t];
      const std::size_t nv = static_cast<std::size_t>(tiles.vertex_offsets[t + 1] - v0);
      px.resize(nv), py.resize(nv), ok.resize(nv);
      for (std::size_t k = 0; k < nv; ++k) {  // each vertex of the tile projected once
        const float* v = tiles.vertices + 3 * (v0 + static_cast<std::int64_t>(k));
        double z = 0;
        ok[k] = cam.ProjectCam(cam.CamFromWorld(glm::dvec3(v[0], v[1], v[2])), &px[k], &py[k], &z);
      }
      for (std::int64_t f = tiles.face_offsets[t]; f < tiles.face_offsets[t + 1]; ++f) {
        const std::int32_t* fv = tiles.faces + 3 * f;
        const std::size_t a = static_cast<std::size_t>(fv[0] - v0), b = static_cast<std::size_t>(fv[1] - v0),
                          c = static_cast<std::size_t>(fv[2] - v0);
        const double area = std::fabs((px[b] - px[a]) * (py[c] - py[a]) - (px[c] - px[a]) * (py[b] - py[a]));
        out[f] = ok[a] && ok[b] && ok[c] && std::isfinite(area) ? static_cast<float>(std::log2(area))
                                                               : std::numeric_limits<float>::quiet_NaN();
      }
    }
  });
}

void PvmVisibleCoarse(const PvmGrid& grid, const Camera& camera, const float* gbuffer_depth, int margin,
                      int ray_stride, std::vector<std::uint8_t>& visible) {
  const int c = grid.coarse;
  const std::int64_t n = CoarseCount(grid);
  visible.assign(static_cast<std::size_t>(n), 0);
  const int h = camera.height, w = camera.width;
  if (gbuffer_depth == nullptr) {
    // Frustum planes through the centre (pinhole): fx X + cx Z >= 0, fx X + (cx - W) Z <= 0, same in y.
    const glm::dmat3 rt = glm::transpose(camera.rot);
    (void)rt;
    ParallelFor(n, 256, [&](std::int64_t b, std::int64_t e) {
      for (std::int64_t id = b; id < e; ++id) {
        const int cx = static_cast<int>(id % c), cy = static_cast<int>((id / c) % c), cz = static_cast<int>(id / (c * c));
        const int idx[3] = {cx, cy, cz};
        double lo[3], hi[3];
        for (int a = 0; a < 3; ++a) {
          lo[a] = grid.origin[a] + static_cast<double>(idx[a]) * grid.sub * grid.cell[a];
          hi[a] = lo[a] + grid.sub * grid.cell[a];
        }
        int out[5] = {0, 0, 0, 0, 0};
        for (int k = 0; k < 8; ++k) {
          const glm::dvec3 p((k & 1) ? hi[0] : lo[0], (k & 2) ? hi[1] : lo[1], (k & 4) ? hi[2] : lo[2]);
          const glm::dvec3 q = camera.CamFromWorld(p);
          out[0] += q.z <= 0.0;
          out[1] += camera.fx * q.x + camera.cx * q.z < 0.0;
          out[2] += camera.fx * q.x + (camera.cx - w) * q.z > 0.0;
          out[3] += camera.fy * q.y + camera.cy * q.z < 0.0;
          out[4] += camera.fy * q.y + (camera.cy - h) * q.z > 0.0;
        }
        bool culled = false;
        for (int k = 0; k < 5; ++k) culled = culled || out[k] == 8;
        visible[static_cast<std::size_t>(id)] = culled ? 0 : 1;
      }
    });
    return;
  }
  // Mark the cells of the G-buffer's surface points: per band of rows a list of cells, merged in
  // band order (the marks are the same whatever the order; lists keep the writes race-free).
  const int band = 16;
  const int nb = (h + band - 1) / band;
  const glm::dvec3 centre = camera.CentreInWorld();
  double lo[3], hi[3], min_cell = 1e300;
  for (int a = 0; a < 3; ++a) {
    lo[a] = grid.origin[a];
    hi[a] = grid.origin[a] + grid.cell[a] * grid.coarse * grid.sub;
    min_cell = std::min(min_cell, grid.cell[a] * grid.sub);
  }
  std::vector<std::vector<std::int32_t>> lists(static_cast<std::size_t>(nb));
  const auto bands = [&](std::int64_t b0, std::int64_t b1) {
    for (std::int64_t b = b0; b < b1; ++b) {
      auto& out = lists[static_cast<std::size_t>(b)];
      std::int32_t last = -1;
      const int y0 = static_cast<int>(b) * band, y1 = std::min(h, y0 + band);
      for (int y = y0; y < y1; ++y) {
        for (int x = 0; x < w; ++x) {
          const float z = gbuffer_depth[static_cast<std::int64_t>(y) * w + x];
          if (!(z > 0.f) || !std::isfinite(z)) continue;
          const glm::dvec3 pc = camera.RayInCam(x + 0.5, y + 0.5) * static_cast<double>(z);
          const glm::dvec3 p = camera.WorldFromCamDir(pc) + camera.CentreInWorld();
          const std::int32_t id = (CoarseAxis(grid, 2, p.z) * c + CoarseAxis(grid, 1, p.y)) * c + CoarseAxis(grid, 0, p.x);
          if (id != last) out.push_back(id);
          last = id;
        }
        // Every ray_stride-th pixel of every ray_stride-th row: the cells its ray crosses in front
        // of the G-buffer's surface (to the grid's far side where it has none), sampled at half
        // the smallest coarse cell size.
        if (ray_stride <= 0 || y % ray_stride != 0) continue;
        for (int x = 0; x < w; x += ray_stride) {
          const float z = gbuffer_depth[static_cast<std::int64_t>(y) * w + x];
          const glm::dvec3 ray = camera.RayInCam(x + 0.5, y + 0.5);  // z = 1: t is depth
          const glm::dvec3 dir = camera.WorldFromCamDir(ray);
          double t0 = 0.0, t1 = (z > 0.f && std::isfinite(z)) ? static_cast<double>(z) : 1e300;
          ClipRayToBox(centre, dir, lo, hi, t0, t1);
          if (!(t0 <= t1)) continue;
          const double step = 0.5 * min_cell / glm::length(dir);
          for (double t = t0; t <= t1 + step; t += step) {
            const glm::dvec3 p = centre + dir * std::min(t, t1);
            const std::int32_t id = (CoarseAxis(grid, 2, p.z) * c + CoarseAxis(grid, 1, p.y)) * c + CoarseAxis(grid, 0, p.x);
            if (id != last) out.push_back(id);
            last = id;
          }
        }
      }
    }
  };
  ParallelForIsa(nb, 1, bands);
  std::vector<std::uint8_t> hit(static_cast<std::size_t>(n), 0);
  for (const auto& l : lists)
    for (std::int32_t id : l) hit[static_cast<std::size_t>(id)] = 1;
  for (std::int64_t id = 0; id < n; ++id) {
    if (!hit[static_cast<std::size_t>(id)]) continue;
    const int cx = static_cast<int>(id % c), cy = static_cast<int>((id / c) % c), cz = static_cast<int>(id / (c * c));
    for (int z = std::max(0, cz - margin); z <= std::min(c - 1, cz + margin); ++z)
      for (int y = std::max(0, cy - margin); y <= std::min(c - 1, cy + margin); ++y)
        for (int x = std::max(0, cx - margin); x <= std::min(c - 1, cx + margin); ++x)
          visible[static_cast<std::size_t>((static_cast<std::int64_t>(z) * c + y) * c + x)] = 1;
  }
}

void PvmSelectTiles(const PvmTileArrays& tiles, const PvmViews& views, const std::vector<std::uint8_t>& visible,
                    const Camera& camera, const PvmRenderOptions& options, PvmFrame& frame) {
  const std::int64_t n = CoarseCount(tiles.grid);
  const std::int64_t chunk = 64;
  const std::int64_t nchunks = (n + chunk - 1) / chunk;
  std::vector<std::vector<std::int64_t>> kept(static_cast<std::size_t>(nchunks));
  std::vector<std::vector<std::uint8_t>> ranks(static_cast<std::size_t>(nchunks));
  const glm::vec3 c_novel = Centre(camera);
  std::vector<glm::vec3> centres(static_cast<std::size_t>(views.count));
  for (int v = 0; v < views.count; ++v) centres[static_cast<std::size_t>(v)] = Centre(views.cameras[v]);
  const PvmGrid& g = tiles.grid;
  const int k = std::max(1, options.max_tiles);
  ParallelFor(nchunks, 1, [&](std::int64_t b0, std::int64_t b1) {
    std::vector<float> pen;
    std::vector<std::int64_t> ids;
    std::vector<int> index(static_cast<std::size_t>(k));
    std::vector<float> weight(static_cast<std::size_t>(k));
    for (std::int64_t ch = b0; ch < b1; ++ch) {
      auto& out = kept[static_cast<std::size_t>(ch)];
      auto& out_rank = ranks[static_cast<std::size_t>(ch)];
      for (std::int64_t cell = ch * chunk; cell < std::min(n, (ch + 1) * chunk); ++cell) {
        if (!visible[static_cast<std::size_t>(cell)]) continue;
        std::int64_t t = tiles.coarse_offsets[cell];
        const std::int64_t t_end = tiles.coarse_offsets[cell + 1];
        while (t < t_end) {
          // One fine cell: tiles t .. u-1.
          const std::int32_t* fc = tiles.tile_cell + 3 * t;
          std::int64_t u = t + 1;
          while (u < t_end && tiles.tile_cell[3 * u] == fc[0] && tiles.tile_cell[3 * u + 1] == fc[1] &&
                 tiles.tile_cell[3 * u + 2] == fc[2])
            ++u;
          const glm::vec3 centre(static_cast<float>(g.origin[0] + (fc[0] + 0.5) * g.cell[0]),
                                 static_cast<float>(g.origin[1] + (fc[1] + 0.5) * g.cell[1]),
                                 static_cast<float>(g.origin[2] + (fc[2] + 0.5) * g.cell[2]));
          pen.clear();
          ids.clear();
          for (std::int64_t s = t; s < u; ++s) {
            const int v = tiles.tile_view[s];
            if (!views.enabled[v]) continue;
            float angle = 0.f;  // the penalty's angle term is the angle max_angle bounds
            const float p = UlrPenalty(centre, c_novel, centres[static_cast<std::size_t>(v)], options.resolution_weight, &angle);
            if (options.max_angle < 3.1415926f && angle > options.max_angle) continue;
            ids.push_back(s);
            pen.push_back(p);
          }
          const int m = UlrSelect(pen.data(), static_cast<int>(pen.size()), k, index.data(), weight.data());
          for (int r = 0; r < m; ++r) {
            out.push_back(ids[static_cast<std::size_t>(index[static_cast<std::size_t>(r)])]);
            out_rank.push_back(static_cast<std::uint8_t>(r));
          }
          t = u;
        }
      }
    }
  });
  frame.tiles.clear();
  frame.tile_rank.clear();
  for (std::int64_t ch = 0; ch < nchunks; ++ch) {
    frame.tiles.insert(frame.tiles.end(), kept[static_cast<std::size_t>(ch)].begin(), kept[static_cast<std::size_t>(ch)].end());
    frame.tile_rank.insert(frame.tile_rank.end(), ranks[static_cast<std::size_t>(ch)].begin(),
                           ranks[static_cast<std::size_t>(ch)].end());
  }
}

// Screen coordinates beyond the rasteriser's guard band (pixels) send the vertex's faces to the
// clipping path.
constexpr float kMaxScreen = static_cast<float>(raster::kGuardPixels);

// raster::ToFixed of a float (|v| <= kMaxScreen), in float arithmetic so that the vertex loop
// vectorises: v * 256 and v - trunc(v) are exact in float, so the same integer.
inline std::int32_t ToFixedF(float v) {
  const float s = v * static_cast<float>(raster::kSubpixel);
  const std::int32_t t = static_cast<std::int32_t>(s);
  const float frac = s - static_cast<float>(t);
  return t + std::int32_t(frac >= 0.5f) - std::int32_t(frac <= -0.5f);
}

// Prefetch of the cache line at p. GCC removes loops of __builtin_prefetch alone (seen here: a
// tile's prefetch loop compiled to nothing), so on x86 it is an asm statement it keeps.
inline void PrefetchLine(const void* p) {
#if defined(__GNUC__) && defined(__x86_64__)
  asm volatile("prefetcht0 %0" : : "m"(*static_cast<const char*>(p)));
#else
  __builtin_prefetch(p);
#endif
}

inline void PrefetchTileOffsets(const PvmTileArrays& tiles, std::int64_t t) {
  PrefetchLine(tiles.vertex_offsets + t);
  PrefetchLine(tiles.face_offsets + t);
}

// A tile's vertices and faces, a cache line (16 floats or indices) at a time.
inline void PrefetchTileData(const PvmTileArrays& tiles, std::int64_t t) {
  const std::int64_t v0 = 3 * tiles.vertex_offsets[t], nv = 3 * tiles.vertex_offsets[t + 1] - v0;
  for (std::int64_t k = 0; k < nv; k += 16) PrefetchLine(tiles.vertices + v0 + k);
  const std::int64_t f0 = 3 * tiles.face_offsets[t], nf = 3 * tiles.face_offsets[t + 1] - f0;
  for (std::int64_t k = 0; k < nf; k += 16) PrefetchLine(tiles.faces + f0 + k);
}

// A face of a tile that may cover a pixel centre of the band: its vertices (indices into the
// tile's) and its pixel bounds in the band.
struct KeptFace {
  std::int32_t a, b, c;
  int ra, rb, ca, cb;
  // The face's index in the tiles (face_src_log2; its back-face test is in the draw loop), or -1 for a
  // near-clipped piece (tested already; no stretch).
  std::int32_t face;
};

// A candidate's stretch code (pvm_render.h kStretchZero, PvmRenderOptions.stretch_weight): log2 of
// its triangle's doubled area in the target (pixels^2, finite, > 0) over src = that in its own view
// (log2); kStretchZero where src is NaN.
inline std::uint8_t StretchCode(double target_area, float src) {
  if (std::isnan(src)) return kStretchZero;
  const float l2 = Log2Pos(std::max(static_cast<float>(target_area), std::numeric_limits<float>::min()));
  // Rounded half up by truncation once clamped to [0, 255.5) (std::round is a call to libm here).
  const float q = kStretchSteps * (l2 - src) + (kStretchZero + 0.5f);
  return static_cast<std::uint8_t>(q >= 255.f ? 255.f : (q > 0.f ? q : 0.f));  // -inf src: 255
}

// True when the triangle (a, b, c) (world) faces the point (cx, cy, cz): its outward normal
// cross(b - a, c - a) faces the triangle's own view (pvm.h), so false for a back face.
inline bool FacesPoint(const float* pa, const float* pb, const float* pc, float cx, float cy, float cz) {
  const float e1x = pb[0] - pa[0], e1y = pb[1] - pa[1], e1z = pb[2] - pa[2];
  const float e2x = pc[0] - pa[0], e2y = pc[1] - pa[1], e2z = pc[2] - pa[2];
  const float nx = e1y * e2z - e1z * e2y, ny = e1z * e2x - e1x * e2z, nz = e1x * e2y - e1y * e2x;
  return nx * (cx - pa[0]) + ny * (cy - pa[1]) + nz * (cz - pa[2]) > 0.f;
}

// A face's vertex for the near-plane clip: world position and camera depth.
struct NearVertex {
  float p[3];
  float z;
};

inline bool WorldLess(const NearVertex& a, const NearVertex& b) {
  return std::lexicographical_compare(a.p, a.p + 3, b.p, b.p + 3);
}

void PvmRasterise(const PvmTileArrays& tiles, const PvmViews& views, const Camera& camera,
                  const PvmRenderOptions& options, PvmFrame& frame) {
  (void)views;
  const int h = camera.height, w = camera.width;
  const int K = std::min(std::max(1, options.max_candidates), kPvmMaxCandidates);
  const std::int64_t npix = static_cast<std::int64_t>(h) * w;
  frame.cand_depth.resize(static_cast<std::size_t>(npix * K));
  frame.cand_view.resize(static_cast<std::size_t>(npix * K));
  frame.cand_rank.resize(static_cast<std::size_t>(npix * K));
  frame.cand_stretch.resize(static_cast<std::size_t>(npix * K));
  // The stretch term's per-candidate codes (StretchCode), or 128 everywhere it is off.
  const bool stretch = options.stretch_weight > 0.f && tiles.face_src_log2 != nullptr;
  frame.stretch_codes = stretch;
  frame.cand_count.resize(static_cast<std::size_t>(npix));
  frame.cand_seen.resize(static_cast<std::size_t>(npix));
  frame.clusters_everywhere = false;  // new candidate lists: the kept clusters are stale
  const glm::dvec3 c_novel = camera.CentreInWorld();
  // Camera as floats for the per-vertex projection (world -> camera -> pixels): the rotation's
  // rows, the translation, fx, fy, cx, cy.
  float cam[16];
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) cam[r * 3 + c] = static_cast<float>(camera.rot[c][r]);
    cam[9 + r] = static_cast<float>(camera.trans[r]);
  }
  cam[12] = static_cast<float>(camera.fx), cam[13] = static_cast<float>(camera.fy);
  cam[14] = static_cast<float>(camera.cx), cam[15] = static_cast<float>(camera.cy);
  const float cnx = static_cast<float>(c_novel.x), cny = static_cast<float>(c_novel.y), cnz = static_cast<float>(c_novel.z);

  // Rows each kept tile may cover, from its AABB's 8 corners (all rows when a corner is behind
  // the near plane); tiles covering nothing are dropped. Then binned into bands in kept order.
  // A tile's triangles are drawn only within its AABB's projection widened by a pixel (`box`:
  // rows and columns; the whole image when a corner is behind the near plane): a no-op for
  // triangles inside the AABB, the part in the cell for a copy of a large triangle (pvm.h).
  const std::int64_t nt = static_cast<std::int64_t>(frame.tiles.size());
  std::vector<std::int32_t> row0(static_cast<std::size_t>(nt)), row1(static_cast<std::size_t>(nt));
  std::vector<std::array<int, 4>> box(static_cast<std::size_t>(nt));
  ParallelFor(nt, 256, [&](std::int64_t b0, std::int64_t b1) {
    for (std::int64_t i = b0; i < b1; ++i) {
      const std::int64_t t = frame.tiles[static_cast<std::size_t>(i)];
      const float* bb = tiles.tile_bounds + 6 * t;
      double ymin = 1e300, ymax = -1e300, xmin = 1e300, xmax = -1e300;
      bool behind = false;
      for (int k = 0; k < 8; ++k) {
        const glm::dvec3 p((k & 1) ? bb[3] : bb[0], (k & 2) ? bb[4] : bb[1], (k & 4) ? bb[5] : bb[2]);
        const glm::dvec3 q = camera.CamFromWorld(p);
        if (!(q.z >= options.near)) {
          behind = true;
          break;
        }
        const double x = camera.fx * q.x / q.z + camera.cx, y = camera.fy * q.y / q.z + camera.cy;
        xmin = std::min(xmin, x), xmax = std::max(xmax, x), ymin = std::min(ymin, y), ymax = std::max(ymax, y);
      }
      std::int32_t r0 = 0, r1 = h - 1;
      box[static_cast<std::size_t>(i)] = {0, h - 1, 0, w - 1};
      if (!behind) {
        const double a0 = std::ceil(ymin - 0.5), a1 = std::floor(ymax - 0.5);
        const double c0 = std::ceil(xmin - 0.5), c1 = std::floor(xmax - 0.5);
        if (a1 < 0 || a0 > h - 1 || c1 < 0 || c0 > w - 1 || a0 > a1 || c0 > c1) {
          r0 = 1, r1 = 0;  // covers no pixel centre
        } else {
          r0 = static_cast<std::int32_t>(std::max(a0, 0.0));
          r1 = static_cast<std::int32_t>(std::min(a1, static_cast<double>(h - 1)));
          box[static_cast<std::size_t>(i)] = {std::max(0, r0 - 1), std::min(h - 1, r1 + 1),
                                              static_cast<int>(std::max(c0 - 1.0, 0.0)),
                                              static_cast<int>(std::min(c1 + 1.0, static_cast<double>(w - 1)))};
        }
      }
      row0[static_cast<std::size_t>(i)] = r0;
      row1[static_cast<std::size_t>(i)] = r1;
    }
  });
  const int nb = (h + kBandRows - 1) / kBandRows;
  std::vector<std::int64_t> start;
  std::vector<std::int32_t> binned;
  BinByBand<std::int32_t>(nb, kBandRows, [&](auto&& emit) {
    for (std::int64_t i = 0; i < nt; ++i) {
      const std::size_t k = static_cast<std::size_t>(i);
      if (row0[k] <= row1[k]) emit(static_cast<std::int32_t>(i), row0[k], row1[k]);
    }
  }, start, binned);
  float* cd = frame.cand_depth.data();
  std::int16_t* cv = frame.cand_view.data();
  std::uint8_t* cr = frame.cand_rank.data();
  std::uint8_t* cst = frame.cand_stretch.data();
  std::uint8_t* cc = frame.cand_count.data();
  std::uint32_t* cs = frame.cand_seen.data();
  std::vector<std::int64_t> tri_count(static_cast<std::size_t>(nb), 0);
  const auto bands = [&](std::int64_t b0, std::int64_t b1) {
    std::vector<float> siz, sz;  // this tile's vertices: 1/z (-1: not drawable as is), camera z
    std::vector<std::int32_t> fx, fy;  // and their snapped screen positions (cpp/ibr/raster.h)
    std::vector<KeptFace> kept, near_kept;
    // The camera and near plane as locals of the task (the vertex loop vectorises).
    const float r[16] = {cam[0], cam[1], cam[2], cam[3], cam[4], cam[5], cam[6], cam[7],
                         cam[8], cam[9], cam[10], cam[11], cam[12], cam[13], cam[14], cam[15]};
    const float near = options.near;
    for (std::int64_t b = b0; b < b1; ++b) {
      const int y0 = static_cast<int>(b) * kBandRows, y1 = std::min(h, y0 + kBandRows);
      std::memset(cc + static_cast<std::int64_t>(y0) * w, 0, static_cast<std::size_t>(y1 - y0) * w);
      std::memset(cs + static_cast<std::int64_t>(y0) * w, 0, static_cast<std::size_t>(y1 - y0) * w * sizeof(std::uint32_t));
      std::int64_t drawn = 0;
      for (std::int64_t q = start[static_cast<std::size_t>(b)]; q < start[static_cast<std::size_t>(b) + 1]; ++q) {
        const std::int64_t i = binned[static_cast<std::size_t>(q)];
        const std::int64_t t = frame.tiles[static_cast<std::size_t>(i)];
        // Prefetch (per-view depth pass on lego 181 -> 161 ms): the offsets of the tile 12 ahead
        // in the band, the vertices and faces of the tile 3 ahead (its offsets are cached by then).
        const std::int64_t q_end = start[static_cast<std::size_t>(b) + 1];
        if (q + 12 < q_end) PrefetchTileOffsets(tiles, frame.tiles[static_cast<std::size_t>(binned[static_cast<std::size_t>(q + 12)])]);
        if (q + 3 < q_end) PrefetchTileData(tiles, frame.tiles[static_cast<std::size_t>(binned[static_cast<std::size_t>(q + 3)])]);
        const std::array<int, 4>& tb = box[static_cast<std::size_t>(i)];
        const int ty0 = std::max(y0, tb[0]), ty1 = std::min(y1 - 1, tb[1]), tx0 = tb[2], tx1 = tb[3];
        const std::int16_t view = static_cast<std::int16_t>(tiles.tile_view[t]);
        const std::uint32_t view_bit = 1u << (static_cast<unsigned>(view) & 31u);
        const std::uint8_t rank = frame.tile_rank[static_cast<std::size_t>(i)];
        const std::int64_t v0 = tiles.vertex_offsets[t], v1 = tiles.vertex_offsets[t + 1];
        const std::size_t nv = static_cast<std::size_t>(v1 - v0);
        fx.resize(nv), fy.resize(nv), siz.resize(nv), sz.resize(nv);
        const float* wv = tiles.vertices + 3 * v0;  // this tile's world vertices
        std::int32_t* vx = fx.data();
        std::int32_t* vy = fy.data();
        float* viz = siz.data();
        float* vz = sz.data();
        for (std::size_t k = 0; k < nv; ++k) {
          const float* v = wv + 3 * k;
          const float X = r[0] * v[0] + r[1] * v[1] + r[2] * v[2] + r[9];
          const float Y = r[3] * v[0] + r[4] * v[1] + r[5] * v[2] + r[10];
          const float Z = r[6] * v[0] + r[7] * v[1] + r[8] * v[2] + r[11];
          // Without a branch (vectorised): a vertex behind the near plane, or projecting outside
          // the guard band, gets siz -1 (its faces take the clipping path) and a snapped position
          // of a clamped (unused) value: a NaN clamps to kMaxScreen.
          const float iz = 1.f / Z;
          const float px = r[12] * X * iz + r[14], py = r[13] * Y * iz + r[15];
          const float qx = std::max(-kMaxScreen, std::min(kMaxScreen, px));
          const float qy = std::max(-kMaxScreen, std::min(kMaxScreen, py));
          vx[k] = ToFixedF(qx);
          vy[k] = ToFixedF(qy);
          vz[k] = Z;
          const bool use = std::isgreaterequal(Z, near) & (qx == px) & (qy == py);  // quiet compares
          viz[k] = use ? iz : -1.f;
        }
        // The pixel centres a face (vertices a, b, c of this tile) may cover in this band and the tile's box.
        const auto pixel_bounds = [&](std::size_t a, std::size_t b, std::size_t c) {
          const std::int64_t X[3] = {fx[a], fx[b], fx[c]}, Y[3] = {fy[a], fy[b], fy[c]};
          raster::CentreBox cb;
          raster::Centres(X, Y, tx0, tx1, ty0, ty1, &cb);  // empty: x0 > x1 or y0 > y1
          return std::array<int, 4>{cb.y0, cb.y1, cb.x0, cb.x1};
        };
        // A face with a vertex behind the near plane and one in front, or one beyond the guard
        // band, is clipped against both (the pieces' new vertices appended to this tile's); rare,
        // so a branch. Cut points come from the lexicographically smaller end (world position
        // for the near plane, screen position for the guard band): two faces sharing an edge get
        // the same point, no crack between them.
        near_kept.clear();
        const auto clip_face = [&](std::size_t ia, std::size_t ib, std::size_t ic) {
          // The face's own back-face test (its pieces are not tested again in the draw loop).
          if (options.cull_back && !FacesPoint(wv + 3 * ia, wv + 3 * ib, wv + 3 * ic, cnx, cny, cnz)) return;
          NearVertex face[3], poly[4];
          const std::size_t id[3] = {ia, ib, ic};
          for (int e = 0; e < 3; ++e) {
            const float* w = wv + 3 * id[e];
            face[e] = {{w[0], w[1], w[2]}, sz[id[e]]};
          }
          const int n = raster::ClipPolygon(
              face, 3, poly, [near](const NearVertex& v) { return v.z >= near; }, WorldLess,
              [near](const NearVertex& p, const NearVertex& q) {
                const float t = (near - p.z) / (q.z - p.z);
                NearVertex c{{}, near};
                for (int a = 0; a < 3; ++a) c.p[a] = p.p[a] + t * (q.p[a] - p.p[a]);
                return c;
              });
          if (n < 3) return;
          raster::ScreenVertex sv[8];
          bool in_band = true;
          for (int k = 0; k < n; ++k) {
            const float* w = poly[k].p;
            const float X = r[0] * w[0] + r[1] * w[1] + r[2] * w[2] + r[9];
            const float Y = r[3] * w[0] + r[4] * w[1] + r[5] * w[2] + r[10];
            const float Z = std::max(near, r[6] * w[0] + r[7] * w[1] + r[8] * w[2] + r[11]);
            // The vertex loop's expressions: a corner this face shares with an unclipped
            // neighbour snaps to the same fixed-point position (no crack between them).
            const float iz = 1.f / Z;
            const float px = r[12] * X * iz + r[14], py = r[13] * Y * iz + r[15];
            if (!(std::isfinite(px) && std::isfinite(py))) return;
            sv[k] = {px, py, iz};
            in_band = in_band && raster::InGuardBand(px, py);
          }
          raster::ScreenVertex clipped[8];
          const raster::ScreenVertex* v = sv;
          int m = n;
          if (!in_band) {
            m = raster::ClipToGuardBand(sv, n, clipped);
            v = clipped;
          }
          std::size_t base = siz.size();
          for (int k = 0; k < m; ++k) {
            fx.push_back(raster::ToFixed(v[k].x)), fy.push_back(raster::ToFixed(v[k].y));
            siz.push_back(static_cast<float>(v[k].iz)), sz.push_back(static_cast<float>(1.0 / v[k].iz));
          }
          for (int t = 1; t + 1 < m; ++t) {
            const std::size_t a = base, b = base + t, c = base + t + 1;
            const auto [ra, rb, ca, cb] = pixel_bounds(a, b, c);
            if (ra <= rb && ca <= cb)
              near_kept.push_back({static_cast<std::int32_t>(a), static_cast<std::int32_t>(b),
                                   static_cast<std::int32_t>(c), ra, rb, ca, cb, -1});
          }
        };
        // The faces that may cover a pixel centre of this band, without a branch per test (most
        // faces are smaller than a pixel and cover none): indices and pixel bounds, compacted.
        const std::int64_t f0 = tiles.face_offsets[t], nf = tiles.face_offsets[t + 1] - f0;
        kept.resize(static_cast<std::size_t>(nf));
        std::size_t nk = 0;
        for (std::int64_t f = 0; f < nf; ++f) {
          const std::int32_t* fv = tiles.faces + 3 * (f0 + f);
          const std::size_t ia = static_cast<std::size_t>(fv[0] - v0), ib = static_cast<std::size_t>(fv[1] - v0),
                            ic = static_cast<std::size_t>(fv[2] - v0);
          const bool front = !(siz[ia] < 0.f) & !(siz[ib] < 0.f) & !(siz[ic] < 0.f);
          const int n_behind = (sz[ia] < near) + (sz[ib] < near) + (sz[ic] < near);
          if (!front && n_behind < 3) clip_face(ia, ib, ic);
          const auto [ra, rb, ca, cb] = pixel_bounds(ia, ib, ic);
          const bool keep = front & (ra <= rb) & (ca <= cb);
          kept[nk] = {static_cast<std::int32_t>(ia), static_cast<std::int32_t>(ib), static_cast<std::int32_t>(ic), ra, rb, ca, cb,
                      static_cast<std::int32_t>(f0 + f)};
          nk += static_cast<std::size_t>(keep);
        }
        if (!near_kept.empty()) {
          kept.resize(nk + near_kept.size());
          std::copy(near_kept.begin(), near_kept.end(), kept.begin() + static_cast<std::ptrdiff_t>(nk));
          nk += near_kept.size();
        }
        for (std::size_t kk = 0; kk < nk; ++kk) {
          const KeptFace& kf = kept[kk];
          const std::size_t ia = static_cast<std::size_t>(kf.a);
          std::size_t ib = static_cast<std::size_t>(kf.b), ic = static_cast<std::size_t>(kf.c);
          const int ra = kf.ra, rb = kf.rb, ca = kf.ca, cb = kf.cb;
          if (options.cull_back && kf.face >= 0 && !FacesPoint(wv + 3 * ia, wv + 3 * ib, wv + 3 * ic, cnx, cny, cnz)) continue;
          std::int64_t X[3] = {fx[ia], fx[ib], fx[ic]}, Y[3] = {fy[ia], fy[ib], fy[ic]};
          std::int64_t area2 = raster::Area2(X, Y);
          if (area2 == 0) continue;
          if (area2 < 0) {
            std::swap(ib, ic);
            std::swap(X[1], X[2]);
            std::swap(Y[1], Y[2]);
            area2 = -area2;
          }
          ++drawn;
          const float iza = siz[ia], izb = siz[ib], izc = siz[ic];
          // The core's top-left rule: a centre on an edge shared by two faces goes to one of them.
          raster::Edges E;
          raster::SetupEdges(X, Y, ca, ra, /*inclusive=*/false, &E);
          // 1 / area only once a pixel centre is covered: most noisy-depth triangles are smaller than
          // a pixel and cover none (the same value when computed; no division otherwise).
          double inv = 0.0;
          bool have_inv = false;
          std::uint8_t scode = kStretchZero;  // with inv: StretchCode of this face
          const raster::CentreBox box{ca, cb, ra, rb};
          raster::ScanTriangle(E, box, [&](int x, int y, std::int64_t e0, std::int64_t e1, std::int64_t e2) {
            if (!have_inv) {
              inv = 1.0 / static_cast<double>(area2);
              have_inv = true;
              const double area_px2 = static_cast<double>(area2) / (double(raster::kSubpixel) * raster::kSubpixel);
              if (stretch && kf.face >= 0) scode = StretchCode(area_px2, tiles.face_src_log2[kf.face]);
            }
            // Barycentric numerators: the biased edge functions with the bias added back.
            const double w0 = static_cast<double>(e0 + E.bias[0]), w1 = static_cast<double>(e1 + E.bias[1]),
                         w2 = static_cast<double>(e2 + E.bias[2]);
            const float iz = static_cast<float>((w0 * iza + w1 * izb + w2 * izc) * inv);
            if (!(iz > 0.f)) return;
            const float z = 1.f / iz;
            const std::int64_t p = static_cast<std::int64_t>(y) * w + x;
            float* pd = cd + p * K;
            std::int16_t* pv = cv + p * K;
            std::uint8_t* pr = cr + p * K;
            const int n = cc[p];
            int s = n;
            // The list holds this view only if its class bit is set: most fragments are a view's
            // first at the pixel and skip the search (same result as always searching).
            if (cs[p] & view_bit) {
              s = 0;
              while (s < n && pv[s] != view) ++s;
            }
            std::uint8_t* pst = cst + p * K;
            if (s < n) {
              if (z < pd[s]) {
                pd[s] = z;
                pr[s] = rank;
                pst[s] = scode;
              }
            } else if (n < K) {
              pd[n] = z;
              pv[n] = view;
              pr[n] = rank;
              pst[n] = scode;
              cc[p] = static_cast<std::uint8_t>(n + 1);
              cs[p] |= view_bit;
            } else {
              int worst = 0;
              for (int j = 1; j < n; ++j)
                if (pr[j] > pr[worst] || (pr[j] == pr[worst] && pv[j] > pv[worst])) worst = j;
              if (rank < pr[worst] || (rank == pr[worst] && view < pv[worst])) {
                pd[worst] = z;
                pv[worst] = view;
                pr[worst] = rank;
                pst[worst] = scode;
                cs[p] |= view_bit;  // the evicted view's bit may stay set: a superset, only a hint
              }
            }
          });
        }
      }
      tri_count[static_cast<std::size_t>(b)] = drawn;
    }
  };
  ParallelForIsa(nb, 1, bands);
  frame.triangles = 0;
  for (std::int64_t c : tri_count) frame.triangles += c;
}

void PvmDropOffMesh(const Camera& camera, const float* gbuffer_depth, int min_views, PvmFrame& frame) {
  if (gbuffer_depth == nullptr || min_views <= 1) return;
  const int h = camera.height, w = camera.width;
  std::uint8_t* count = frame.cand_count.data();
  const std::uint8_t need = static_cast<std::uint8_t>(std::min(min_views, 255));
  ParallelFor(h, 16, [&](std::int64_t a, std::int64_t b) {
    for (std::int64_t p = a * w; p < b * w; ++p) {
      const float g = gbuffer_depth[p];
      if (count[p] != 0 && count[p] < need && !(g > 0.f && std::isfinite(g))) count[p] = 0;
    }
  });
}

// True when the view (camera, depth map) sees past world point p: p projects into its image, no
// pixel of the 3 x 3 around p's projection (clipped to the image) has a depth < (1 - tol) x p's
// depth in the view (p hidden there), and most of them (more than half) have a depth >
// (1 + point_tol) x p's depth or none (0, NaN, inf): a view whose depth there is p's own sees p
// itself, and a background candidate of its per-view mesh on the ray through p comes from the
// mesh's depth-edge cut (a thin surface seen at a grazing angle), not from free space. The
// free-space count of PvmCluster.
static bool SeesPast(const Camera& cam, const float* depth, const glm::dvec3& p, float tol, float point_tol) {
  double ix = 0, iy = 0, iz = 0;
  if (!cam.ProjectCam(cam.CamFromWorld(p), &ix, &iy, &iz)) return false;
  if (!(ix >= 0.0 && iy >= 0.0 && ix < cam.width && iy < cam.height)) return false;
  const int px = static_cast<int>(ix), py = static_cast<int>(iy);
  const double in_front = (1.0 - static_cast<double>(tol)) * iz;
  const double beyond = (1.0 + static_cast<double>(point_tol)) * iz;
  int n = 0, n_beyond = 0;
  for (int y = std::max(0, py - 1); y <= std::min(cam.height - 1, py + 1); ++y) {
    const float* row = depth + static_cast<std::size_t>(y) * static_cast<std::size_t>(cam.width);
    for (int x = std::max(0, px - 1); x <= std::min(cam.width - 1, px + 1); ++x) {
      const float d = row[x];
      const bool surface = d > 0.f && std::isfinite(d);
      if (surface && d < in_front) return false;
      ++n;
      n_beyond += !surface || d > beyond;
    }
  }
  return 2 * n_beyond > n;
}

// True when the surface point P (world) of a one-cluster pixel with n_fg foreground candidates
// (of the views vv[0 .. n)), seen from the novel camera at c_novel, is seen through: at least
// tau_empty x n_fg of the enabled views without a candidate on the ray, within max_angle of the
// novel camera's ray at P (the views PvmSelectTiles may rank there), see past P (SeesPast). Their
// per-view meshes put nothing on the ray near P, so the candidates at P are sheets that other
// views' meshes span across a gap (a through-hole seen obliquely). The cheap part first: most
// surfaces have too few views without a candidate to reach the count, and nothing is projected.
// others and has: scratch (has: views.count zeros, left so).
static bool SeenThrough(const PvmViews& views, const std::vector<glm::vec3>& centres, const glm::vec3& c_novel,
                        const glm::dvec3& p, int n_fg, const std::int16_t* vv, int n, const PvmRenderOptions& options,
                        bool limited, float cos_max, std::vector<int>& others, std::vector<std::uint8_t>& has) {
  const int need = static_cast<int>(std::ceil(static_cast<double>(options.tau_empty) * std::max(1, n_fg)));
  if (need > views.count - n) return false;
  const glm::vec3 pf(p), to_novel = c_novel - pf;
  // angle <= max_angle (limited) as dot >= cos_max |a| |b| without square roots.
  const float cos2 = cos_max * cos_max, len2_novel = glm::dot(to_novel, to_novel);
  others.clear();
  for (int i = 0; i < n; ++i) has[static_cast<std::size_t>(vv[i])] = 1;  // the views with a candidate
  for (int v = 0; v < views.count; ++v) {
    if (!views.enabled[v] || has[static_cast<std::size_t>(v)]) continue;
    const glm::vec3 to_view = centres[static_cast<std::size_t>(v)] - pf;
    const float dot = glm::dot(to_view, to_novel), len2 = glm::dot(to_view, to_view) * len2_novel;
    bool ok = len2 > 0.f;
    if (ok && limited) ok = cos_max >= 0.f ? dot >= 0.f && dot * dot >= cos2 * len2 : dot >= 0.f || dot * dot <= cos2 * len2;
    if (ok) others.push_back(v);
  }
  for (int i = 0; i < n; ++i) has[static_cast<std::size_t>(vv[i])] = 0;  // all 0 again for the next pixel
  const int m = static_cast<int>(others.size());
  int past = 0;
  for (int i = 0; i < m; ++i) {
    if (past + (m - i) < need) return false;
    const int v = others[static_cast<std::size_t>(i)];
    if (SeesPast(views.cameras[v], views.depths[v], p, options.free_space_tol, options.free_space_point_tol) &&
        ++past >= need) {
      return true;
    }
  }
  return false;
}

void PvmCluster(const PvmViews& views, const Camera& camera, const std::uint8_t* pixel_mask,
                const PvmRenderOptions& options, bool colours, PvmFrame& frame, bool reuse_clusters) {
  const int h = camera.height, w = camera.width;
  const int K = std::min(std::max(1, options.max_candidates), kPvmMaxCandidates);
  const std::int64_t npix = static_cast<std::int64_t>(h) * w;
  reuse_clusters = reuse_clusters && colours && frame.clusters_everywhere &&
                   frame.d_fg.size() == static_cast<std::size_t>(npix) && frame.bg_bits.size() == static_cast<std::size_t>(npix);
  if (!reuse_clusters) {
    frame.clusters_everywhere = pixel_mask == nullptr;  // set now: the loop below fills them
    frame.bg_bits.resize(static_cast<std::size_t>(npix));
    frame.d_fg.assign(static_cast<std::size_t>(npix), 0.f);
    frame.d_bg.assign(static_cast<std::size_t>(npix), 0.f);
    frame.n_fg.assign(static_cast<std::size_t>(npix), 0);
    frame.n_bg.assign(static_cast<std::size_t>(npix), 0);
  }
  // Colours are read (PvmFilter) only at masked pixels with a candidate, where they are written.
  frame.c_fg.resize(static_cast<std::size_t>(npix * 3));
  frame.c_bg.resize(static_cast<std::size_t>(npix * 3));
  // The filter reads clusters up to R pixels around a masked pixel: cluster the mask dilated by R
  // (with reuse_clusters they exist everywhere already).
  std::vector<std::uint8_t> need;
  if (pixel_mask != nullptr && !reuse_clusters) {
    // PvmFilter's window radius (a multiple of filter_step; was ceil(radius_sigmas * sigma), short of
    // it when that is not a multiple of the step, so a masked render could differ from a full one).
    const int step = std::max(1, options.filter_step);
    const int r = options.filtered ? static_cast<int>(std::ceil(options.radius_sigmas * options.sigma / step)) * step : 0;
    std::vector<std::uint8_t> rows(static_cast<std::size_t>(npix), 0);
    need.assign(static_cast<std::size_t>(npix), 0);
    ParallelFor(h, 8, [&](std::int64_t a, std::int64_t b) {
      for (std::int64_t y = a; y < b; ++y) {
        int last = -1000000;  // last masked column seen
        for (int x = 0; x < w; ++x) {
          if (pixel_mask[y * w + x]) last = x;
          if (x - last <= r) rows[static_cast<std::size_t>(y * w + x)] = 1;
        }
        last = 1000000;
        for (int x = w - 1; x >= 0; --x) {
          if (pixel_mask[y * w + x]) last = x;
          if (last - x <= r) rows[static_cast<std::size_t>(y * w + x)] = 1;
        }
      }
    });
    ParallelFor(w, 64, [&](std::int64_t a, std::int64_t b) {
      for (std::int64_t x = a; x < b; ++x) {
        int last = -1000000;
        for (int y = 0; y < h; ++y) {
          if (rows[static_cast<std::size_t>(y * w + x)]) last = y;
          if (y - last <= r) need[static_cast<std::size_t>(y * w + x)] = 1;
        }
        last = 1000000;
        for (int y = h - 1; y >= 0; --y) {
          if (rows[static_cast<std::size_t>(y * w + x)]) last = y;
          if (last - y <= r) need[static_cast<std::size_t>(y * w + x)] = 1;
        }
      }
    });
  }
  const glm::dvec3 c_novel_d = camera.CentreInWorld();
  const glm::vec3 c_novel(c_novel_d);
  std::vector<glm::vec3> centres(static_cast<std::size_t>(views.count));
  for (int v = 0; v < views.count; ++v) centres[static_cast<std::size_t>(v)] = Centre(views.cameras[v]);
  const int ulr_k = std::max(1, options.ulr_k);
  const bool free_space = options.free_space && views.depths != nullptr;
  const bool stretch = frame.stretch_codes && options.stretch_weight > 0.f;
  ParallelFor(h, 4, [&](std::int64_t a, std::int64_t b) {
    double pos[kPvmMaxCandidates][2];  // a candidate's position in its view's image
    bool projected[kPvmMaxCandidates];
    float pen[kPvmMaxCandidates];
    int member[kPvmMaxCandidates];
    bool bg[kPvmMaxCandidates];
    std::vector<int> index(static_cast<std::size_t>(ulr_k));
    std::vector<float> weight(static_cast<std::size_t>(ulr_k));
    std::vector<int> others;  // SeenThrough's views
    std::vector<std::uint8_t> has(static_cast<std::size_t>(views.count), 0);  // and its scratch (all 0)
    others.reserve(static_cast<std::size_t>(views.count));
    const bool limited = options.max_angle < 3.1415926f;
    const float cos_max = limited ? std::cos(options.max_angle) : -1.f;
    for (std::int64_t y = a; y < b; ++y) {
      for (int x = 0; x < w; ++x) {
        const std::int64_t p = y * w + x;
        const bool masked = pixel_mask == nullptr || pixel_mask[p];
        if (reuse_clusters ? !masked : (!need.empty() && !need[static_cast<std::size_t>(p)])) continue;
        const int n = frame.cand_count[static_cast<std::size_t>(p)];
        if (n == 0) continue;
        const float* d = frame.cand_depth.data() + p * K;
        const std::int16_t* vv = frame.cand_view.data() + p * K;
        const std::uint8_t* sc = frame.cand_stretch.data() + p * K;
        double m0 = 0.0, m1 = 0.0;
        bool two = false;
        if (reuse_clusters) {  // the depth pass's clusters: membership bits, two = a background exists
          const unsigned bits = frame.bg_bits[static_cast<std::size_t>(p)];
          for (int i = 0; i < n; ++i) bg[i] = ((bits >> i) & 1u) != 0;
          two = frame.n_bg[static_cast<std::size_t>(p)] > 0;
        } else {
        // 2-means on the depths.
        float lo = d[0], hi = d[0];
        for (int i = 1; i < n; ++i) {
          lo = std::min(lo, d[i]);
          hi = std::max(hi, d[i]);
        }
        m0 = lo, m1 = hi;
        for (int i = 0; i < n; ++i) bg[i] = false;
        two = hi - lo > options.merge_rel * lo;
        if (two) {
          for (int it = 0; it < 16; ++it) {
            bool changed = false;
            double s0 = 0, s1 = 0;
            int k0 = 0, k1 = 0;
            for (int i = 0; i < n; ++i) {
              const bool to_bg = std::fabs(d[i] - m1) < std::fabs(d[i] - m0);
              changed = changed || to_bg != bg[i] || it == 0;
              bg[i] = to_bg;
              if (to_bg) {
                s1 += d[i];
                ++k1;
              } else {
                s0 += d[i];
                ++k0;
              }
            }
            m0 = s0 / k0;  // k0, k1 >= 1: the smallest depth stays nearer m0, the largest nearer m1
            m1 = s1 / k1;
            if (!changed) break;
          }
          two = m1 - m0 > options.merge_rel * m0;
        }
        if (!two) {
          double s = 0;
          for (int i = 0; i < n; ++i) {
            bg[i] = false;
            s += d[i];
          }
          m0 = s / n;
        }
        unsigned bits = 0;
        for (int i = 0; i < n; ++i) bits |= (bg[i] ? 1u : 0u) << i;
        frame.bg_bits[static_cast<std::size_t>(p)] = static_cast<std::uint16_t>(bits);
        }  // 2-means
        // #N_bg: the background candidates, or with free_space those whose view sees past the
        // foreground point (pvm_render.h, stage 4). None counted: one cluster, the foreground.
        int k1 = 0;
        for (int i = 0; i < n; ++i) k1 += bg[i] ? 1 : 0;
        int counted = k1;
        // The pixel's ray (world) and the foreground point on it: the free-space tests and the colours.
        const glm::dvec3 ray = camera.WorldFromCamDir(camera.RayInCam(x + 0.5, y + 0.5));
        const glm::dvec3 fg_point = c_novel_d + ray * m0;
        if (reuse_clusters) {
          counted = frame.n_bg[static_cast<std::size_t>(p)];
        } else if (two && free_space) {
          counted = 0;
          for (int i = 0; i < n; ++i) {
            if (bg[i] && SeesPast(views.cameras[vv[i]], views.depths[vv[i]], fg_point, options.free_space_tol,
                                     options.free_space_point_tol)) ++counted;
          }
        }
        const bool two_counted = two && counted > 0;
        if (!reuse_clusters && !two_counted && free_space && options.tau_empty > 0.f &&
            SeenThrough(views, centres, c_novel, fg_point, n - k1, vv, n, options, limited, cos_max, others, has)) {
          frame.cand_count[static_cast<std::size_t>(p)] = 0;  // empty: n_fg stays 0, so not valid
          continue;
        }
        if (!colours || !masked) {  // a pixel of the dilation ring: Eq. 1 reads its clusters, not its colours
          frame.d_fg[static_cast<std::size_t>(p)] = static_cast<float>(m0);
          frame.n_fg[static_cast<std::size_t>(p)] = static_cast<std::uint8_t>(n - k1);
          if (two_counted) {
            frame.d_bg[static_cast<std::size_t>(p)] = static_cast<float>(m1);
            frame.n_bg[static_cast<std::size_t>(p)] = static_cast<std::uint8_t>(counted);
          }
          continue;
        }
        // Candidate penalties and image positions; a candidate's colour is read (colour_of) only
        // when a cluster's blend uses it: at most ulr_k per cluster of up to 12 candidates (the
        // same colours and sums as reading them all: cluster & blend 91 -> 85 ms per 1280x720 frame).
        for (int i = 0; i < n; ++i) {
          // The penalty as the ULR method's per-pixel loop computes it (UlrPenaltyFast: the novel
          // side once per candidate point, polynomial atan2 within 1e-5 rad of UlrPenalty's
          // std::atan2, which cost as much as the rest of this loop).
          pen[i] = std::numeric_limits<float>::infinity();
          projected[i] = false;
          if (bg[i] && !two_counted) continue;  // a background candidate of a one-cluster pixel: unused
          const glm::dvec3 pw = c_novel_d + ray * static_cast<double>(d[i]);
          const int v = vv[i];
          const Camera& cam = views.cameras[v];
          double iz = 0;
          projected[i] = cam.ProjectCam(cam.CamFromWorld(pw), &pos[i][0], &pos[i][1], &iz);
          if (projected[i]) {
            const glm::vec3 pf(pw);
            const glm::vec3 to_novel = c_novel - pf;
            pen[i] = UlrPenaltyFast(pf, to_novel, glm::length(to_novel), centres[static_cast<std::size_t>(v)],
                                    options.resolution_weight);
            if (stretch) {  // pvm_render.h stage 4, "Stretch"
              pen[i] += options.stretch_weight * std::max(0.f, StretchOctaves(sc[i]) - options.stretch_free);
            }
          }
        }
        // Candidate i's colour from its view (0 where it does not project). Read at most once per
        // pixel without a cache: a candidate is in one cluster, and a blend uses it once.
        const auto colour_of = [&](int i, float c[3]) {
          c[0] = c[1] = c[2] = 0.f;
          if (projected[i]) {
            const Camera& cam = views.cameras[vv[i]];
            ReadRgb(views.images[vv[i]], static_cast<std::ptrdiff_t>(cam.width) * 3, cam.width, cam.height,
                    pos[i][0], pos[i][1], options.cubic, c);
          }
        };
        for (int k = 0; k < (two_counted ? 2 : 1); ++k) {
          int m = 0;
          float sub_pen[kPvmMaxCandidates];
          for (int i = 0; i < n; ++i)
            if (bg[i] == (k == 1)) {
              member[m] = i;
              sub_pen[m++] = pen[i];
            }
          float c3[3] = {0.f, 0.f, 0.f};
          const int sel = UlrSelect(sub_pen, m, ulr_k, index.data(), weight.data());
          if (sel == 0) {  // no candidate has a finite penalty: unweighted mean (0 where none projects)
            for (int j = 0; j < m; ++j) {
              float c[3];
              colour_of(member[j], c);
              for (int q = 0; q < 3; ++q) c3[q] += c[q] / static_cast<float>(m);
            }
          } else {
            // The k-th kept candidate has weight 0 (UlrSelect): not read (as ULR's blend; adding
            // 0 x a finite colour changes no bit).
            for (int j = 0; j < sel; ++j) {
              const float wj = weight[static_cast<std::size_t>(j)];
              if (!(wj > 0.f)) continue;
              float c[3];
              colour_of(member[index[static_cast<std::size_t>(j)]], c);
              for (int q = 0; q < 3; ++q) c3[q] += wj * c[q];
            }
          }
          float* out = (k == 0 ? frame.c_fg.data() : frame.c_bg.data()) + 3 * p;
          out[0] = c3[0];
          out[1] = c3[1];
          out[2] = c3[2];
          if (reuse_clusters) continue;  // kept: the same depths and sizes
          if (k == 0) {
            frame.d_fg[static_cast<std::size_t>(p)] = static_cast<float>(m0);
            frame.n_fg[static_cast<std::size_t>(p)] = static_cast<std::uint8_t>(m);
          } else {
            frame.d_bg[static_cast<std::size_t>(p)] = static_cast<float>(m1);
            frame.n_bg[static_cast<std::size_t>(p)] = static_cast<std::uint8_t>(counted);
          }
        }
      }
    }
  });
}

void PvmFilter(const double* box, const Camera& camera, const std::uint8_t* pixel_mask,
               const PvmRenderOptions& options, bool colours, PvmFrame& frame, float* color, float* depth, float* vote,
               std::uint8_t* valid, std::uint8_t* inside_grid, bool reuse_inside) {
  const int h = camera.height, w = camera.width;
  const std::size_t npix = static_cast<std::size_t>(h) * static_cast<std::size_t>(w);
  reuse_inside = reuse_inside && frame.inside.size() == npix;
  if (!reuse_inside) frame.inside.resize(npix);
  std::uint8_t* kept_inside = frame.inside.data();
  const int step = std::max(1, options.filter_step);
  const int r = static_cast<int>(std::ceil(options.radius_sigmas * options.sigma / step)) * step;
  const int side = 2 * r + 1;
  std::vector<float> gauss(static_cast<std::size_t>(side) * side);
  for (int dy = -r; dy <= r; ++dy)
    for (int dx = -r; dx <= r; ++dx)
      gauss[static_cast<std::size_t>((dy + r) * side + dx + r)] =
          options.sigma > 0.f ? std::exp(-(dx * dx + dy * dy) / (2.f * options.sigma * options.sigma))
                              : (dx == 0 && dy == 0 ? 1.f : 0.f);
  const double* lo = box;
  const double* hi = box + 3;
  const glm::dvec3 c_novel = camera.CentreInWorld();
  const float* dfg = frame.d_fg.data();
  const float* dbg = frame.d_bg.data();
  const std::uint8_t* nfg = frame.n_fg.data();
  const std::uint8_t* nbg = frame.n_bg.data();
  // Pairs of the Eq. 1 window: (2 R / step + 1)^2 neighbours, two clusters each, padded to 4.
  const std::size_t per_axis = static_cast<std::size_t>(2 * (r / step) + 1);
  const std::size_t max_pairs = 2 * per_axis * per_axis + 4;
#if defined(IBR_PVM_AVX2)
  const bool avx2 = UseAvx2();  // Eq. 1's exponentials eight at a time (PairSumsAvx2: same bits)
#endif
  const auto rows = [&](std::int64_t a, std::int64_t b) {
    std::vector<float> pair_w(max_pairs), pair_d(max_pairs);
    (void)pair_w, (void)pair_d;
    for (std::int64_t y = a; y < b; ++y) {
      for (int x = 0; x < w; ++x) {
        const std::int64_t p = y * w + x;
        if (reuse_inside) {
          inside_grid[p] = kept_inside[p];
        } else {
          // Ray against the surface's box (slabs).
          const glm::dvec3 dir = camera.WorldFromCamDir(camera.RayInCam(x + 0.5, y + 0.5));
          double t0 = 0.0, t1 = std::numeric_limits<double>::infinity();
          ClipRayToBox(c_novel, dir, lo, hi, t0, t1);
          inside_grid[p] = kept_inside[p] = t0 <= t1 ? 1 : 0;
        }
        float* out = color + 3 * p;
        out[0] = out[1] = out[2] = 0.f;
        depth[p] = 0.f;
        vote[p] = 0.f;
        valid[p] = 0;
        if (pixel_mask != nullptr && !pixel_mask[p]) continue;
        const int n0 = nfg[p], n1 = nbg[p];
        if (n0 == 0) continue;
        valid[p] = 1;
        const float* c0 = frame.c_fg.data() + 3 * p;
        const float* c1 = frame.c_bg.data() + 3 * p;
        if (n1 == 0) {
          if (colours) {  // without colours (the depth pass) PvmCluster wrote none: colour stays 0
            out[0] = c0[0];
            out[1] = c0[1];
            out[2] = c0[2];
          }
          depth[p] = dfg[p];
          vote[p] = 1.f;
          continue;
        }
        // Eq. 2 vote.
        const bool pick_bg = static_cast<float>(n1) >= options.tau_depth * static_cast<float>(n0);
        depth[p] = pick_bg ? dbg[p] : dfg[p];
        vote[p] = static_cast<float>(pick_bg ? n1 : n0) / static_cast<float>(n0 + n1);
        if (!colours) continue;
        if (!options.filtered) {
          out[0] = c0[0];
          out[1] = c0[1];
          out[2] = c0[2];
          continue;
        }
        // Eq. 1.
        const float di0 = dfg[p], di1 = dbg[p];
        double w0 = 0.0, w1 = 0.0;
#if defined(__SSE2__)
        // The window's (G #N, d) pairs of both clusters gathered into a list, then the two
        // exponentials of four pairs at a time (ExpNeg4, the same polynomial as ExpNeg). Float
        // accumulators per lane, summed in double at the end: the weights agree with the scalar
        // loop's (double accumulation in window order) to float rounding, ~1e-7 relative.
        {
          float* pw = pair_w.data();
          float* pd = pair_d.data();
          int np = 0;
          for (int oy = -r; oy <= r; oy += step) {
            const int yy = static_cast<int>(y) + oy;
            if (yy < 0 || yy >= h) continue;
            const float* grow = gauss.data() + static_cast<std::size_t>((oy + r) * side + r - x);
            for (int ox = -r; ox <= r; ox += step) {
              const int xx = x + ox;
              if (xx < 0 || xx >= w) continue;
              const std::int64_t q = static_cast<std::int64_t>(yy) * w + xx;
              const float g = grow[xx];
              if (nfg[q]) pw[np] = g * nfg[q], pd[np++] = dfg[q];
              if (nbg[q]) pw[np] = g * nbg[q], pd[np++] = dbg[q];
            }
          }
          while (np & 3) pw[np] = 0.f, pd[np++] = di0;
          alignas(16) float l0[4], l1[4];
#if defined(IBR_PVM_AVX2)
          if (avx2) {
            PairSumsAvx2(pw, pd, np, options.alpha, di0, di1, l0, l1);
          } else
#endif
          {
          const __m128 A = _mm_set1_ps(options.alpha), D0 = _mm_set1_ps(di0), D1 = _mm_set1_ps(di1);
          const __m128 sign = _mm_set1_ps(-0.f);
          __m128 s0 = _mm_setzero_ps(), s1 = _mm_setzero_ps();
          for (int k = 0; k < np; k += 4) {
            const __m128 wt = _mm_loadu_ps(pw + k), d = _mm_loadu_ps(pd + k);
            s0 = _mm_add_ps(s0, _mm_mul_ps(wt, ExpNeg4(_mm_mul_ps(A, _mm_andnot_ps(sign, _mm_sub_ps(d, D0))))));
            s1 = _mm_add_ps(s1, _mm_mul_ps(wt, ExpNeg4(_mm_mul_ps(A, _mm_andnot_ps(sign, _mm_sub_ps(d, D1))))));
          }
          _mm_store_ps(l0, s0);
          _mm_store_ps(l1, s1);
          }
          w0 = (static_cast<double>(l0[0]) + l0[1]) + (static_cast<double>(l0[2]) + l0[3]);
          w1 = (static_cast<double>(l1[0]) + l1[1]) + (static_cast<double>(l1[2]) + l1[3]);
        }
#else
        // Window offsets -r, -r + step, ..., r (step = filter_step; step 1 = every neighbour).
        for (int oy = -r; oy <= r; oy += step) {
          const int yy = static_cast<int>(y) + oy;
          if (yy < 0 || yy >= h) continue;
          const float* grow = gauss.data() + static_cast<std::size_t>((oy + r) * side + r - x);
          for (int ox = -r; ox <= r; ox += step) {
            const int xx = x + ox;
            if (xx < 0 || xx >= w) continue;
            const std::int64_t q = static_cast<std::int64_t>(yy) * w + xx;
            const float g = grow[xx];
            if (nfg[q]) {
              const float gn = g * nfg[q];
              w0 += gn * ExpNeg(options.alpha * std::fabs(dfg[q] - di0));
              w1 += gn * ExpNeg(options.alpha * std::fabs(dfg[q] - di1));
            }
            if (nbg[q]) {
              const float gn = g * nbg[q];
              w0 += gn * ExpNeg(options.alpha * std::fabs(dbg[q] - di0));
              w1 += gn * ExpNeg(options.alpha * std::fabs(dbg[q] - di1));
            }
          }
        }
#endif
        // W0^g / (W0^g + W1^g) through the ratio (no overflow for large gamma).
        double a1 = 0.0;
        if (w0 > 0.0 && w1 > 0.0) {
          const double t = std::exp(options.gamma * std::log(w1 / w0));
          a1 = std::isfinite(t) ? t / (1.0 + t) : 1.0;
        } else if (w1 > 0.0) {
          a1 = 1.0;
        }
        const float f1 = static_cast<float>(a1), f0 = 1.f - f1;
        for (int k = 0; k < 3; ++k) out[k] = f0 * c0[k] + f1 * c1[k];
      }
    }
  };
  ParallelForIsa(h, 4, rows);
}

}  // namespace ibr
