// The completion's colour clean-up (clean.h).
#include "kernels/inpaint/clean.h"

#include <cmath>

#include "ibr/parallel.h"

namespace ibr {

void CleanColorKernel(const float* color, const std::uint8_t* hole, std::int64_t n, int c, float* out) {
  ParallelFor(n, 1 << 14, [&](std::int64_t p0, std::int64_t p1) {
    for (std::int64_t p = p0; p < p1; ++p) {
      const float* in = color + p * c;
      float* o = out + p * c;
      if (hole != nullptr && hole[p]) {
        for (int k = 0; k < c; ++k) o[k] = 0.0f;
        continue;
      }
      for (int k = 0; k < c; ++k) o[k] = std::isfinite(in[k]) ? in[k] : 0.0f;
    }
  });
}

}  // namespace ibr
