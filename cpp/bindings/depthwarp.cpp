// The depthwarp family's bindings: the backward depth warp and its N-buffer Y-map
// (cpp/kernels/depthwarp/depthwarp.h, nbuffer.h), warping-based occlusion culling (culling.h) and
// soft shadows (shadows.h). Python: ibrtools.depthwarp.core, ibrtools.depthwarp.culling, ibrtools.depthwarp.shadows.
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include <glm/glm.hpp>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "array.h"
#include "ibr/camera.h"
#include "ibr/checks.h"
#include "ibr/embree_scene.h"
#include "ibr/errors.h"
#include "kernels/depthwarp/culling.h"
#include "kernels/depthwarp/depthwarp.h"
#include "kernels/depthwarp/front.h"
#include "kernels/depthwarp/shadows.h"
#include "module.h"

// Bindings of the depth warp and the Y-map (cpp/kernels/depthwarp/front.h): array checks (dtypes,
// shapes, aliasing), then the front (value checks, buffers, pipelines, stage times) with the GIL
// released. Python: ibrtools.depthwarp.core (the only user; other modules use that API).
namespace ibr::bind {
namespace {

using FloatArray = py::array_t<float, py::array::c_style>;
using IntArray = py::array_t<std::int32_t, py::array::c_style>;
using DoubleArray = py::array_t<double, py::array::c_style>;

// The checked arrays of a motion computation (one or more layers) and the front's inputs.
struct MotionArgs {
  FloatArray layers;  // (L, H, W)
  IntArray ids;       // (L, H, W) or empty
  bool has_ids = false;
  DepthWarpMotionInputs in;
};

MotionArgs CheckMotionArgs(const py::handle& layers_obj, const Camera& src, const Camera& dst,
                           const py::handle& ids_obj, const py::handle& motion_obj) {
  DepthWarpCheckPinhole(src, "src");
  DepthWarpCheckPinhole(dst, "dst");
  MotionArgs a;
  a.layers = CheckArray<float>(layers_obj, "layers", {{"L", -1}, {"H", src.height}, {"W", src.width}});
  const int num_layers = static_cast<int>(a.layers.shape(0));
  if (num_layers < 1 || num_layers > 127) {
    throw ShapeError("layers: expected 1..127 layers, got " + std::to_string(num_layers));
  }
  {
    py::gil_scoped_release release;
    DepthWarpCheckDepth(a.layers.data(), std::int64_t(num_layers) * src.height * src.width);
  }
  std::vector<glm::dmat4> motions;
  if (!motion_obj.is_none()) {
    DoubleArray m = CheckArray<double>(motion_obj, "object_motion", {{"K", -1}, {"4", 4}, {"4", 4}});
    const double* p = m.data();
    for (py::ssize_t k = 0; k < m.shape(0); ++k, p += 16) {
      glm::dmat4 t(1.0);
      for (int r = 0; r < 4; ++r) {
        for (int c = 0; c < 4; ++c) {
          if (!std::isfinite(p[r * 4 + c])) {
            throw BadValueError("object_motion[" + std::to_string(k) + "]: contains NaN or infinity");
          }
          t[c][r] = p[r * 4 + c];
        }
      }
      if (std::fabs(p[12]) > 1e-9 || std::fabs(p[13]) > 1e-9 || std::fabs(p[14]) > 1e-9 ||
          std::fabs(p[15] - 1.0) > 1e-9) {
        throw BadValueError("object_motion[" + std::to_string(k) + "]: last row must be (0, 0, 0, 1)");
      }
      motions.push_back(t);
    }
  }
  if (!ids_obj.is_none()) {
    if (motion_obj.is_none()) throw BadValueError("object_ids: given without object_motion");
    a.ids = CheckArray<std::int32_t>(ids_obj, "object_ids", {{"L", num_layers}, {"H", src.height}, {"W", src.width}});
    a.has_ids = true;
  } else if (!motion_obj.is_none() && !motions.empty()) {
    throw BadValueError("object_motion: given without object_ids");
  }
  py::gil_scoped_release release;
  a.in = DepthWarpPrepareMotion(a.layers.data(), num_layers, src.height, src.width,
                                a.has_ids ? a.ids.data() : nullptr, motions, src, dst);
  return a;
}

// The packed (L, H, W, 4) output of a motion computation: `out` (checked) or a new array.
FloatArray MotionOutput(const MotionArgs& a, const py::handle& out_obj) {
  const DepthWarpMotionInputs& in = a.in;
  FloatArray packed = out_obj.is_none()
                          ? NewArray<float>({in.num_layers, in.height, in.width, 4})
                          : CheckArray<float>(out_obj, "out", {{"L", in.num_layers}, {"H", in.height}, {"W", in.width}, {"4", 4}},
                                              true);
  if (!out_obj.is_none() && (Overlaps(packed, a.layers) || (a.has_ids && Overlaps(packed, a.ids)))) {
    throw BadValueError("out: shares memory with an input");
  }
  return packed;
}

const char* AxesName(int a) {
  switch (static_cast<DepthWarpAxes>(a)) {
    case DepthWarpAxes::kAxisAligned: return "aab";
    case DepthWarpAxes::kOriented: return "oriented";
    case DepthWarpAxes::kDegeneratePca: return "aab (degenerate pca)";
    case DepthWarpAxes::kOrientedNotSmaller: return "aab (oriented not smaller)";
    case DepthWarpAxes::kEmpty: return "empty";
  }
  return "?";
}

FloatArray CheckPacked(const py::handle& obj) {
  FloatArray p = CheckArray<float>(obj, "packed", {{"L", -1}, {"H", -1}, {"W", -1}, {"4", 4}});
  if (p.shape(0) < 1 || p.shape(0) > 127 || p.shape(1) < 1 || p.shape(2) < 1) {
    throw ShapeError("packed: expected 1..127 layers of at least 1x1 pixels, got " + DescribeShape(p));
  }
  return p;
}

// The DepthWarpMips object to fill: `reuse` (a DepthWarpMips) or a new one, sized for (nl, hh, ww).
py::object PrepareMips(const py::object& reuse, int nl, int hh, int ww) {
  if (!reuse.is_none() && !py::isinstance<DepthWarpMips>(reuse)) {
    throw DtypeError("reuse: expected a DepthWarpMips or None");
  }
  py::object result = reuse.is_none() ? py::cast(DepthWarpMips()) : reuse;
  result.cast<DepthWarpMips&>().Prepare(nl, hh, ww);
  return result;
}

}  // namespace

static void BindDepthWarp(py::module_& m) {
  m.def(
      "dw_motion",
      [](py::handle layers, const Camera& src, const Camera& dst, py::handle ids, py::handle motion, py::handle out,
         bool simd) {
        MotionArgs a = CheckMotionArgs(layers, src, dst, ids, motion);
        FloatArray packed = MotionOutput(a, out);
        float* p = packed.mutable_data();
        py::gil_scoped_release release;
        DepthWarpMotionLayers(a.in, src, dst, simd, p);
        return packed;
      },
      py::arg("layers"), py::arg("src"), py::arg("dst"), py::arg("object_ids") = py::none(),
      py::arg("object_motion") = py::none(), py::arg("out") = py::none(), py::arg("simd") = true,
      "Exact motion buffers (cpp/kernels/depthwarp/depthwarp.h DepthWarpMotion) of layers float32 (L, H, W) z in "
      "src (0 = empty) into dst: float32 (L, H, W, 4) = (mx, my, z_dst, 0); z_dst = 0 marks invalid pixels. "
      "object_ids int32 (L, H, W) in -1..K-1 with object_motion float64 (K, 4, 4) new_world_from_old_world. "
      "out: an existing writeable float32 (L, H, W, 4) array to fill (and return) instead of a new one. "
      "simd=False: the scalar loop for every pixel (the same bits as the default SSE2 path; for tests).");

  py::class_<DepthWarpMips>(m, "DepthWarpMips", "Min-max motion mipmaps of each layer (dw_build_mips).")
      .def_readonly("num_layers", &DepthWarpMips::num_layers)
      .def_property_readonly("axes", [](const DepthWarpMips& mm) {
        std::vector<std::string> out;
        for (int a : mm.axes) out.push_back(AxesName(a));
        return out;
      })
      .def("rotation", [](const DepthWarpMips& mm, int layer) {
        if (layer < 0 || layer >= mm.num_layers) throw BadValueError("layer: out of range");
        DoubleArray r = NewArray<double>({2, 2});
        for (int i = 0; i < 4; ++i) r.mutable_data()[i] = mm.rot[layer][i];
        return r;
      }, py::arg("layer"), "u = R v: the 2x2 rotation of the layer's bound axes.")
      .def("num_levels", [](const DepthWarpMips& mm, int layer) {
        if (layer < 0 || layer >= mm.num_layers) throw BadValueError("layer: out of range");
        return static_cast<int>(mm.levels[layer].size());
      }, py::arg("layer"))
      .def("level", [](const DepthWarpMips& mm, int layer, int level) {
        if (layer < 0 || layer >= mm.num_layers) throw BadValueError("layer: out of range");
        if (level < 1 || level > static_cast<int>(mm.levels[layer].size())) throw BadValueError("level: out of range");
        const auto [h, w] = mm.dims[layer][level - 1];
        FloatArray a = NewArray<float>({h, w, 4});
        std::copy(mm.levels[layer][level - 1].begin(), mm.levels[layer][level - 1].end(), a.mutable_data());
        return a;
      }, py::arg("layer"), py::arg("level"),
      "A copy of level >= 1 (h, w, 4) = (min u, min w, max u, max w); empty texels (+inf, +inf, -inf, -inf).");

  m.def(
      "dw_build_mips",
      [](py::handle packed_obj, bool oriented, int pca_grid, py::object reuse) -> py::object {
        FloatArray packed = CheckPacked(packed_obj);
        DepthWarpCheckPcaGrid(pca_grid);
        py::object result = PrepareMips(reuse, static_cast<int>(packed.shape(0)), static_cast<int>(packed.shape(1)),
                                        static_cast<int>(packed.shape(2)));
        DepthWarpMips& mm = result.cast<DepthWarpMips&>();
        {
          py::gil_scoped_release release;
          mm.Build(packed.data(), oriented, pca_grid);
        }
        return result;
      },
      py::arg("packed"), py::arg("oriented") = false, py::arg("pca_grid") = 16, py::arg("reuse") = py::none(),
      "Min-max motion mipmaps (DepthWarpChooseAxes, DepthWarpMipLevel1/Down) of packed float32 "
      "(L, H, W, 4) from dw_motion; oriented: try PCA axes of a pca_grid x pca_grid sample per layer. "
      "reuse: a DepthWarpMips to refill (returned; its buffers are kept when the size matches).");

  m.def(
      "dw_motion_mips",
      [](py::handle layers, const Camera& src, const Camera& dst, py::handle ids, py::handle motion, bool oriented,
         int pca_grid, py::handle out, py::object reuse) {
        MotionArgs a = CheckMotionArgs(layers, src, dst, ids, motion);
        DepthWarpCheckPcaGrid(pca_grid);
        FloatArray packed = MotionOutput(a, out);
        py::object result = PrepareMips(reuse, a.in.num_layers, a.in.height, a.in.width);
        DepthWarpMips& mm = result.cast<DepthWarpMips&>();
        float* pd = packed.mutable_data();
        double motion_ms = 0, mipmap_ms = 0;
        {
          py::gil_scoped_release release;
          mm.BuildWithMotion(a.in, src, dst, oriented, pca_grid, pd, &motion_ms, &mipmap_ms);
        }
        return py::make_tuple(packed, result, motion_ms, mipmap_ms);
      },
      py::arg("layers"), py::arg("src"), py::arg("dst"), py::arg("object_ids") = py::none(),
      py::arg("object_motion") = py::none(), py::arg("oriented") = false, py::arg("pca_grid") = 16,
      py::arg("out") = py::none(), py::arg("reuse") = py::none(),
      "dw_motion followed by dw_build_mips in one call: (packed float32 (L, H, W, 4), DepthWarpMips, motion_ms, "
      "mipmap_ms). With axis-aligned bounds (oriented false) level 1 of the mipmaps is built in the motion pass "
      "(DepthWarpMotionMipLevel1: bit-identical, without re-reading the packed buffer) and its time counts as "
      "motion_ms. out / reuse: buffers to refill, as in dw_motion / dw_build_mips.");

  const DepthWarpFrameOptions kFrame;  // the defaults of dw_warp's arguments
  // The search's defaults the depthwarp method exposes as parameters (ibrtools.depthwarp.method.DEFAULTS
  // reads them from here): seeds, iters, threshold (px; the float's 7 significant digits), dilate, bound.
  {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.7g", kFrame.warp.threshold);
    py::dict defaults;
    defaults["seeds"] = kFrame.warp.seeds;
    defaults["iters"] = kFrame.warp.iters;
    defaults["threshold"] = std::stod(buf);
    defaults["dilate"] = kFrame.dilate;
    defaults["bound"] = kFrame.warp.tight ? "tight" : "global";
    m.attr("DEPTHWARP_DEFAULTS") = defaults;
  }
  m.def(
      "dw_warp",
      [](py::handle packed_obj, const DepthWarpMips& mm, int dst_height, int dst_width, int seeds, int iters,
         float threshold, bool tight, int steps, float early_exit, std::uint32_t seed, bool dilate,
         int dilate_min_neighbors, bool skip_farther, int tile, bool pixel_step, py::handle seen_src,
         py::handle seen_dst, float edge_motion, py::handle surface_ids) {
        FloatArray packed = CheckPacked(packed_obj);
        if (packed.shape(0) != mm.num_layers || packed.shape(1) != mm.height || packed.shape(2) != mm.width) {
          throw ShapeError("mips: built for (" + std::to_string(mm.num_layers) + ", " + std::to_string(mm.height) +
                           ", " + std::to_string(mm.width) + ") but packed is " + DescribeShape(packed));
        }
        if (dst_height < 1 || dst_width < 1) throw BadValueError("dst size: expected >= 1x1");
        DepthWarpFrameOptions opt;
        opt.warp.seeds = seeds, opt.warp.iters = iters, opt.warp.threshold = threshold, opt.warp.tight = tight;
        opt.warp.steps = steps, opt.warp.early_exit = early_exit, opt.warp.seed = seed;
        opt.warp.skip_farther = skip_farther, opt.warp.tile = tile, opt.warp.pixel_step = pixel_step;
        opt.warp.edge_motion = edge_motion;
        opt.dilate = dilate, opt.dilate_min_neighbors = dilate_min_neighbors;
        opt.Check();
        IntArray surface;
        const bool prove = !surface_ids.is_none();
        if (prove) {
          surface = CheckArray<std::int32_t>(surface_ids, "surface_ids",
                                             {{"L", mm.num_layers}, {"H", mm.height}, {"W", mm.width}});
        }
        DepthWarpSeen seen;
        if (seen_src.is_none() != seen_dst.is_none()) {
          throw BadValueError("seen_src, seen_dst: give both cameras (unseen-space rejection) or neither");
        }
        if (!seen_src.is_none()) {
          Camera src, dst;
          try {
            src = seen_src.cast<Camera>();
            dst = seen_dst.cast<Camera>();
          } catch (const py::cast_error&) {
            throw DtypeError("seen_src, seen_dst: expected _core.Camera objects");
          }
          seen = DepthWarpMakeSeen(src, dst, mm.width, mm.height, dst_width, dst_height);
          opt.warp.seen = &seen;
        }
        FloatArray depth = NewArray<float>({dst_height, dst_width});
        py::array_t<std::int8_t, py::array::c_style> layer = NewArray<std::int8_t>({dst_height, dst_width});
        py::object occluder = py::none();
        FloatArray proven;
        if (prove) {
          proven = NewArray<float>({dst_height, dst_width});
          occluder = proven;
        }
        DepthWarpFrameStats stats;
        {
          float* d = depth.mutable_data();
          std::int8_t* l = layer.mutable_data();
          float* pr = prove ? proven.mutable_data() : nullptr;
          py::gil_scoped_release release;
          stats = DepthWarpRenderFrame(packed.data(), mm, prove ? surface.data() : nullptr, opt, dst_height, dst_width,
                                       d, l, pr);
        }
        py::dict c;
        c["converged"] = stats.counters.converged;
        c["early_exit"] = stats.counters.early_exit;
        c["searched"] = stats.counters.searched;
        c["samples"] = stats.counters.samples;
        c["lookups"] = stats.counters.lookups;
        c["dilated"] = stats.dilated;
        c["warp_ms"] = stats.warp_ms;
        c["dilate_ms"] = stats.dilate_ms;
        return py::make_tuple(depth, layer, c, occluder);
      },
      py::arg("packed"), py::arg("mips"), py::arg("dst_height"), py::arg("dst_width"),
      py::arg("seeds") = kFrame.warp.seeds, py::arg("iters") = kFrame.warp.iters,
      py::arg("threshold") = kFrame.warp.threshold, py::arg("tight") = kFrame.warp.tight,
      py::arg("steps") = kFrame.warp.steps, py::arg("early_exit") = kFrame.warp.early_exit,
      py::arg("seed") = kFrame.warp.seed, py::arg("dilate") = kFrame.dilate,
      py::arg("dilate_min_neighbors") = kFrame.dilate_min_neighbors, py::arg("skip_farther") = kFrame.warp.skip_farther,
      py::arg("tile") = kFrame.warp.tile, py::arg("pixel_step") = kFrame.warp.pixel_step,
      py::arg("seen_src") = py::none(), py::arg("seen_dst") = py::none(),
      py::arg("edge_motion") = kFrame.warp.edge_motion, py::arg("surface_ids") = py::none(),
      "Backward depth warp (DepthWarpBackward, then DepthWarpDilate when dilate): returns depth float32 "
      "(H', W') (0 in holes), layer int8 (H', W') (-1 in holes), a dict of counters and wall times, and the "
      "proven occluder depth float32 (H', W') (0 where nothing is proven; before dilation) when surface_ids "
      "int32 (L, H, W) (the source pixels' object ids, < 0 = none) is given, else None. "
      "seen_src, seen_dst (pinhole Cameras, both or neither): unseen-space rejection of deep-layer samples "
      "(DepthWarpSeen: a sample of layer >= 1 is accepted only where the target ray in front of it lies "
      "inside the source camera's view).");

  m.def(
      "dw_forward",
      [](py::handle layers_obj, const Camera& src, const Camera& dst, py::handle ids, py::handle motion,
         const std::string& kind) {
        DepthWarpForwardKind k;
        if (kind == "vfw") {
          k = DepthWarpForwardKind::kVfw;
        } else if (kind == "afw") {
          k = DepthWarpForwardKind::kAfw;
        } else {
          throw BadValueError("kind: expected 'vfw' or 'afw', got '" + kind + "'");
        }
        MotionArgs a = CheckMotionArgs(layers_obj, src, dst, ids, motion);
        FloatArray depth = NewArray<float>({dst.height, dst.width});
        py::array_t<std::int8_t, py::array::c_style> layer = NewArray<std::int8_t>({dst.height, dst.width});
        double motion_ms = 0, warp_ms = 0;
        {
          float* d = depth.mutable_data();
          std::int8_t* l = layer.mutable_data();
          py::gil_scoped_release release;
          DepthWarpForwardFrame(k, a.in, src, dst, d, l, &motion_ms, &warp_ms);
        }
        return py::make_tuple(depth, layer, motion_ms, warp_ms);
      },
      py::arg("layers"), py::arg("src"), py::arg("dst"), py::arg("object_ids") = py::none(),
      py::arg("object_motion") = py::none(), py::arg("kind") = "vfw",
      "Forward depth warp baselines (DepthWarpForward, 'vfw' quad splats / 'afw' atomic-min points, both "
      "with the half-pixel support expansion): (depth (H', W') float32, layer int8, motion_ms, warp_ms).");

  py::class_<DepthWarpYMap>(m, "YMap",
                            "Y-map of a depth buffer for conservative max-depth queries (cpp/kernels/depthwarp/nbuffer.h).")
      .def(py::init([](py::handle depth_obj, int mip_levels) {
             FloatArray depth = CheckArray<float>(depth_obj, "depth", {{"H", -1}, {"W", -1}});
             const int h = static_cast<int>(depth.shape(0)), w = static_cast<int>(depth.shape(1));
             if (h < 1 || w < 1) throw ShapeError("depth: expected at least 1x1 pixels, got " + DescribeShape(depth));
             py::gil_scoped_release release;
             return DepthWarpYMap(depth.data(), h, w, mip_levels);
           }),
           py::arg("depth"), py::arg("mip_levels") = 2)
      .def_property_readonly("height", &DepthWarpYMap::height)
      .def_property_readonly("width", &DepthWarpYMap::width)
      .def_property_readonly("mip_levels", &DepthWarpYMap::mip_levels)
      .def_property_readonly("num_nbuffer_levels", &DepthWarpYMap::num_nbuffer_levels)
      .def("max_depth", [](const DepthWarpYMap& y, py::handle boxes_obj) {
             IntArray boxes = CheckArray<std::int32_t>(boxes_obj, "boxes", {{"K", -1}, {"4", 4}});
             const py::ssize_t k = boxes.shape(0);
             FloatArray out = NewArray<float>({k});
             const std::int32_t* b = boxes.data();
             float* o = out.mutable_data();
             {
               py::gil_scoped_release release;
               y.MaxDepth(b, k, o);
             }
             return out;
           }, py::arg("boxes"),
           "boxes int32 (K, 4) = (x0, y0, x1, y1), x1/y1 exclusive, clipped; float32 (K,) >= the max over each box "
           "(+inf for an empty box).");
}

}  // namespace ibr::bind

// Bindings of warping-based occlusion culling (cpp/kernels/depthwarp/culling.h) and soft shadows from
// light-sample shadow maps / traced occlusion rays (cpp/kernels/depthwarp/shadows.h); used by
// python/ibrtools/culling.py and python/ibrtools/shadows.py. Thin: array checks (array.h),
// value checks the kernels rely on, outputs allocated once as numpy arrays, GIL released.
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
  if (const std::int64_t i = FindOutOfRange(f, m * 3, 0, n); i >= 0) {
    throw BadValueError("faces: vertex index " + std::to_string(f[i]) + " out of range [0, " + std::to_string(n) +
                        ") in face " + std::to_string(i / 3));
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
    if (FindNonFinite(lights.data(), std::int64_t(s) * 3) >= 0) {
      throw BadValueError("light_positions: contain NaN or infinity");
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

static void BindCullingAndShadows(py::module_& m) {
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

namespace ibr::bind {

void BindDepthwarp(py::module_& m) {
  BindDepthWarp(m);
  BindCullingAndShadows(m);
}

}  // namespace ibr::bind
