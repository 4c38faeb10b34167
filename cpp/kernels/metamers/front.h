// The metamers family's front (Python: ibrtools.metamers.foveate, ibrtools.inpaint.metameric through
// cpp/bindings/metamers.cpp): the steerable pyramid's value checks and the multi-level pipelines
// over the kernels of mip.h, callable from C++ without Python. The binding checks the arrays'
// dtypes and shapes and allocates the outputs.
#pragma once
#include <string>

#include "ibr/image.h"

namespace ibr {

// Throws BadValueError unless the steerable pyramid has fitted taps for `orientations` (2 or 4)
// and `levels` is in 0 .. SteerableMaxLevels(h, w).
void SteerableCheckOptions(int orientations, int levels, int h, int w);

// Throws BadValueError naming `name` when the image holds NaN or infinite values.
void SteerableCheckFinite(const ImageView<const float>& image, const std::string& name);

// The box-filter MIP chain of in: out[l] = MipDown(level l) for l = 0 .. levels - 1 (level 0 = in);
// out[l] (ceil(H / 2^(l+1)), ceil(W / 2^(l+1)), C).
void MipBuildChain(const ImageView<const float>& in, const ImageView<float>* out, int levels);

// The fused foveation of one pyramid level in place (mip.h MipFoveateChange): the moments' MIP
// chain of the k bands (h, w, C), `levels` levels above them (2 k C channels, allocated here), then
// the change of every band at its per-pixel MIP level (level (h, w)) with noise (h, w, C) per band.
void MipFoveateLevel(const ImageView<float>* bands, int k, const ImageView<const float>& level,
                     const ImageView<const float>* noise, int levels);

}  // namespace ibr
