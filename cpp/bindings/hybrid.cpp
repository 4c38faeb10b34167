// Binding of the hybrid-IBR preprocessing kernels (cpp/kernels/hybrid/pvm.h): _core.pvm_triangulate
// (one view's depth map -> triangles over its pixel grid) and _core.pvm_slice (per-view meshes
// -> tiles of a two-level voxel grid). Thin: checks arrays (array.h) and values, releases the
// GIL around the kernels, hands the kernels' buffers to numpy without copying.
// Python: ibrtools.hybrid.pvm.
#include <cmath>
#include <cstring>
#include <string>
#include <utility>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "array.h"
#include "ibr/errors.h"
#include "kernels/hybrid/pvm.h"
#include "module.h"

namespace ibr::bind {
namespace {

// A numpy array owning `v` (moved into a capsule: no copy).
template <typename T>
py::array_t<T> Own(std::vector<T>&& v, std::vector<py::ssize_t> shape) {
  auto* heap = new std::vector<T>(std::move(v));
  py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<T>*>(p); });
  return py::array_t<T>(shape, heap->data(), owner);
}

bool AllFinite(const float* p, std::size_t n) {
  for (std::size_t i = 0; i < n; ++i)
    if (!std::isfinite(p[i])) return false;
  return true;
}

}  // namespace

void BindHybrid(py::module_& m) {
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
        if (!AllFinite(vertices.data(), static_cast<std::size_t>(nv) * 3)) {
          throw BadValueError("vertices: contain NaN or infinity");
        }
        const std::int32_t* f = faces.data();
        for (py::ssize_t i = 0; i < 3 * nf; ++i) {
          if (f[i] < 0 || f[i] >= nv) {
            throw BadValueError("faces: vertex index " + std::to_string(f[i]) + " out of range [0, " +
                                std::to_string(nv) + ")");
          }
        }
        const std::int32_t* fvw = face_view.data();
        for (py::ssize_t i = 0; i < nf; ++i) {
          if (fvw[i] < 0 || fvw[i] >= n_views) {
            throw BadValueError("face_view: view " + std::to_string(fvw[i]) + " out of range [0, " +
                                std::to_string(n_views) + ")");
          }
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
