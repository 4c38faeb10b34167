// The hybrid family's front: the checks of its options (hybrid.h).
#include <cmath>
#include <string>

#include "ibr/errors.h"
#include "kernels/hybrid/hybrid.h"

namespace ibr {
namespace {

void CheckFiniteAtLeast(float v, const char* name, double lo) {
  if (!std::isfinite(v) || v < lo) {
    throw BadValueError(std::string(name) + ": expected a finite number >= " + std::to_string(lo) + ", got " +
                        std::to_string(v));
  }
}

}  // namespace

void UlrOptions::Check() const {
  if (k < 1 || k > kMaxK) {
    throw BadValueError("k: expected 1 .. " + std::to_string(kMaxK) + " views per pixel, got " + std::to_string(k));
  }
  CheckFiniteAtLeast(resolution_weight, "resolution_weight", 0.0);
  CheckFiniteAtLeast(depth_tol, "depth_tol", 0.0);
}

}  // namespace ibr
