// Binding of the harmonisation kernels (cpp/kernels/harmonise.h): _core.cross_view_prediction.
// Thin: checks arrays (array.h) and values, releases the GIL around the kernel.
// Python: ibrtools.hybrid.harmonise.
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "array.h"
#include "ibr/errors.h"
#include "kernels/harmonise.h"
#include "module.h"

namespace ibr::bind {

void BindHarmonise(py::module_& m) {
  m.def(
      "cross_view_prediction",
      [](const Camera& camera, py::handle depth_obj, const std::vector<Camera>& cameras, py::list depths_obj,
         py::list images_obj, double depth_tol, double quantile) {
        auto depth = CheckArray<float>(depth_obj, "depth", {{"H", camera.height}, {"W", camera.width}});
        if (depths_obj.size() != cameras.size() || images_obj.size() != cameras.size()) {
          throw ShapeError("cameras, depths, images: expected lists of one length, got " +
                           std::to_string(cameras.size()) + ", " + std::to_string(depths_obj.size()) + ", " +
                           std::to_string(images_obj.size()));
        }
        if (!(depth_tol > 0.0) || !std::isfinite(depth_tol)) {
          throw BadValueError("depth_tol: expected a finite number > 0, got " + std::to_string(depth_tol));
        }
        if (!(quantile >= 0.0 && quantile <= 1.0)) {
          throw BadValueError("quantile: expected a number in [0, 1], got " + std::to_string(quantile));
        }
        std::vector<py::array_t<float, py::array::c_style>> keep;
        std::vector<PredictionSource> sources(cameras.size());
        for (std::size_t k = 0; k < cameras.size(); ++k) {
          const Camera& ck = cameras[k];
          const std::string dn = "depths[" + std::to_string(k) + "]";
          const std::string in = "images[" + std::to_string(k) + "]";
          auto dk = CheckArray<float>(depths_obj[k], dn.c_str(), {{"H", ck.height}, {"W", ck.width}});
          auto ik = CheckArray<float>(images_obj[k], in.c_str(), {{"H", ck.height}, {"W", ck.width}, {"3", 3}});
          sources[k] = PredictionSource{&cameras[k], dk.data(), ik.data()};
          keep.push_back(dk);
          keep.push_back(ik);
        }
        auto pred = NewArray<float>({camera.height, camera.width, 3});
        auto n_seen = NewArray<std::int32_t>({camera.height, camera.width});
        {
          py::gil_scoped_release release;
          CrossViewPrediction(camera, depth.data(), sources, depth_tol, quantile, pred.mutable_data(),
                              n_seen.mutable_data());
        }
        return py::make_tuple(pred, n_seen);
      },
      py::arg("camera"), py::arg("depth"), py::arg("cameras"), py::arg("depths"), py::arg("images"),
      py::arg("depth_tol"), py::arg("quantile") = 0.5,
      "Diffuse prediction of a view's pixels from other views (cpp/kernels/harmonise.h): camera "
      "(_core.Camera), depth (H, W) float32 (<= 0: no surface); cameras: list of _core.Camera, depths: "
      "list of their (Hk, Wk) float32 depth, images: list of their (Hk, Wk, 3) float32 colours; returns "
      "(prediction (H, W, 3) float32, n_seen (H, W) int32).");
}

}  // namespace ibr::bind
