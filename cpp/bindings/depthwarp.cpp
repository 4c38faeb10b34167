// The depthwarp family's bindings: the backward depth warp and its N-buffer Y-map
// (cpp/kernels/depthwarp/depthwarp.h, nbuffer.h), warping-based occlusion culling (culling.h) and
// soft shadows (shadows.h). Python: ibrtools.depthwarp, ibrtools.culling, ibrtools.shadows.
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <glm/glm.hpp>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "array.h"
#include "ibr/camera.h"
#include "ibr/embree_scene.h"
#include "ibr/errors.h"
#include "kernels/depthwarp/culling.h"
#include "kernels/depthwarp/depthwarp.h"
#include "kernels/depthwarp/nbuffer.h"
#include "kernels/depthwarp/shadows.h"
#include "module.h"

// Bindings of cpp/kernels/depthwarp/depthwarp.h and cpp/kernels/depthwarp/nbuffer.h: the checking front (dtypes,
// shapes, pinhole cameras, finiteness, object ids in range), the scratch buffers and the calls with
// the GIL released. Python: ibrtools.depthwarp (the only user; other modules use that API).
namespace ibr::bind {
namespace {

using FloatArray = py::array_t<float, py::array::c_style>;
using IntArray = py::array_t<std::int32_t, py::array::c_style>;
using DoubleArray = py::array_t<double, py::array::c_style>;

double MsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

void CheckPinhole(const Camera& c, const char* name) {
  if (c.model != CameraModel::kPinhole) {
    throw BadValueError(std::string(name) + ": equirect camera not supported by depthwarp (pinhole only)");
  }
}

// Counts NaN (and, unless allow_inf, infinite) values, GIL released.
std::int64_t CountNonFinite(const float* p, std::int64_t n, bool allow_inf, bool allow_negative, std::int64_t* negative) {
  std::int64_t bad = 0, neg = 0;
  py::gil_scoped_release release;
  for (std::int64_t i = 0; i < n; ++i) {
    const float v = p[i];
    bad += std::isnan(v) || (!allow_inf && std::isinf(v));
    neg += v < 0.0f;
  }
  *negative = allow_negative ? 0 : neg;
  return bad;
}

// The checked inputs of a motion computation (one or more layers).
struct MotionInputs {
  FloatArray layers;  // (L, H, W)
  py::object ids_keep;
  IntArray ids;       // (L, H, W) or empty
  bool has_ids = false;
  std::vector<double> dst_from_src;  // (K + 1) x 12
  int num_motions = 0;
  int num_layers = 0, height = 0, width = 0;
};

MotionInputs CheckMotionInputs(const py::handle& layers_obj, const Camera& src, const Camera& dst,
                               const py::handle& ids_obj, const py::handle& motion_obj) {
  CheckPinhole(src, "src");
  CheckPinhole(dst, "dst");
  MotionInputs in;
  in.layers = CheckArray<float>(layers_obj, "layers", {{"L", -1}, {"H", src.height}, {"W", src.width}});
  in.num_layers = static_cast<int>(in.layers.shape(0));
  in.height = src.height;
  in.width = src.width;
  if (in.num_layers < 1 || in.num_layers > 127) {
    throw ShapeError("layers: expected 1..127 layers, got " + std::to_string(in.num_layers));
  }
  std::int64_t negative = 0, bad = 0;
  const std::int64_t n = std::int64_t(in.num_layers) * in.height * in.width;
  {
    py::gil_scoped_release release;
    DepthWarpCountBadDepth(in.layers.data(), n, &bad, &negative);  // threaded (~25 MB at L = 3, 1080p)
  }
  if (bad || negative) {
    throw BadValueError("layers: depth must be finite and >= 0 (0 = empty), got " + std::to_string(bad) +
                        " NaN/infinite and " + std::to_string(negative) + " negative values");
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
  in.num_motions = static_cast<int>(motions.size());
  if (!ids_obj.is_none()) {
    if (motion_obj.is_none()) throw BadValueError("object_ids: given without object_motion");
    in.ids = CheckArray<std::int32_t>(ids_obj, "object_ids",
                                      {{"L", in.num_layers}, {"H", in.height}, {"W", in.width}});
    in.has_ids = true;
    const std::int32_t* p = in.ids.data();
    std::int64_t out_of_range = 0;
    const int k = in.num_motions;
    {
      py::gil_scoped_release release;
      for (std::int64_t i = 0; i < n; ++i) out_of_range += p[i] < -1 || p[i] >= k;
    }
    if (out_of_range) {
      throw BadValueError("object_ids: expected -1 (static) or 0.." + std::to_string(k - 1) +
                          " (an index into object_motion), got " + std::to_string(out_of_range) +
                          " values out of range");
    }
  } else if (!motion_obj.is_none() && in.num_motions > 0) {
    throw BadValueError("object_motion: given without object_ids");
  }
  // dst_from_src = dst.cam_from_world * motion * src.world_from_cam (3x4 row-major each).
  auto pose = [](const Camera& c) {
    glm::dmat4 m(c.rot);
    m[3] = glm::dvec4(c.trans, 1.0);
    return m;
  };
  const glm::dmat4 dst_from_world = pose(dst), world_from_src = glm::inverse(pose(src));
  auto push = [&](const glm::dmat4& a) {
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 4; ++c) in.dst_from_src.push_back(a[c][r]);
    }
  };
  push(dst_from_world * world_from_src);
  for (const glm::dmat4& t : motions) push(dst_from_world * t * world_from_src);
  return in;
}

// The packed (L, H, W, 4) output of a motion computation: `out` (checked) or a new array.
FloatArray MotionOutput(const MotionInputs& in, const py::handle& out_obj) {
  FloatArray packed = out_obj.is_none()
                          ? NewArray<float>({in.num_layers, in.height, in.width, 4})
                          : CheckArray<float>(out_obj, "out", {{"L", in.num_layers}, {"H", in.height}, {"W", in.width}, {"4", 4}},
                                              true);
  if (!out_obj.is_none() && (Overlaps(packed, in.layers) || (in.has_ids && Overlaps(packed, in.ids)))) {
    throw BadValueError("out: shares memory with an input");
  }
  return packed;
}

FloatArray ComputeMotion(const MotionInputs& in, const Camera& src, const Camera& dst, const py::handle& out_obj,
                         bool simd = true) {
  FloatArray packed = MotionOutput(in, out_obj);
  DepthWarpMover mover{&src, &dst, in.dst_from_src.data(), in.num_motions, simd};
  const std::int64_t plane = std::int64_t(in.height) * in.width;
  float* out = packed.mutable_data();
  const float* depth = in.layers.data();
  const std::int32_t* ids = in.has_ids ? in.ids.data() : nullptr;
  py::gil_scoped_release release;
  for (int j = 0; j < in.num_layers; ++j) {
    ImageView<const float> d(depth + j * plane, in.height, in.width);
    ImageView<const std::int32_t> idv(ids ? ids + j * plane : nullptr, in.height, in.width);
    DepthWarpMotion(d, ids ? &idv : nullptr, mover, ImageView<float>(out + j * plane * 4, in.height, in.width, 4));
  }
  return packed;
}

// Min-max motion mipmaps of every layer of a packed (L, H, W, 4) buffer.
struct MotionMips {
  int num_layers = 0, height = 0, width = 0;
  std::vector<std::vector<std::vector<float>>> levels;  // [layer][level - 1]
  std::vector<std::vector<std::vector<float>>> zlevels; // [layer][level - 1]: min z_dst
  std::vector<std::vector<std::pair<int, int>>> dims;   // (h, w) of each level
  std::vector<std::array<float, 4>> rot;
  std::vector<int> axes;
};

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

// The MotionMips object to fill: `reuse` (a DepthWarpMips) or a new one, sized for (nl, hh, ww);
// a reused object of the same size keeps its buffers (no page faults).
py::object PrepareMips(const py::object& reuse, int nl, int hh, int ww) {
  if (!reuse.is_none() && !py::isinstance<MotionMips>(reuse)) {
    throw DtypeError("reuse: expected a DepthWarpMips or None");
  }
  py::object result = reuse.is_none() ? py::cast(MotionMips()) : reuse;
  MotionMips& mm = result.cast<MotionMips&>();
  if (mm.num_layers != nl || mm.height != hh || mm.width != ww) {
    mm = MotionMips();
    mm.num_layers = nl, mm.height = hh, mm.width = ww;
    mm.levels.resize(nl);
    mm.zlevels.resize(nl);
    mm.dims.resize(nl);
    mm.rot.resize(nl);
    mm.axes.resize(nl);
    for (int j = 0; j < nl; ++j) {
      int h = hh, w = ww;
      while (h > 1 || w > 1) {
        h = (h + 1) / 2, w = (w + 1) / 2;
        mm.dims[j].push_back({h, w});
        mm.levels[j].emplace_back(std::size_t(h) * w * 4);
        mm.zlevels[j].emplace_back(std::size_t(h) * w);
      }
    }
  }
  return result;
}

ImageView<float> MipView(MotionMips& mm, int j, std::size_t l) {
  return ImageView<float>(mm.levels[j][l].data(), mm.dims[j][l].first, mm.dims[j][l].second, 4);
}
ImageView<float> ZMipView(MotionMips& mm, int j, std::size_t l) {
  return ImageView<float>(mm.zlevels[j][l].data(), mm.dims[j][l].first, mm.dims[j][l].second);
}

// Levels first_level.. (1-based) of layer j; level 1 from the packed layer pv. GIL released by the caller.
void FillMips(MotionMips& mm, int j, const ImageView<const float>& pv, std::size_t first_level) {
  for (std::size_t l = first_level - 1; l < mm.levels[j].size(); ++l) {
    if (l == 0) {
      DepthWarpMipLevel1(pv, mm.rot[j].data(), MipView(mm, j, 0), ZMipView(mm, j, 0));
    } else {
      const ImageView<float> in = MipView(mm, j, l - 1), in_z = ZMipView(mm, j, l - 1);
      DepthWarpMipDown(ImageView<const float>(in.data, in.height, in.width, 4),
                       ImageView<const float>(in_z.data, in_z.height, in_z.width), MipView(mm, j, l), ZMipView(mm, j, l));
    }
  }
}

// Y-map: the front owns the levels; the kernels fill and read them.
struct YMap {
  int height = 0, width = 0, mip_levels = 0;
  std::vector<std::vector<float>> nbuf;  // N-buffer levels of the coarse image
  int ch = 0, cw = 0;
};

}  // namespace

static void BindDepthWarp(py::module_& m) {
  m.def(
      "dw_motion",
      [](py::handle layers, const Camera& src, const Camera& dst, py::handle ids, py::handle motion, py::handle out,
         bool simd) {
        MotionInputs in = CheckMotionInputs(layers, src, dst, ids, motion);
        return ComputeMotion(in, src, dst, out, simd);
      },
      py::arg("layers"), py::arg("src"), py::arg("dst"), py::arg("object_ids") = py::none(),
      py::arg("object_motion") = py::none(), py::arg("out") = py::none(), py::arg("simd") = true,
      "Exact motion buffers (cpp/kernels/depthwarp/depthwarp.h DepthWarpMotion) of layers float32 (L, H, W) z in "
      "src (0 = empty) into dst: float32 (L, H, W, 4) = (mx, my, z_dst, 0); z_dst = 0 marks invalid pixels. "
      "object_ids int32 (L, H, W) in -1..K-1 with object_motion float64 (K, 4, 4) new_world_from_old_world. "
      "out: an existing writeable float32 (L, H, W, 4) array to fill (and return) instead of a new one. "
      "simd=False: the scalar loop for every pixel (the same bits as the default SSE2 path; for tests).");

  py::class_<MotionMips>(m, "DepthWarpMips", "Min-max motion mipmaps of each layer (dw_build_mips).")
      .def_readonly("num_layers", &MotionMips::num_layers)
      .def_property_readonly("axes", [](const MotionMips& mm) {
        std::vector<std::string> out;
        for (int a : mm.axes) out.push_back(AxesName(a));
        return out;
      })
      .def("rotation", [](const MotionMips& mm, int layer) {
        if (layer < 0 || layer >= mm.num_layers) throw BadValueError("layer: out of range");
        DoubleArray r = NewArray<double>({2, 2});
        for (int i = 0; i < 4; ++i) r.mutable_data()[i] = mm.rot[layer][i];
        return r;
      }, py::arg("layer"), "u = R v: the 2x2 rotation of the layer's bound axes.")
      .def("num_levels", [](const MotionMips& mm, int layer) {
        if (layer < 0 || layer >= mm.num_layers) throw BadValueError("layer: out of range");
        return static_cast<int>(mm.levels[layer].size());
      }, py::arg("layer"))
      .def("level", [](const MotionMips& mm, int layer, int level) {
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
        if (pca_grid < 2 || pca_grid > 1024) throw BadValueError("pca_grid: expected 2..1024, got " + std::to_string(pca_grid));
        const int nl = static_cast<int>(packed.shape(0)), hh = static_cast<int>(packed.shape(1)),
                  ww = static_cast<int>(packed.shape(2));
        py::object result = PrepareMips(reuse, nl, hh, ww);
        MotionMips& mm = result.cast<MotionMips&>();
        const std::int64_t plane = std::int64_t(hh) * ww * 4;
        const float* pd = packed.data();
        {
          py::gil_scoped_release release;
          for (int j = 0; j < nl; ++j) {
            ImageView<const float> pv(pd + j * plane, hh, ww, 4);
            mm.axes[j] = static_cast<int>(DepthWarpChooseAxes(pv, oriented, pca_grid, mm.rot[j].data()));
            FillMips(mm, j, pv, 1);
          }
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
        MotionInputs in = CheckMotionInputs(layers, src, dst, ids, motion);
        if (pca_grid < 2 || pca_grid > 1024) throw BadValueError("pca_grid: expected 2..1024, got " + std::to_string(pca_grid));
        FloatArray packed = MotionOutput(in, out);
        py::object result = PrepareMips(reuse, in.num_layers, in.height, in.width);
        MotionMips& mm = result.cast<MotionMips&>();
        DepthWarpMover mover{&src, &dst, in.dst_from_src.data(), in.num_motions};
        const std::int64_t plane = std::int64_t(in.height) * in.width;
        float* pd = packed.mutable_data();
        double motion_ms = 0, mipmap_ms = 0;
        {
          py::gil_scoped_release release;
          for (int j = 0; j < in.num_layers; ++j) {
            ImageView<const float> d(in.layers.data() + j * plane, in.height, in.width);
            ImageView<const std::int32_t> idv(in.has_ids ? in.ids.data() + j * plane : nullptr, in.height, in.width);
            const ImageView<const std::int32_t>* idp = in.has_ids ? &idv : nullptr;
            ImageView<float> pv(pd + j * plane * 4, in.height, in.width, 4);
            const ImageView<const float> pcv(pv.data, in.height, in.width, 4);
            auto t0 = std::chrono::steady_clock::now();
            std::size_t first = 1;
            if (!oriented && !mm.levels[j].empty()) {
              // Axis-aligned bounds: level 1 is built in the motion pass (same results, one pass).
              mm.rot[j] = {1.0f, 0.0f, 0.0f, 1.0f};
              mm.axes[j] = static_cast<int>(DepthWarpAxes::kAxisAligned);
              DepthWarpMotionMipLevel1(d, idp, mover, pv, MipView(mm, j, 0), ZMipView(mm, j, 0));
              first = 2;
              motion_ms += MsSince(t0);
              t0 = std::chrono::steady_clock::now();
            } else {
              DepthWarpMotion(d, idp, mover, pv);
              motion_ms += MsSince(t0);
              t0 = std::chrono::steady_clock::now();
              mm.axes[j] = static_cast<int>(DepthWarpChooseAxes(pcv, oriented, pca_grid, mm.rot[j].data()));
            }
            FillMips(mm, j, pcv, first);
            mipmap_ms += MsSince(t0);
          }
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

  m.def(
      "dw_warp",
      [](py::handle packed_obj, const MotionMips& mm, int dst_height, int dst_width, int seeds, int iters,
         float threshold, bool tight, int steps, float early_exit, std::uint32_t seed, bool dilate,
         int dilate_min_neighbors, bool skip_farther, int tile, bool pixel_step, py::handle seen_src,
         py::handle seen_dst, float edge_motion, py::handle surface_ids) {
        FloatArray packed = CheckPacked(packed_obj);
        if (packed.shape(0) != mm.num_layers || packed.shape(1) != mm.height || packed.shape(2) != mm.width) {
          throw ShapeError("mips: built for (" + std::to_string(mm.num_layers) + ", " + std::to_string(mm.height) +
                           ", " + std::to_string(mm.width) + ") but packed is " + DescribeShape(packed));
        }
        if (dst_height < 1 || dst_width < 1) throw BadValueError("dst size: expected >= 1x1");
        if (seeds < 1 || seeds > 4096) throw BadValueError("seeds: expected 1..4096, got " + std::to_string(seeds));
        if (iters < 0 || iters > 1000) throw BadValueError("iters: expected 0..1000, got " + std::to_string(iters));
        if (!(threshold > 0.0f) || !std::isfinite(threshold)) throw BadValueError("threshold: expected a finite number > 0");
        if (steps < 0 || steps > 64) throw BadValueError("steps: expected 0..64, got " + std::to_string(steps));
        if (!(early_exit >= 0.0f) || !std::isfinite(early_exit)) throw BadValueError("early_exit: expected a finite number >= 0");
        if (dilate_min_neighbors < 1 || dilate_min_neighbors > 8) {
          throw BadValueError("dilate_min_neighbors: expected 1..8, got " + std::to_string(dilate_min_neighbors));
        }
        const std::int64_t plane = std::int64_t(mm.height) * mm.width * 4;
        std::vector<std::vector<ImageView<const float>>> mip_views(mm.num_layers), zmip_views(mm.num_layers);
        std::vector<DepthWarpLayer> layers(mm.num_layers);
        for (int j = 0; j < mm.num_layers; ++j) {
          for (std::size_t l = 0; l < mm.levels[j].size(); ++l) {
            mip_views[j].emplace_back(mm.levels[j][l].data(), mm.dims[j][l].first, mm.dims[j][l].second, 4);
            zmip_views[j].emplace_back(mm.zlevels[j][l].data(), mm.dims[j][l].first, mm.dims[j][l].second);
          }
          layers[j].packed = ImageView<const float>(packed.data() + j * plane, mm.height, mm.width, 4);
          layers[j].mips = mip_views[j].data();
          layers[j].zmips = zmip_views[j].data();
          layers[j].n_mips = static_cast<int>(mip_views[j].size());
          for (int i = 0; i < 4; ++i) layers[j].rot[i] = mm.rot[j][i];
        }
        IntArray surface;
        const bool prove = !surface_ids.is_none();
        if (prove) {
          surface = CheckArray<std::int32_t>(surface_ids, "surface_ids",
                                             {{"L", mm.num_layers}, {"H", mm.height}, {"W", mm.width}});
          const std::int64_t ids_plane = std::int64_t(mm.height) * mm.width;
          for (int j = 0; j < mm.num_layers; ++j) {
            layers[j].surface = ImageView<const std::int32_t>(surface.data() + j * ids_plane, mm.height, mm.width);
          }
        }
        DepthWarpOptions opt;
        opt.seeds = seeds, opt.iters = iters, opt.threshold = threshold, opt.tight = tight, opt.steps = steps;
        opt.early_exit = early_exit, opt.seed = seed, opt.skip_farther = skip_farther;
        if (tile < 1 || tile > kDepthWarpMaxTile) {
          throw BadValueError("tile: expected 1.." + std::to_string(kDepthWarpMaxTile) + ", got " + std::to_string(tile));
        }
        opt.tile = tile, opt.pixel_step = pixel_step;
        if (!(edge_motion >= 0.0f) || !std::isfinite(edge_motion)) {
          throw BadValueError("edge_motion: expected a finite number >= 0 (0 = off)");
        }
        opt.edge_motion = edge_motion;
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
          CheckPinhole(src, "seen_src");
          CheckPinhole(dst, "seen_dst");
          if (src.width != mm.width || src.height != mm.height) {
            throw ShapeError("seen_src: camera is " + std::to_string(src.width) + "x" + std::to_string(src.height) +
                             " but the source layers are " + std::to_string(mm.width) + "x" + std::to_string(mm.height));
          }
          if (dst.width != dst_width || dst.height != dst_height) {
            throw ShapeError("seen_dst: camera size differs from dst_width x dst_height");
          }
          // src_from_dst = src.cam_from_world * dst.world_from_cam (rigid: world_from_cam = (R^T, -R^T t)).
          const glm::dmat3 r = src.rot * glm::transpose(dst.rot);
          const glm::dvec3 t = src.trans - r * dst.trans;
          for (int row = 0; row < 3; ++row) {
            for (int col = 0; col < 3; ++col) seen.src_from_dst[4 * row + col] = r[col][row];
            seen.src_from_dst[4 * row + 3] = t[row];
          }
          seen.dst_fx = dst.fx, seen.dst_fy = dst.fy, seen.dst_cx = dst.cx, seen.dst_cy = dst.cy;
          seen.src_fx = src.fx, seen.src_fy = src.fy, seen.src_cx = src.cx, seen.src_cy = src.cy;
          seen.src_width = src.width, seen.src_height = src.height;
          opt.seen = &seen;
        }
        FloatArray depth = NewArray<float>({dst_height, dst_width});
        py::array_t<std::int8_t, py::array::c_style> layer = NewArray<std::int8_t>({dst_height, dst_width});
        py::object occluder = py::none();
        FloatArray proven;
        if (prove) {
          proven = NewArray<float>({dst_height, dst_width});
          occluder = proven;
        }
        DepthWarpCounters counters;
        double warp_ms = 0, dilate_ms = 0;
        std::int64_t dilated = 0;
        {
          py::gil_scoped_release release;
          auto t0 = std::chrono::steady_clock::now();
          ImageView<float> dv(depth.mutable_data(), dst_height, dst_width);
          ImageView<std::int8_t> lv(layer.mutable_data(), dst_height, dst_width);
          ImageView<float> pv(prove ? proven.mutable_data() : nullptr, dst_height, dst_width);
          DepthWarpBackward(layers.data(), mm.num_layers, opt, dv, lv, &counters, prove ? &pv : nullptr);
          warp_ms = MsSince(t0);
          if (dilate) {
            t0 = std::chrono::steady_clock::now();
            // In place, from a per-thread copy of the layers kept between calls (no fresh pages per frame).
            static thread_local std::vector<std::int8_t> l_in;
            l_in.assign(lv.data, lv.data + lv.NumPixels());
            dilated = DepthWarpDilate(ImageView<const std::int8_t>(l_in.data(), dst_height, dst_width),
                                      dilate_min_neighbors, dv, lv);
            dilate_ms = MsSince(t0);
          }
        }
        py::dict c;
        c["converged"] = counters.converged;
        c["early_exit"] = counters.early_exit;
        c["searched"] = counters.searched;
        c["samples"] = counters.samples;
        c["lookups"] = counters.lookups;
        c["dilated"] = dilated;
        c["warp_ms"] = warp_ms;
        c["dilate_ms"] = dilate_ms;
        return py::make_tuple(depth, layer, c, occluder);
      },
      py::arg("packed"), py::arg("mips"), py::arg("dst_height"), py::arg("dst_width"), py::arg("seeds") = 16,
      py::arg("iters") = 3, py::arg("threshold") = 0.5f, py::arg("tight") = true, py::arg("steps") = 3,
      py::arg("early_exit") = 0.5f, py::arg("seed") = 0u, py::arg("dilate") = true,
      py::arg("dilate_min_neighbors") = 5, py::arg("skip_farther") = true, py::arg("tile") = 8,
      py::arg("pixel_step") = true, py::arg("seen_src") = py::none(), py::arg("seen_dst") = py::none(),
      py::arg("edge_motion") = 0.0f, py::arg("surface_ids") = py::none(),
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
        MotionInputs in = CheckMotionInputs(layers_obj, src, dst, ids, motion);
        auto t0 = std::chrono::steady_clock::now();
        FloatArray packed = ComputeMotion(in, src, dst, py::none());
        const double motion_ms = MsSince(t0);
        const int dh = dst.height, dw = dst.width;
        FloatArray depth = NewArray<float>({dh, dw});
        py::array_t<std::int8_t, py::array::c_style> layer = NewArray<std::int8_t>({dh, dw});
        double warp_ms = 0;
        {
          py::gil_scoped_release release;
          t0 = std::chrono::steady_clock::now();
          std::vector<std::uint64_t> key(std::size_t(dh) * dw, ~std::uint64_t(0));
          ImageView<std::uint64_t> kv(key.data(), dh, dw);
          DepthWarpMover mover{&src, &dst, in.dst_from_src.data(), in.num_motions};
          const std::int64_t plane = std::int64_t(in.height) * in.width;
          for (int j = 0; j < in.num_layers; ++j) {
            ImageView<const float> d(in.layers.data() + j * plane, in.height, in.width);
            ImageView<const std::int32_t> idv(in.has_ids ? in.ids.data() + j * plane : nullptr, in.height, in.width);
            ImageView<const float> pv(packed.data() + j * plane * 4, in.height, in.width, 4);
            DepthWarpForward(k, d, in.has_ids ? &idv : nullptr, pv, mover, j, kv);
          }
          DepthWarpDecodeKeys(ImageView<const std::uint64_t>(key.data(), dh, dw),
                              ImageView<float>(depth.mutable_data(), dh, dw),
                              ImageView<std::int8_t>(layer.mutable_data(), dh, dw));
          warp_ms = MsSince(t0);
        }
        return py::make_tuple(depth, layer, motion_ms, warp_ms);
      },
      py::arg("layers"), py::arg("src"), py::arg("dst"), py::arg("object_ids") = py::none(),
      py::arg("object_motion") = py::none(), py::arg("kind") = "vfw",
      "Forward depth warp baselines (DepthWarpForward, 'vfw' quad splats / 'afw' atomic-min points, both "
      "with the half-pixel support expansion): (depth (H', W') float32, layer int8, motion_ms, warp_ms).");

  py::class_<YMap>(m, "YMap", "Y-map of a depth buffer for conservative max-depth queries (cpp/kernels/depthwarp/nbuffer.h).")
      .def(py::init([](py::handle depth_obj, int mip_levels) {
             FloatArray depth = CheckArray<float>(depth_obj, "depth", {{"H", -1}, {"W", -1}});
             const int h = static_cast<int>(depth.shape(0)), w = static_cast<int>(depth.shape(1));
             if (h < 1 || w < 1) throw ShapeError("depth: expected at least 1x1 pixels, got " + DescribeShape(depth));
             if (mip_levels < 0 || mip_levels > 8) {
               throw BadValueError("mip_levels: expected 0..8, got " + std::to_string(mip_levels));
             }
             std::int64_t neg = 0;
             if (CountNonFinite(depth.data(), std::int64_t(h) * w, true, true, &neg)) {
               throw BadValueError("depth: contains NaN (set holes to the far depth, or +inf, before building)");
             }
             YMap y;
             y.height = h, y.width = w, y.mip_levels = mip_levels;
             py::gil_scoped_release release;
             std::vector<float> cur(depth.data(), depth.data() + std::int64_t(h) * w);
             int ch = h, cw = w;
             for (int l = 0; l < mip_levels; ++l) {
               const int nh = (ch + 1) / 2, nw = (cw + 1) / 2;
               std::vector<float> next(std::size_t(nh) * nw);
               MaxMipDown(ImageView<const float>(cur.data(), ch, cw), ImageView<float>(next.data(), nh, nw));
               cur.swap(next);
               ch = nh, cw = nw;
             }
             y.ch = ch, y.cw = cw;
             const int top = 31 - __builtin_clz(static_cast<unsigned>(std::min(ch, cw)));  // floor(log2 min)
             y.nbuf.push_back(std::move(cur));
             for (int l = 1; l <= top; ++l) {
               std::vector<float> next(std::size_t(ch) * cw);
               NBufferStep(ImageView<const float>(y.nbuf.back().data(), ch, cw), 1 << (l - 1),
                           ImageView<float>(next.data(), ch, cw));
               y.nbuf.push_back(std::move(next));
             }
             return y;
           }),
           py::arg("depth"), py::arg("mip_levels") = 2)
      .def_readonly("height", &YMap::height)
      .def_readonly("width", &YMap::width)
      .def_readonly("mip_levels", &YMap::mip_levels)
      .def_property_readonly("num_nbuffer_levels", [](const YMap& y) { return static_cast<int>(y.nbuf.size()); })
      .def("max_depth", [](const YMap& y, py::handle boxes_obj) {
             IntArray boxes = CheckArray<std::int32_t>(boxes_obj, "boxes", {{"K", -1}, {"4", 4}});
             const py::ssize_t k = boxes.shape(0);
             FloatArray out = NewArray<float>({k});
             std::vector<ImageView<const float>> views;
             for (const auto& l : y.nbuf) views.emplace_back(l.data(), y.ch, y.cw);
             const std::int32_t* b = boxes.data();
             float* o = out.mutable_data();
             {
               py::gil_scoped_release release;
               NBufferQuery(views.data(), static_cast<int>(views.size()), y.mip_levels, y.height, y.width, b, k, o);
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
