// The covered pixels beside each hole pixel (hole_sides.h).
#include "kernels/inpaint/hole_sides.h"

#include <algorithm>

#include "ibr/parallel.h"

namespace ibr {
namespace {

// Adds covered pixel (y, x) as one side of hole pixel (hy, hx).
inline void AddSide(const ImageView<const std::uint8_t>& background, const ImageView<const float>& known_depth,
                    int y, int x, std::uint8_t* side, float* around) {
  *side = static_cast<std::uint8_t>(*side + 1 + (background.At(y, x) ? 16 : 0));
  *around = std::max(*around, known_depth.At(y, x));
}

}  // namespace

void HoleSidesKernel(const ImageView<const std::uint8_t>& hole, const ImageView<const std::uint8_t>& background,
                     const ImageView<const float>& known_depth, const ImageView<std::uint8_t>& sides,
                     const ImageView<float>& around) {
  const int h = hole.height, w = hole.width;
  // Left and right: the pixels before and after each run of holes in a row.
  ParallelFor(h, 8, [&](std::int64_t y0, std::int64_t y1) {
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const std::uint8_t* hr = hole.Row(y);
      std::uint8_t* sr = sides.Row(y);
      float* ar = around.Row(y);
      std::fill(sr, sr + w, std::uint8_t{0});
      std::fill(ar, ar + w, 0.0f);
      int x = 0;
      while (x < w) {
        if (!hr[x]) {
          ++x;
          continue;
        }
        int end = x;
        while (end < w && hr[end]) ++end;  // the run of holes [x, end)
        for (int k = x; k < end; ++k) {
          if (x > 0) AddSide(background, known_depth, y, x - 1, sr + k, ar + k);
          if (end < w) AddSide(background, known_depth, y, end, sr + k, ar + k);
        }
        x = end;
      }
    }
  });
  // Up and down: per column, the last covered row above (a top-down sweep) and below (bottom-up);
  // blocks of columns, so that each row's access is contiguous.
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
              AddSide(background, known_depth, last[x - x0], x, &sides.At(y, x), &around.At(y, x));
            }
          }
        }
      }
    }
  });
}

}  // namespace ibr
