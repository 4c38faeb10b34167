// The push-pull options of a binding's arguments, shared by ibrtools.inpaint.pushpull
// (inpaint.cpp) and the moments push-pulls of metameric inpainting (metameric.cpp): depth None
// (classic push-pull) or float32 (h, w) (depth-aware, Alg. 1 of dos Anjos et al.), gamma and
// depth_threshold finite and >= 0; one-line errors naming the argument.
#pragma once
#include <cmath>
#include <string>

#include "array.h"
#include "kernels/inpaint/pushpull.h"

namespace ibr::bind {

// `depth` receives the checked depth array (kept alive by the caller) when depth_obj is not None.
inline PushPullOptions CheckPushPullArgs(py::handle depth_obj, py::ssize_t h, py::ssize_t w, double depth_threshold,
                                         double gamma, py::array_t<float, py::array::c_style>* depth) {
  if (!(std::isfinite(gamma) && gamma >= 0.0)) {
    throw BadValueError("gamma: expected a finite number >= 0, got " + std::to_string(gamma));
  }
  if (!(std::isfinite(depth_threshold) && depth_threshold >= 0.0)) {
    throw BadValueError("depth_threshold: expected a finite number >= 0, got " + std::to_string(depth_threshold));
  }
  PushPullOptions options;
  options.gamma = static_cast<float>(gamma);
  options.depth_threshold = static_cast<float>(depth_threshold);
  if (!depth_obj.is_none()) {
    *depth = CheckArray<float>(depth_obj, "depth", {{"H", h}, {"W", w}});
    options.depth_aware = true;
  }
  return options;
}

}  // namespace ibr::bind
