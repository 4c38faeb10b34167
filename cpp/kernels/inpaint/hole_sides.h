// What lies beside each hole pixel (python/ibrtools/inpaint/complete.py, the completion's fill):
// the nearest covered (non-hole) pixel to its left, right, above and below, when there is one,
// summarised per hole pixel as
//   votes     the number of those found (0..4),
//   bg_votes  how many of them are background at infinity (`background` non-zero),
//   around    the largest `known_depth` among them (0 when none has one: known_depth is 0 on the
//             background and where the depth is unknown).
// Written per pixel: sides (H, W) = votes | bg_votes << 4 and around (H, W), both 0 outside the
// holes. The same as ibrtools.inpaint.pushpull.nearest_covered's four directions, reduced.
//
// Shapes: hole, background (H, W) one byte per pixel (non-zero = true); known_depth (H, W)
// float32; sides (H, W) uint8 and around (H, W) float32, written. The binding
// (cpp/bindings/inpaint.cpp) checks them. Three passes: rows (left and right: the ends of each
// run of holes), then columns in blocks (up and down), each multithreaded with ibr::ParallelFor
// over independent rows or columns; sums of small integers and maxima, so the result is the
// same for any thread count. Nothing is allocated or thrown.
#pragma once
#include <cstdint>

#include "ibr/image.h"

namespace ibr {

void HoleSidesKernel(const ImageView<const std::uint8_t>& hole, const ImageView<const std::uint8_t>& background,
                     const ImageView<const float>& known_depth, const ImageView<std::uint8_t>& sides,
                     const ImageView<float>& around);

}  // namespace ibr
