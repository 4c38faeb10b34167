// Binding of the PVM renderer (cpp/kernels/hybrid/pvm_render.h): _core.PvmRenderer holds the tiles
// (references to the numpy arrays of tiles.npz, checked once), the input views' cameras and
// images, and the per-frame buffers; render() runs the five stages with the GIL released and
// returns the outputs and per-stage times. Thin: checks arrays (array.h) and values, the
// kernels do the work. Python: ibrtools.hybrid.pvm_render.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "array.h"
#include "ibr/camera.h"
#include "ibr/errors.h"
#include "kernels/hybrid/pvm_render.h"
#include "module.h"

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

bool SameCamera(const Camera& a, const Camera& b) {
  if (a.model != b.model || a.width != b.width || a.height != b.height || a.fx != b.fx || a.fy != b.fy ||
      a.cx != b.cx || a.cy != b.cy || a.trans != b.trans)
    return false;
  for (int c = 0; c < 3; ++c)
    if (a.rot[c] != b.rot[c]) return false;
  return true;
}

class PvmRendererCore {
 public:
  PvmRendererCore(py::handle vertices, py::handle faces, py::handle face_offsets, py::handle vertex_offsets,
                  py::handle tile_view, py::handle tile_cell, py::handle tile_bounds, py::handle coarse_offsets, std::vector<double> origin,
                  std::vector<double> cell, int coarse, int sub, std::vector<Camera> cameras, py::list images,
                  py::handle enabled, py::handle depths) {
    vertices_ = CheckArray<float>(vertices, "vertices", {{"V", -1}, {"3", 3}});
    faces_ = CheckArray<std::int32_t>(faces, "faces", {{"F", -1}, {"3", 3}});
    tile_view_ = CheckArray<std::int32_t>(tile_view, "tile_view", {{"T", -1}});
    const py::ssize_t nt = tile_view_.shape(0);
    face_offsets_ = CheckOffsets(face_offsets, "face_offsets", nt + 1);
    tile_cell_ = CheckArray<std::int32_t>(tile_cell, "tile_cell", {{"T", nt}, {"3", 3}});
    vertex_offsets_ = CheckOffsets(vertex_offsets, "vertex_offsets", nt + 1);
    tile_bounds_ = CheckArray<float>(tile_bounds, "tile_bounds", {{"T", nt}, {"2", 2}, {"3", 3}});
    if (coarse < 1 || sub < 1 || static_cast<std::int64_t>(coarse) * sub > 4096) {
      throw BadValueError("coarse, sub: expected >= 1 with coarse * sub <= 4096, got " + std::to_string(coarse) +
                          ", " + std::to_string(sub));
    }
    const py::ssize_t nc = static_cast<py::ssize_t>(coarse) * coarse * coarse;
    coarse_offsets_ = CheckOffsets(coarse_offsets, "coarse_offsets", nc + 1);
    if (origin.size() != 3 || cell.size() != 3) throw ShapeError("origin, cell: expected 3 numbers each");
    for (int a = 0; a < 3; ++a) {
      if (!std::isfinite(origin[a]) || !(cell[a] > 0.0) || !std::isfinite(cell[a])) {
        throw BadValueError("origin, cell: expected finite numbers with cell > 0");
      }
    }
    const int nv = static_cast<int>(cameras.size());
    if (nv < 1 || nv > 32767) throw BadValueError("cameras: expected 1 .. 32767 views, got " + std::to_string(nv));
    if (static_cast<int>(py::len(images)) != nv) {
      throw ShapeError("images: expected one image per camera (" + std::to_string(nv) + "), got " +
                       std::to_string(py::len(images)));
    }
    for (int v = 0; v < nv; ++v) {
      const std::string name = "images[" + std::to_string(v) + "]";
      images_.push_back(CheckArray<float>(images[static_cast<std::size_t>(v)], name.c_str(),
                                          {{"H_v", cameras[v].height}, {"W_v", cameras[v].width}, {"3", 3}}));
      image_ptrs_.push_back(images_.back().data());
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
        depth_ptrs_.push_back(depths_.back().data());
      }
    }
    auto en = CheckArray<bool>(enabled, "enabled", {{"views", nv}});
    enabled_.assign(en.data(), en.data() + nv);
    cameras_ = std::move(cameras);
    // Index checks, once.
    const std::int64_t n_vert = vertices_.shape(0), n_face = faces_.shape(0);
    if (n_face > INT32_MAX) throw BadValueError("faces: expected at most 2^31 - 1 faces, got " + std::to_string(n_face));
    const std::int32_t* f = faces_.data();
    for (std::int64_t i = 0; i < 3 * n_face; ++i) {
      if (f[i] < 0 || f[i] >= n_vert) throw BadValueError("faces: index out of range [0, " + std::to_string(n_vert) + ")");
    }
    const float* vp = vertices_.data();
    for (std::int64_t i = 0; i < 3 * n_vert; ++i) {
      if (!std::isfinite(vp[i])) throw BadValueError("vertices: expected finite coordinates");
    }
    const std::int64_t* fo = face_offsets_.data();
    const std::int64_t* vo = vertex_offsets_.data();
    if (fo[0] != 0 || fo[nt] != n_face) throw BadValueError("face_offsets: expected 0 .. F");
    if (vo[0] != 0 || vo[nt] != n_vert) throw BadValueError("vertex_offsets: expected 0 .. V");
    const float* tb = tile_bounds_.data();
    for (std::int64_t i = 0; i < 6 * static_cast<std::int64_t>(nt); ++i) {
      if (!std::isfinite(tb[i])) throw BadValueError("tile_bounds: expected finite numbers");
    }
    for (py::ssize_t t = 0; t < nt; ++t) {
      if (fo[t + 1] < fo[t]) throw BadValueError("face_offsets: expected non-decreasing");
      if (vo[t + 1] < vo[t]) throw BadValueError("vertex_offsets: expected non-decreasing");
      for (std::int64_t i = 3 * fo[t]; i < 3 * fo[t + 1]; ++i) {
        if (f[i] < vo[t] || f[i] >= vo[t + 1]) {
          throw BadValueError("faces: tile " + std::to_string(t) + " indexes a vertex outside its vertex range");
        }
      }
      const std::int32_t v = tile_view_.data()[t];
      if (v < 0 || v >= nv) throw BadValueError("tile_view: view index out of range [0, " + std::to_string(nv) + ")");
      for (int a = 0; a < 3; ++a) {
        const std::int32_t c = tile_cell_.data()[3 * t + a];
        if (c < 0 || c >= coarse * sub) throw BadValueError("tile_cell: fine cell out of range");
      }
    }
    const std::int64_t* co = coarse_offsets_.data();
    if (co[0] != 0 || co[nc] != nt) throw BadValueError("coarse_offsets: expected 0 .. T");
    for (py::ssize_t c = 0; c < nc; ++c) {
      if (co[c + 1] < co[c]) throw BadValueError("coarse_offsets: expected non-decreasing");
    }
    tiles_.vertices = vertices_.data();
    tiles_.faces = faces_.data();
    tiles_.face_offsets = face_offsets_.data();
    tiles_.vertex_offsets = vertex_offsets_.data();
    tiles_.tile_bounds = tile_bounds_.data();
    tiles_.tile_view = tile_view_.data();
    tiles_.tile_cell = tile_cell_.data();
    tiles_.coarse_offsets = coarse_offsets_.data();
    tiles_.num_tiles = nt;
    for (int a = 0; a < 3; ++a) {
      tiles_.grid.origin[a] = origin[a];
      tiles_.grid.cell[a] = cell[a];
    }
    tiles_.grid.coarse = coarse;
    tiles_.grid.sub = sub;
    // Each face's area in its own view (the stretch term): once, here (lego's 6.1 M faces: ~0.1 s).
    face_src_log2_.resize(static_cast<std::size_t>(n_face));
    {
      py::gil_scoped_release release;
      PvmFaceSourceLog2Area(tiles_, cameras_.data(), face_src_log2_.data());
    }
    tiles_.face_src_log2 = face_src_log2_.data();
    // inside_grid's box: the union of the tiles' AABBs (= the bounds of the PVM vertices), each side
    // padded by 1e-4 of its extent (an axis flatter than 1e-6 of the largest: of the largest), as
    // grid_bounds pads the grid; no tiles: the grid's box.
    double lo[3] = {HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi[3] = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
    for (std::int64_t i = 0; i < static_cast<std::int64_t>(nt); ++i) {
      for (int a = 0; a < 3; ++a) {
        lo[a] = std::min(lo[a], static_cast<double>(tb[6 * i + a]));
        hi[a] = std::max(hi[a], static_cast<double>(tb[6 * i + 3 + a]));
      }
    }
    if (nt > 0) {
      const double big = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
      for (int a = 0; a < 3; ++a) {
        const double ext = hi[a] - lo[a] > 1e-6 * big ? hi[a] - lo[a] : big;
        tiles_.box[a] = lo[a] - 1e-4 * ext;
        tiles_.box[3 + a] = hi[a] + 1e-4 * ext;
      }
    } else {
      for (int a = 0; a < 3; ++a) {
        tiles_.box[a] = origin[a];
        tiles_.box[3 + a] = origin[a] + cell[a] * coarse * sub;
      }
    }
  }

  py::dict Render(const Camera& camera, py::handle gbuffer_obj, py::handle mask_obj, bool filtered, float sigma,
                  float alpha, float gamma, float tau_depth, int max_tiles, int max_candidates, int ulr_k,
                  float merge_rel, float radius_sigmas, int margin, float near, bool cull_back, float max_angle_deg, int ray_stride, int filter_step,
                  bool free_space, float free_space_tol, float free_space_point_tol, float tau_empty, int min_views,
                  float stretch_weight, float stretch_free, const std::string& resample, const std::string& mode) {
    const bool depth_only = mode == "depth", resolve = mode == "resolve";
    if (!depth_only && !resolve && mode != "full") {
      throw BadValueError("mode: expected full, depth or resolve, got " + mode);
    }
    if (camera.model != CameraModel::kPinhole) {
      throw BadValueError("camera: PVM rendering takes a pinhole target camera (equirect targets are not built)");
    }
    const py::ssize_t h = camera.height, w = camera.width;
    if (resolve && !(depth_frame_ && SameCamera(camera, depth_camera_))) {
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
    auto finite_min = [](float v, const char* name, float lo, bool strict) {
      if (!std::isfinite(v) || (strict ? !(v > lo) : !(v >= lo))) {
        throw BadValueError(std::string(name) + ": expected a finite number " + (strict ? "> " : ">= ") +
                            std::to_string(lo) + ", got " + std::to_string(v));
      }
    };
    finite_min(sigma, "sigma", 0.f, true);
    finite_min(alpha, "alpha", 0.f, false);
    finite_min(gamma, "gamma", 0.f, true);
    finite_min(tau_depth, "tau_depth", 0.f, false);
    finite_min(merge_rel, "merge_rel", 0.f, false);
    finite_min(radius_sigmas, "radius_sigmas", 0.f, false);
    finite_min(near, "near", 0.f, true);
    finite_min(max_angle_deg, "max_angle", 0.f, true);
    finite_min(free_space_tol, "free_space_tol", 0.f, false);
    if (free_space_tol >= 1.f) throw BadValueError("free_space_tol: expected < 1, got " + std::to_string(free_space_tol));
    finite_min(free_space_point_tol, "free_space_point_tol", 0.f, false);
    finite_min(tau_empty, "tau_empty", 0.f, false);
    finite_min(stretch_weight, "stretch_weight", 0.f, false);
    finite_min(stretch_free, "stretch_free", 0.f, false);
    if (radius_sigmas * sigma > 64.f) throw BadValueError("radius_sigmas * sigma: expected <= 64 pixels");
    if (max_tiles < 1 || max_tiles > 255) throw BadValueError("max_tiles: expected 1 .. 255, got " + std::to_string(max_tiles));
    if (max_candidates < 1 || max_candidates > kPvmMaxCandidates) {
      throw BadValueError("max_candidates: expected 1 .. " + std::to_string(kPvmMaxCandidates) + ", got " +
                          std::to_string(max_candidates));
    }
    if (ulr_k < 1 || ulr_k > 64) throw BadValueError("ulr_k: expected 1 .. 64, got " + std::to_string(ulr_k));
    if (filter_step < 1 || filter_step > 16) {
      throw BadValueError("filter_step: expected 1 .. 16, got " + std::to_string(filter_step));
    }
    if (min_views < 1 || min_views > kPvmMaxCandidates) {
      throw BadValueError("min_views: expected 1 .. " + std::to_string(kPvmMaxCandidates) + ", got " +
                          std::to_string(min_views));
    }
    if (ray_stride < 0) throw BadValueError("ray_stride: expected >= 0, got " + std::to_string(ray_stride));
    if (margin < 0 || margin > 32) throw BadValueError("margin: expected 0 .. 32, got " + std::to_string(margin));
    PvmRenderOptions o;
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
    o.cubic = ParseResample(resample);
    o.min_views = min_views;
    o.max_angle = max_angle_deg >= 180.f ? 3.15f : max_angle_deg * 3.14159265f / 180.f;
    PvmViews views;
    views.count = static_cast<int>(cameras_.size());
    views.cameras = cameras_.data();
    views.images = image_ptrs_.data();
    views.enabled = enabled_.data();
    views.depths = depth_ptrs_.empty() ? nullptr : depth_ptrs_.data();
    auto color = NewArray<float>({h, w, 3});
    auto depth = NewArray<float>({h, w});
    auto vote = NewArray<float>({h, w});
    auto valid = NewArray<bool>({h, w});
    auto inside = NewArray<bool>({h, w});
    double ms[5];
    {
      py::gil_scoped_release release;
      using Clock = std::chrono::steady_clock;
      auto t = Clock::now();
      auto lap = [&](int i) {
        const auto now = Clock::now();
        ms[i] = std::chrono::duration<double, std::milli>(now - t).count();
        t = now;
      };
      ms[0] = ms[1] = ms[2] = 0.0;
      if (!resolve) {
        PvmVisibleCoarse(tiles_.grid, camera, gptr, o.margin, o.ray_stride, frame_.visible);
        lap(0);
        PvmSelectTiles(tiles_, views, frame_.visible, camera, o, frame_);
        lap(1);
        PvmRasterise(tiles_, views, camera, o, frame_);
        PvmDropOffMesh(camera, gptr, o.min_views, frame_);
        lap(2);
      }
      // resolve: the depth pass clustered every pixel (it takes no mask); only the masked colours remain.
      PvmCluster(views, camera, mptr, o, !depth_only, frame_, resolve);
      lap(3);
      PvmFilter(tiles_.box, camera, mptr, o, !depth_only, frame_, color.mutable_data(), depth.mutable_data(), vote.mutable_data(),
                reinterpret_cast<std::uint8_t*>(valid.mutable_data()),
                reinterpret_cast<std::uint8_t*>(inside.mutable_data()), resolve);
      lap(4);
    }
    if (!resolve) {
      depth_frame_ = true;  // the candidate lists of this camera stay for resolve calls
      depth_camera_ = camera;
    }
    std::int64_t nvis = 0;
    for (std::uint8_t v : frame_.visible) nvis += v;
    py::dict times;
    times["voxel_lookup"] = ms[0];
    times["tile_sort"] = ms[1];
    times["per_view_depth_pass"] = ms[2];
    times["cluster_blend"] = ms[3];
    times["spatial_filter"] = ms[4];
    py::dict out;
    out["color"] = color;
    out["depth"] = depth;
    out["vote"] = vote;
    out["valid"] = valid;
    out["inside_grid"] = inside;
    out["times_ms"] = times;
    out["visible_coarse"] = nvis;
    out["tiles"] = static_cast<std::int64_t>(frame_.tiles.size());
    out["triangles"] = frame_.triangles;
    return out;
  }

  // Candidate lists of the last frame (for tests and inspection): count (H, W) uint8, depth
  // (H, W, K) f32 and view (H, W, K) int16 (entries past count are unspecified).
  py::dict Candidates(int h, int w, int k) const {
    const std::size_t npix = static_cast<std::size_t>(h) * static_cast<std::size_t>(w);
    if (frame_.cand_count.size() != npix || frame_.cand_depth.size() != npix * static_cast<std::size_t>(k)) {
      throw BadValueError("candidates: no frame of that size and max_candidates rendered yet");
    }
    auto count = NewArray<std::uint8_t>({h, w});
    auto depth = NewArray<float>({h, w, k});
    auto view = py::array_t<std::int16_t, py::array::c_style>(std::vector<py::ssize_t>{h, w, k});
    std::copy(frame_.cand_count.begin(), frame_.cand_count.end(), count.mutable_data());
    std::copy(frame_.cand_depth.begin(), frame_.cand_depth.end(), depth.mutable_data());
    std::copy(frame_.cand_view.begin(), frame_.cand_view.end(), view.mutable_data());
    py::dict out;
    out["count"] = count;
    out["depth"] = depth;
    out["view"] = view;
    if (frame_.stretch_codes && frame_.cand_stretch.size() == npix * static_cast<std::size_t>(k)) {
      auto stretch = NewArray<float>({h, w, k});  // log2 s in octaves, as the penalty reads the codes
      std::transform(frame_.cand_stretch.begin(), frame_.cand_stretch.end(), stretch.mutable_data(), StretchOctaves);
      out["stretch"] = stretch;
    }
    if (frame_.clusters_everywhere && frame_.n_fg.size() == npix) {  // cluster sizes #N_fg, #N_bg (Eq. 1, 2)
      auto n_fg = NewArray<std::uint8_t>({h, w});
      auto n_bg = NewArray<std::uint8_t>({h, w});
      std::copy(frame_.n_fg.begin(), frame_.n_fg.end(), n_fg.mutable_data());
      std::copy(frame_.n_bg.begin(), frame_.n_bg.end(), n_bg.mutable_data());
      out["n_fg"] = n_fg;
      out["n_bg"] = n_bg;
    }
    return out;
  }

 private:
  F32 vertices_;
  I32 faces_, tile_view_, tile_cell_;
  I64 face_offsets_, vertex_offsets_, coarse_offsets_;
  F32 tile_bounds_;
  std::vector<F32> images_;
  std::vector<const float*> image_ptrs_;
  std::vector<F32> depths_;  // empty: no free-space count
  std::vector<const float*> depth_ptrs_;
  std::vector<std::uint8_t> enabled_;
  std::vector<Camera> cameras_;
  std::vector<float> face_src_log2_;  // PvmFaceSourceLog2Area of the tiles
  PvmTileArrays tiles_;
  PvmFrame frame_;
  bool depth_frame_ = false;  // frame_ holds the candidate lists of depth_camera_
  Camera depth_camera_;
};

}  // namespace

void BindPvmRender(py::module_& m) {
  py::class_<PvmRendererCore>(m, "PvmRenderer",
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
      .def("render", &PvmRendererCore::Render, py::arg("camera"), py::arg("gbuffer_depth") = py::none(),
           py::arg("pixel_mask") = py::none(), py::arg("filtered") = true, py::arg("sigma") = 3.f,
           py::arg("alpha") = 7.f, py::arg("gamma") = 7.f, py::arg("tau_depth") = 0.83f, py::arg("max_tiles") = 12,
           py::arg("max_candidates") = 12, py::arg("ulr_k") = 3, py::arg("merge_rel") = 0.02f,
           py::arg("radius_sigmas") = 2.f, py::arg("margin") = 1, py::arg("near") = 1e-3f,
           py::arg("cull_back") = true, py::arg("max_angle") = 55.f, py::arg("ray_stride") = 8, py::arg("filter_step") = 2,
           py::arg("free_space") = true, py::arg("free_space_tol") = 0.02f,
           py::arg("free_space_point_tol") = 0.005f, py::arg("tau_empty") = 2.f, py::arg("min_views") = 2,
           py::arg("stretch_weight") = 0.1f, py::arg("stretch_free") = 0.f,
           py::arg("resample") = "cubic", py::arg("mode") = "full",
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
      .def("candidates", &PvmRendererCore::Candidates, py::arg("height"), py::arg("width"),
           py::arg("max_candidates") = 12,
           "The last frame's per-pixel candidate lists (count, depth, view), with the stretch term on their "
           "stretch (log2 of the triangle's magnification, octaves, 1/16 steps, within +-8) and, when it clustered "
           "every pixel, the cluster sizes n_fg, n_bg (the counted background: free_space).");
}

}  // namespace ibr::bind
