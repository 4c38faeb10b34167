// Bindings of cpp/kernels/metamers/steerable.h: the checking front (dtypes, shapes of every level,
// orientations, levels against the image size, finiteness) and the calls with the GIL released.
// Python: ibrtools.steerable.
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "array.h"
#include "ibr/errors.h"
#include "kernels/metamers/steerable.h"
#include "module.h"

namespace ibr::bind {
namespace {

using FloatArray = py::array_t<float, py::array::c_style>;

void CheckOrientations(int orientations) {
  if (!SteerableOrientationsSupported(orientations)) {
    throw BadValueError("orientations: expected 2 or 4 (the fitted taps in cpp/kernels/metamers/steerable_taps.h), got " +
                        std::to_string(orientations));
  }
}

void CheckLevels(int levels, int h, int w) {
  const int max_levels = SteerableMaxLevels(h, w);
  if (levels < 0 || levels > max_levels) {
    throw BadValueError("levels: expected 0.." + std::to_string(max_levels) + " for a " + std::to_string(h) + "x" +
                        std::to_string(w) + " image (every level's input must be at least 3x3), got " +
                        std::to_string(levels));
  }
}

void CheckColour(bool ycbcr, py::ssize_t c) {
  if (ycbcr && c != 3) {
    throw ShapeError("image: ycbcr=True needs 3 channels (RGB), got " + std::to_string(c) +
                     "; pass ycbcr=False to filter the channels as given");
  }
}

template <typename T>
ImageView<T> View(const FloatArray& a) {
  return ImageView<T>(const_cast<float*>(a.data()), static_cast<int>(a.shape(0)), static_cast<int>(a.shape(1)),
                      static_cast<int>(a.shape(2)));
}

void CheckFinite(const FloatArray& a, const std::string& name) {
  std::int64_t bad;
  {
    py::gil_scoped_release release;
    bad = SteerableCountNonFinite(View<const float>(a));
  }
  if (bad) throw BadValueError(name + ": contains " + std::to_string(bad) + " NaN or infinite values");
}

}  // namespace

void BindSteerable(py::module_& m) {
  m.def("steerable_max_levels", &SteerableMaxLevels, py::arg("height"), py::arg("width"),
        "Largest number of steerable-pyramid levels for an H x W image (every level's input >= 3x3).");

  m.def(
      "steerable_analyse",
      [](py::handle image_obj, int levels, int orientations, bool ycbcr) {
        FloatArray image = CheckArray<float>(image_obj, "image", {{"H", -1}, {"W", -1}, {"C", -1}});
        const py::ssize_t h = image.shape(0), w = image.shape(1), c = image.shape(2);
        if (h < 3 || w < 3 || c < 1) {
          throw ShapeError("image: expected at least 3x3 pixels and 1 channel, got shape " + DescribeShape(image));
        }
        CheckOrientations(orientations);
        CheckLevels(levels, static_cast<int>(h), static_cast<int>(w));
        CheckColour(ycbcr, c);
        CheckFinite(image, "image");
        SteerablePyramidViews<float> pyr;
        pyr.levels = levels;
        pyr.orientations = orientations;
        FloatArray hi = NewArray<float>({h, w, c});
        pyr.highpass = View<float>(hi);
        py::list bands;
        for (int l = 0; l < levels; ++l) {
          py::list level;
          const py::ssize_t hl = SteerableLevelSize(static_cast<int>(h), l);
          const py::ssize_t wl = SteerableLevelSize(static_cast<int>(w), l);
          for (int k = 0; k < orientations; ++k) {
            FloatArray b = NewArray<float>({hl, wl, c});
            pyr.bands.push_back(View<float>(b));
            level.append(b);
          }
          bands.append(level);
        }
        FloatArray lo = NewArray<float>({SteerableLevelSize(static_cast<int>(h), levels),
                                         SteerableLevelSize(static_cast<int>(w), levels), c});
        pyr.lowpass = View<float>(lo);
        {
          py::gil_scoped_release release;
          SteerableAnalyseKernel(View<const float>(image), ycbcr, pyr);
        }
        return py::make_tuple(hi, bands, lo);
      },
      py::arg("image"), py::arg("levels") = 4, py::arg("orientations") = 2, py::arg("ycbcr") = true,
      "Steerable pyramid analysis (cpp/kernels/metamers/steerable.h). image float32 (H, W, C), H, W >= 3. Returns "
      "(highpass (H, W, C), bands [level][orientation] each (h_l, w_l, C), lowpass (h_L, w_L, C)).");

  m.def(
      "steerable_synthesise",
      [](py::handle hi_obj, py::sequence bands_obj, py::handle lo_obj, int orientations, bool ycbcr) {
        FloatArray hi = CheckArray<float>(hi_obj, "highpass", {{"H", -1}, {"W", -1}, {"C", -1}});
        const py::ssize_t h = hi.shape(0), w = hi.shape(1), c = hi.shape(2);
        if (h < 3 || w < 3 || c < 1) {
          throw ShapeError("highpass: expected at least 3x3 pixels and 1 channel, got shape " + DescribeShape(hi));
        }
        CheckOrientations(orientations);
        const int levels = static_cast<int>(py::len(bands_obj));
        CheckLevels(levels, static_cast<int>(h), static_cast<int>(w));
        CheckColour(ycbcr, c);
        std::vector<FloatArray> keep;
        SteerablePyramidViews<const float> pyr;
        pyr.levels = levels;
        pyr.orientations = orientations;
        pyr.highpass = View<const float>(hi);
        CheckFinite(hi, "highpass");
        for (int l = 0; l < levels; ++l) {
          py::handle level_obj = bands_obj[l];
          if (!py::isinstance<py::sequence>(level_obj) || py::len(level_obj) != static_cast<std::size_t>(orientations)) {
            throw ShapeError("bands[" + std::to_string(l) + "]: expected a list of " + std::to_string(orientations) +
                             " orientation bands");
          }
          const py::ssize_t hl = SteerableLevelSize(static_cast<int>(h), l);
          const py::ssize_t wl = SteerableLevelSize(static_cast<int>(w), l);
          py::sequence level = py::reinterpret_borrow<py::sequence>(level_obj);
          for (int k = 0; k < orientations; ++k) {
            const std::string name = "bands[" + std::to_string(l) + "][" + std::to_string(k) + "]";
            FloatArray b = CheckArray<float>(level[k], name.c_str(), {{"h_l", hl}, {"w_l", wl}, {"C", c}});
            CheckFinite(b, name);
            pyr.bands.push_back(View<const float>(b));
            keep.push_back(b);
          }
        }
        FloatArray lo = CheckArray<float>(lo_obj, "lowpass",
                                          {{"h_L", SteerableLevelSize(static_cast<int>(h), levels)},
                                           {"w_L", SteerableLevelSize(static_cast<int>(w), levels)},
                                           {"C", c}});
        CheckFinite(lo, "lowpass");
        pyr.lowpass = View<const float>(lo);
        FloatArray out = NewArray<float>({h, w, c});
        {
          py::gil_scoped_release release;
          SteerableSynthesiseKernel(pyr, ycbcr, View<float>(out));
        }
        return out;
      },
      py::arg("highpass"), py::arg("bands"), py::arg("lowpass"), py::arg("orientations") = 2,
      py::arg("ycbcr") = true,
      "Steerable pyramid synthesis (collapse) of (highpass, bands[level][orientation], lowpass) as returned by "
      "steerable_analyse; returns the image float32 (H, W, C).");
}

}  // namespace ibr::bind
