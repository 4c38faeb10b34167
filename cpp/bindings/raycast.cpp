// Binding of the reference ray caster (cpp/ibr/embree_scene.h, cpp/kernels/raycast/raycast.h):
// _core.RayScene. Thin: checks arrays (array.h), allocates the outputs once as numpy arrays
// the kernel writes into (returned without a copy), releases the GIL around the kernel.
#include <memory>
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "array.h"
#include "ibr/embree_scene.h"
#include "ibr/errors.h"
#include "kernels/raycast/raycast.h"
#include "module.h"

namespace ibr::bind {
namespace {

const char* const kOutputNames[] = {"color", "depth", "distance", "normal", "object_id", "prim_id", "bary", "hit"};

std::string OutputList() {
  std::string s;
  for (const char* n : kOutputNames) s += std::string(s.empty() ? "" : ", ") + n;
  return s;
}

// The scene plus its shading attributes. Attribute arrays are referenced, not copied: they
// are checked once here and must not be resized (ibrtools.Mesh never does).
class RayScene {
 public:
  RayScene(const py::object& vertices_obj, const py::object& faces_obj, const py::object& object_ids_obj,
           const py::object& vertex_colors_obj, const py::object& uvs_obj, const py::object& texture_ids_obj,
           const py::list& textures_obj, const py::object& materials_obj, const std::string& quality,
           bool robust) {
    auto vertices = CheckArray<float>(vertices_obj, "vertices", {{"N", -1}, {"3", 3}});
    auto faces = CheckArray<std::int32_t>(faces_obj, "faces", {{"M", -1}, {"3", 3}});
    const py::ssize_t n = vertices.shape(0), m = faces.shape(0);
    const std::int32_t* object_ids = nullptr;
    if (!object_ids_obj.is_none()) {
      object_ids_ = CheckArray<std::int32_t>(object_ids_obj, "object_ids", {{"M", m}});
      object_ids = object_ids_.data();
    }
    EmbreeSceneOptions options;
    options.quality = BuildQualityFromName(quality);
    options.robust = robust;
    if (!vertex_colors_obj.is_none()) {
      vertex_colors_ = CheckArray<float>(vertex_colors_obj, "vertex_colors", {{"N", n}, {"3", 3}});
      surface_.vertex_colors = vertex_colors_.data();
    }
    if (!uvs_obj.is_none()) {
      uvs_ = CheckArray<float>(uvs_obj, "uvs", {{"M", m}, {"3", 3}, {"2", 2}});
      surface_.uvs = uvs_.data();
    }
    if (!texture_ids_obj.is_none()) {
      texture_ids_ = CheckArray<std::int32_t>(texture_ids_obj, "texture_ids", {{"M", m}});
      surface_.texture_ids = texture_ids_.data();
    }
    for (std::size_t i = 0; i < textures_obj.size(); ++i) {
      const std::string name = "textures[" + std::to_string(i) + "]";
      auto t = CheckArray<float>(textures_obj[i], name.c_str(), {{"H", -1}, {"W", -1}, {"3", 3}});
      texture_views_.push_back({t.data(), static_cast<int>(t.shape(0)), static_cast<int>(t.shape(1))});
      textures_.push_back(std::move(t));
    }
    surface_.textures = texture_views_.data();
    surface_.num_textures = static_cast<int>(texture_views_.size());
    if (!materials_obj.is_none()) {
      materials_ = CheckArray<float>(materials_obj, "materials", {{"K", -1}, {"2", 2}});
      surface_.materials = materials_.data();
      surface_.num_materials = static_cast<int>(materials_.shape(0));
    }
    CheckSurface(surface_, m);
    const float* v = vertices.data();
    const std::int32_t* f = faces.data();
    py::gil_scoped_release release;
    scene_ = EmbreeScene::Build(v, n, f, m, object_ids, options);
  }

  py::dict Render(const Camera& camera, const std::vector<std::string>& outputs, const py::list& lights_obj,
                  float ambient, const std::vector<float>& background, int packet) {
    if (background.size() != 3) throw ShapeError("background: expected 3 values (linear RGB)");
    RaycastOptions options;
    options.packet = packet;
    CheckRaycastOptions(options);
    std::vector<Light> lights;
    for (std::size_t i = 0; i < lights_obj.size(); ++i) {
      // (kind, vector, colour, shadows): ibrtools.raycast.reference.Light, flattened.
      const auto t = lights_obj[i].cast<py::tuple>();
      if (t.size() != 4) throw ShapeError("lights: expected (kind, vector, color, shadows) tuples");
      Light l;
      l.kind = LightKindFromName(t[0].cast<std::string>(), i);
      const auto vec = t[1].cast<std::vector<float>>();
      const auto col = t[2].cast<std::vector<float>>();
      if (vec.size() != 3 || col.size() != 3) throw ShapeError("lights: vector and color must have 3 values");
      for (int c = 0; c < 3; ++c) l.vector[c] = vec[c], l.color[c] = col[c];
      l.shadows = t[3].cast<bool>();
      lights.push_back(l);
    }
    ShadingOptions shading;
    shading.lights = lights.data();
    shading.num_lights = static_cast<int>(lights.size());
    shading.ambient = ambient;
    for (int c = 0; c < 3; ++c) shading.background[c] = background[c];
    CheckShading(shading);

    const py::ssize_t h = camera.height, w = camera.width;
    py::dict result;
    RaycastOutputs out;
    for (const std::string& name : outputs) {
      if (result.contains(name)) continue;
      if (name == "color") {
        auto a = NewArray<float>({h, w, 3}); out.color = a.mutable_data(); result[name.c_str()] = a;
      } else if (name == "depth") {
        auto a = NewArray<float>({h, w}); out.depth = a.mutable_data(); result[name.c_str()] = a;
      } else if (name == "distance") {
        auto a = NewArray<float>({h, w}); out.distance = a.mutable_data(); result[name.c_str()] = a;
      } else if (name == "normal") {
        auto a = NewArray<float>({h, w, 3}); out.normal = a.mutable_data(); result[name.c_str()] = a;
      } else if (name == "object_id") {
        auto a = NewArray<std::int32_t>({h, w}); out.object_id = a.mutable_data(); result[name.c_str()] = a;
      } else if (name == "prim_id") {
        auto a = NewArray<std::int32_t>({h, w}); out.prim_id = a.mutable_data(); result[name.c_str()] = a;
      } else if (name == "bary") {
        auto a = NewArray<float>({h, w, 2}); out.bary = a.mutable_data(); result[name.c_str()] = a;
      } else if (name == "hit") {
        auto a = NewArray<bool>({h, w});
        out.hit = reinterpret_cast<std::uint8_t*>(a.mutable_data());  // numpy bool: one byte, 0 or 1
        result[name.c_str()] = a;
      } else {
        throw BadValueError("outputs: unknown output '" + name + "'; expected any of " + OutputList());
      }
    }
    {
      py::gil_scoped_release release;
      RaycastCamera(*scene_, camera, surface_, shading, options, out);
    }
    scene_->ThrowIfError("ray queries");
    return result;
  }

  py::array_t<std::int32_t> VisibleObjectIds(const Camera& camera) {
    std::vector<std::int32_t> ids;
    {
      py::gil_scoped_release release;
      ids = VisibleObjects(*scene_, camera);
    }
    auto a = NewArray<std::int32_t>({static_cast<py::ssize_t>(ids.size())});
    std::copy(ids.begin(), ids.end(), a.mutable_data());
    return a;
  }

  // Deep depth buffer: (L, H, W) depth and object ids by depth peeling (kernels/raycast/raycast.h), with
  // generalised umbra culling for novel camera centres `umbra_positions` (K, 3) float64 in world
  // axes (each within `umbra_radius`); None = standard peeling.
  py::dict Peel(const Camera& camera, int layers, const py::object& positions_obj, double radius) {
    PeelOptions options;
    options.layers = layers;
    options.novel_radius = radius;
    std::vector<double> in_cam;
    if (!positions_obj.is_none()) {
      auto pos = CheckArray<double>(positions_obj, "umbra_positions", {{"K", -1}, {"3", 3}});
      const double* p = pos.data();
      for (py::ssize_t k = 0; k < pos.shape(0); ++k) {
        const glm::dvec3 q = camera.CamFromWorld(glm::dvec3(p[3 * k], p[3 * k + 1], p[3 * k + 2]));
        in_cam.insert(in_cam.end(), {q.x, q.y, q.z});
      }
      options.novel_in_cam = in_cam.data();
      options.num_novel = static_cast<int>(pos.shape(0));
    }
    CheckPeel(camera, options);
    const py::ssize_t h = camera.height, w = camera.width;
    auto depth = NewArray<float>({layers, h, w});
    auto ids = NewArray<std::int32_t>({layers, h, w});
    PeelOutputs out;
    out.depth = depth.mutable_data();
    out.object_id = ids.mutable_data();
    {
      py::gil_scoped_release release;
      PeelCamera(*scene_, camera, options, out);
    }
    scene_->ThrowIfError("ray queries");
    py::dict result;
    result["depth"] = depth;
    result["object_id"] = ids;
    return result;
  }

  const EmbreeScene& Scene() const { return *scene_; }

 private:
  std::unique_ptr<EmbreeScene> scene_;
  py::array_t<std::int32_t, py::array::c_style> object_ids_, texture_ids_;
  py::array_t<float, py::array::c_style> vertex_colors_, uvs_, materials_;
  std::vector<py::array_t<float, py::array::c_style>> textures_;
  std::vector<TextureView> texture_views_;
  SurfaceView surface_;
};

}  // namespace

void BindRaycast(py::module_& m) {
  m.attr("EMBREE_VERSION") = RTC_VERSION_STRING;
  py::class_<RayScene>(m, "RayScene",
                       "A triangle mesh in an Embree BVH (built once) with its shading attributes; "
                       "renders reference buffers and shaded colour for cameras (cpp/kernels/raycast/raycast.h).")
      .def(py::init<const py::object&, const py::object&, const py::object&, const py::object&, const py::object&,
                    const py::object&, const py::list&, const py::object&, const std::string&, bool>(),
           py::arg("vertices"), py::arg("faces"), py::arg("object_ids") = py::none(), py::kw_only(),
           py::arg("vertex_colors") = py::none(), py::arg("uvs") = py::none(), py::arg("texture_ids") = py::none(),
           py::arg("textures") = py::list(), py::arg("materials") = py::none(), py::arg("quality") = "high",
           py::arg("robust") = true,
           "vertices float32 (N, 3), faces int32 (M, 3), object_ids int32 (M,); shading: vertex_colors float32 "
           "(N, 3), uvs float32 (M, 3, 2) OBJ convention, texture_ids int32 (M,), textures list of float32 "
           "(H, W, 3) linear, materials float32 (K, 2) = (specular, shininess). quality: BVH build quality "
           "'low'|'medium'|'high'; robust: watertight intersection.")
      .def("render", &RayScene::Render, py::arg("camera"), py::arg("outputs"), py::arg("lights") = py::list(),
           py::arg("ambient") = 0.15f, py::arg("background") = std::vector<float>{0.f, 0.f, 0.f},
           py::arg("packet") = 16,
           "Render the named outputs (color, depth, distance, normal, object_id, prim_id, bary, hit) for a "
           "_core.Camera; lights: list of (kind 'point'|'directional', vector (3,), color (3,), shadows). "
           "packet: rays per Embree query (1 = scalar reference path, 8, 16). Returns {name: array}.")
      .def("peel", &RayScene::Peel, py::arg("camera"), py::arg("layers"), py::kw_only(),
           py::arg("umbra_positions") = py::none(), py::arg("umbra_radius") = 0.0,
           "Deep depth buffer by depth peeling: {'depth': float32 (L, H, W) z (0 = empty), 'object_id': "
           "int32 (L, H, W) (-1 = empty)}. umbra_positions float64 (K, 3) world centres of the novel cameras "
           "(generalised umbra culling, Eq. 1 of Lee et al. 2018), each within umbra_radius; None = plain peeling.")
      .def("visible_objects", &RayScene::VisibleObjectIds, py::arg("camera"),
           "Sorted unique object ids (int32) hit by any primary ray of the camera.")
      .def_property_readonly("num_vertices", [](const RayScene& s) { return s.Scene().NumVertices(); })
      .def_property_readonly("num_faces", [](const RayScene& s) { return s.Scene().NumFaces(); })
      .def_property_readonly("build_ms", [](const RayScene& s) { return s.Scene().BuildMilliseconds(); },
                             "BVH build time in milliseconds (checks and copies excluded).");
}

}  // namespace ibr::bind
