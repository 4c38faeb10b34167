// The process-wide instruction-set switch of RunIsa (simd.h).
#include "ibr/simd.h"

#include <atomic>

namespace ibr {
namespace {
std::atomic<int> g_isa{-1};  // -1 auto, 0 baseline, 1 AVX2
}  // namespace

// __builtin_cpu_supports takes a string literal only, hence a macro rather than a function.
#if defined(__GNUC__) && defined(__x86_64__)
#define IBR_CPU_SUPPORTS(feature) __builtin_cpu_supports(feature)
#else
#define IBR_CPU_SUPPORTS(feature) false
#endif

bool CpuHasAvx2() {
  static const bool has = IBR_CPU_SUPPORTS("avx2");
  return has;
}

bool CpuHasAvx512f() {
  static const bool has = IBR_CPU_SUPPORTS("avx512f");
  return has;
}

bool SetIsa(Isa isa) {
  if (isa == Isa::kAvx2 && !CpuHasAvx2()) return false;
  g_isa.store(static_cast<int>(isa), std::memory_order_relaxed);
  return true;
}

bool UseAvx2() {
  const int isa = g_isa.load(std::memory_order_relaxed);
  return isa < 0 ? CpuHasAvx2() : isa == 1;
}

}  // namespace ibr
