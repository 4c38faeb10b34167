// The process-wide instruction-set switch of RunIsa (simd.h).
#include "ibr/simd.h"

#include <atomic>

namespace ibr {
namespace {
std::atomic<int> g_isa{-1};  // -1 auto, 0 baseline, 1 AVX2
}  // namespace

bool CpuHasAvx2() {
#if defined(__GNUC__) && defined(__x86_64__)
  static const bool has = __builtin_cpu_supports("avx2");
  return has;
#else
  return false;
#endif
}

bool CpuHasAvx512f() {
#if defined(__GNUC__) && defined(__x86_64__)
  static const bool has = __builtin_cpu_supports("avx512f");
  return has;
#else
  return false;
#endif
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
