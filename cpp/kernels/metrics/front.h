// The metrics family's checked front (Python: ibrtools.metrics through cpp/bindings/metrics.cpp):
// the value checks of SSIM's options and inputs, callable from C++ without Python. The binding
// checks dtypes and shapes (bindings/array.h: equal shapes, at least win x win pixels), converts
// and calls these. Definitions: ssim.h.
#pragma once

#include "ibr/image.h"
#include "kernels/metrics/ssim.h"

namespace ibr {

// Throws BadValueError unless data_range is positive and finite, win_size odd and >= 3, K1 and
// K2 positive and finite.
void SsimCheckOptions(const SsimOptions& options);

// SsimKernel after checking a and b finite (BadValueError naming the first with a NaN or an
// infinity, and how many). a, b of one shape, at least win x win (the binding checks).
double Ssim(const ImageView<const float>& a, const ImageView<const float>& b, const SsimOptions& options,
            const ImageView<float>& map);

}  // namespace ibr
