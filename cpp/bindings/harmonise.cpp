// Binding of the harmonisation kernels (cpp/kernels/harmonise.h): _core.cross_view_prediction,
// _core.interpolate_vertex_values.
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
  m.def(
      "interpolate_vertex_values",
      [](py::handle prim_obj, py::handle bary_obj, py::handle faces_obj, py::handle values_obj) {
        auto prim = CheckArray<std::int32_t>(prim_obj, "prim_id", {{"H", -1}, {"W", -1}});
        const py::ssize_t h = prim.shape(0), w = prim.shape(1);
        auto bary = CheckArray<float>(bary_obj, "bary", {{"H", h}, {"W", w}, {"2", 2}});
        auto faces = CheckArray<std::int32_t>(faces_obj, "faces", {{"M", -1}, {"3", 3}});
        auto values = CheckArray<float>(values_obj, "values", {{"N", -1}, {"C", -1}});
        const py::ssize_t n_faces = faces.shape(0), n_vert = values.shape(0), ch = values.shape(1);
        if (ch < 1 || ch > 64) throw ShapeError("values: expected 1 to 64 channels, got " + DescribeShape(values));
        {
          const std::int32_t* f = faces.data();
          for (py::ssize_t i = 0; i < 3 * n_faces; ++i) {
            if (f[i] < 0 || f[i] >= n_vert) {
              throw BadValueError("faces: vertex index " + std::to_string(f[i]) + " out of range [0, " +
                                  std::to_string(n_vert) + ")");
            }
          }
          const std::int32_t* p = prim.data();
          for (py::ssize_t i = 0; i < h * w; ++i) {
            if (p[i] < -1 || p[i] >= n_faces) {
              throw BadValueError("prim_id: triangle index " + std::to_string(p[i]) + " out of range [-1, " +
                                  std::to_string(n_faces) + ")");
            }
          }
        }
        auto out = NewArray<float>({h, w, ch});
        {
          py::gil_scoped_release release;
          InterpolateVertexValues(prim.data(), bary.data(), h * w, faces.data(), values.data(), static_cast<int>(ch),
                                  out.mutable_data());
        }
        return out;
      },
      py::arg("prim_id"), py::arg("bary"), py::arg("faces"), py::arg("values"),
      "Per-vertex values interpolated over the rendered triangles (cpp/kernels/harmonise.h): prim_id (H, W) "
      "int32 (-1: no triangle), bary (H, W, 2) float32, faces (M, 3) int32, values (N, C) float32; returns "
      "(H, W, C) float32, 0 where prim_id is -1.");
}

}  // namespace ibr::bind
