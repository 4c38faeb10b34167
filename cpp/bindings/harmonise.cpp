// Binding of the harmonisation kernel (cpp/kernels/hybrid/harmonise.h): _core.cross_view_prediction; and
// of the per-vertex statistics' gain loops
// (cpp/kernels/hybrid/vertexstats.h): _core.vertex_colour_sums, _core.gain_median_ratios.
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
#include "kernels/hybrid/harmonise.h"
#include "kernels/hybrid/vertexstats.h"
#include "module.h"

namespace ibr::bind {

namespace {

// bounds: (V + 1,) int64 from 0 to num_rows, non-decreasing; index: (num_rows,) int64 in [0, n).
void CheckSamples(const py::array_t<std::int64_t, py::array::c_style>& bounds,
                  const py::array_t<std::int64_t, py::array::c_style>& index, py::ssize_t n) {
  const std::int64_t* b = bounds.data();
  const py::ssize_t v = bounds.shape(0) - 1, rows = index.shape(0);
  if (v < 0 || b[0] != 0 || b[v] != rows) {
    throw ShapeError("bounds: expected (views + 1,) offsets from 0 to " + std::to_string(rows) +
                     " (the samples), got " + DescribeShape(bounds));
  }
  for (py::ssize_t k = 0; k < v; ++k) {
    if (b[k + 1] < b[k]) throw BadValueError("bounds: expected non-decreasing offsets, got " + std::to_string(b[k]) +
                                             " then " + std::to_string(b[k + 1]));
  }
  const std::int64_t* ix = index.data();
  for (py::ssize_t i = 0; i < rows; ++i) {
    if (ix[i] < 0 || ix[i] >= n) {
      throw BadValueError("index: vertex " + std::to_string(ix[i]) + " out of range [0, " + std::to_string(n) + ")");
    }
  }
}

}  // namespace

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
      "Diffuse prediction of a view's pixels from other views (cpp/kernels/hybrid/harmonise.h): camera "
      "(_core.Camera), depth (H, W) float32 (<= 0: no surface); cameras: list of _core.Camera, depths: "
      "list of their (Hk, Wk) float32 depth, images: list of their (Hk, Wk, 3) float32 colours; returns "
      "(prediction (H, W, 3) float32, n_seen (H, W) int32).");
  m.def(
      "vertex_colour_sums",
      [](py::handle index_obj, py::handle color_obj, py::handle bounds_obj, py::handle gains_obj,
         py::ssize_t num_vertices, bool squares) {
        if (num_vertices < 0) throw BadValueError("num_vertices: expected >= 0, got " + std::to_string(num_vertices));
        auto index = CheckArray<std::int64_t>(index_obj, "index", {{"S", -1}});
        const py::ssize_t s = index.shape(0);
        auto color = CheckArray<double>(color_obj, "color", {{"3", 3}, {"S", s}});
        auto bounds = CheckArray<std::int64_t>(bounds_obj, "bounds", {{"V + 1", -1}});
        CheckSamples(bounds, index, num_vertices);
        const py::ssize_t v = bounds.shape(0) - 1;
        auto gains = CheckArray<double>(gains_obj, "gains", {{"V", v}, {"3", 3}});
        auto sum = NewArray<double>({num_vertices, 3});
        py::object sum2 = py::none();
        py::array_t<double, py::array::c_style> sq;
        if (squares) sq = NewArray<double>({num_vertices, 3});
        {
          py::gil_scoped_release release;
          VertexColourSums(index.data(), color.data(), s, bounds.data(), static_cast<int>(v), gains.data(),
                           num_vertices, sum.mutable_data(), squares ? sq.mutable_data() : nullptr);
        }
        if (squares) sum2 = sq;
        return py::make_tuple(sum, sum2);
      },
      py::arg("index"), py::arg("color"), py::arg("bounds"), py::arg("gains"), py::arg("num_vertices"),
      py::kw_only(), py::arg("squares") = false,
      "Per-vertex sums of gain-divided colour samples (cpp/kernels/hybrid/vertexstats.h): index (S,) int64 vertex per "
      "sample, color (3, S) float64, bounds (V + 1,) int64 (view v's samples at [bounds[v], bounds[v + 1])), "
      "gains (V, 3) float64; returns (sum (N, 3) float64, sum of squares (N, 3) or None), numpy bincount's bits.");
  m.def(
      "gain_median_ratios",
      [](py::handle index_obj, py::handle color_obj, py::handle bounds_obj, py::handle gains_obj, py::handle mean_obj) {
        auto index = CheckArray<std::int64_t>(index_obj, "index", {{"S", -1}});
        const py::ssize_t s = index.shape(0);
        auto color = CheckArray<double>(color_obj, "color", {{"S", s}, {"3", 3}});
        auto mean = CheckArray<double>(mean_obj, "mean", {{"N", -1}, {"3", 3}});
        auto bounds = CheckArray<std::int64_t>(bounds_obj, "bounds", {{"V + 1", -1}});
        CheckSamples(bounds, index, mean.shape(0));
        const py::ssize_t v = bounds.shape(0) - 1;
        auto gains = CheckArray<double>(gains_obj, "gains", {{"V", v}, {"3", 3}});
        auto median = NewArray<double>({v, 3});
        auto count = NewArray<std::int64_t>({v});
        {
          py::gil_scoped_release release;
          GainMedianRatios(index.data(), color.data(), bounds.data(), static_cast<int>(v), gains.data(), mean.data(),
                           median.mutable_data(), count.mutable_data());
        }
        return py::make_tuple(median, count);
      },
      py::arg("index"), py::arg("color"), py::arg("bounds"), py::arg("gains"), py::arg("mean"),
      "Per view, the per-channel median of color / gain / mean over its samples whose vertex mean is > 1e-3 in "
      "every channel (cpp/kernels/hybrid/vertexstats.h): index (S,) int64, color (S, 3) float64, bounds (V + 1,) int64, "
      "gains (V, 3) float64, mean (N, 3) float64; returns (median (V, 3) float64, 1 where no sample counts; "
      "count (V,) int64), numpy median's bits.");
}

}  // namespace ibr::bind
