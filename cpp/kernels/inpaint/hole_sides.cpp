// The covered pixels beside each hole pixel (hole_sides.h).
#include "kernels/inpaint/hole_sides.h"

#include <algorithm>

#include "ibr/parallel.h"

namespace ibr {
namespace {

// Calls visit(hy, hx, y, x, side) for every hole pixel (hy, hx) and each of its nearest covered
// pixels (y, x) to the left, right, above and below (side 0, 1, 2, 3). Rows first (the ends of
// each run of holes), then blocks of columns (a top-down and a bottom-up sweep, each row's access
// contiguous); within each of the two passes a hole pixel is visited by one thread only.
template <typename Visit>
void VisitSides(const ImageView<const std::uint8_t>& hole, const Visit& visit) {
  const int h = hole.height, w = hole.width;
  ParallelFor(h, 8, [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const std::uint8_t* hr = hole.Row(y);
      int x = 0;
      while (x < w) {
        if (!hr[x]) {
          ++x;
          continue;
        }
        int end = x;
        while (end < w && hr[end]) ++end;  // the run of holes [x, end)
        for (int k = x; k < end; ++k) {
          if (x > 0) visit(y, k, y, x - 1, 0);
          if (end < w) visit(y, k, y, end, 1);
        }
        x = end;
      }
    }
  });
  constexpr int kBlock = 64;
  const int blocks = (w + kBlock - 1) / kBlock;
  ParallelFor(blocks, 1, [&](std::int64_t b0, std::int64_t b1) {
    int last[kBlock];
    for (int b = static_cast<int>(b0); b < static_cast<int>(b1); ++b) {
      const int x0 = b * kBlock, x1 = std::min(w, x0 + kBlock);
      for (int pass = 0; pass < 2; ++pass) {
        std::fill(last, last + kBlock, -1);
        for (int i = 0; i < h; ++i) {
          const int y = pass == 0 ? i : h - 1 - i;
          const std::uint8_t* hr = hole.Row(y);
          for (int x = x0; x < x1; ++x) {
            if (!hr[x]) {
              last[x - x0] = y;
            } else if (last[x - x0] >= 0) {
              visit(y, x, last[x - x0], x, 2 + pass);
            }
          }
        }
      }
    }
  });
}

}  // namespace

void HoleSidesKernel(const ImageView<const std::uint8_t>& hole, const ImageView<const std::uint8_t>& background,
                     const ImageView<const float>& known_depth, double occluder_ratio,
                     const ImageView<std::uint8_t>& sides, const ImageView<float>& around) {
  const int h = hole.height, w = hole.width;
  ParallelFor(h, 8, [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      std::fill(sides.Row(y), sides.Row(y) + w, std::uint8_t{0});
      std::fill(around.Row(y), around.Row(y) + w, 0.0f);
    }
  });
  VisitSides(hole, [&](int hy, int hx, int y, int x, int side) {
    const int code = background.At(y, x) ? kSideBackground : kSideSurface;
    sides.At(hy, hx) = static_cast<std::uint8_t>(sides.At(hy, hx) | code << (2 * side));
    around.At(hy, hx) = std::max(around.At(hy, hx), known_depth.At(y, x));
  });
  if (occluder_ratio <= 0.0) return;
  // The occluders, once `around` is complete (hole_sides.h): surface -> occluder sets both bits.
  VisitSides(hole, [&](int hy, int hx, int y, int x, int side) {
    const double d = known_depth.At(y, x);
    if (!background.At(y, x) && d > 0.0 && d * occluder_ratio < around.At(hy, hx)) {
      sides.At(hy, hx) = static_cast<std::uint8_t>(sides.At(hy, hx) | kSideOccluder << (2 * side));
    }
  });
}

}  // namespace ibr
