// A method's colour as the completion writes it (python/ibrtools/inpaint/complete.py clean_color):
// NaN and +-inf become 0, and every channel of a hole pixel (hole non-zero) becomes +0; other
// values are copied as they are. color, out (n pixels x c channels) float32, hole (n) one byte per
// pixel or null (no hole mask). One pass, multithreaded over pixels; nothing allocated or thrown.
#pragma once
#include <cstdint>

namespace ibr {

void CleanColorKernel(const float* color, const std::uint8_t* hole, std::int64_t n, int c, float* out);

}  // namespace ibr
