// CPU dispatch for plain loops (no intrinsics): the engine is built for the SSE2 baseline (no
// -march=native) and runs loops compiled for AVX2 where the CPU has it. AVX2 does not enable FMA,
// so GCC cannot contract a * b + c: both versions perform the same IEEE operations and give the
// same bits, whatever the CPU. Not "avx512f": it enables FMA, and contraction changes results by
// ~1 ulp (measured: ~2e-6 on the steerable pyramid's test images) for ~5 % speed. Functions using
// AVX2 intrinsics take __attribute__((target("avx2"))) and a run-time check instead.
//
// Two forms:
//  - RunIsa(fn, args...) (ParallelForIsa for a ParallelFor body): fn (a loop body, usually a
//    lambda) with every call inside it inlined,
//    compiled for AVX2 and the baseline; which one runs follows the process-wide switch SetIsa
//    (auto: AVX2 when the CPU has it), so tests can run the baseline on an AVX2 CPU and compare
//    bits (_core.set_warp_isa: the forward warp, the G-buffer raster, the PVM loops).
//  - IBR_AVX2_CLONES on a function: GCC function multi-versioning, picked once at load time by the
//    CPU (no switch: the baseline version runs only on CPUs without AVX2).
#pragma once
#include <cstdint>

#include "ibr/parallel.h"

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define IBR_HAVE_AVX2_DISPATCH 1
#if defined(__SANITIZE_THREAD__)
// Not under ThreadSanitizer: a clone's resolver runs while the module is being relocated, and
// TSan's instrumented entry hook inside it would call through a GOT entry not relocated yet.
#define IBR_AVX2_CLONES
#else
#define IBR_AVX2_CLONES __attribute__((target_clones("avx2", "default")))
#endif
#else
#define IBR_AVX2_CLONES
#endif

namespace ibr {

enum class Isa : int { kAuto = -1, kBaseline = 0, kAvx2 = 1 };

// Whether the CPU has AVX2 (run-time check; also for the kernels' intrinsic AVX2 paths).
bool CpuHasAvx2();
// Whether the CPU has AVX-512F (run-time check; ULR's intrinsic AVX-512 view loop and depth test).
bool CpuHasAvx512f();
// Process-wide (tests and benchmarks); false, and nothing changes, when kAvx2 is asked on a CPU
// without AVX2.
bool SetIsa(Isa isa);
// Whether RunIsa runs the AVX2 version now.
bool UseAvx2();

#if defined(IBR_HAVE_AVX2_DISPATCH)
template <class F, class... Args>
__attribute__((target("avx2"), flatten)) void CallAvx2(const F& fn, Args... args) {
  fn(args...);
}
#endif

template <class F, class... Args>
void RunIsa(const F& fn, Args... args) {
#if defined(IBR_HAVE_AVX2_DISPATCH)
  if (UseAvx2()) {
    CallAvx2(fn, args...);
    return;
  }
#endif
  fn(args...);
}

// ParallelFor(n, grain, body) with every chunk run through RunIsa.
template <class F>
void ParallelForIsa(std::int64_t n, std::int64_t grain, const F& body) {
  ParallelFor(n, grain, [&](std::int64_t b, std::int64_t e) { RunIsa(body, b, e); });
}

}  // namespace ibr
