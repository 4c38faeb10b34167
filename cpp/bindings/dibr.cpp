// Binding of depth-image-based rendering (cpp/kernels/dibr/forward_warp.h, cpp/kernels/dibr/blend.h):
// _core.WarpOptions, _core.DibrAccumulator (streaming warp + blend into one target camera)
// and _core.forward_warp (one view, per-view buffers); _core.warp_with_holes and _core.warp_flow
// (single-view warp with background-depth holes, dos Anjos et al. sec. 3.1). Thin: checks arrays (array.h),
// calls the kernels and the front (cpp/kernels/dibr/front.h: value checks, the accumulator and its
// storage pool) with the GIL released.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "array.h"
#include "ibr/camera.h"
#include "ibr/errors.h"
#include "ibr/simd.h"
#include "kernels/dibr/blend.h"
#include "kernels/dibr/depth_stats.h"
#include "kernels/dibr/forward_warp.h"
#include "kernels/dibr/front.h"
#include "module.h"

namespace ibr::bind {
namespace {

void CheckFiniteColor(const py::array_t<float, py::array::c_style>& color) {
  const float* p = color.data();
  const std::int64_t n = color.size();
  py::gil_scoped_release release;
  DibrCheckFiniteColor(p, n);
}

// A checked input view: colour (H, W, 3), depth (H, W) with (H, W) = the camera's size.
struct InputView {
  py::array_t<float, py::array::c_style> color, depth;
};

// finite_color: also check that the colour is finite here (false: the kernel counts it,
// WarpCounts::bad_colors, and the caller raises after it).
InputView CheckInput(const py::handle& color_obj, const py::handle& depth_obj, const Camera& camera,
                     bool finite_color = true) {
  InputView v;
  v.depth = CheckArray<float>(depth_obj, "depth", {{"H", camera.height}, {"W", camera.width}});
  v.color = CheckArray<float>(color_obj, "color", {{"H", camera.height}, {"W", camera.width}, {"3", 3}});
  if (finite_color) CheckFiniteColor(v.color);
  if (camera.height < 2 || camera.width < 2) {
    throw ShapeError("depth: the view must be at least 2 x 2 pixels to form triangles, got " +
                     std::to_string(camera.height) + " x " + std::to_string(camera.width));
  }
  return v;
}

}  // namespace

void BindDibr(py::module_& m) {
  py::class_<WarpOptions>(m, "WarpOptions",
                          "Options of the forward mesh warp (cpp/kernels/dibr/forward_warp.h); defaults: RVS 4.0.")
      .def(py::init<>())
      .def_property(
          "quality", [](const WarpOptions& o) { return std::string(WarpQualityName(o.quality)); },
          [](WarpOptions& o, const std::string& s) { o.quality = WarpQualityFromName(s); },
          "Triangle quality (paper Table 1): 'side' (default, RVS), 'shape', 'depth', 'normal'.")
      .def_property(
          "side_threshold", [](const WarpOptions& o) { return o.side_threshold; },
          [](WarpOptions& o, float t) {
            WarpOptions checked = o;
            checked.side_threshold = t;
            DibrCheckWarpOptions(checked);
            o = checked;
          },
          "T in target pixels; 0 = auto: max(4, 10 * sqrt(W * H / (1920 * 1080))).")
      .def_property(
          "blend_exponent", [](const WarpOptions& o) { return o.blend_exponent; },
          [](WarpOptions& o, float p) {
            WarpOptions checked = o;
            checked.blend_exponent = p;
            DibrCheckWarpOptions(checked);
            o = checked;
          },
          "p in the blending weight (q / d)^p; RVS uses 5, the paper's Eq. 2 is q / d^3.")
      .def_property(
          "depth_test",
          [](const WarpOptions& o) { return std::string(DepthTestName(o.depth_test)); },
          [](WarpOptions& o, const std::string& s) { o.depth_test = DepthTestFromName(s); },
          "'combined' (paper Eq. 2: largest q / d^3 wins) or 'nearest' (plain z-buffer).")
      .def_readwrite("discard_stretched", &WarpOptions::discard_stretched,
                     "Drop triangles whose quality reaches 0 (paper Eq. 1) instead of flooring it (RVS).")
      .def_property(
          "view_weight", [](const WarpOptions& o) { return o.view_weight; },
          [](WarpOptions& o, float v) {
            WarpOptions checked = o;
            checked.view_weight = v;
            DibrCheckWarpOptions(checked);
            o = checked;
          },
          "Per-view factor on every fragment weight, w = view_weight * (q / d)^p, in [1e-6, 1]; 1 = RVS.")
      .def("effective_side_threshold", [](const WarpOptions& o, const Camera& t) { return SideThreshold(o, t); },
           py::arg("target_camera"), "T used for this target camera.")
      .def("__repr__", [](const WarpOptions& o) {
        return "WarpOptions(quality='" + std::string(WarpQualityName(o.quality)) +
               "', side_threshold=" + std::to_string(o.side_threshold) +
               ", blend_exponent=" + std::to_string(o.blend_exponent) + ", depth_test='" +
               DepthTestName(o.depth_test) +
               "', discard_stretched=" + (o.discard_stretched ? "True" : "False") + ")";
      });

  const DibrAccumulatorOptions kAccumulator;  // the defaults of DibrAccumulator's arguments
  py::class_<DibrAccumulator>(m, "DibrAccumulator",
                              "Streaming DIBR into one target camera: add_view warps a colour + depth view and "
                              "adds it to running sums (constant memory); result() blends (paper Eq. 3).")
      .def(py::init([](const Camera& target, float stretched_quality, bool stretched_holes, float depth_tolerance) {
             DibrAccumulatorOptions o;
             o.stretched_quality = stretched_quality;
             o.stretched_holes = stretched_holes;
             o.depth_tolerance = depth_tolerance;
             return std::make_unique<DibrAccumulator>(target, o);
           }),
           py::arg("target_camera"), py::arg("stretched_quality") = kAccumulator.stretched_quality,
           py::arg("stretched_holes") = kAccumulator.stretched_holes,
           py::arg("depth_tolerance") = kAccumulator.depth_tolerance,
           "Visibility across views (cpp/kernels/dibr/blend.h; all off = RVS): stretched_quality in [0, 1] "
           "(fragments with q below it are stretched: never mixed into unstretched content), "
           "stretched_holes (pixels only stretched fragments cover become holes), depth_tolerance "
           "(relative: a nearer fragment replaces the sums, a farther one is dropped).")
      .def("add_view",
           [](DibrAccumulator& acc, const py::object& color_obj, const py::object& depth_obj, const Camera& camera,
              const WarpOptions& options) {
             // The colour's finiteness is counted by the kernel, in its parallel projection pass.
             InputView in = CheckInput(color_obj, depth_obj, camera, false);
             const ImageView<const float> color = ConstViewOf(in.color), depth = ConstViewOf(in.depth);
             py::gil_scoped_release release;
             acc.AddView(color, depth, camera, options);
           },
           py::arg("color"), py::arg("depth"), py::arg("camera"),
           py::arg("options") = WarpOptions(),
           "color float32 (H, W, 3) linear, depth float32 (H, W) (pinhole: z, equirect: ray distance; 0 = "
           "unknown, +inf = at infinity), camera: _core.Camera of size W x H. GIL released.")
      .def("result",
           [](DibrAccumulator& acc, bool srgb_to_linear) {
             const py::ssize_t h = acc.target().height, w = acc.target().width;
             auto color = NewArray<float>({h, w, 3});
             auto depth = NewArray<float>({h, w});
             auto conf = NewArray<float>({h, w});
             auto hole = NewArray<bool>({h, w});
             float *c = color.mutable_data(), *d = depth.mutable_data(), *q = conf.mutable_data();
             auto* o = reinterpret_cast<std::uint8_t*>(hole.mutable_data());
             {
               py::gil_scoped_release release;
               acc.Resolve(c, d, q, o, srgb_to_linear);
             }
             return py::make_tuple(color, depth, conf, hole);
           },
           py::arg("srgb_to_linear") = false,
           "(color (H, W, 3) f32, depth (H, W) f32 (0 in holes), confidence (H, W) f32 = sum over views of "
           "the kept triangle quality in (0, 1], hole (H, W) bool). srgb_to_linear: the added colours were "
           "sRGB encodings (blend space 'srgb'); the blended colour is decoded inside the resolve with the "
           "curve of _core.srgb_to_linear (read from a table of it in [0, 1]: within 1e-6 of srgb_to_linear of "
           "result()'s colour; holes stay 0). GIL released.")
      .def("reset", &DibrAccumulator::Reset, "Forget every view added.")
      .def_property_readonly("num_views", &DibrAccumulator::num_views)
      .def_property_readonly("last_add_ms", &DibrAccumulator::last_add_ms,
                             "Wall time of the last add_view's warp + accumulation (checks excluded), ms.");

  m.def(
      "forward_warp",
      [](const py::object& color_obj, const py::object& depth_obj, const Camera& camera, const Camera& target,
         const WarpOptions& options) {
        InputView in = CheckInput(color_obj, depth_obj, camera);
        const ImageView<const float> color = ConstViewOf(in.color), depth = ConstViewOf(in.depth);
        const py::ssize_t th = target.height, tw = target.width;
        auto c = NewArray<float>({th, tw, 3});
        auto d = NewArray<float>({th, tw});
        auto w = NewArray<float>({th, tw});
        std::vector<float> quality(std::size_t(th) * tw);
        WarpScratch scratch;
        ImageView<float> cv(c.mutable_data(), int(th), int(tw), 3), dv(d.mutable_data(), int(th), int(tw)),
            wv(w.mutable_data(), int(th), int(tw));
        WarpCounts counts;
        {
          py::gil_scoped_release release;
          counts = ForwardWarp(color, depth, camera, target, options, scratch, cv, dv, wv, quality.data(), nullptr);
        }
        DibrCheckCounts(counts);
        return py::make_tuple(c, d, w);
      },
      py::arg("color"), py::arg("depth"), py::arg("camera"), py::arg("target_camera"),
      py::arg("options") = WarpOptions(),
      "Warp one view: (color (Ht, Wt, 3), depth (Ht, Wt) (0 = not covered), weight (Ht, Wt) = (q / d)^p "
      "(0 = not covered)). GIL released.");

  m.def(
      "set_warp_isa",
      [](const std::string& name) {
        Isa isa;
        if (name == "auto") {
          isa = Isa::kAuto;
        } else if (name == "baseline") {
          isa = Isa::kBaseline;
        } else if (name == "avx2") {
          isa = Isa::kAvx2;
        } else {
          throw BadValueError("isa: expected 'auto', 'baseline' or 'avx2', got '" + name + "'");
        }
        if (!SetIsa(isa)) throw BadValueError("isa: 'avx2' asked but this CPU has no AVX2");
      },
      py::arg("isa"),
      "Instruction set of the engine's plain hot loops (process-wide; for tests and benchmarks): the forward "
      "warp's, the G-buffer raster's, the PVM renderer's voxel lookup, depth pass and filter, the hybrid's "
      "selection blur and ulr_blend(simd='auto') (cpp/ibr/simd.h). "
      "'auto' (default: AVX2 clones when the CPU has AVX2), 'baseline' (SSE2) or 'avx2'. Results are identical.");
  m.def(
      "warp_isa", [] { return std::string(UseAvx2() ? "avx2" : "baseline"); },
      "Instruction set the engine's plain hot loops (set_warp_isa) use now: 'avx2' or 'baseline'.");
  m.def("cpu_has_avx2", &CpuHasAvx2, "Whether this CPU has AVX2 (run-time check).");
  m.def(
      "valid_depth_order_stats",
      [](py::handle depth_obj, py::sequence quantiles_obj) {
        const auto depth = CheckArray<float>(depth_obj, "depth", {{"H", -1}, {"W", -1}});
        std::vector<double> quantiles;
        for (const py::handle q_obj : quantiles_obj) {
          const double q = q_obj.cast<double>();
          if (!(q >= 0.0 && q <= 1.0)) throw BadValueError("quantiles: expected values in [0, 1], got " + std::to_string(q));
          quantiles.push_back(q);
        }
        DepthOrderStats s;
        {
          py::gil_scoped_release release;
          s = ValidDepthOrderStats(depth.data(), depth.size(), quantiles);
        }
        py::list ranks, values;
        for (const std::int64_t r : s.ranks) ranks.append(r);
        for (const float v : s.values) values.append(v);
        return py::make_tuple(s.count, s.min, s.max, ranks, values);
      },
      py::arg("depth"), py::arg("quantiles"),
      "Order statistics of a depth map's valid values, finite and > 0 (cpp/kernels/dibr/depth_stats.h; Python: "
      "ibrtools.dibr.view_selection.depth_range): (count, min, max, ranks, values), per quantile q the two ranks "
      "numpy.quantile's linear method reads (floor((count - 1) q) and the next) and their values, exactly.");

  m.attr("WARP_SURFACE") = int(kMaskSurface);
  m.attr("WARP_DISOCCLUDED") = int(kMaskDisoccluded);
  m.attr("WARP_UNCOVERED") = int(kMaskUncovered);
  m.def(
      "warp_with_holes",
      [](const py::object& color_obj, const py::object& depth_obj, const Camera& camera, const Camera& target,
         float stretch_threshold, float depth_jump) {
        HoleWarpOptions options;
        options.stretch_threshold = stretch_threshold;
        options.depth_jump = depth_jump;
        DibrCheckHoleWarpOptions(options);
        InputView in = CheckInput(color_obj, depth_obj, camera);
        const ImageView<const float> color = ConstViewOf(in.color), depth = ConstViewOf(in.depth);
        const py::ssize_t th = target.height, tw = target.width;
        auto c = NewArray<float>({th, tw, 3});
        auto d = NewArray<float>({th, tw});
        auto mk = NewArray<std::uint8_t>({th, tw});
        ImageView<float> cv(c.mutable_data(), int(th), int(tw), 3), dv(d.mutable_data(), int(th), int(tw));
        std::uint8_t* mp = mk.mutable_data();
        WarpCounts counts;
        {
          py::gil_scoped_release release;
          WarpScratch scratch;
          counts = WarpWithHoles(color, depth, camera, target, options, scratch, cv, dv, mp);
        }
        DibrCheckHoleCounts(counts);
        return py::make_tuple(c, d, mk);
      },
      py::arg("color"), py::arg("depth"), py::arg("camera"), py::arg("target_camera"),
      py::arg("stretch_threshold") = kDefaultStretchThreshold, py::arg("depth_jump") = kDefaultDepthJump,
      "Warp one RGB-D view into target_camera with background-depth holes (dos Anjos et al. sec. 3.1, "
      "Eq. 1; cpp/kernels/dibr/forward_warp.h). color float32 (H, W, 3), depth float32 (H, W) (pinhole: z, "
      "equirect: ray distance; 0 = unknown, +inf = at infinity). Quads whose longest target edge exceeds "
      "stretch_threshold pixels and whose corner depths differ by more than a factor 1 + depth_jump (0 = "
      "stretch only) are stretched. Returns (color (Ht, Wt, 3) (0 in holes), depth (Ht, Wt) "
      "(surface depth; background depth in disocclusions; 0 where nothing lands), mask (Ht, Wt) uint8: "
      "WARP_SURFACE 0, WARP_DISOCCLUDED 1, WARP_UNCOVERED 2). GIL released.");
  m.def(
      "warp_flow",
      [](const py::object& color_obj, const py::object& depth_obj, const py::object& flow_obj,
         float stretch_threshold, float depth_jump) {
        HoleWarpOptions options;
        options.stretch_threshold = stretch_threshold;
        options.depth_jump = depth_jump;
        DibrCheckHoleWarpOptions(options);
        auto depth_arr = CheckArray<float>(depth_obj, "depth", {{"H", -1}, {"W", -1}});
        const int h = int(depth_arr.shape(0)), w = int(depth_arr.shape(1));
        auto color_arr = CheckArray<float>(color_obj, "color", {{"H", h}, {"W", w}, {"3", 3}});
        CheckFiniteColor(color_arr);
        auto flow_arr = CheckArray<float>(flow_obj, "flow", {{"H", h}, {"W", w}, {"2", 2}});
        if (h < 2 || w < 2) {
          throw ShapeError("depth: the view must be at least 2 x 2 pixels to form triangles, got " +
                           std::to_string(h) + " x " + std::to_string(w));
        }
        const ImageView<const float> color = ConstViewOf(color_arr), depth = ConstViewOf(depth_arr);
        const float* flow = flow_arr.data();
        auto c = NewArray<float>({h, w, 3});
        auto d = NewArray<float>({h, w});
        auto mk = NewArray<std::uint8_t>({h, w});
        ImageView<float> cv(c.mutable_data(), h, w, 3), dv(d.mutable_data(), h, w);
        std::uint8_t* mp = mk.mutable_data();
        WarpCounts counts;
        {
          py::gil_scoped_release release;
          WarpScratch scratch;
          counts = WarpFlowWithHoles(color, depth, flow, options, scratch, cv, dv, mp);
        }
        DibrCheckHoleCounts(counts);
        return py::make_tuple(c, d, mk);
      },
      py::arg("color"), py::arg("depth"), py::arg("flow"), py::arg("stretch_threshold") = kDefaultStretchThreshold,
      py::arg("depth_jump") = kDefaultDepthJump,
      "Warp one RGB-D image by a per-pixel motion field with background-depth holes (forward_warp.h, "
      "flow form): flow float32 (H, W, 2) = target - source position in pixels (x, y); depth orders "
      "the fragments (larger = farther; 0 = unknown). Returns (color, depth, mask) as warp_with_holes, "
      "of the input's size. GIL released.");
}

}  // namespace ibr::bind
