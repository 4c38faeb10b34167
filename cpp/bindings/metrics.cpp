// Bindings of cpp/kernels/metrics/ssim.h: dtypes, shapes and sizes checked here, the options and
// the values by the front (cpp/kernels/metrics/front.h), called with the GIL released.
// Python: ibrtools.metrics.
#include <cmath>
#include <string>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "array.h"
#include "ibr/errors.h"
#include "kernels/metrics/front.h"
#include "module.h"

namespace ibr::bind {
namespace {

using FloatArray = py::array_t<float, py::array::c_style>;

// a and b: float32 (H, W) or (H, W, C), same shape, at least win x win (their values: the front's).
void CheckPair(const py::handle& a_obj, const py::handle& b_obj, int win_size, FloatArray* a_out,
               FloatArray* b_out) {
  auto dims_of = [](const py::handle& obj) -> std::vector<Dim> {
    if (py::isinstance<py::array>(obj) && py::reinterpret_borrow<py::array>(obj).ndim() == 3) {
      return {{"H", -1}, {"W", -1}, {"C", -1}};
    }
    return {{"H", -1}, {"W", -1}};
  };
  FloatArray a = CheckArray<float>(a_obj, "a", dims_of(a_obj));
  FloatArray b = CheckArray<float>(b_obj, "b", dims_of(b_obj));
  if (a.ndim() != b.ndim() || a.shape(0) != b.shape(0) || a.shape(1) != b.shape(1) ||
      (a.ndim() == 3 && a.shape(2) != b.shape(2))) {
    throw ShapeError("a and b: images of different shapes, a " + DescribeShape(a) + " and b " +
                     DescribeShape(b));
  }
  if (a.shape(0) < win_size || a.shape(1) < win_size) {
    throw ShapeError("a and b: SSIM needs images of at least " + std::to_string(win_size) + "x" +
                     std::to_string(win_size) + " pixels (the window), got shape " + DescribeShape(a));
  }
  if (a.ndim() == 3 && a.shape(2) < 1) throw ShapeError("a and b: images with 0 channels");
  *a_out = a;
  *b_out = b;
}

}  // namespace

void BindMetrics(py::module_& m) {
  m.def(
      "ssim",
      [](py::handle a_obj, py::handle b_obj, double data_range, bool return_map, int win_size,
         double k1, double k2, bool sample_covariance) {
        SsimOptions options;
        options.win_size = win_size;
        options.k1 = k1;
        options.k2 = k2;
        options.data_range = data_range;
        options.sample_covariance = sample_covariance;
        SsimCheckOptions(options);
        FloatArray a, b;
        CheckPair(a_obj, b_obj, win_size, &a, &b);
        py::object map_obj = py::none();
        ImageView<float> map_view;
        if (return_map) {
          FloatArray map = NewArray<float>({a.shape(0), a.shape(1)});
          map_view = ViewOf(map);
          map_obj = map;
        }
        const ImageView<const float> va = ConstViewOf(a), vb = ConstViewOf(b);
        double mean = 0.0;
        {
          py::gil_scoped_release release;
          mean = Ssim(va, vb, options, map_view);
        }
        return py::make_tuple(mean, map_obj);
      },
      py::arg("a"), py::arg("b"), py::arg("data_range") = SsimOptions{}.data_range, py::arg("return_map") = false,
      py::arg("win_size") = SsimOptions{}.win_size, py::arg("k1") = SsimOptions{}.k1, py::arg("k2") = SsimOptions{}.k2,
      py::arg("sample_covariance") = SsimOptions{}.sample_covariance,
      "SSIM of two float32 images (H, W) or (H, W, C), skimage's default definition (7x7 box "
      "window, sample covariance, mean over the image cropped by 3 pixels, channel mean). Returns "
      "(mean, map or None); map is float32 (H, W), the per-pixel SSIM averaged over channels.");
}

}  // namespace ibr::bind
