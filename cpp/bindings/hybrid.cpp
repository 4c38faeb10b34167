// The hybrid family's bindings: per-view meshes and tiles (cpp/kernels/hybrid/pvm.h), TM / ULR /
// hybrid rendering (hybrid.h, ulr.h, gbuffer_raster.h, atlas8.h), the PVM renderer (pvm_render.h)
// and the texture stage's harmonisation (harmonise.h, vertexstats.h). Python: ibrtools.hybrid,
// ibrtools.hybrid.method.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "array.h"
#include "ibr/camera.h"
#include "ibr/checks.h"
#include "ibr/errors.h"
#include "kernels/hybrid/atlas8.h"
#include "kernels/hybrid/front.h"
#include "kernels/hybrid/gbuffer_raster.h"
#include "kernels/hybrid/harmonise.h"
#include "kernels/hybrid/hybrid.h"
#include "kernels/hybrid/pvm.h"
#include "kernels/hybrid/pvm_render.h"
#include "kernels/hybrid/ulr.h"
#include "kernels/hybrid/vertexstats.h"
#include "module.h"

// Binding of the hybrid-IBR preprocessing kernels (cpp/kernels/hybrid/pvm.h): _core.pvm_triangulate
// (one view's depth map -> triangles over its pixel grid) and _core.pvm_slice (per-view meshes
// -> tiles of a two-level voxel grid). Thin: checks arrays (array.h) and values, releases the
// GIL around the kernels, hands the kernels' buffers to numpy without copying.
// Python: ibrtools.hybrid.pvm.
namespace ibr::bind {
namespace {

// A numpy array owning `v` (moved into a capsule: no copy).
template <typename T>
py::array_t<T> Own(std::vector<T>&& v, std::vector<py::ssize_t> shape) {
  auto* heap = new std::vector<T>(std::move(v));
  py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<T>*>(p); });
  return py::array_t<T>(shape, heap->data(), owner);
}

}  // namespace

static void BindPvmMeshes(py::module_& m) {
  m.def(
      "pvm_triangulate",
      [](py::handle depth_obj, py::handle field_obj, float max_rel_jump, float plane_tol, int max_block) {
        auto depth = CheckArray<float>(depth_obj, "depth", {{"H", -1}, {"W", -1}});
        const py::ssize_t h = depth.shape(0), w = depth.shape(1);
        if (h < 2 || w < 2) {
          throw ShapeError("depth: expected at least 2 x 2 pixels to form triangles, got " + DescribeShape(depth));
        }
        if (h * w > (py::ssize_t(1) << 31) - 1) throw ShapeError("depth: more than 2^31 pixels");
        py::array_t<float, py::array::c_style> field;
        const float* field_ptr = nullptr;
        if (!field_obj.is_none()) {
          field = CheckArray<float>(field_obj, "plane_field", {{"H", h}, {"W", w}});
          field_ptr = field.data();
        }
        if (!(max_rel_jump > 0.f) || !std::isfinite(max_rel_jump)) {
          throw BadValueError("max_rel_jump: expected a finite number > 0, got " + std::to_string(max_rel_jump));
        }
        if (!(plane_tol >= 0.f) || !std::isfinite(plane_tol)) {
          throw BadValueError("plane_tol: expected a finite number >= 0, got " + std::to_string(plane_tol));
        }
        if (max_block < 1 || max_block > 256 || (max_block & (max_block - 1)) != 0) {
          throw BadValueError("max_block: expected a power of two in [1, 256], got " + std::to_string(max_block));
        }
        PvmTriangulateOptions opt;
        opt.max_rel_jump = max_rel_jump;
        opt.plane_tol = plane_tol;
        opt.max_block = max_block;
        std::vector<std::int32_t> faces;
        {
          py::gil_scoped_release release;
          PvmTriangulate(depth.data(), field_ptr, static_cast<int>(h), static_cast<int>(w), opt, faces);
        }
        const py::ssize_t n = static_cast<py::ssize_t>(faces.size() / 3);
        return Own(std::move(faces), {n, 3});
      },
      py::arg("depth"), py::arg("plane_field"), py::arg("max_rel_jump") = 0.03f, py::arg("plane_tol") = 1e-3f,
      py::arg("max_block") = 16,
      "Triangles over the pixel grid of depth float32 (H, W) (cpp/kernels/hybrid/pvm.h PvmTriangulate): int32 (F, 3) "
      "vertex ids y * W + x (pixel centres), counter-clockwise seen from the camera; edges cut where the relative "
      "depth jump exceeds max_rel_jump; blocks of up to max_block quads merged where plane_field (float32 (H, W), "
      "1/z for pinhole; None = no merging) is planar within plane_tol.");

  m.def(
      "pvm_slice",
      [](py::handle vertices_obj, py::handle faces_obj, py::handle view_obj, int n_views,
         std::vector<double> origin, std::vector<double> cell, int coarse, int sub, bool clip_all) {
        auto vertices = CheckArray<float>(vertices_obj, "vertices", {{"N", -1}, {"3", 3}});
        auto faces = CheckArray<std::int32_t>(faces_obj, "faces", {{"M", -1}, {"3", 3}});
        const py::ssize_t nv = vertices.shape(0), nf = faces.shape(0);
        auto face_view = CheckArray<std::int32_t>(view_obj, "face_view", {{"M", nf}});
        if (n_views < 1) throw BadValueError("n_views: expected >= 1, got " + std::to_string(n_views));
        if (origin.size() != 3 || cell.size() != 3) throw ShapeError("origin, cell: expected 3 numbers each");
        for (int a = 0; a < 3; ++a) {
          if (!std::isfinite(origin[a])) throw BadValueError("origin: expected finite numbers");
          if (!(cell[a] > 0) || !std::isfinite(cell[a])) {
            throw BadValueError("cell: expected finite sizes > 0 (empty bounds?), got " + std::to_string(cell[a]));
          }
        }
        if (coarse < 1 || sub < 1 || coarse * sub > 4096) {
          throw BadValueError("coarse, sub: expected >= 1 with coarse * sub <= 4096, got " + std::to_string(coarse) +
                              ", " + std::to_string(sub));
        }
        const double n_keys = std::pow(double(coarse) * sub, 3) * n_views;
        if (n_keys > 4e18) throw BadValueError("pvm_slice: too many tiles for a 64-bit key");
        if (nf > (py::ssize_t(1) << 31) - 1 || nv > (py::ssize_t(1) << 31) - 1) {
          throw ShapeError("pvm_slice: more than 2^31 faces or vertices");
        }
        if (FindNonFinite(vertices.data(), std::int64_t(nv) * 3) >= 0) {
          throw BadValueError("vertices: contain NaN or infinity");
        }
        const std::int32_t* f = faces.data();
        if (const std::int64_t i = FindOutOfRange(f, 3 * std::int64_t(nf), 0, nv); i >= 0) {
          throw BadValueError("faces: vertex index " + std::to_string(f[i]) + " out of range [0, " +
                              std::to_string(nv) + ")");
        }
        const std::int32_t* fvw = face_view.data();
        if (const std::int64_t i = FindOutOfRange(fvw, std::int64_t(nf), 0, n_views); i >= 0) {
          throw BadValueError("face_view: view " + std::to_string(fvw[i]) + " out of range [0, " +
                              std::to_string(n_views) + ")");
        }
        PvmGrid grid{{origin[0], origin[1], origin[2]}, {cell[0], cell[1], cell[2]}, coarse, sub};
        PvmTiles t;
        {
          py::gil_scoped_release release;
          PvmSlice(vertices.data(), nv, faces.data(), face_view.data(), nf, n_views, grid, clip_all, t);
        }
        const py::ssize_t n_tiles = static_cast<py::ssize_t>(t.keys.size());
        const py::ssize_t v_out = static_cast<py::ssize_t>(t.vertices.size() / 3);
        const py::ssize_t f_out = static_cast<py::ssize_t>(t.faces.size() / 3);
        py::dict d;
        d["vertices"] = Own(std::move(t.vertices), {v_out, 3});
        d["faces"] = Own(std::move(t.faces), {f_out, 3});
        d["face_source"] = Own(std::move(t.face_source), {f_out});
        d["keys"] = Own(std::move(t.keys), {n_tiles});
        d["face_offsets"] = Own(std::move(t.face_offsets), {static_cast<py::ssize_t>(n_tiles + 1)});
        d["vertex_offsets"] = Own(std::move(t.vertex_offsets), {static_cast<py::ssize_t>(n_tiles + 1)});
        d["bounds"] = Own(std::move(t.bounds), {n_tiles, 2, 3});
        return d;
      },
      py::arg("vertices"), py::arg("faces"), py::arg("face_view"), py::arg("n_views"), py::arg("origin"),
      py::arg("cell"), py::arg("coarse") = 32, py::arg("sub") = 4, py::arg("clip_all") = false,
      "Sort triangles (vertices float32 (N, 3), faces int32 (M, 3), face_view int32 (M,)) into the fine cells of a "
      "two-level grid (cpp/kernels/hybrid/pvm.h PvmSlice): whole, in the cell of their centroid, or, reaching beyond the "
      "coarse cells next to it, a copy in every cell they have area in; clip_all: every triangle crossing a cell "
      "face clipped into pieces. Returns a dict: vertices (V, 3), faces (F, 3) (indices into vertices), "
      "face_source (F,), keys (T,) ascending, face_offsets / vertex_offsets (T + 1,), bounds (T, 2, 3).");
}

}  // namespace ibr::bind

// Binding of the hybrid rendering kernels (cpp/kernels/hybrid/hybrid.h, cpp/kernels/hybrid/ulr.h):
// _core.interpolate_vertex_attribute (TM colour / view-dependent texture from the G-buffer),
// _core.sample_atlas (TM colour from the texture atlas at the G-buffer's hits),
// _core.ulr_penalty / _core.ulr_select (the shared ULR ranking, for tests and Python callers),
// _core.ulr_blend (per-pixel ULR), _core.hybrid_select, _core.blur_selection,
// _core.hybrid_composite. Thin: checks arrays (array.h) and values, allocates the outputs,
// releases the GIL around the kernels.
namespace ibr::bind {
namespace {

using FArray = py::array_t<float, py::array::c_style>;

void CheckLabels(const py::array_t<std::uint8_t, py::array::c_style>& label) {
  if (FindOutOfRange(label.data(), label.size(), 0, kLabelNone + 1) >= 0) {
    throw BadValueError("label: values must be 0 (TM), 1 (ULR), 2 (PVM) or 3 (none)");
  }
}

const std::uint8_t* BoolData(const py::array_t<bool, py::array::c_style>& a) {
  return reinterpret_cast<const std::uint8_t*>(a.data());
}

float CheckFinite(double v, const char* name, double lo) {
  if (!std::isfinite(v) || v < lo) {
    throw BadValueError(std::string(name) + ": expected a finite number >= " + std::to_string(lo) + ", got " +
                        std::to_string(v));
  }
  return static_cast<float>(v);
}

// The G-buffer hits a per-pixel read indexes: prim ids in [-1, m) (-1 = no hit) and, at the hits,
// finite barycentrics (a non-finite one would make the interpolated position undefined).
void CheckHits(const py::array_t<std::int32_t, py::array::c_style>& prim,
               const py::array_t<float, py::array::c_style>& bary, py::ssize_t m) {
  const auto w = prim.shape(1);
  const std::int32_t* p = prim.data();
  const float* ba = bary.data();
  if (const std::int64_t i = HybridFindBadHit(p, ba, prim.size(), m); i >= 0) {
    if (p[i] < -1 || p[i] >= m) {
      throw BadValueError("prim_id: " + std::to_string(p[i]) + " is not a face index in [-1, " + std::to_string(m) +
                          ")");
    }
    if (p[i] >= 0 && !(std::isfinite(ba[2 * i]) && std::isfinite(ba[2 * i + 1]))) {
      throw BadValueError("bary: expected finite barycentrics where prim_id >= 0, got (" + std::to_string(ba[2 * i]) +
                          ", " + std::to_string(ba[2 * i + 1]) + ") at pixel (" + std::to_string(i / w) + ", " +
                          std::to_string(i % w) + ")");
    }
  }
}

FArray InterpolateVertexAttributeBinding(const py::object& prim_obj, const py::object& bary_obj,
                                         const py::object& faces_obj, const py::object& attrib_obj) {
  auto prim = CheckArray<std::int32_t>(prim_obj, "prim_id", {{"H", -1}, {"W", -1}});
  const auto h = prim.shape(0), w = prim.shape(1);
  auto bary = CheckArray<float>(bary_obj, "bary", {{"H", h}, {"W", w}, {"2", 2}});
  auto faces = CheckArray<std::int32_t>(faces_obj, "faces", {{"M", -1}, {"3", 3}});
  py::array a = py::reinterpret_borrow<py::array>(attrib_obj);
  const bool one_channel = py::isinstance<py::array>(attrib_obj) && a.ndim() == 1;
  auto attrib = one_channel ? CheckArray<float>(attrib_obj, "attrib", {{"N", -1}})
                            : CheckArray<float>(attrib_obj, "attrib", {{"N", -1}, {"C", -1}});
  const auto n = attrib.shape(0);
  const int channels = one_channel ? 1 : static_cast<int>(attrib.shape(1));
  if (channels < 1) throw ShapeError("attrib: expected at least one channel, got 0");
  CheckHits(prim, bary, faces.shape(0));
  FArray out = one_channel ? NewArray<float>({h, w}) : NewArray<float>({h, w, channels});
  std::int64_t bad = -1;  // a hit face with a vertex index out of range (not read; faces no pixel hits are not read)
  {
    py::gil_scoped_release release;
    bad = InterpolateVertexAttribute(prim.data(), bary.data(), static_cast<std::int64_t>(h) * w, faces.data(),
                                     attrib.data(), n, channels, out.mutable_data());
  }
  if (bad >= 0) {
    const std::int32_t* fv = faces.data() + 3 * static_cast<py::ssize_t>(prim.data()[bad]);
    throw BadValueError("faces: face " + std::to_string(prim.data()[bad]) + " (hit at pixel (" +
                        std::to_string(bad / w) + ", " + std::to_string(bad % w) + ")) has vertex indices (" +
                        std::to_string(fv[0]) + ", " + std::to_string(fv[1]) + ", " + std::to_string(fv[2]) +
                        "), expected each in [0, " + std::to_string(n) + ")");
  }
  return out;
}

FArray SampleAtlasBinding(const py::object& prim_obj, const py::object& bary_obj, const py::object& uv_obj,
                          const py::object& atlas_obj) {
  auto prim = CheckArray<std::int32_t>(prim_obj, "prim_id", {{"H", -1}, {"W", -1}});
  const auto h = prim.shape(0), w = prim.shape(1);
  auto bary = CheckArray<float>(bary_obj, "bary", {{"H", h}, {"W", w}, {"2", 2}});
  auto uv = CheckArray<float>(uv_obj, "uv", {{"M", -1}, {"3", 3}, {"2", 2}});
  // float32 (h, w, 3) linear RGB, or uint8 (h, w, 4) sRGB RGBA (kernels/hybrid/atlas8.h).
  const bool srgb8 = py::isinstance<py::array>(atlas_obj) &&
                     py::reinterpret_borrow<py::array>(atlas_obj).dtype().is(py::dtype::of<std::uint8_t>());
  py::array_t<float, py::array::c_style> atlas;
  py::array_t<std::uint8_t, py::array::c_style> atlas8;
  if (srgb8) {
    atlas8 = CheckArray<std::uint8_t>(atlas_obj, "atlas", {{"h", -1}, {"w", -1}, {"4", 4}});
  } else {
    atlas = CheckArray<float>(atlas_obj, "atlas", {{"h", -1}, {"w", -1}, {"3", 3}});
  }
  const auto ah = srgb8 ? atlas8.shape(0) : atlas.shape(0), aw = srgb8 ? atlas8.shape(1) : atlas.shape(1);
  if (ah < 1 || aw < 1) {
    throw ShapeError("atlas: expected at least 1 x 1 texels, got " + std::to_string(ah) + " x " + std::to_string(aw));
  }
  CheckHits(prim, bary, uv.shape(0));
  FArray out = NewArray<float>({h, w, py::ssize_t(3)});
  std::int64_t bad = -1;  // a hit whose face uv are not finite (the kernel reads no texel there)
  {
    py::gil_scoped_release release;
    if (srgb8) {
      bad = SampleAtlasSrgb8(prim.data(), bary.data(), static_cast<std::int64_t>(h) * w, uv.data(),
                             ConstViewOf(atlas8), out.mutable_data());
    } else {
      bad = SampleAtlas(prim.data(), bary.data(), static_cast<std::int64_t>(h) * w, uv.data(), ConstViewOf(atlas),
                        out.mutable_data());
    }
  }
  if (bad >= 0) {
    throw BadValueError("uv: expected finite coordinates, face " + std::to_string(prim.data()[bad]) +
                        " (hit at pixel (" + std::to_string(bad / w) + ", " + std::to_string(bad % w) +
                        ")) has a non-finite one");
  }
  return out;
}

// The input views of ULR and of the texture bake: each (camera, colour (h, w, 3), depth (h, w)) with
// (h, w) the camera's size; the checked arrays are appended to `keep` (the views point into them).
std::vector<UlrInputView> InputViews(const py::list& views_obj, std::vector<FArray>& keep) {
  std::vector<UlrInputView> views;
  for (std::size_t i = 0; i < views_obj.size(); ++i) {
    const std::string nm = "views[" + std::to_string(i) + "]";
    py::handle item = views_obj[i];
    if (!py::isinstance<py::tuple>(item) || py::len(item) != 3) throw DtypeError(nm + ": expected a (camera, color, depth) tuple");
    py::tuple t = py::reinterpret_borrow<py::tuple>(item);
    if (!py::isinstance<Camera>(t[0])) throw DtypeError(nm + "[0]: expected a _core.Camera");
    UlrInputView v;
    v.camera = t[0].cast<Camera>();
    if (v.camera.width < 1 || v.camera.height < 1) throw ShapeError(nm + ": expected a camera of at least 1 x 1 pixels");
    const std::string cn = nm + ".color", dn = nm + ".depth";
    auto c = CheckArray<float>(t[1], cn.c_str(), {{"h", v.camera.height}, {"w", v.camera.width}, {"3", 3}});
    auto d = CheckArray<float>(t[2], dn.c_str(), {{"h", v.camera.height}, {"w", v.camera.width}});
    v.color = ConstViewOf(c);
    v.depth = ConstViewOf(d);
    keep.push_back(c);
    keep.push_back(d);
    views.push_back(v);
  }
  return views;
}

// _core.point_colors (kernels/hybrid/atlas8.h PointColors): the texture bake's ULR-weighted colour at points.
py::tuple PointColorsBinding(const py::object& points_obj, const py::object& normals_obj, const py::list& views_obj,
                             int k, double depth_tol) {
  if (k < 1) throw BadValueError("k: expected >= 1 views per point, got " + std::to_string(k));
  PointColorOptions opt;
  opt.k = k;
  opt.depth_tol = CheckFinite(depth_tol, "depth_tol", 0.0);
  auto points = CheckArray<double>(points_obj, "points", {{"N", -1}, {"3", 3}});
  const auto n = points.shape(0);
  auto normals = CheckArray<double>(normals_obj, "normals", {{"N", n}, {"3", 3}});
  if (views_obj.size() == 0) throw BadValueError("views: expected at least one (camera, color, depth)");
  std::vector<FArray> keep;
  const std::vector<UlrInputView> views = InputViews(views_obj, keep);
  FArray color = NewArray<float>({n, py::ssize_t(3)});
  auto seen = py::array_t<std::int32_t, py::array::c_style>(std::vector<py::ssize_t>{n});
  {
    py::gil_scoped_release release;
    PointColors(points.data(), normals.data(), static_cast<std::int64_t>(n), views.data(),
                static_cast<int>(views.size()), opt, color.mutable_data(), seen.mutable_data());
  }
  return py::make_tuple(color, seen);
}

// _core.texel_points (kernels/hybrid/atlas8.h TexelPoints): the used texels of a band of atlas rows,
// their barycentrics, surface points and unit normals.
py::tuple TexelPointsBinding(const py::object& fot_obj, int row0, const py::object& uv_obj,
                             const py::object& vertices_obj, const py::object& faces_obj,
                             const py::object& normals_obj) {
  auto fot = CheckArray<std::int32_t>(fot_obj, "face_of_texel", {{"rows", -1}, {"W", -1}});
  auto faces = CheckArray<std::int32_t>(faces_obj, "faces", {{"M", -1}, {"3", 3}});
  const py::ssize_t m = faces.shape(0);
  auto uv = CheckArray<float>(uv_obj, "uv", {{"M", m}, {"3", 3}, {"2", 2}});
  auto vertices = CheckArray<float>(vertices_obj, "vertices", {{"N", -1}, {"3", 3}});
  const py::ssize_t nv = vertices.shape(0);
  auto normals = CheckArray<float>(normals_obj, "normals", {{"N", nv}, {"3", 3}});
  if (row0 < 0) throw BadValueError("row0: expected >= 0, got " + std::to_string(row0));
  const py::ssize_t rows = fot.shape(0), width = fot.shape(1);
  const std::int32_t* fo = fot.data();
  if (const std::int64_t i = FindOutOfRange(fo, std::int64_t(rows) * width, -1, m); i >= 0) {
    throw BadValueError("face_of_texel: face " + std::to_string(fo[i]) + " out of range [-1, " + std::to_string(m) +
                        ")");
  }
  const std::int32_t* f = faces.data();
  if (const std::int64_t i = FindOutOfRange(f, 3 * std::int64_t(m), 0, nv); i >= 0) {
    throw BadValueError("faces: vertex " + std::to_string(f[i]) + " out of range [0, " + std::to_string(nv) + ")");
  }
  std::vector<std::int64_t> row_start(static_cast<std::size_t>(rows) + 1);
  TexelRowStarts(fo, static_cast<int>(rows), static_cast<int>(width), row_start.data());
  const py::ssize_t t = row_start.back();
  auto ys = NewArray<std::int64_t>({t});
  auto xs = NewArray<std::int64_t>({t});
  auto face = NewArray<std::int32_t>({t});
  auto bary = NewArray<double>({t, py::ssize_t(3)});
  auto pts = NewArray<double>({t, py::ssize_t(3)});
  auto nrm = NewArray<double>({t, py::ssize_t(3)});
  {
    py::gil_scoped_release release;
    TexelPoints(fo, row_start.data(), static_cast<int>(rows), static_cast<int>(width), row0, uv.data(),
                vertices.data(), faces.data(), normals.data(), ys.mutable_data(), xs.mutable_data(),
                face.mutable_data(), bary.mutable_data(), pts.mutable_data(), nrm.mutable_data());
  }
  return py::make_tuple(ys, xs, face, bary, pts, nrm);
}

py::dict RasterGBufferBinding(const Camera& camera, const py::object& vertices_obj, const py::object& faces_obj,
                              bool normal) {
  if (camera.model != CameraModel::kPinhole) {
    throw BadValueError("raster_gbuffer: pinhole cameras only (use the ray caster for equirect)");
  }
  if (camera.width < 1 || camera.height < 1) throw BadValueError("raster_gbuffer: the camera has no pixels");
  auto vertices = CheckArray<float>(vertices_obj, "vertices", {{"N", -1}, {"3", 3}});
  auto faces = CheckArray<std::int32_t>(faces_obj, "faces", {{"M", -1}, {"3", 3}});
  const auto n = vertices.shape(0), m = faces.shape(0);
  {
    if (FindNonFinite(vertices.data(), 3 * std::int64_t(n)) >= 0) {
      throw BadValueError("vertices: expected finite coordinates");
    }
    const std::int32_t* f = faces.data();
    if (const std::int64_t i = FindOutOfRange(f, 3 * std::int64_t(m), 0, n); i >= 0) {
      throw BadValueError("faces: index " + std::to_string(f[i]) + " out of range for " + std::to_string(n) +
                          " vertices");
    }
  }
  const py::ssize_t h = camera.height, w = camera.width;
  FArray depth = NewArray<float>({h, w});
  auto prim = NewArray<std::int32_t>({h, w});
  FArray bary = NewArray<float>({h, w, py::ssize_t(2)});
  FArray nrm = normal ? NewArray<float>({h, w, py::ssize_t(3)}) : FArray();
  {
    py::gil_scoped_release release;
    RasterGBuffer(camera, vertices.data(), n, faces.data(), m, depth.mutable_data(), prim.mutable_data(),
                  bary.mutable_data(), normal ? nrm.mutable_data() : nullptr);
  }
  py::dict out;
  out["depth"] = depth;
  out["prim_id"] = prim;
  out["bary"] = bary;
  if (normal) out["normal"] = nrm;
  return out;
}

py::tuple UlrBlendBinding(const Camera& novel, const py::object& depth_obj, const py::list& views_obj,
                          const py::object& normal_obj, const py::object& mask_obj, int k, double resolution_weight,
                          double depth_tol, const std::string& resample, bool reference, const std::string& simd) {
  UlrOptions opt;
  opt.k = k;
  opt.resolution_weight = static_cast<float>(resolution_weight);
  opt.depth_tol = static_cast<float>(depth_tol);
  opt.Check();
  opt.reference = reference;
  opt.cubic = ParseResample(resample);
  if (simd == "sse2") {
    opt.simd = UlrSimd::kSse2;
  } else if (simd == "avx2") {
    opt.simd = UlrSimd::kAvx2;
  } else if (simd != "auto") {
    throw BadValueError("simd: expected 'auto', 'avx2' or 'sse2', got '" + simd + "'");
  }
  auto depth = CheckArray<float>(depth_obj, "gbuffer_depth", {{"H", novel.height}, {"W", novel.width}});
  const auto h = depth.shape(0), w = depth.shape(1);
  FArray normal;
  if (!normal_obj.is_none()) normal = CheckArray<float>(normal_obj, "normal", {{"H", h}, {"W", w}, {"3", 3}});
  py::array_t<bool, py::array::c_style> mask;
  if (!mask_obj.is_none()) mask = CheckArray<bool>(mask_obj, "pixel_mask", {{"H", h}, {"W", w}});
  std::vector<FArray> keep;
  const std::vector<UlrInputView> views = InputViews(views_obj, keep);
  FArray color = NewArray<float>({h, w, 3});
  auto count = py::array_t<std::uint8_t, py::array::c_style>(std::vector<py::ssize_t>{h, w});
  {
    py::gil_scoped_release release;
    UlrBlend(novel, ConstViewOf(depth), normal_obj.is_none() ? ImageView<const float>() : ConstViewOf(normal),
             mask_obj.is_none() ? nullptr : BoolData(mask), views.data(), static_cast<int>(views.size()), opt,
             ViewOf(color), ViewOf(count));
  }
  return py::make_tuple(color, count);
}

py::array_t<std::uint8_t> HybridSelectBinding(const py::object& depth_obj, const py::object& inside_obj,
                                              const py::object& valid_obj, const py::object& pvm_depth_obj,
                                              const py::object& vd_obj, double geo_threshold, double tau_var) {
  auto depth = CheckArray<float>(depth_obj, "gbuffer_depth", {{"H", -1}, {"W", -1}});
  const auto h = depth.shape(0), w = depth.shape(1);
  HybridSelectOptions opt;
  opt.geo_threshold = CheckFinite(geo_threshold, "geo_threshold", 0.0);
  if (!std::isfinite(tau_var)) throw BadValueError("tau_var: expected a finite number, got " + std::to_string(tau_var));
  opt.tau_var = static_cast<float>(tau_var);
  py::array_t<bool, py::array::c_style> inside, valid;
  FArray pvm_depth, vd;
  if (!inside_obj.is_none()) inside = CheckArray<bool>(inside_obj, "inside_grid", {{"H", h}, {"W", w}});
  if (valid_obj.is_none() != pvm_depth_obj.is_none()) {
    throw BadValueError("pvm_valid and pvm_depth: give both or neither");
  }
  if (!valid_obj.is_none()) {
    valid = CheckArray<bool>(valid_obj, "pvm_valid", {{"H", h}, {"W", w}});
    pvm_depth = CheckArray<float>(pvm_depth_obj, "pvm_depth", {{"H", h}, {"W", w}});
  }
  if (!vd_obj.is_none()) vd = CheckArray<float>(vd_obj, "vd", {{"H", h}, {"W", w}});
  auto label = py::array_t<std::uint8_t, py::array::c_style>(std::vector<py::ssize_t>{h, w});
  {
    py::gil_scoped_release release;
    HybridSelect(ConstViewOf(depth), inside_obj.is_none() ? nullptr : BoolData(inside),
                 valid_obj.is_none() ? nullptr : BoolData(valid), valid_obj.is_none() ? nullptr : pvm_depth.data(),
                 vd_obj.is_none() ? nullptr : vd.data(), opt, ViewOf(label));
  }
  return label;
}

FArray BlurSelectionBinding(const py::object& label_obj, double sigma, double min_weight, bool decimate,
                            double pvm_floor) {
  auto label = CheckArray<std::uint8_t>(label_obj, "label", {{"H", -1}, {"W", -1}});
  const float s = CheckFinite(sigma, "sigma_blur", 0.0);
  if (s > 1000.f) throw BadValueError("sigma_blur: expected <= 1000 pixels, got " + std::to_string(sigma));
  const float mw = CheckFinite(min_weight, "min_weight", 0.0);
  if (!(min_weight <= 1.0 / 3.0))
    throw BadValueError("min_weight: expected a weight in [0, 1/3], got " + std::to_string(min_weight));
  const float floor = CheckFinite(pvm_floor, "pvm_floor", 0.0);
  if (!(pvm_floor <= 1.0)) throw BadValueError("pvm_floor: expected a weight in [0, 1], got " + std::to_string(pvm_floor));
  const auto h = label.shape(0), w = label.shape(1);
  CheckLabels(label);
  FArray out = NewArray<float>({h, w, 3});
  // The full-resolution blur's planes (written before read); the decimated one needs none.
  std::unique_ptr<float[]> scratch;
  if (!decimate || BlurSelectionFactor(s) == 1) scratch.reset(new float[static_cast<std::size_t>(h) * w * 3]);
  {
    py::gil_scoped_release release;
    BlurSelection(ConstViewOf(label), s, mw, scratch.get(), ViewOf(out), decimate);
    FloorPvmWeight(ViewOf(out), floor);
  }
  return out;
}

FArray HybridCompositeBinding(const py::object& weights_obj, const py::object& tm_obj, const py::object& ulr_obj,
                              const py::object& ulr_count_obj, const py::object& pvm_obj, const py::object& valid_obj) {
  auto weights = CheckArray<float>(weights_obj, "weights", {{"H", -1}, {"W", -1}, {"3", 3}});
  const auto h = weights.shape(0), w = weights.shape(1);
  auto tm = CheckArray<float>(tm_obj, "tm", {{"H", h}, {"W", w}, {"3", 3}});
  if (ulr_obj.is_none() != ulr_count_obj.is_none()) throw BadValueError("ulr and ulr_count: give both or neither");
  if (pvm_obj.is_none() != valid_obj.is_none()) throw BadValueError("pvm and pvm_valid: give both or neither");
  FArray ulr, pvm;
  py::array_t<std::uint8_t, py::array::c_style> count;
  py::array_t<bool, py::array::c_style> valid;
  if (!ulr_obj.is_none()) {
    ulr = CheckArray<float>(ulr_obj, "ulr", {{"H", h}, {"W", w}, {"3", 3}});
    count = CheckArray<std::uint8_t>(ulr_count_obj, "ulr_count", {{"H", h}, {"W", w}});
  }
  if (!pvm_obj.is_none()) {
    pvm = CheckArray<float>(pvm_obj, "pvm", {{"H", h}, {"W", w}, {"3", 3}});
    valid = CheckArray<bool>(valid_obj, "pvm_valid", {{"H", h}, {"W", w}});
  }
  FArray out = NewArray<float>({h, w, 3});
  {
    py::gil_scoped_release release;
    HybridComposite(ConstViewOf(weights), ConstViewOf(tm), ulr_obj.is_none() ? nullptr : ulr.data(),
                    ulr_obj.is_none() ? nullptr : count.data(), pvm_obj.is_none() ? nullptr : pvm.data(),
                    pvm_obj.is_none() ? nullptr : BoolData(valid), ViewOf(out));
  }
  return out;
}

py::tuple HybridNeedsBinding(const py::object& weights_obj, const py::object& valid_obj) {
  auto weights = CheckArray<float>(weights_obj, "weights", {{"H", -1}, {"W", -1}, {"3", 3}});
  const auto h = weights.shape(0), w = weights.shape(1);
  auto valid = CheckArray<bool>(valid_obj, "pvm_valid", {{"H", h}, {"W", w}});
  auto need_ulr = NewArray<bool>({h, w});
  auto need_pvm = NewArray<bool>({h, w});
  std::int64_t counts[2] = {0, 0};
  {
    py::gil_scoped_release release;
    HybridNeeds(ConstViewOf(weights), BoolData(valid), reinterpret_cast<std::uint8_t*>(need_ulr.mutable_data()),
                reinterpret_cast<std::uint8_t*>(need_pvm.mutable_data()), counts);
  }
  return py::make_tuple(need_ulr, need_pvm, counts[0], counts[1]);
}

py::dict HybridFrameOutputsBinding(const py::object& label_obj, const py::object& weights_obj,
                                   const py::object& gdepth_obj, const py::object& pvm_depth_obj) {
  auto label = CheckArray<std::uint8_t>(label_obj, "label", {{"H", -1}, {"W", -1}});
  const auto h = label.shape(0), w = label.shape(1);
  CheckLabels(label);
  auto weights = CheckArray<float>(weights_obj, "weights", {{"H", h}, {"W", w}, {"3", 3}});
  auto gdepth = CheckArray<float>(gdepth_obj, "gbuffer_depth", {{"H", h}, {"W", w}});
  auto pdepth = CheckArray<float>(pvm_depth_obj, "pvm_depth", {{"H", h}, {"W", w}});
  auto hole = NewArray<bool>({h, w});
  FArray depth = NewArray<float>({h, w});
  FArray selection = NewArray<float>({h, w, 3});
  std::int64_t counts[4] = {0, 0, 0, 0};
  {
    py::gil_scoped_release release;
    HybridFrameOutputs(ConstViewOf(label), ConstViewOf(weights), gdepth.data(), pdepth.data(),
                       reinterpret_cast<std::uint8_t*>(hole.mutable_data()), depth.mutable_data(),
                       selection.mutable_data(), counts);
  }
  py::dict out;
  out["hole"] = hole;
  out["depth"] = depth;
  out["selection"] = selection;
  out["label_counts"] = py::make_tuple(counts[0], counts[1], counts[2], counts[3]);
  return out;
}

}  // namespace

static void BindHybridRender(py::module_& m) {
  m.def("interpolate_vertex_attribute", &InterpolateVertexAttributeBinding, py::arg("prim_id"), py::arg("bary"),
        py::arg("faces"), py::arg("attrib"),
        "Per-vertex attribute (N,) or (N, C) float32 interpolated at each pixel's hit (prim_id (H, W) int32, "
        "-1 = none; bary (H, W, 2) Embree (u, v)): (H, W) or (H, W, C), 0 where nothing is hit.");
  m.def("raster_gbuffer", &RasterGBufferBinding, py::arg("camera"), py::arg("vertices"), py::arg("faces"),
        py::kw_only(), py::arg("normal") = true,
        "G-buffer of a triangle mesh by rasterisation (pinhole cameras): the nearest face at each pixel centre, "
        "as the Embree ray caster gives it. vertices (N, 3) float32 world, faces (M, 3) int32. Returns a dict: depth "
        "(H, W) float32 z (0 = no hit), prim_id (H, W) int32 (-1), bary (H, W, 2) float32 Embree (u, v), and with "
        "normal=True the unit geometric normal (H, W, 3) in world axes facing the camera.");
  m.def("sample_atlas", &SampleAtlasBinding, py::arg("prim_id"), py::arg("bary"), py::arg("uv"), py::arg("atlas"),
        "TM colour from a texture atlas: atlas (h, w, 3) float32 linear RGB, or (h, w, 4) uint8 sRGB RGBA (decoded to "
        "linear per texel, alpha unused), read bilinearly (edge-clamped) at each pixel's hit "
        "(prim_id (H, W) int32, -1 = none; bary (H, W, 2) Embree (u, v)) at the face's uv (M, 3, 2) float32 in atlas "
        "pixels (x right, y down, centres at +0.5): (H, W, 3), 0 where nothing is hit. The hits' barycentrics and "
        "their faces' uv must be finite.");
  m.def("texel_points", &TexelPointsBinding, py::arg("face_of_texel"), py::arg("row0"), py::arg("uv"),
        py::arg("vertices"), py::arg("faces"), py::arg("normals"),
        "The used texels of atlas rows row0.. (face_of_texel (rows, W) int32, -1 = unused; kernels/hybrid/atlas8.h "
        "TexelPoints), row-major: (ys (T,) int64 absolute rows, xs (T,) int64, face (T,) int32, bary (T, 3) float64 "
        "of the texel centre in the face's chart uv (M, 3, 2), clamped to the face; points (T, 3) float64 on the "
        "mesh (vertices (N, 3) float32, faces (M, 3) int32), unit normals (T, 3) float64 of normals (N, 3) float32).");
  m.def("point_colors", &PointColorsBinding, py::arg("points"), py::arg("normals"), py::arg("views"), py::kw_only(),
        py::arg("k") = 4, py::arg("depth_tol") = 0.02,
        "ULR-weighted colour of the views at surface points (the texture bake; kernels/hybrid/atlas8.h PointColors): "
        "points, normals (N, 3) float64 (unit normals), views = [(camera, color (h, w, 3), depth (h, w)), ...] -> "
        "(color (N, 3) float32, 0 where no view sees the point; seen (N,) int32 views that see it).");
  m.def(
      "ulr_penalty",
      [](const std::vector<float>& p, const std::vector<float>& c_novel, const std::vector<float>& c_view,
         double resolution_weight, bool fast) {
        if (p.size() != 3 || c_novel.size() != 3 || c_view.size() != 3) {
          throw ShapeError("ulr_penalty: p, c_novel and c_view must have 3 coordinates each");
        }
        const glm::vec3 pp(p[0], p[1], p[2]), cn(c_novel[0], c_novel[1], c_novel[2]);
        const glm::vec3 cv(c_view[0], c_view[1], c_view[2]);
        if (fast) return UlrPenaltyFast(pp, cn - pp, glm::length(cn - pp), cv, static_cast<float>(resolution_weight));
        return UlrPenalty(pp, cn, cv, static_cast<float>(resolution_weight));
      },
      py::arg("p"), py::arg("c_novel"), py::arg("c_view"),
      py::arg("resolution_weight") = UlrOptions::kDefaultResolutionWeight, py::arg("fast") = false,
      "ULR penalty (cpp/kernels/hybrid/ulr.h): angle + resolution_weight * max(0, |c_view-p|/|c_novel-p| - 1); "
      "fast=True: the per-pixel kernel's version (polynomial atan2, within 2e-5).");
  m.def(
      "ulr_select",
      [](const py::object& pen_obj, int k) {
        auto pen = CheckArray<float>(pen_obj, "penalty", {{"n", -1}});
        if (k < 1 || k > UlrOptions::kMaxK) {
          throw BadValueError("k: expected 1 .. " + std::to_string(UlrOptions::kMaxK) + ", got " + std::to_string(k));
        }
        std::vector<int> idx(k);
        std::vector<float> wt(k);
        const int mm = UlrSelect(pen.data(), static_cast<int>(pen.shape(0)), k, idx.data(), wt.data());
        idx.resize(mm);
        wt.resize(mm);
        return py::make_tuple(idx, wt);
      },
      py::arg("penalty"), py::arg("k"),
      "The k smallest finite penalties (cpp/kernels/hybrid/ulr.h UlrSelect): (indices, weights summing to 1).");
  m.attr("ULR_MAX_K") = UlrOptions::kMaxK;
  m.attr("ULR_DEFAULT_K") = UlrOptions::kDefaultK;
  m.attr("ULR_DEFAULT_RESOLUTION_WEIGHT") = UlrOptions::kDefaultResolutionWeight;
  m.attr("ULR_DEFAULT_DEPTH_TOL") = UlrOptions::kDefaultDepthTol;
  m.def("ulr_blend", &UlrBlendBinding, py::arg("camera"), py::arg("gbuffer_depth"), py::arg("views"), py::kw_only(),
        py::arg("normal") = py::none(), py::arg("pixel_mask") = py::none(), py::arg("k") = UlrOptions::kDefaultK,
        py::arg("resolution_weight") = UlrOptions::kDefaultResolutionWeight,
        py::arg("depth_tol") = UlrOptions::kDefaultDepthTol, py::arg("resample") = "cubic",
        py::arg("reference") = false, py::arg("simd") = "auto",
        "Per-pixel ULR at the G-buffer's points: views = [(camera, color, depth), ...] -> (color (H, W, 3), "
        "count (H, W) uint8 views used, 0 = none sees the point). resample: the views' colour reads, 'cubic' "
        "(Catmull-Rom, clamped to the 2 x 2 texels' range) or 'bilinear'. reference=True: the scalar reference path "
        "(double projections) instead of the fast one (float, SIMD over views; pinhole views only). "
        "simd='auto' follows set_warp_isa (AVX-512 / AVX2 where the CPU has them, SSE2 under 'baseline'); "
        "'avx2' / 'sse2': the fast path at most AVX2 / in SSE2 even where the CPU has more (the same bits; for tests).");
  m.def("hybrid_select", &HybridSelectBinding, py::arg("gbuffer_depth"), py::kw_only(),
        py::arg("inside_grid") = py::none(), py::arg("pvm_valid") = py::none(), py::arg("pvm_depth") = py::none(),
        py::arg("vd") = py::none(), py::arg("geo_threshold") = 0.03, py::arg("tau_var") = 0.82,
        "Per-pixel method (Prakash et al. 2021 Fig. 7): uint8 (H, W) 0 TM, 1 ULR, 2 PVM, 3 nothing to render. "
        "Defaults: the paper's values; --method hybrid passes its own (hybrid/method.py HYBRID_DEFAULTS: tau_var 0).");
  m.def("blur_selection", &BlurSelectionBinding, py::arg("label"), py::arg("sigma_blur"), py::arg("min_weight") = 0.0,
        py::arg("decimate") = false, py::arg("pvm_floor") = 0.0,
        "Gaussian-blurred one-hot selection weights (H, W, 3) = (TM, ULR, PVM), normalised to sum 1; "
        "weights below min_weight (<= 1/3) set to 0 and the rest normalised again. decimate: for sigma_blur >= 8, "
        "blur at 1/f resolution (f = min(4, sigma_blur // 4)) on block means and read back bilinearly "
        "(the same Gaussian to ~1e-3). AVX2 loops as set_warp_isa allows (the same bits). pvm_floor (in [0, 1]): "
        "last, where the weights sum to > 0 and PVM's is below it, PVM's becomes pvm_floor and TM's and ULR's are "
        "scaled by (1 - pvm_floor) / (1 - pvm) (0: no change).");
  m.def("hybrid_composite", &HybridCompositeBinding, py::arg("weights"), py::arg("tm"), py::kw_only(),
        py::arg("ulr") = py::none(), py::arg("ulr_count") = py::none(), py::arg("pvm") = py::none(),
        py::arg("pvm_valid") = py::none(),
        "Composite of TM, ULR and PVM colours by the selection weights, with fallbacks (PVM -> ULR -> TM).");
  m.def("hybrid_needs", &HybridNeedsBinding, py::arg("weights"), py::arg("pvm_valid"),
        "Where the composite needs colours: (need_ulr, need_pvm, n_ulr, n_pvm). need_pvm = PVM weight > 0 and "
        "pvm_valid; need_ulr = ULR weight > 0, or PVM weight > 0 where the PVM is not valid.");
  m.def("hybrid_frame_outputs", &HybridFrameOutputsBinding, py::arg("label"), py::arg("weights"),
        py::arg("gbuffer_depth"), py::arg("pvm_depth"),
        "The hybrid frame's hole (label none, no weight), depth (PVM's where the label is PVM, else the G-buffer's), "
        "selection image (red PVM, green TM, blue ULR weights) and label_counts (tm, ulr, pvm, none).");
}

}  // namespace ibr::bind

// Binding of the PVM renderer (cpp/kernels/hybrid/front.h PvmRenderer, the five stages of
// pvm_render.h): _core.PvmRenderer checks the arrays of tiles.npz and the input views' images once and
// keeps them alive for the front, which checks their values and owns the per-frame buffers;
// render() converts the arguments to PvmRendererOptions (defaults and Check() in the front), calls
// the front with the GIL released and returns the outputs and per-stage times.
// Python: ibrtools.hybrid.pvm_render.
namespace ibr::bind {
namespace {

using F32 = py::array_t<float, py::array::c_style>;
using I32 = py::array_t<std::int32_t, py::array::c_style>;
using I64 = py::array_t<std::int64_t, py::array::c_style>;

// array.h has no int64 dtype name: the 1-D int64 offset arrays are checked here.
I64 CheckOffsets(py::handle obj, const char* name, py::ssize_t n) {
  if (!py::isinstance<py::array>(obj)) {
    throw DtypeError(std::string(name) + ": expected a numpy int64 array of shape (" + std::to_string(n) + ",)");
  }
  py::array a = py::reinterpret_borrow<py::array>(obj);
  if (!a.dtype().equal(py::dtype::of<std::int64_t>())) {
    throw DtypeError(std::string(name) + ": expected int64 array of shape (" + std::to_string(n) + ",), got " +
                     std::string(py::str(a.dtype())) + " " + DescribeShape(a));
  }
  if (a.ndim() != 1 || a.shape(0) != n || !(a.flags() & py::array::c_style)) {
    throw ShapeError(std::string(name) + ": expected a contiguous int64 array of shape (" + std::to_string(n) +
                     ",), got " + DescribeShape(a));
  }
  return py::reinterpret_borrow<I64>(a);
}

// _core.PvmRenderer: the numpy arrays the front borrows (kept alive here) and the front's renderer.
class PvmRendererBinding {
 public:
  PvmRendererBinding(py::handle vertices, py::handle faces, py::handle face_offsets, py::handle vertex_offsets,
                     py::handle tile_view, py::handle tile_cell, py::handle tile_bounds, py::handle coarse_offsets,
                     std::vector<double> origin, std::vector<double> cell, int coarse, int sub,
                     std::vector<Camera> cameras, py::list images, py::handle enabled, py::handle depths) {
    vertices_ = CheckArray<float>(vertices, "vertices", {{"V", -1}, {"3", 3}});
    faces_ = CheckArray<std::int32_t>(faces, "faces", {{"F", -1}, {"3", 3}});
    tile_view_ = CheckArray<std::int32_t>(tile_view, "tile_view", {{"T", -1}});
    const py::ssize_t nt = tile_view_.shape(0);
    face_offsets_ = CheckOffsets(face_offsets, "face_offsets", nt + 1);
    tile_cell_ = CheckArray<std::int32_t>(tile_cell, "tile_cell", {{"T", nt}, {"3", 3}});
    vertex_offsets_ = CheckOffsets(vertex_offsets, "vertex_offsets", nt + 1);
    tile_bounds_ = CheckArray<float>(tile_bounds, "tile_bounds", {{"T", nt}, {"2", 2}, {"3", 3}});
    PvmCheckGridSize(coarse, sub);
    const py::ssize_t nc = static_cast<py::ssize_t>(coarse) * coarse * coarse;
    coarse_offsets_ = CheckOffsets(coarse_offsets, "coarse_offsets", nc + 1);
    if (origin.size() != 3 || cell.size() != 3) throw ShapeError("origin, cell: expected 3 numbers each");
    PvmCheckGridGeometry(origin.data(), cell.data());
    const int nv = static_cast<int>(cameras.size());
    PvmCheckNumViews(nv);
    if (static_cast<int>(py::len(images)) != nv) {
      throw ShapeError("images: expected one image per camera (" + std::to_string(nv) + "), got " +
                       std::to_string(py::len(images)));
    }
    std::vector<const float*> image_ptrs, depth_ptrs;
    for (int v = 0; v < nv; ++v) {
      const std::string name = "images[" + std::to_string(v) + "]";
      images_.push_back(CheckArray<float>(images[static_cast<std::size_t>(v)], name.c_str(),
                                          {{"H_v", cameras[v].height}, {"W_v", cameras[v].width}, {"3", 3}}));
      image_ptrs.push_back(images_.back().data());
    }
    if (!depths.is_none()) {  // the free-space count's depth maps (pvm_render.h, stage 4)
      if (!py::isinstance<py::list>(depths) || static_cast<int>(py::len(depths)) != nv) {
        throw ShapeError("depths: expected None or a list of one depth map per camera (" + std::to_string(nv) + ")");
      }
      const py::list depth_list = py::reinterpret_borrow<py::list>(depths);
      for (int v = 0; v < nv; ++v) {
        const std::string name = "depths[" + std::to_string(v) + "]";
        depths_.push_back(CheckArray<float>(depth_list[static_cast<std::size_t>(v)], name.c_str(),
                                            {{"H_v", cameras[v].height}, {"W_v", cameras[v].width}}));
        depth_ptrs.push_back(depths_.back().data());
      }
    }
    auto en = CheckArray<bool>(enabled, "enabled", {{"views", nv}});
    std::vector<std::uint8_t> enabled_bytes(en.data(), en.data() + nv);
    PvmTileInputs t;
    t.vertices = vertices_.data();
    t.num_vertices = vertices_.shape(0);
    t.faces = faces_.data();
    t.num_faces = faces_.shape(0);
    t.face_offsets = face_offsets_.data();
    t.vertex_offsets = vertex_offsets_.data();
    t.tile_view = tile_view_.data();
    t.tile_cell = tile_cell_.data();
    t.tile_bounds = tile_bounds_.data();
    t.num_tiles = nt;
    t.coarse_offsets = coarse_offsets_.data();
    for (int a = 0; a < 3; ++a) t.origin[a] = origin[a], t.cell[a] = cell[a];
    t.coarse = coarse;
    t.sub = sub;
    py::gil_scoped_release release;
    renderer_ = std::make_unique<PvmRenderer>(t, std::move(cameras), std::move(image_ptrs), std::move(depth_ptrs),
                                              std::move(enabled_bytes));
  }

  py::dict Render(const Camera& camera, py::handle gbuffer_obj, py::handle mask_obj, bool filtered, float sigma,
                  float alpha, float gamma, float tau_depth, int max_tiles, int max_candidates, int ulr_k,
                  float merge_rel, float radius_sigmas, int margin, float near, bool cull_back, float max_angle_deg,
                  int ray_stride, int filter_step, bool free_space, float free_space_tol, float free_space_point_tol,
                  float tau_empty, int min_views, float stretch_weight, float stretch_free, const std::string& resample,
                  const std::string& mode) {
    const bool depth_only = mode == "depth", resolve = mode == "resolve";
    if (!depth_only && !resolve && mode != "full") {
      throw BadValueError("mode: expected full, depth or resolve, got " + mode);
    }
    if (camera.model != CameraModel::kPinhole) {
      throw BadValueError("camera: PVM rendering takes a pinhole target camera (equirect targets are not built)");
    }
    const py::ssize_t h = camera.height, w = camera.width;
    if (resolve && !renderer_->HasDepthPass(camera)) {
      throw BadValueError("resolve: no depth pass of a " + std::to_string(w) + "x" + std::to_string(h) +
                          " camera to resolve (call depth_pass first, with the same camera)");
    }
    if (depth_only && !mask_obj.is_none()) throw BadValueError("pixel_mask: the depth pass takes none");
    if (resolve && !gbuffer_obj.is_none()) throw BadValueError("gbuffer_depth: resolve reuses the depth pass's");
    F32 gbuf;
    const float* gptr = nullptr;
    if (!gbuffer_obj.is_none()) {
      gbuf = CheckArray<float>(gbuffer_obj, "gbuffer_depth", {{"H", h}, {"W", w}});
      gptr = gbuf.data();
    }
    py::array_t<bool, py::array::c_style> mask;
    const std::uint8_t* mptr = nullptr;
    if (!mask_obj.is_none()) {
      mask = CheckArray<bool>(mask_obj, "pixel_mask", {{"H", h}, {"W", w}});
      mptr = reinterpret_cast<const std::uint8_t*>(mask.data());
    }
    PvmRendererOptions opt;
    PvmRenderOptions& o = opt.render;
    o.filtered = filtered;
    o.sigma = sigma;
    o.alpha = alpha;
    o.gamma = gamma;
    o.tau_depth = tau_depth;
    o.max_tiles = max_tiles;
    o.max_candidates = max_candidates;
    o.ulr_k = ulr_k;
    o.merge_rel = merge_rel;
    o.radius_sigmas = radius_sigmas;
    o.margin = margin;
    o.near = near;
    o.cull_back = cull_back;
    o.ray_stride = ray_stride;
    o.filter_step = filter_step;
    o.free_space = free_space;
    o.free_space_tol = free_space_tol;
    o.free_space_point_tol = free_space_point_tol;
    o.tau_empty = tau_empty;
    o.stretch_weight = stretch_weight;
    o.stretch_free = stretch_free;
    o.min_views = min_views;
    opt.max_angle_deg = max_angle_deg;
    opt.Check();
    o.cubic = ParseResample(resample);
    auto color = NewArray<float>({h, w, 3});
    auto depth = NewArray<float>({h, w});
    auto vote = NewArray<float>({h, w});
    auto valid = NewArray<bool>({h, w});
    auto inside = NewArray<bool>({h, w});
    PvmRenderStats stats;
    {
      float *c = color.mutable_data(), *d = depth.mutable_data(), *vt = vote.mutable_data();
      auto* va = reinterpret_cast<std::uint8_t*>(valid.mutable_data());
      auto* in = reinterpret_cast<std::uint8_t*>(inside.mutable_data());
      const PvmRenderMode m = resolve ? PvmRenderMode::kResolve : depth_only ? PvmRenderMode::kDepth : PvmRenderMode::kFull;
      const PvmRenderOptions resolved = opt.Resolved();
      py::gil_scoped_release release;
      stats = renderer_->Render(camera, gptr, mptr, resolved, m, c, d, vt, va, in);
    }
    py::dict times;
    times["voxel_lookup"] = stats.ms[0];
    times["tile_sort"] = stats.ms[1];
    times["per_view_depth_pass"] = stats.ms[2];
    times["cluster_blend"] = stats.ms[3];
    times["spatial_filter"] = stats.ms[4];
    py::dict out;
    out["color"] = color;
    out["depth"] = depth;
    out["vote"] = vote;
    out["valid"] = valid;
    out["inside_grid"] = inside;
    out["times_ms"] = times;
    out["visible_coarse"] = stats.visible_coarse;
    out["tiles"] = stats.tiles;
    out["triangles"] = stats.triangles;
    return out;
  }

  // Candidate lists of the last frame (for tests and inspection): count (H, W) uint8, depth
  // (H, W, K) f32 and view (H, W, K) int16 (entries past count are unspecified).
  py::dict Candidates(int h, int w, int k) const {
    renderer_->CheckCandidates(h, w, k);
    auto count = NewArray<std::uint8_t>({h, w});
    auto depth = NewArray<float>({h, w, k});
    auto view = py::array_t<std::int16_t, py::array::c_style>(std::vector<py::ssize_t>{h, w, k});
    PvmCandidateBuffers buf;
    buf.count = count.mutable_data();
    buf.depth = depth.mutable_data();
    buf.view = view.mutable_data();
    py::dict out;
    out["count"] = count;
    out["depth"] = depth;
    out["view"] = view;
    if (renderer_->HasStretch(h, w, k)) {
      auto stretch = NewArray<float>({h, w, k});  // log2 s in octaves
      buf.stretch = stretch.mutable_data();
      out["stretch"] = stretch;
    }
    if (renderer_->HasClusters(h, w)) {  // cluster sizes #N_fg, #N_bg (Eq. 1, 2)
      auto n_fg = NewArray<std::uint8_t>({h, w});
      auto n_bg = NewArray<std::uint8_t>({h, w});
      buf.n_fg = n_fg.mutable_data();
      buf.n_bg = n_bg.mutable_data();
      out["n_fg"] = n_fg;
      out["n_bg"] = n_bg;
    }
    renderer_->CopyCandidates(h, w, k, buf);
    return out;
  }

 private:
  F32 vertices_;
  I32 faces_, tile_view_, tile_cell_;
  I64 face_offsets_, vertex_offsets_, coarse_offsets_;
  F32 tile_bounds_;
  std::vector<F32> images_;
  std::vector<F32> depths_;
  std::unique_ptr<PvmRenderer> renderer_;
};

}  // namespace

static void BindPvmRender(py::module_& m) {
  const PvmRendererOptions kPvm;  // the defaults of render's arguments
  const PvmRenderOptions& d = kPvm.render;
  py::class_<PvmRendererBinding>(m, "PvmRenderer",
                              "PVM tiles + input views; render() runs cpp/kernels/hybrid/pvm_render.h's five stages. "
                              "Not thread-safe: one render at a time per object (it reuses its frame buffers).")
      .def(py::init<py::handle, py::handle, py::handle, py::handle, py::handle, py::handle, py::handle, py::handle,
                    std::vector<double>,
                    std::vector<double>, int, int, std::vector<Camera>, py::list, py::handle, py::handle>(),
           py::arg("vertices"), py::arg("faces"), py::arg("face_offsets"), py::arg("vertex_offsets"),
           py::arg("tile_view"), py::arg("tile_cell"), py::arg("tile_bounds"), py::arg("coarse_offsets"), py::arg("origin"), py::arg("cell"), py::arg("coarse"), py::arg("sub"),
           py::arg("cameras"), py::arg("images"), py::arg("enabled"), py::arg("depths") = py::none(),
           "Arrays as in tiles.npz (docs/FORMAT.md), tile_view indexing `cameras`; images float32 (H_v, W_v, 3) "
           "linear RGB per camera; enabled bool (views,): views the renderer may use; depths None or float32 "
           "(H_v, W_v) per camera (the views' depth, for render's free_space count).")
      .def("render", &PvmRendererBinding::Render, py::arg("camera"), py::arg("gbuffer_depth") = py::none(),
           py::arg("pixel_mask") = py::none(), py::arg("filtered") = d.filtered, py::arg("sigma") = d.sigma,
           py::arg("alpha") = d.alpha, py::arg("gamma") = d.gamma, py::arg("tau_depth") = d.tau_depth,
           py::arg("max_tiles") = d.max_tiles, py::arg("max_candidates") = d.max_candidates, py::arg("ulr_k") = d.ulr_k,
           py::arg("merge_rel") = d.merge_rel, py::arg("radius_sigmas") = d.radius_sigmas, py::arg("margin") = d.margin,
           py::arg("near") = d.near, py::arg("cull_back") = d.cull_back, py::arg("max_angle") = kPvm.max_angle_deg,
           py::arg("ray_stride") = d.ray_stride, py::arg("filter_step") = d.filter_step,
           py::arg("free_space") = d.free_space, py::arg("free_space_tol") = d.free_space_tol,
           py::arg("free_space_point_tol") = d.free_space_point_tol, py::arg("tau_empty") = d.tau_empty,
           py::arg("min_views") = d.min_views, py::arg("stretch_weight") = d.stretch_weight,
           py::arg("stretch_free") = d.stretch_free, py::arg("resample") = d.cubic ? "cubic" : "bilinear",
           py::arg("mode") = "full",
           "dict: color (H, W, 3), depth (H, W) (Eq. 2 vote), vote (H, W), valid, inside_grid (H, W) bool, "
           "times_ms per stage, visible_coarse, tiles, triangles. free_space: a background candidate counts in Eq. 1 / "
           "Eq. 2 only when its view sees past the foreground point (needs depths; pvm_render.h); with it, tau_empty > 0 "
           "empties a one-cluster pixel seen past by >= tau_empty x n_fg views without a candidate. min_views: where "
           "gbuffer_depth has no surface, candidate lists of fewer views are emptied (1: never). stretch_weight, "
           "stretch_free: a candidate's ULR penalty gains stretch_weight x max(0, log2 s - stretch_free), s its triangle's "
           "area in the target over its area in its own view (0: off). resample: the candidates' "
           "colour reads, 'cubic' (Catmull-Rom, clamped to the 2 x 2 texels' range) or 'bilinear'. mode: full (all stages); depth (stages "
           "1-4 without colours: depth, vote, valid, inside_grid; colour 0; the frame is kept); resolve "
           "(colours of pixel_mask from the kept depth pass: stages 4-5 only).")
      .def("candidates", &PvmRendererBinding::Candidates, py::arg("height"), py::arg("width"),
           py::arg("max_candidates") = d.max_candidates,
           "The last frame's per-pixel candidate lists (count, depth, view), with the stretch term on their "
           "stretch (log2 of the triangle's magnification, octaves, 1/16 steps, within +-8) and, when it clustered "
           "every pixel, the cluster sizes n_fg, n_bg (the counted background: free_space).");

  // The renderer's defaults as one dict, in the order of --param's documentation (docs/pvm_render.md):
  // Python's ibrtools.hybrid.pvm_render.DEFAULTS reads them from here. A float default is given with the
  // 7 significant digits that name it (0.83, not 0.8299999833), the same float when passed back.
  const auto f = [](float v) { char buf[32]; std::snprintf(buf, sizeof buf, "%.7g", v); return std::stod(buf); };
  py::dict defaults;
  defaults["sigma"] = f(d.sigma);
  defaults["alpha"] = f(d.alpha);
  defaults["gamma"] = f(d.gamma);
  defaults["tau_depth"] = f(d.tau_depth);
  defaults["max_tiles"] = d.max_tiles;
  defaults["max_candidates"] = d.max_candidates;
  defaults["ulr_k"] = d.ulr_k;
  defaults["merge_rel"] = f(d.merge_rel);
  defaults["radius_sigmas"] = f(d.radius_sigmas);
  defaults["margin"] = d.margin;
  defaults["near"] = f(d.near);
  defaults["cull_back"] = d.cull_back;
  defaults["max_angle"] = f(kPvm.max_angle_deg);
  defaults["ray_stride"] = d.ray_stride;
  defaults["filter_step"] = d.filter_step;
  defaults["filtered"] = d.filtered;
  defaults["free_space"] = d.free_space;
  defaults["free_space_tol"] = f(d.free_space_tol);
  defaults["free_space_point_tol"] = f(d.free_space_point_tol);
  defaults["tau_empty"] = f(d.tau_empty);
  defaults["min_views"] = d.min_views;
  defaults["stretch_weight"] = f(d.stretch_weight);
  defaults["stretch_free"] = f(d.stretch_free);
  defaults["resample"] = d.cubic ? "cubic" : "bilinear";
  m.attr("PVM_DEFAULTS") = defaults;
}

}  // namespace ibr::bind

// Binding of the harmonisation kernel (cpp/kernels/hybrid/harmonise.h): _core.cross_view_prediction; and
// of the per-vertex statistics' gain loops
// (cpp/kernels/hybrid/vertexstats.h): _core.vertex_colour_sums, _core.gain_median_ratios.
// Thin: checks arrays (array.h) and values, releases the GIL around the kernel.
// Python: ibrtools.hybrid.harmonise.
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
  if (const std::int64_t k = FindDecreasing(b, v + 1); k >= 0) {
    throw BadValueError("bounds: expected non-decreasing offsets, got " + std::to_string(b[k]) + " then " +
                        std::to_string(b[k + 1]));
  }
  const std::int64_t* ix = index.data();
  if (const std::int64_t i = FindOutOfRange(ix, rows, 0, n); i >= 0) {
    throw BadValueError("index: vertex " + std::to_string(ix[i]) + " out of range [0, " + std::to_string(n) + ")");
  }
}

}  // namespace

static void BindHarmonise(py::module_& m) {
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

namespace ibr::bind {

void BindHybrid(py::module_& m) {
  BindPvmMeshes(m);
  BindHybridRender(m);
  BindPvmRender(m);
  BindHarmonise(m);
}

}  // namespace ibr::bind
