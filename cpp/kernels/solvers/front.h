// The solvers family's front (Python: ibrtools.solvers through cpp/bindings/solvers.cpp): the value
// checks of the grid max-flow's capacities and of Poisson blending's inputs and options, callable
// from C++ without Python. The capacity and input checks return the error's message ("" when the
// inputs are good) so that callers can run them with the GIL released and raise afterwards;
// PoissonCheckOptions throws BadValueError.
#pragma once
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <type_traits>

#include "ibr/image.h"
#include "kernels/solvers/poisson.h"

namespace ibr {

__extension__ typedef __int128 MaxflowInt128;  // GCC / Clang: exact sums of int64 capacities

// The four capacity arrays (source, sink, right, down) of n pixels each: finite and >= 0, and their
// total (edges twice: a residual edge holds both directions' capacities), which bounds every
// residual capacity and the flow, must fit the capacity type (int64 capacities summing past 2^63
// would give a wrapped, silently wrong flow and cut; float64 sums past 1e308 become inf).
template <typename Cap>
std::string MaxflowCheckCapacities(const Cap* const arrays[4], std::int64_t n) {
  const char* names[4] = {"source_cap", "sink_cap", "right", "down"};
  MaxflowInt128 total_int = 0;
  double total_float = 0.0;
  for (int k = 0; k < 4; ++k) {
    for (std::int64_t i = 0; i < n; ++i) {
      const Cap v = arrays[k][i];
      if (!(v >= 0) || !std::isfinite(static_cast<double>(v))) {
        return std::string(names[k]) + ": expected finite capacities >= 0, got " + std::to_string(v) +
               " at flat index " + std::to_string(i);
      }
      const int times = k < 2 ? 1 : 2;
      if constexpr (std::is_integral_v<Cap>) {
        total_int += static_cast<MaxflowInt128>(v) * times;
      } else {
        total_float += static_cast<double>(v) * times;
      }
    }
  }
  if constexpr (std::is_integral_v<Cap>) {
    if (total_int > static_cast<MaxflowInt128>(std::numeric_limits<Cap>::max())) {
      return "capacities: their total (source_cap + sink_cap + 2 x (right + down)) exceeds the int64 range "
             "(2^63 - 1); scale them down";
    }
  } else if (!std::isfinite(total_float)) {
    return "capacities: their total (source_cap + sink_cap + 2 x (right + down)) overflows float64; "
           "scale them down";
  }
  return "";
}

// tol in (0, 1), max_iter >= 1, smooth_sweeps 1..8, coarse_scale in (0, 2).
void PoissonCheckOptions(const PoissonOptions& options);

// The mask must leave boundary pixels outside it, and boundary and source be finite.
std::string PoissonCheckInputs(const ImageView<const float>& boundary, const ImageView<const float>& source,
                               const ImageView<const std::uint8_t>& mask);

}  // namespace ibr
