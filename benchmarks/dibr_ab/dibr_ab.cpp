// A/B driver of the DIBR kernels without Python (benchmarks/dibr_ab.py builds and runs it):
// k colour + depth views -> one target, ClearBlend (or, with kernels that have BlendBuffers::fresh, none:
// the first view writes the sums, as _core.DibrAccumulator does) + k ForwardWarp (accumulating) + ResolveBlend,
// the options of --method dibr (side_threshold 10, stretched_quality 0.1, stretched_holes). The colour's
// finiteness is checked as the binding does it: by the kernel (check_color) or, for older kernels, by the
// binding's serial loop before each view (both inside the timed region).
//   dibr_ab DIR THREADS REPEATS VIEWS [plain] [srgb]
// (plain: no visibility rules across views, as benchmarks/bench_dibr.py's DibrAccumulator(); srgb: the blend
// space "srgb" of --method dibr: the views' colours are sRGB-encoded before the timing, as the renderer caches
// them, and the blended colour is decoded -- inside ResolveBlend with kernels that have BlendSpace, else by a
// separate SrgbToLinear pass over the result, timed, as the renderer did before).
// DIR holds cams.txt (per view then the target: W H fx fy cx cy and the 3 x 4 cam_from_world, row
// major) and c<i>.raw / d<i>.raw (float32 colour (H, W, 3) and depth (H, W)). Prints the minimum
// over REPEATS runs (after one warm-up) of the process CPU time and of the wall time, and an
// FNV-1a hash of the outputs (colour, depth, confidence, hole): equal hashes = identical bits.
#include <chrono>
#include <ctime>
static double Cpu() { timespec t; clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t); return t.tv_sec * 1e3 + t.tv_nsec * 1e-6; }
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <cstdint>
#include <vector>
#include <algorithm>
#include "ibr/parallel.h"
#include "ibr/simd.h"  // the tree's switch: also for a base revision older than it
#include "kernels/dibr/forward_warp.h"
#include "kernels/dibr/blend.h"
#include "ibr/colour.h"
using namespace ibr;
static std::vector<float> Load(const char* p, size_t n) {
  std::vector<float> v(n); FILE* f = fopen(p, "rb"); if (!f || fread(v.data(), 4, n, f) != n) { perror(p); exit(1); } fclose(f); return v;
}
int main(int argc, char** argv) {
  if (argc < 5) { fprintf(stderr, "usage: dibr_ab DIR THREADS REPEATS VIEWS [plain] [srgb]\n"); return 2; }
  bool plain = false, srgb = false;
  for (int a = 5; a < argc; ++a) {
    if (strcmp(argv[a], "plain") == 0) plain = true;
    else if (strcmp(argv[a], "srgb") == 0) srgb = true;
    else { fprintf(stderr, "unknown option %s\n", argv[a]); return 2; }
  }
  const char* dir = argv[1];
  int threads = atoi(argv[2]), reps = atoi(argv[3]), nviews = atoi(argv[4]);
  SetNumThreads(threads);
  char p[4096];
  snprintf(p, sizeof p, "%s/cams.txt", dir);
  FILE* f = fopen(p, "r");
  if (!f) { perror(p); return 1; }
  std::vector<Camera> cams(nviews + 1);
  for (int i = 0; i <= nviews; ++i) {
    double a[18]; for (int k = 0; k < 18; ++k) if (fscanf(f, "%lf", &a[k]) != 1) return 1;
    Camera& c = cams[i]; c.width = int(a[0]); c.height = int(a[1]); c.fx = a[2]; c.fy = a[3]; c.cx = a[4]; c.cy = a[5];
    for (int r = 0; r < 3; ++r) { for (int cc = 0; cc < 3; ++cc) c.rot[cc][r] = a[6 + 4 * r + cc]; c.trans[r] = a[6 + 4 * r + 3]; }
  }
  fclose(f);
  const int W = cams[nviews].width, H = cams[nviews].height;  // target
  const size_t n = size_t(W) * H;
  std::vector<std::vector<float>> col(nviews), dep(nviews);
  for (int i = 0; i < nviews; ++i) {
    const size_t ni = size_t(cams[i].width) * cams[i].height;
    snprintf(p, sizeof p, "%s/c%d.raw", dir, i); col[i] = Load(p, 3 * ni);
    snprintf(p, sizeof p, "%s/d%d.raw", dir, i); dep[i] = Load(p, ni);
    if (srgb) for (float& v : col[i]) v = SrgbEncode(std::max(v, 0.f));  // dibr/method.py srgb_encode (cached there)
  }
  std::vector<float> swc(3 * n), sw(n), swi(n), sq(n), mq(n), vc(3 * n), vd(n), vw(n), vq(n), oc(3 * n), od(n), oq(n);
  std::vector<unsigned char> oh(n);
  BlendBuffers acc; acc.height = H; acc.width = W; acc.sum_wc = swc.data(); acc.sum_w = sw.data(); acc.sum_w_invd = swi.data();
  acc.sum_q = sq.data(); acc.max_q = mq.data(); acc.stretched_quality = 0.1f; acc.stretched_holes = true;
  if (plain) { acc.stretched_quality = 0.f; acc.stretched_holes = false; }  // bench_dibr's DibrAccumulator()
  WarpOptions opt; opt.side_threshold = 10.f;
  WarpScratch scratch;
  double best_cpu = 1e30, best = 1e30, best_warp = 1e30, best_res = 1e30;
  unsigned long long hsh = 0;
  if (reps < 1) reps = 1;
  for (int rep = 0; rep <= reps; ++rep) {
    auto t0 = std::chrono::steady_clock::now(); double c0 = Cpu();
#ifdef IBR_BLEND_FRESH  // the kernels have it: the first view writes the sums (no clearing pass, as the binding)
    acc.fresh = true;
#else
    ClearBlend(acc);
#endif
    for (int i = 0; i < nviews; ++i) {
#ifndef IBR_FORWARD_WARP_CHECK_COLOR
      // Older kernels: the binding checked the colour before the kernel, serially (its loop).
      {
        std::uint32_t any = 0;
        const float* cp = col[i].data();
        for (size_t k = 0; k < col[i].size(); ++k) { std::uint32_t u; std::memcpy(&u, cp + k, 4); any |= std::uint32_t((u & 0x7f800000u) == 0x7f800000u); }
        if (any) { fprintf(stderr, "non-finite colour\n"); return 1; }
      }
#endif
#ifdef IBR_FORWARD_WARP_BAND_LOCAL  // the kernels have it: no per-view buffers (as the binding)
      ForwardWarp(ImageView<const float>(col[i].data(), cams[i].height, cams[i].width, 3), ImageView<const float>(dep[i].data(), cams[i].height, cams[i].width), cams[i], cams[nviews], opt, scratch,
                  ImageView<float>(), ImageView<float>(), ImageView<float>(), nullptr, &acc
#ifdef IBR_FORWARD_WARP_CHECK_COLOR  // the binding's finite-colour check, in the kernel's projection pass
                  , true
#endif
                  );
#else
      ForwardWarp(ImageView<const float>(col[i].data(), cams[i].height, cams[i].width, 3), ImageView<const float>(dep[i].data(), cams[i].height, cams[i].width), cams[i], cams[nviews], opt, scratch,
                  ImageView<float>(vc.data(), H, W, 3), ImageView<float>(vd.data(), H, W), ImageView<float>(vw.data(), H, W), vq.data(), &acc);
#endif
#ifdef IBR_BLEND_FRESH
      acc.fresh = false;
#endif
    }
    auto t1 = std::chrono::steady_clock::now();
#if defined(IBR_BLEND_RESOLVE_SRGB)  // as the binding: AVX2 when the warp uses it; the decode in the resolve
    ResolveBlend(acc, oc.data(), od.data(), oq.data(), oh.data(), UseAvx2(),
                 srgb ? BlendSpace::kSrgb : BlendSpace::kLinear);
#else
#ifdef IBR_BLEND_RESOLVE_AVX2
    ResolveBlend(acc, oc.data(), od.data(), oq.data(), oh.data(), UseAvx2());
#else
    ResolveBlend(acc, oc.data(), od.data(), oq.data(), oh.data());
#endif
    if (srgb) SrgbToLinear(oc.data(), oc.data(), std::int64_t(oc.size()));  // _core.srgb_to_linear's pass
#endif
    auto t2 = std::chrono::steady_clock::now(); double c2 = Cpu();
    double a = std::chrono::duration<double, std::milli>(t1 - t0).count(), b = std::chrono::duration<double, std::milli>(t2 - t1).count();
    if (rep > 0) { best_cpu = std::min(best_cpu, c2 - c0); best = std::min(best, a + b); best_warp = std::min(best_warp, a); best_res = std::min(best_res, b); }
  }
  // FNV-1a over outputs
  hsh = 1469598103934665603ull;
  auto mix = [&](const void* d, size_t bytes) { const unsigned char* c = (const unsigned char*)d; for (size_t k = 0; k < bytes; ++k) { hsh ^= c[k]; hsh *= 1099511628211ull; } };
  mix(oc.data(), 4 * oc.size()); mix(od.data(), 4 * od.size()); mix(oq.data(), 4 * oq.size()); mix(oh.data(), oh.size());
  printf("cpu_ms %.2f wall_ms %.2f warp_ms %.2f resolve_ms %.2f hash %016llx\n", best_cpu, best, best_warp, best_res, hsh);
}
