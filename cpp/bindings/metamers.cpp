// The metamers family's bindings: the small-filter steerable pyramid (cpp/kernels/metamers/steerable.h)
// and the moment mipmaps of foveation (mip.h). Python: ibrtools.metamers.steerable, ibrtools.metamers.foveate.
#include <cmath>
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "array.h"
#include "ibr/checks.h"
#include "ibr/errors.h"
#include "kernels/metamers/front.h"
#include "kernels/metamers/mip.h"
#include "kernels/metamers/steerable.h"
#include "module.h"

// Bindings of cpp/kernels/metamers/steerable.h: dtypes and shapes of every level checked here, the
// orientations, levels and finiteness by the front (front.h), the calls with the GIL released.
// Python: ibrtools.metamers.steerable.
namespace ibr::bind {
namespace {

using FloatArray = py::array_t<float, py::array::c_style>;

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
  py::gil_scoped_release release;
  SteerableCheckFinite(View<const float>(a), name);
}

}  // namespace

static void BindSteerable(py::module_& m) {
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
        SteerableCheckOptions(orientations, levels, static_cast<int>(h), static_cast<int>(w));
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
        const int levels = static_cast<int>(py::len(bands_obj));
        SteerableCheckOptions(orientations, levels, static_cast<int>(h), static_cast<int>(w));
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

// Bindings of cpp/kernels/metamers/mip.h and its pipelines (front.h): the checks (dtypes, shapes of the
// chain, finiteness of the level map) and the calls with the GIL released. Python: ibrtools.metamers.foveate.
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

static void BindMip(py::module_& m) {
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
          MipBuildChain(in, views.data(), levels);
        }
        py::list result;
        for (FloatArray& a : out) result.append(a);
        return result;
      },
      py::arg("image"), py::arg("levels") = -1,
      "Box-filter MIP chain of image float32 (H, W, C) (cpp/kernels/metamers/mip.h): a list of `levels` arrays "
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
          bad = CountNonFiniteValues(lp, std::int64_t(hh) * ww);
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
      "Trilinear read of a MIP chain (cpp/kernels/metamers/mip.h): levels = [level 0 (H, W, C), level 1 "
      "(ceil(H/2), ceil(W/2), C), ...] float32; level float32 (H, W), finite, the fractional MIP level "
      "per pixel (clamped to [0, len(levels) - 1]; <= 0 copies level 0 exactly). Returns float32 (H, W, C).");

  m.def(
      "mip_foveate_level",
      [](py::handle bands_obj, py::handle level_obj, py::handle noise_obj, int levels) {
        std::vector<FloatArray> bands = CheckArrayList(bands_obj, "bands", -1, -1, -1, true);
        const py::ssize_t h = bands[0].shape(0), w = bands[0].shape(1), c = bands[0].shape(2);
        const py::ssize_t k = static_cast<py::ssize_t>(bands.size());
        std::vector<FloatArray> noise = CheckPairedArrayList(noise_obj, "noise", bands, "band");
        if (2 * k * c > kMipMaxMomentChannels) {
          throw ShapeError("bands: 2 x bands x channels must be <= " + std::to_string(kMipMaxMomentChannels) +
                           ", got " + std::to_string(2 * k * c));
        }
        const int top = MaxLevels(h, w);
        if (levels < 0 || levels > top) {
          throw BadValueError("levels: expected 0.." + std::to_string(top) + " for " + std::to_string(h) + "x" +
                              std::to_string(w) + " bands, got " + std::to_string(levels));
        }
        FloatArray level = CheckArray<float>(level_obj, "level", {{"h", h}, {"w", w}});
        for (std::size_t i = 0; i < bands.size(); ++i) {
          for (std::size_t j = 0; j < bands.size(); ++j) {
            if (i != j && Overlaps(bands[i], bands[j])) {
              throw BadValueError("bands[" + std::to_string(i) + "]: shares memory with bands[" + std::to_string(j) +
                                  "] (each is written in place)");
            }
          }
          for (std::size_t j = 0; j < noise.size(); ++j) {
            if (Overlaps(bands[i], noise[j])) {
              throw BadValueError("bands[" + std::to_string(i) + "]: shares memory with noise[" + std::to_string(j) +
                                  "]");
            }
          }
          if (Overlaps(bands[i], level)) {
            throw BadValueError("bands[" + std::to_string(i) + "]: shares memory with level");
          }
        }
        std::int64_t bad = 0;
        const float* lp = level.data();
        {
          py::gil_scoped_release release;
          bad = CountNonFiniteValues(lp, std::int64_t(h) * w);
        }
        if (bad) throw BadValueError("level: contains " + std::to_string(bad) + " NaN or infinite values");
        std::vector<ImageView<float>> band_views;
        std::vector<ImageView<const float>> noise_views;
        for (FloatArray& b : bands) band_views.push_back(ViewOf(b));
        for (FloatArray& a : noise) noise_views.push_back(ConstViewOf(a));
        const ImageView<const float> level_view = ConstViewOf(level);
        {
          py::gil_scoped_release release;
          MipFoveateLevel(band_views.data(), static_cast<int>(k), level_view, noise_views.data(), levels);
        }
      },
      py::arg("bands"), py::arg("level"), py::arg("noise"), py::arg("levels"),
      "One pyramid level of a foveated metamer, in place (cpp/kernels/metamers/mip.h MipFoveateChange): bands "
      "k float32 (h, w, C) arrays, written with their change; level float32 (h, w) finite, the MIP level "
      "per sample; noise k float32 (h, w, C); levels 0..mip_max_levels(h, w), the chain height of the "
      "moments [X, X^2] (built here, never returned). Where level <= 0 the change is 0; elsewhere it is "
      "mean + sigma * noise - band with the moments read trilinearly at min(level, levels). Equals "
      "mip_build + mip_lookup + metameric_composite + subtraction to float rounding.");
}

}  // namespace ibr::bind

namespace ibr::bind {

void BindMetamers(py::module_& m) {
  BindSteerable(m);
  BindMip(m);
}

}  // namespace ibr::bind
