// The metrics family's checked front (front.h).
#include "kernels/metrics/front.h"

#include <cmath>
#include <cstdint>
#include <string>

#include "ibr/errors.h"

namespace ibr {

void SsimCheckOptions(const SsimOptions& o) {
  if (!(std::isfinite(o.data_range) && o.data_range > 0)) {
    throw BadValueError("data_range: expected a positive finite number, got " + std::to_string(o.data_range));
  }
  if (o.win_size < 3 || o.win_size % 2 == 0) {
    throw BadValueError("win_size: expected an odd integer >= 3, got " + std::to_string(o.win_size));
  }
  if (!(o.k1 > 0 && o.k2 > 0 && std::isfinite(o.k1) && std::isfinite(o.k2))) {
    throw BadValueError("K1, K2: expected positive finite numbers");
  }
}

double Ssim(const ImageView<const float>& a, const ImageView<const float>& b, const SsimOptions& options,
            const ImageView<float>& map) {
  const std::int64_t n = a.NumPixels() * a.channels;
  const std::int64_t bad_a = CountNonFinite(a.data, n);
  const std::int64_t bad_b = CountNonFinite(b.data, n);
  if (bad_a || bad_b) {
    throw BadValueError(std::string(bad_a ? "a" : "b") + ": contains " + std::to_string(bad_a ? bad_a : bad_b) +
                        " NaN or infinite values");
  }
  return SsimKernel(a, b, options, map);
}

}  // namespace ibr
