// Bindings of the multi-view stereo family (cpp/kernels/mvs/mvs.h): convert, call, return.
// Python: ibrtools.mvs.
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "array.h"
#include "ibr/errors.h"
#include "kernels/mvs/mvs.h"
#include "module.h"

namespace ibr::bind {
namespace {

using FloatArray = py::array_t<float, py::array::c_style>;
using mvs::PatchMatchOptions;

// The sources as the kernel sees them; `keep` holds the checked arrays alive.
std::vector<mvs::SourceView> Sources(const py::list& greys, const py::list& cameras, const py::object& depths,
                                     std::vector<FloatArray>* keep) {
  if (greys.size() != cameras.size()) {
    throw ShapeError("sources: " + std::to_string(greys.size()) + " grey images for " +
                     std::to_string(cameras.size()) + " cameras");
  }
  const bool with_depth = !depths.is_none();
  py::list dl = with_depth ? py::list(depths) : py::list();
  if (with_depth && dl.size() != greys.size()) {
    throw ShapeError("source_depths: expected one depth map per source view");
  }
  std::vector<mvs::SourceView> out;
  for (std::size_t i = 0; i < greys.size(); ++i) {
    const std::string name = "source_greys[" + std::to_string(i) + "]";
    keep->push_back(CheckArray<float>(greys[i], name.c_str(), {{"H", -1}, {"W", -1}}));
    mvs::SourceView s;
    s.grey = ConstViewOf(keep->back());
    s.camera = cameras[i].cast<Camera>();
    if (with_depth && !dl[i].is_none()) {
      const std::string dn = "source_depths[" + std::to_string(i) + "]";
      keep->push_back(CheckArray<float>(dl[i], dn.c_str(), {{"H", s.grey.height}, {"W", s.grey.width}}));
      s.depth = ConstViewOf(keep->back());
    }
    out.push_back(s);
  }
  return out;
}

}  // namespace

void BindMvs(py::module_& m) {
  py::class_<PatchMatchOptions>(m, "PatchMatchOptions",
                                "Options of PatchMatch stereo (cpp/kernels/mvs/patchmatch.h); the defaults are "
                                "ibrtools.mvs.MvsOptions'.")
      .def(py::init<>())
      .def_readwrite("window_radius", &PatchMatchOptions::window_radius)
      .def_readwrite("window_step", &PatchMatchOptions::window_step)
      .def_readwrite("sigma_color", &PatchMatchOptions::sigma_color)
      .def_readwrite("sigma_spatial", &PatchMatchOptions::sigma_spatial)
      .def_readwrite("iterations", &PatchMatchOptions::iterations)
      .def_readwrite("first_iteration", &PatchMatchOptions::first_iteration)
      .def_readwrite("refine_only", &PatchMatchOptions::refine_only)
      .def_readwrite("best_k", &PatchMatchOptions::best_k)
      .def_readwrite("min_depth", &PatchMatchOptions::min_depth)
      .def_readwrite("max_depth", &PatchMatchOptions::max_depth)
      .def_readwrite("seed", &PatchMatchOptions::seed)
      .def_readwrite("min_variance", &PatchMatchOptions::min_variance)
      .def_readwrite("geom_weight", &PatchMatchOptions::geom_weight)
      .def_readwrite("geom_max_error", &PatchMatchOptions::geom_max_error)
      .def("check", [](const PatchMatchOptions& o) { mvs::CheckOptions(o); },
           "Raise BadValueError naming the first option out of its bounds.");
  m.attr("MVS_MAX_WINDOW_RADIUS") = mvs::kMaxWindowRadius;
  m.attr("MVS_MAX_ITERATIONS") = mvs::kMaxIterations;
  m.attr("MVS_MAX_SOURCE_VIEWS") = mvs::kMaxSourceViews;

  m.def(
      "mvs_patchmatch",
      [](py::handle ref_obj, const Camera& ref_cam, py::list greys, py::list cameras, py::object depths,
         const PatchMatchOptions& options, py::object init_depth, py::object init_normal) {
        FloatArray ref = CheckArray<float>(ref_obj, "ref_grey", {{"H", -1}, {"W", -1}});
        const py::ssize_t h = ref.shape(0), w = ref.shape(1);
        std::vector<FloatArray> keep;
        const std::vector<mvs::SourceView> sources = Sources(greys, cameras, depths, &keep);
        FloatArray depth = NewArray<float>({h, w}), cost = NewArray<float>({h, w});
        FloatArray normal = NewArray<float>({h, w, 3});
        const bool initialised = !init_depth.is_none();
        if (initialised) {
          FloatArray d0 = CheckArray<float>(init_depth, "init_depth", {{"H", h}, {"W", w}});
          FloatArray n0 = CheckArray<float>(init_normal, "init_normal", {{"H", h}, {"W", w}, {"3", 3}});
          std::copy(d0.data(), d0.data() + h * w, depth.mutable_data());
          std::copy(n0.data(), n0.data() + h * w * 3, normal.mutable_data());
        }
        mvs::PatchMatchStats stats;
        {
          py::gil_scoped_release release;
          stats = mvs::RunPatchMatch(ConstViewOf(ref), ref_cam, sources, options, initialised, ViewOf(depth),
                                     ViewOf(normal), ViewOf(cost));
        }
        py::dict st;
        st["evaluations"] = stats.evaluations;
        st["textureless"] = stats.textureless;
        return py::make_tuple(depth, normal, cost, st);
      },
      py::arg("ref_grey"), py::arg("ref_camera"), py::arg("source_greys"), py::arg("source_cameras"),
      py::arg("source_depths"), py::arg("options"), py::arg("init_depth") = py::none(),
      py::arg("init_normal") = py::none(),
      "PatchMatch stereo of one reference view (cpp/kernels/mvs/patchmatch.h): grey float32 (H, W) images in "
      "[0, 1], pinhole _core.Camera objects, source depth maps (or None; needed when options.geom_weight > 0), "
      "optional starting hypotheses. Returns (depth (H, W), normal (H, W, 3), cost (H, W), stats dict).");

  m.def(
      "mvs_consistent_views",
      [](py::handle depth_obj, const Camera& ref_cam, py::list depths, py::list cameras, float max_error_px,
         float max_rel_depth, float min_angle_deg) {
        FloatArray depth = CheckArray<float>(depth_obj, "ref_depth", {{"H", -1}, {"W", -1}});
        if (depths.size() != cameras.size()) throw ShapeError("source_depths: one per source camera");
        std::vector<FloatArray> keep;
        std::vector<mvs::SourceView> sources;
        for (std::size_t i = 0; i < depths.size(); ++i) {
          const std::string name = "source_depths[" + std::to_string(i) + "]";
          keep.push_back(CheckArray<float>(depths[i], name.c_str(), {{"H", -1}, {"W", -1}}));
          mvs::SourceView s;
          s.depth = ConstViewOf(keep.back());
          s.camera = cameras[i].cast<Camera>();
          sources.push_back(s);
        }
        FloatArray count = NewArray<float>({depth.shape(0), depth.shape(1)});
        {
          py::gil_scoped_release release;
          mvs::RunConsistentViews(ConstViewOf(depth), ref_cam, sources, max_error_px, max_rel_depth, min_angle_deg,
                                  ViewOf(count));
        }
        return count;
      },
      py::arg("ref_depth"), py::arg("ref_camera"), py::arg("source_depths"), py::arg("source_cameras"),
      py::arg("max_error_px"), py::arg("max_rel_depth"), py::arg("min_angle_deg"),
      "Per pixel, the number of sources whose depth agrees with ref_depth by forward-backward reprojection "
      "(cpp/kernels/mvs/patchmatch.h ConsistentViews). float32 (H, W).");
}

}  // namespace ibr::bind
