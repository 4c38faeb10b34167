// Bindings of cpp/kernels/solvers/maxflow.h and cpp/kernels/solvers/poisson.h: array checks (shapes,
// dtypes), the front's value checks (front.h: non-negative finite capacities, finite images, options)
// and the calls with the GIL released. Python: ibrtools.solvers.
#include <cmath>
#include <limits>
#include <string>
#include <type_traits>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "array.h"
#include "ibr/errors.h"
#include "kernels/solvers/front.h"
#include "kernels/solvers/maxflow.h"
#include "kernels/solvers/poisson.h"
#include "module.h"

namespace ibr::bind {

// int64 capacities arrive as `long long` (numpy's int64 on LP64 is equivalent to it): array.h
// names int32/uint32/uint8/float types only, and this keeps its list untouched.
template <> inline const char* DtypeName<long long>() { return "int64"; }

namespace {

template <typename Cap, typename KernelCap = Cap>
py::tuple GridMaxflowTyped(py::handle source_obj, py::handle sink_obj, py::handle right_obj, py::handle down_obj) {
  auto source = CheckArray<Cap>(source_obj, "source_cap", {{"H", -1}, {"W", -1}});
  const py::ssize_t h = source.shape(0), w = source.shape(1);
  auto sink = CheckArray<Cap>(sink_obj, "sink_cap", {{"H", h}, {"W", w}});
  auto right = CheckArray<Cap>(right_obj, "right", {{"H", h}, {"W", w}});
  auto down = CheckArray<Cap>(down_obj, "down", {{"H", h}, {"W", w}});
  if (h * w >= (py::ssize_t(1) << 31)) {
    throw ShapeError("source_cap: at most 2^31 - 1 pixels, got shape " + DescribeShape(source));
  }
  auto sink_side = NewArray<bool>({h, w});
  Cap flow = 0;
  std::string bad;
  {
    py::gil_scoped_release release;
    const Cap* const arrays[4] = {source.data(), sink.data(), right.data(), down.data()};
    bad = MaxflowCheckCapacities<Cap>(arrays, std::int64_t(h) * w);
    if (bad.empty()) {
      static_assert(sizeof(Cap) == sizeof(KernelCap), "same representation");
      flow = static_cast<Cap>(GridMaxflowKernel<KernelCap>(
          static_cast<int>(h), static_cast<int>(w), reinterpret_cast<const KernelCap*>(source.data()),
          reinterpret_cast<const KernelCap*>(sink.data()), reinterpret_cast<const KernelCap*>(right.data()),
          reinterpret_cast<const KernelCap*>(down.data()), reinterpret_cast<std::uint8_t*>(sink_side.mutable_data())));
    }
  }
  if (!bad.empty()) throw BadValueError(bad);
  return py::make_tuple(flow, sink_side);
}

}  // namespace

void BindSolvers(py::module_& m) {
  m.def(
      "grid_maxflow",
      [](py::handle source_cap, py::handle sink_cap, py::handle right, py::handle down) {
        if (py::isinstance<py::array>(source_cap) &&
            py::reinterpret_borrow<py::array>(source_cap).dtype().equal(py::dtype::of<long long>())) {
          return GridMaxflowTyped<long long, std::int64_t>(source_cap, sink_cap, right, down);
        }
        return GridMaxflowTyped<double>(source_cap, sink_cap, right, down);
      },
      py::arg("source_cap"), py::arg("sink_cap"), py::arg("right"), py::arg("down"),
      "Boykov-Kolmogorov max-flow on a 4-connected grid (cpp/kernels/solvers/maxflow.h). All four arrays (H, W), "
      "int64 (exact) or float64, >= 0. Returns (flow, sink_side bool (H, W)).");

  m.def(
      "poisson_blend",
      [](py::handle boundary_obj, py::handle source_obj, py::handle mask_obj, double tol, int max_iter,
         int smooth_sweeps, double coarse_scale) {
        const bool has_c = py::isinstance<py::array>(boundary_obj) &&
                           py::reinterpret_borrow<py::array>(boundary_obj).ndim() == 3;
        auto boundary = has_c ? CheckArray<float>(boundary_obj, "boundary", {{"H", -1}, {"W", -1}, {"C", -1}})
                              : CheckArray<float>(boundary_obj, "boundary", {{"H", -1}, {"W", -1}});
        const py::ssize_t h = boundary.shape(0), w = boundary.shape(1), c = has_c ? boundary.shape(2) : 1;
        if (h < 1 || w < 1 || c < 1) {
          throw ShapeError("boundary: expected at least 1 pixel and 1 channel, got shape " + DescribeShape(boundary));
        }
        auto source = has_c ? CheckArray<float>(source_obj, "source", {{"H", h}, {"W", w}, {"C", c}})
                            : CheckArray<float>(source_obj, "source", {{"H", h}, {"W", w}});
        auto mask = CheckArray<bool>(mask_obj, "mask", {{"H", h}, {"W", w}});
        PoissonOptions options;
        options.tol = tol;
        options.max_iter = max_iter;
        options.smooth_sweeps = smooth_sweeps;
        options.coarse_scale = coarse_scale;
        PoissonCheckOptions(options);
        const ImageView<const float> bview(boundary.data(), int(h), int(w), int(c));
        const ImageView<const float> sview(source.data(), int(h), int(w), int(c));
        const ImageView<const std::uint8_t> mview(reinterpret_cast<const std::uint8_t*>(mask.data()), int(h), int(w),
                                                  1);
        auto out = has_c ? NewArray<float>({h, w, c}) : NewArray<float>({h, w});
        const ImageView<float> oview(out.mutable_data(), int(h), int(w), int(c));
        PoissonStats stats;
        std::string bad;
        {
          py::gil_scoped_release release;
          bad = PoissonCheckInputs(bview, sview, mview);
          if (bad.empty()) stats = PoissonBlendKernel(bview, sview, mview, options, oview);
        }
        if (!bad.empty()) throw BadValueError(bad);
        py::dict info;
        info["iterations"] = stats.iterations;
        info["relative_residual"] = stats.relative_residual;
        info["converged"] = stats.converged;
        info["unknowns"] = stats.unknowns;
        return py::make_tuple(out, info);
      },
      py::arg("boundary"), py::arg("source"), py::arg("mask"), py::arg("tol") = 1e-6, py::arg("max_iter") = 200,
      py::arg("smooth_sweeps") = 1, py::arg("coarse_scale") = 1.8,
      "Perez et al. 2003 seamless cloning by multigrid-preconditioned CG (cpp/kernels/solvers/poisson.h). boundary, "
      "source float32 (H, W) or (H, W, C); mask bool (H, W). Returns (out, info).");
}

}  // namespace ibr::bind
