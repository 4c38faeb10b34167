// Bindings of warping-based occlusion culling (cpp/kernels/depthwarp/culling.h) and soft shadows from
// light-sample shadow maps / traced occlusion rays (cpp/kernels/depthwarp/shadows.h); used by
// python/ibrtools/culling.py and python/ibrtools/shadows.py. Thin: array checks (array.h),
// value checks the kernels rely on, outputs allocated once as numpy arrays, GIL released.
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "array.h"
#include "ibr/embree_scene.h"
#include "ibr/errors.h"
#include "kernels/depthwarp/culling.h"
#include "kernels/depthwarp/shadows.h"
#include "module.h"

namespace ibr::bind {
namespace {

void RequirePinhole(const Camera& c, const char* name) {
  if (c.model != CameraModel::kPinhole) throw BadValueError(std::string(name) + ": expected a pinhole camera");
}

py::array_t<float> CullObjectBoxes(const py::object& vertices_obj, const py::object& faces_obj,
                                   const py::object& object_ids_obj, int num_objects) {
  auto vertices = CheckArray<float>(vertices_obj, "vertices", {{"N", -1}, {"3", 3}});
  auto faces = CheckArray<std::int32_t>(faces_obj, "faces", {{"M", -1}, {"3", 3}});
  auto ids = CheckArray<std::int32_t>(object_ids_obj, "object_ids", {{"M", faces.shape(0)}});
  if (num_objects < 0) throw BadValueError("num_objects: expected >= 0, got " + std::to_string(num_objects));
  const std::int64_t n = vertices.shape(0), m = faces.shape(0);
  const std::int32_t* f = faces.data();
  for (std::int64_t i = 0; i < m * 3; ++i) {
    if (f[i] < 0 || f[i] >= n) {
      throw BadValueError("faces: vertex index " + std::to_string(f[i]) + " out of range [0, " + std::to_string(n) +
                          ") in face " + std::to_string(i / 3));
    }
  }
  auto boxes = NewArray<float>({num_objects, 2, 3});
  float* out = boxes.mutable_data();
  const float* v = vertices.data();
  const std::int32_t* id = ids.data();
  {
    py::gil_scoped_release release;
    ObjectBoxes(v, f, m, id, num_objects, out);
  }
  return boxes;
}

py::tuple CullProjectBoxes(const py::object& boxes_obj, const Camera& camera, double near, int pad) {
  auto boxes = CheckArray<float>(boxes_obj, "boxes", {{"K", -1}, {"2", 2}, {"3", 3}});
  RequirePinhole(camera, "camera");
  if (!(near > 0.0) || !std::isfinite(near)) throw BadValueError("near: expected a finite number > 0");
  if (pad < 0) throw BadValueError("pad: expected an integer >= 0, got " + std::to_string(pad));
  const py::ssize_t k = boxes.shape(0);
  auto state = NewArray<std::uint8_t>({k});
  auto rect = NewArray<std::int32_t>({k, 4});
  auto min_z = NewArray<float>({k});
  CullOptions opt;
  opt.near = near;
  opt.pad = pad;
  const float* b = boxes.data();
  std::uint8_t* s = state.mutable_data();
  std::int32_t* r = rect.mutable_data();
  float* z = min_z.mutable_data();
  {
    py::gil_scoped_release release;
    ProjectBoxes(b, k, camera, opt, s, r, z);
  }
  return py::make_tuple(state, rect, min_z);
}

void CullAwocFill(const py::object& depth_obj, const py::object& hole_obj, const py::object& motion_obj,
                  const py::object& dst_depth_obj, int steps, const py::object& sky_obj,
                  const py::object& source_depth_obj) {
  auto depth = CheckArray<float>(depth_obj, "depth", {{"H'", -1}, {"W'", -1}}, true);
  auto hole = CheckArray<bool>(hole_obj, "hole", {{"H'", depth.shape(0)}, {"W'", depth.shape(1)}}, true);
  auto motion = CheckArray<float>(motion_obj, "motion", {{"H", -1}, {"W", -1}, {"2", 2}});
  auto dst = CheckArray<float>(dst_depth_obj, "dst_depth", {{"H", motion.shape(0)}, {"W", motion.shape(1)}});
  if (steps < 0 || steps > 16) throw BadValueError("steps: expected 0..16, got " + std::to_string(steps));
  if (Overlaps(depth, hole)) throw BadValueError("depth and hole: must not share memory");
  const int h = static_cast<int>(motion.shape(0)), w = static_cast<int>(motion.shape(1));
  if (h < 1 || w < 1) throw ShapeError("motion: expected a non-empty (H, W, 2) array");
  const double* sky = nullptr;
  const float* src = nullptr;
  py::array_t<double, py::array::c_style> sky_arr;
  py::array_t<float, py::array::c_style> src_arr;
  if (!sky_obj.is_none() || !source_depth_obj.is_none()) {
    if (sky_obj.is_none() || source_depth_obj.is_none()) {
      throw BadValueError("sky_from_target and source_depth: give both or neither");
    }
    sky_arr = CheckArray<double>(sky_obj, "sky_from_target", {{"3", 3}, {"3", 3}});
    src_arr = CheckArray<float>(source_depth_obj, "source_depth", {{"H", h}, {"W", w}});
    for (int i = 0; i < 9; ++i) {
      if (!std::isfinite(sky_arr.data()[i])) throw BadValueError("sky_from_target: contains NaN or infinity");
    }
    sky = sky_arr.data();
    src = src_arr.data();
  }
  std::vector<float> scratch(static_cast<std::size_t>(AwocScratchSize(h, w)));
  const float* m = motion.data();
  const float* d = dst.data();
  float* out = depth.mutable_data();
  auto* ho = reinterpret_cast<std::uint8_t*>(hole.mutable_data());  // numpy bool: one byte, 0 or 1
  const int oh = static_cast<int>(depth.shape(0)), ow = static_cast<int>(depth.shape(1));
  py::gil_scoped_release release;
  AwocFill(m, d, h, w, steps, sky, src, scratch.data(), out, ho, oh, ow);
}

py::array_t<float> ShadowMapVisibilityPy(const py::object& depth_obj, const Camera& view, const py::object& maps_obj,
                                         const std::vector<Camera>& cams, float bias, float slope_bias) {
  auto depth = CheckArray<float>(depth_obj, "view_depth", {{"H", view.height}, {"W", view.width}});
  if (cams.empty()) throw BadValueError("cameras: expected at least one shadow-map camera");
  auto maps = CheckArray<float>(maps_obj, "maps", {{"S", static_cast<py::ssize_t>(cams.size())}, {"Hs", -1}, {"Ws", -1}});
  for (std::size_t s = 0; s < cams.size(); ++s) {
    const std::string name = "cameras[" + std::to_string(s) + "]";
    RequirePinhole(cams[s], name.c_str());
    if (cams[s].height != maps.shape(1) || cams[s].width != maps.shape(2)) {
      throw ShapeError(name + ": size " + std::to_string(cams[s].width) + "x" + std::to_string(cams[s].height) +
                       " does not match maps (S, Hs, Ws) = " + DescribeShape(maps));
    }
  }
  if (!std::isfinite(bias) || bias < 0.0f) throw BadValueError("bias: expected a finite number >= 0");
  if (!std::isfinite(slope_bias) || slope_bias < 0.0f) throw BadValueError("slope_bias: expected a finite number >= 0");
  auto vis = NewArray<float>({view.height, view.width});
  const float* d = depth.data();
  const float* mp = maps.data();
  float* out = vis.mutable_data();
  {
    py::gil_scoped_release release;
    ShadowMapVisibility(d, view, mp, cams.data(), static_cast<int>(cams.size()), bias, slope_bias, out);
  }
  return vis;
}

// A mesh in an Embree BVH for occlusion rays only (no shading attributes).
class OcclusionScene {
 public:
  OcclusionScene(const py::object& vertices_obj, const py::object& faces_obj) {
    auto vertices = CheckArray<float>(vertices_obj, "vertices", {{"N", -1}, {"3", 3}});
    auto faces = CheckArray<std::int32_t>(faces_obj, "faces", {{"M", -1}, {"3", 3}});
    const float* v = vertices.data();
    const std::int32_t* f = faces.data();
    const std::int64_t n = vertices.shape(0), m = faces.shape(0);
    py::gil_scoped_release release;
    scene_ = EmbreeScene::Build(v, n, f, m, nullptr);
  }

  py::array_t<float> Visibility(const py::object& depth_obj, const Camera& view, const py::object& lights_obj,
                                float eps_rel) {
    auto depth = CheckArray<float>(depth_obj, "view_depth", {{"H", view.height}, {"W", view.width}});
    auto lights = CheckArray<double>(lights_obj, "light_positions", {{"S", -1}, {"3", 3}});
    const py::ssize_t s = lights.shape(0);
    if (s < 1) throw BadValueError("light_positions: expected at least one light sample");
    for (py::ssize_t i = 0; i < s * 3; ++i) {
      if (!std::isfinite(lights.data()[i])) throw BadValueError("light_positions: contain NaN or infinity");
    }
    if (!std::isfinite(eps_rel) || eps_rel < 0.0f) throw BadValueError("eps_rel: expected a finite number >= 0");
    auto vis = NewArray<float>({view.height, view.width});
    const float* d = depth.data();
    const double* l = lights.data();
    float* out = vis.mutable_data();
    {
      py::gil_scoped_release release;
      TracedVisibility(*scene_, d, view, l, static_cast<int>(s), eps_rel, out);
    }
    scene_->ThrowIfError("occlusion rays");
    return vis;
  }

  double BuildMs() const { return scene_->BuildMilliseconds(); }

 private:
  std::unique_ptr<EmbreeScene> scene_;
};

}  // namespace

void BindCulling(py::module_& m) {
  m.def("cull_object_boxes", &CullObjectBoxes, py::arg("vertices"), py::arg("faces"), py::arg("object_ids"),
        py::arg("num_objects"),
        "World AABB (K, 2, 3) float32 (min, max) of the faces of each object id in [0, K) (empty: +inf, -inf).");
  m.def("cull_project_boxes", &CullProjectBoxes, py::arg("boxes"), py::arg("camera"), py::arg("near"),
        py::arg("pad"),
        "Frustum test and screen rectangles of world boxes (K, 2, 3) for a pinhole _core.Camera: returns "
        "(state uint8 (K,) 0 outside / 1 crosses near / 2 on screen, rect int32 (K, 4) x0 y0 x1 y1, "
        "min_z float32 (K,)); cpp/kernels/depthwarp/culling.h.");
  m.def("cull_awoc_fill", &CullAwocFill, py::arg("depth"), py::arg("hole"), py::arg("motion"),
        py::arg("dst_depth"), py::arg("steps"), py::arg("sky_from_target") = py::none(),
        py::arg("source_depth") = py::none(),
        "AWOC: fill the holes of a warped depth (H', W') float32 / hole bool, in place, with the nearest "
        "moved depth of the source pixels at the corners of each hole's narrowed search bound "
        "(motion (H, W, 2), dst_depth (H, W) from depthwarp.motion_buffer); holes whose direction was empty in "
        "source_depth (via the 3x3 sky_from_target map) stay holes; cpp/kernels/depthwarp/culling.h.");
  m.def("shadow_map_visibility", &ShadowMapVisibilityPy, py::arg("view_depth"), py::arg("view"), py::arg("maps"),
        py::arg("cameras"), py::arg("bias"), py::arg("slope_bias"),
        "Fraction of the S shadow maps (S, Hs, Ws) in which each view pixel's surface point is lit "
        "(cpp/kernels/depthwarp/shadows.h); bias in shadow-map texels, slope_bias times the map's own depth slope.");
  py::class_<OcclusionScene>(m, "OcclusionScene", "A triangle mesh in an Embree BVH for occlusion rays.")
      .def(py::init<const py::object&, const py::object&>(), py::arg("vertices"), py::arg("faces"))
      .def("visibility", &OcclusionScene::Visibility, py::arg("view_depth"), py::arg("view"),
           py::arg("light_positions"), py::arg("eps_rel"),
           "Fraction of the light samples (S, 3) float64 each view pixel's surface point sees (occlusion rays).")
      .def_property_readonly("build_ms", &OcclusionScene::BuildMs);
}

}  // namespace ibr::bind
