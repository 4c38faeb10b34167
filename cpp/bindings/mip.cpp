// Bindings of cpp/kernels/mip.h: the checking front (dtypes, shapes of the chain, finiteness of
// the level map) and the calls with the GIL released. Python: ibrtools.foveate.
#include <cmath>
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "array.h"
#include "ibr/errors.h"
#include "kernels/mip.h"
#include "module.h"

namespace ibr::bind {
namespace {

using FloatArray = py::array_t<float, py::array::c_style>;

// Levels above the full resolution until 1x1: ceil halving.
int MaxLevels(py::ssize_t h, py::ssize_t w) {
  int n = 0;
  while (h > 1 || w > 1) {
    h = (h + 1) / 2;
    w = (w + 1) / 2;
    ++n;
  }
  return n;
}

}  // namespace

void BindMip(py::module_& m) {
  m.def(
      "mip_max_levels", [](py::ssize_t h, py::ssize_t w) {
        if (h < 1 || w < 1) throw BadValueError("mip_max_levels: expected height, width >= 1");
        return MaxLevels(h, w);
      },
      py::arg("height"), py::arg("width"),
      "Number of MIP levels above an (height, width) image (ceil halving down to 1x1).");

  m.def(
      "mip_build",
      [](py::handle image_obj, int levels) {
        FloatArray image = CheckArray<float>(image_obj, "image", {{"H", -1}, {"W", -1}, {"C", -1}});
        const py::ssize_t h = image.shape(0), w = image.shape(1), c = image.shape(2);
        if (h < 1 || w < 1 || c < 1) {
          throw ShapeError("image: expected at least 1x1 pixels and 1 channel, got " + DescribeShape(image));
        }
        const int top = MaxLevels(h, w);
        if (levels < 0) levels = top;
        if (levels > top) {
          throw BadValueError("levels: expected 0.." + std::to_string(top) + " (or -1 = all) for a " +
                              std::to_string(h) + "x" + std::to_string(w) + " image, got " + std::to_string(levels));
        }
        std::vector<FloatArray> out;
        py::ssize_t lh = h, lw = w;
        for (int l = 0; l < levels; ++l) {
          lh = (lh + 1) / 2;
          lw = (lw + 1) / 2;
          out.push_back(NewArray<float>({lh, lw, c}));
        }
        std::vector<ImageView<float>> views;
        for (FloatArray& a : out) views.push_back(ViewOf(a));
        const ImageView<const float> in = ConstViewOf(image);
        {
          py::gil_scoped_release release;
          for (int l = 0; l < levels; ++l) {
            const ImageView<float>& prev = views[l > 0 ? l - 1 : 0];
            const ImageView<const float> src =
                l == 0 ? in : ImageView<const float>(prev.data, prev.height, prev.width, prev.channels);
            MipDown(src, views[l]);
          }
        }
        py::list result;
        for (FloatArray& a : out) result.append(a);
        return result;
      },
      py::arg("image"), py::arg("levels") = -1,
      "Box-filter MIP chain of image float32 (H, W, C) (cpp/kernels/mip.h): a list of `levels` arrays "
      "(-1 = down to 1x1), level l+1 of shape (ceil(H / 2^(l+1)), ceil(W / 2^(l+1)), C), each the 2x2 "
      "average of the previous one (odd sizes: the pixels that exist). The input itself is level 0 and "
      "is not in the list.");

  m.def(
      "mip_lookup",
      [](py::handle levels_obj, py::handle level_obj) {
        if (!py::isinstance<py::list>(levels_obj) && !py::isinstance<py::tuple>(levels_obj)) {
          throw DtypeError("levels: expected a list of float32 (h, w, C) arrays (level 0 first), got " +
                           std::string(py::str(py::type::of(levels_obj).attr("__name__"))));
        }
        std::vector<FloatArray> levels;
        py::ssize_t h = -1, w = -1, c = -1;
        for (py::handle item : levels_obj) {
          const std::string name = "levels[" + std::to_string(levels.size()) + "]";
          FloatArray a = CheckArray<float>(item, name.c_str(), {{"h", h}, {"w", w}, {"C", c}});
          if (levels.empty()) {
            if (a.shape(0) < 1 || a.shape(1) < 1 || a.shape(2) < 1) {
              throw ShapeError("levels[0]: expected at least 1x1 pixels and 1 channel, got " + DescribeShape(a));
            }
            c = a.shape(2);
          }
          levels.push_back(a);
          h = (a.shape(0) + 1) / 2;
          w = (a.shape(1) + 1) / 2;
        }
        if (levels.empty()) throw ShapeError("levels: expected at least level 0, got an empty list");
        const py::ssize_t hh = levels[0].shape(0), ww = levels[0].shape(1);
        FloatArray level = CheckArray<float>(level_obj, "level", {{"H", hh}, {"W", ww}});
        std::int64_t bad = 0;
        const float* lp = level.data();
        {
          py::gil_scoped_release release;
          for (std::int64_t i = 0; i < std::int64_t(hh) * ww; ++i) bad += !std::isfinite(lp[i]);
        }
        if (bad) throw BadValueError("level: contains " + std::to_string(bad) + " NaN or infinite values");
        FloatArray out = NewArray<float>({hh, ww, c});
        std::vector<ImageView<const float>> views;
        for (FloatArray& a : levels) views.push_back(ConstViewOf(a));
        const ImageView<const float> level_view = ConstViewOf(level);
        const ImageView<float> out_view = ViewOf(out);
        {
          py::gil_scoped_release release;
          MipLookup(views.data(), static_cast<int>(views.size()), level_view, out_view);
        }
        return out;
      },
      py::arg("levels"), py::arg("level"),
      "Trilinear read of a MIP chain (cpp/kernels/mip.h): levels = [level 0 (H, W, C), level 1 "
      "(ceil(H/2), ceil(W/2), C), ...] float32; level float32 (H, W), finite, the fractional MIP level "
      "per pixel (clamped to [0, len(levels) - 1]; <= 0 copies level 0 exactly). Returns float32 (H, W, C).");
}

}  // namespace ibr::bind
