// What lies beside each hole pixel (python/ibrtools/inpaint/complete.py, the completion's fill):
// the nearest covered (non-hole) pixel to its left, right, above and below, when there is one.
// Written per hole pixel:
//   sides   2 bits per side, left in bits 0-1, right 2-3, up 4-5, down 6-7: kSideNone (no covered
//           pixel that way: the image's edge), kSideBackground (`background` non-zero: the
//           background at infinity), kSideSurface, or kSideOccluder when occluder_ratio > 0: a
//           surface side whose known_depth times occluder_ratio is below `around`, the near side
//           of a disocclusion (a pole in front of the sky says nothing of what its hole shows;
//           the side opposite it does);
//   around  the largest `known_depth` of the sides (0 when none has one: known_depth is 0 on the
//           background and where the depth is unknown).
// Both are 0 outside the holes. The sides are those of ibrtools.inpaint.pushpull.nearest_covered.
//
// Shapes: hole, background (H, W) one byte per pixel (non-zero = true); known_depth (H, W)
// float32; occluder_ratio 0 (no occluders) or > 1; sides (H, W) uint8 and around (H, W) float32,
// written. The binding (cpp/bindings/inpaint.cpp) checks them. Each visit of the sides is two
// passes: rows (left and right: the ends of each run of holes), then columns in blocks (up and
// down), each multithreaded with ibr::ParallelFor over independent rows or columns; the
// occluders are a second visit once `around` is complete. Bit sets and maxima, so the result is
// the same for any thread count. Nothing is allocated or thrown.
#pragma once
#include <cstdint>

#include "ibr/image.h"

namespace ibr {

constexpr int kSideNone = 0, kSideBackground = 1, kSideSurface = 2, kSideOccluder = 3;

void HoleSidesKernel(const ImageView<const std::uint8_t>& hole, const ImageView<const std::uint8_t>& background,
                     const ImageView<const float>& known_depth, double occluder_ratio,
                     const ImageView<std::uint8_t>& sides, const ImageView<float>& around);

}  // namespace ibr
