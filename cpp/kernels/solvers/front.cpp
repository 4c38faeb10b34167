// The solvers family's front (front.h).
#include "kernels/solvers/front.h"

#include "ibr/errors.h"

namespace ibr {

void PoissonCheckOptions(const PoissonOptions& o) {
  if (!(std::isfinite(o.tol) && o.tol > 0.0 && o.tol < 1.0)) {
    throw BadValueError("tol: expected a number in (0, 1), got " + std::to_string(o.tol));
  }
  if (o.max_iter < 1) throw BadValueError("max_iter: expected >= 1, got " + std::to_string(o.max_iter));
  if (o.smooth_sweeps < 1 || o.smooth_sweeps > 8) {
    throw BadValueError("smooth_sweeps: expected 1..8, got " + std::to_string(o.smooth_sweeps));
  }
  if (!(o.coarse_scale > 0.0 && o.coarse_scale < 2.0)) {
    throw BadValueError("coarse_scale: expected a number in (0, 2), got " + std::to_string(o.coarse_scale));
  }
}

std::string PoissonCheckInputs(const ImageView<const float>& bview, const ImageView<const float>& sview,
                               const ImageView<const std::uint8_t>& mask) {
  std::int64_t count = 0, bad_count = 0;
  const std::int64_t n = std::int64_t(mask.height) * mask.width;
  const std::int64_t c = bview.channels;
  const std::uint8_t* m = mask.data;
  for (std::int64_t i = 0; i < n; ++i) count += m[i];
  if (count == n) return "mask: covers the whole image; Poisson blending needs boundary pixels outside the mask";
  for (std::int64_t i = 0; i < n * c; ++i) {
    if (!std::isfinite(bview.data[i]) || !std::isfinite(sview.data[i])) ++bad_count;
  }
  if (bad_count) return "boundary/source: contain " + std::to_string(bad_count) + " NaN or infinite values";
  return "";
}

}  // namespace ibr
