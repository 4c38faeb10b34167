// CPU dispatch for plain loops. IBR_AVX2_CLONES compiles a function twice, for AVX2 and for the
// baseline (SSE2), and picks one at load time (GCC function multi-versioning; the build does not
// use -march=native). AVX2 does not enable FMA, so GCC cannot contract a * b + c: both versions
// perform the same IEEE operations and give the same bits, whatever the CPU. Not "avx512f": it
// enables FMA, and contraction changes results by ~1 ulp (measured: ~2e-6 on the steerable
// pyramid's test images) for ~5 % speed. Functions using AVX2 intrinsics take
// __attribute__((target("avx2"))) and a runtime check instead.
#pragma once

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define IBR_AVX2_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define IBR_AVX2_CLONES
#endif

namespace ibr {

// fn(args...) built for AVX2 and the baseline (IBR_AVX2_CLONES) with every call inside inlined
// (flatten), fn's body included: for a ParallelFor body written as a lambda, e.g.
// ParallelFor(n, g, [&](std::int64_t a, std::int64_t b) { RunAvx2Clones(body, a, b); }).
// (cpp/kernels/forward_warp.cpp's CallAvx2 is the same idea with an ISA switch for its tests.)
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
template <class F, class... Args>
__attribute__((target_clones("avx2", "default"), flatten)) void RunAvx2Clones(const F& fn, Args... args) {
  fn(args...);
}
#else
template <class F, class... Args>
void RunAvx2Clones(const F& fn, Args... args) {
  fn(args...);
}
#endif

}  // namespace ibr
