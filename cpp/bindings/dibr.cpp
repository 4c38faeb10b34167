// Binding of depth-image-based rendering (cpp/kernels/dibr/forward_warp.h, cpp/kernels/dibr/blend.h):
// _core.WarpOptions, _core.DibrAccumulator (streaming warp + blend into one target camera)
// and _core.forward_warp (one view, per-view buffers); _core.warp_with_holes and _core.warp_flow
// (single-view warp with background-depth holes, dos Anjos et al. sec. 3.1). Thin: checks arrays (array.h),
// releases the GIL around the kernels, raises typed errors after them.
#include <chrono>
#include <cstdint>
#include <cstring>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "array.h"
#include "ibr/camera.h"
#include "ibr/errors.h"
#include "ibr/simd.h"
#include "kernels/dibr/blend.h"
#include "kernels/dibr/forward_warp.h"
#include "module.h"

namespace ibr::bind {
namespace {

const char* QualityName(WarpQuality q) {
  switch (q) {
    case WarpQuality::kSide: return "side";
    case WarpQuality::kShape: return "shape";
    case WarpQuality::kDepth: return "depth";
    case WarpQuality::kNormal: return "normal";
  }
  return "?";
}

WarpQuality ParseQuality(const std::string& s) {
  if (s == "side") return WarpQuality::kSide;
  if (s == "shape") return WarpQuality::kShape;
  if (s == "depth") return WarpQuality::kDepth;
  if (s == "normal") return WarpQuality::kNormal;
  throw BadValueError("quality: expected 'side', 'shape', 'depth' or 'normal', got '" + s + "'");
}

DepthTest ParseDepthTest(const std::string& s) {
  if (s == "combined") return DepthTest::kCombined;
  if (s == "nearest") return DepthTest::kNearest;
  throw BadValueError("depth_test: expected 'combined' or 'nearest', got '" + s + "'");
}

// Colour must be finite everywhere: a NaN or inf input colour would otherwise be blended into
// the output image (found by tests/test_stress.py; DESIGN.md: NaN never leaks into an output).
// A float is not finite when its exponent bits are all set; the integer OR-reduction vectorises
// (one pass over the colour, about a millisecond per 1080p view).
void ThrowBadColor(std::int64_t bad) {
  throw BadValueError("color: " + std::to_string(bad) + " values are NaN or infinite (expected finite colour)");
}

void CheckFiniteColor(const py::array_t<float, py::array::c_style>& color) {
  const float* p = color.data();
  const std::ptrdiff_t n = color.size();
  std::uint32_t any = 0;
  for (std::ptrdiff_t i = 0; i < n; ++i) {
    std::uint32_t u;
    std::memcpy(&u, p + i, sizeof u);
    any |= std::uint32_t((u & 0x7f800000u) == 0x7f800000u);
  }
  if (any) {
    std::ptrdiff_t bad = 0;
    for (std::ptrdiff_t i = 0; i < n; ++i) bad += !std::isfinite(p[i]);
    ThrowBadColor(bad);
  }
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

void CheckCounts(const WarpCounts& c) {
  if (c.bad_depths > 0) {
    throw BadValueError("depth: " + std::to_string(c.bad_depths) +
                        " values are NaN or negative (expected > 0, 0 = unknown, +inf = at infinity)");
  }
  if (c.valid_vertices == 0) throw BadValueError("depth: no valid depth (every value is 0 = unknown)");
}

float CheckStretch(float t) {
  if (!(t > 0.f) || std::isinf(t)) {
    throw BadValueError("stretch_threshold: expected a finite number of pixels > 0, got " + std::to_string(t));
  }
  return t;
}

float CheckJump(float j) {
  if (!(j >= 0.f) || std::isinf(j)) {
    throw BadValueError("depth_jump: expected a finite number >= 0 (0 = off), got " + std::to_string(j));
  }
  return j;
}

// (color, depth, mask) of the hole-mode warp; throws after the kernel for bad depth / flow.
py::tuple HoleResult(py::array_t<float> c, py::array_t<float> d, py::array_t<std::uint8_t> m, const WarpCounts& counts) {
  if (counts.bad_flow > 0) {
    throw BadValueError("flow: " + std::to_string(counts.bad_flow) + " vectors are not finite (NaN or inf)");
  }
  CheckCounts(counts);
  return py::make_tuple(c, d, m);
}

double MsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// The memory of a DibrAccumulator: the running sums of its target size (uninitialised: the sums
// start "fresh", blend.h, and the first view writes every pixel) and the warp's scratch.
struct AccumulatorStorage {
  std::size_t pixels = 0;
  std::unique_ptr<float[]> sum_wc, sum_w, sum_w_invd, sum_q, max_q;
  WarpScratch scratch;
};

// One spare storage, the last one a destroyed accumulator left: the renderer makes a new
// accumulator per frame (render/dibr.py), and 58 MB of new sums + 25 MB of new vertex scratch
// at 1080p cost page faults (the kernel zeroes every page on first touch) in each frame's first
// views -- about 20 ms of CPU per frame, measured (docs/dibr.md, "Speed"). A new accumulator of
// the same target size takes the spare (any bits in the sums are fine: they start fresh); one of
// another size frees it. So at most one unused set (83 MB at 1080p) stays allocated.
std::mutex g_spare_mutex;
std::unique_ptr<AccumulatorStorage> g_spare;

std::unique_ptr<AccumulatorStorage> TakeStorage(std::size_t n) {
  std::unique_ptr<AccumulatorStorage> s;
  {
    std::lock_guard<std::mutex> lock(g_spare_mutex);
    s = std::move(g_spare);
  }
  if (s && s->pixels == n) return s;
  s.reset();  // another size: free it before allocating
  s = std::make_unique<AccumulatorStorage>();
  s->pixels = n;
  s->sum_wc.reset(new float[3 * n]);
  s->sum_w.reset(new float[n]);
  s->sum_w_invd.reset(new float[n]);
  s->sum_q.reset(new float[n]);
  s->max_q.reset(new float[n]);
  return s;
}

void ReturnStorage(std::unique_ptr<AccumulatorStorage> s) {
  std::unique_ptr<AccumulatorStorage> old;
  std::lock_guard<std::mutex> lock(g_spare_mutex);
  old = std::move(g_spare);  // freed after the lock is released (declared before the guard)
  g_spare = std::move(s);
}

class DibrAccumulator {
 public:
  DibrAccumulator(const Camera& target, float stretched_quality, bool stretched_holes, float depth_tolerance)
      : target_(target) {
    if (!(stretched_quality >= 0.f && stretched_quality <= 1.f)) {
      throw BadValueError("stretched_quality: expected a number in [0, 1], got " + std::to_string(stretched_quality));
    }
    if (!(depth_tolerance >= 0.f && depth_tolerance < 1.f)) {
      throw BadValueError("depth_tolerance: expected a number in [0, 1), got " + std::to_string(depth_tolerance));
    }
    if (stretched_holes && stretched_quality == 0.f) {
      throw BadValueError("stretched_holes: needs stretched_quality > 0 to say which fragments are stretched");
    }
    // Not cleared: the sums start "fresh" (blend.h), the first view writes them.
    storage_ = TakeStorage(std::size_t(target.width) * target.height);
    buffers_.stretched_quality = stretched_quality;
    buffers_.stretched_holes = stretched_holes;
    buffers_.depth_tolerance = depth_tolerance;
    Buffers();
  }

  ~DibrAccumulator() {
    if (storage_) ReturnStorage(std::move(storage_));
  }
  DibrAccumulator(const DibrAccumulator&) = delete;
  DibrAccumulator& operator=(const DibrAccumulator&) = delete;

  void AddView(const py::object& color_obj, const py::object& depth_obj, const Camera& camera,
               const WarpOptions& options) {
    // The colour's finiteness is counted by the kernel, in its parallel projection pass.
    InputView in = CheckInput(color_obj, depth_obj, camera, false);
    const ImageView<const float> color = ConstViewOf(in.color), depth = ConstViewOf(in.depth);
    WarpCounts counts;
    {
      py::gil_scoped_release release;
      const auto t0 = std::chrono::steady_clock::now();
      // The kernel adds the view to the sums only when its colour and depth passed the checks
      // below. Band-local mode (forward_warp.h): no per-view full-size buffers.
      counts = ForwardWarp(color, depth, camera, target_, options, storage_->scratch, ImageView<float>(), ImageView<float>(),
                           ImageView<float>(), nullptr, &buffers_, true);
      if (counts.bad_depths == 0 && counts.valid_vertices > 0 && counts.bad_colors == 0) {
        ++num_views_;
        buffers_.fresh = false;  // the view wrote every pixel's sums
      }
      last_ms_ = MsSince(t0);
    }
    if (counts.bad_colors > 0) ThrowBadColor(counts.bad_colors);
    CheckCounts(counts);
  }

  // srgb_to_linear: the views' colours were sRGB encodings (render/dibr.py, blend_space "srgb");
  // the resolve decodes the blended colour row by row (blend.h BlendSpace::kSrgb).
  py::tuple Result(bool srgb_to_linear) {
    const py::ssize_t h = target_.height, w = target_.width;
    auto color = NewArray<float>({h, w, 3});
    auto depth = NewArray<float>({h, w});
    auto conf = NewArray<float>({h, w});
    auto hole = NewArray<bool>({h, w});
    float *c = color.mutable_data(), *d = depth.mutable_data(), *q = conf.mutable_data();
    auto* o = reinterpret_cast<std::uint8_t*>(hole.mutable_data());
    {
      py::gil_scoped_release release;
      if (buffers_.fresh) {  // no view since reset(): empty sums
        ClearBlend(buffers_);
        buffers_.fresh = false;
      }
      ResolveBlend(buffers_, c, d, q, o, UseAvx2(),
                   srgb_to_linear ? BlendSpace::kSrgb : BlendSpace::kLinear);
    }
    return py::make_tuple(color, depth, conf, hole);
  }

  // The next view writes the sums instead of adding to them (BlendBuffers::fresh): no clearing pass.
  void Reset() {
    buffers_.fresh = true;
    num_views_ = 0;
  }

  int NumViews() const { return num_views_; }
  double LastMs() const { return last_ms_; }
  const Camera& Target() const { return target_; }

 private:
  void Buffers() {
    buffers_.height = target_.height;
    buffers_.width = target_.width;
    buffers_.sum_wc = storage_->sum_wc.get();
    buffers_.sum_w = storage_->sum_w.get();
    buffers_.sum_w_invd = storage_->sum_w_invd.get();
    buffers_.sum_q = storage_->sum_q.get();
    buffers_.max_q = storage_->max_q.get();
    buffers_.fresh = true;
  }

  Camera target_;
  std::unique_ptr<AccumulatorStorage> storage_;  // sums (uninitialised: fresh) and scratch
  BlendBuffers buffers_;
  int num_views_ = 0;
  double last_ms_ = 0.0;
};

}  // namespace

void BindDibr(py::module_& m) {
  py::class_<WarpOptions>(m, "WarpOptions",
                          "Options of the forward mesh warp (cpp/kernels/dibr/forward_warp.h); defaults: RVS 4.0.")
      .def(py::init<>())
      .def_property(
          "quality", [](const WarpOptions& o) { return std::string(QualityName(o.quality)); },
          [](WarpOptions& o, const std::string& s) { o.quality = ParseQuality(s); },
          "Triangle quality (paper Table 1): 'side' (default, RVS), 'shape', 'depth', 'normal'.")
      .def_property(
          "side_threshold", [](const WarpOptions& o) { return o.side_threshold; },
          [](WarpOptions& o, float t) {
            if (!(t >= 0.f) || std::isinf(t)) throw BadValueError("side_threshold: expected a finite value >= 0 (0 = auto)");
            o.side_threshold = t;
          },
          "T in target pixels; 0 = auto: max(4, 10 * sqrt(W * H / (1920 * 1080))).")
      .def_property(
          "blend_exponent", [](const WarpOptions& o) { return o.blend_exponent; },
          [](WarpOptions& o, float p) {
            if (!(p >= 0.f && p <= 16.f)) throw BadValueError("blend_exponent: expected a value in [0, 16]");
            o.blend_exponent = p;
          },
          "p in the blending weight (q / d)^p; RVS uses 5, the paper's Eq. 2 is q / d^3.")
      .def_property(
          "depth_test",
          [](const WarpOptions& o) { return std::string(o.depth_test == DepthTest::kCombined ? "combined" : "nearest"); },
          [](WarpOptions& o, const std::string& s) { o.depth_test = ParseDepthTest(s); },
          "'combined' (paper Eq. 2: largest q / d^3 wins) or 'nearest' (plain z-buffer).")
      .def_readwrite("discard_stretched", &WarpOptions::discard_stretched,
                     "Drop triangles whose quality reaches 0 (paper Eq. 1) instead of flooring it (RVS).")
      .def_property(
          "view_weight", [](const WarpOptions& o) { return o.view_weight; },
          [](WarpOptions& o, float v) {
            if (!(v >= 1e-6f && v <= 1.f)) throw BadValueError("view_weight: expected a value in [1e-6, 1]");
            o.view_weight = v;
          },
          "Per-view factor on every fragment weight, w = view_weight * (q / d)^p, in [1e-6, 1]; 1 = RVS.")
      .def("effective_side_threshold", [](const WarpOptions& o, const Camera& t) { return SideThreshold(o, t); },
           py::arg("target_camera"), "T used for this target camera.")
      .def("__repr__", [](const WarpOptions& o) {
        return "WarpOptions(quality='" + std::string(QualityName(o.quality)) +
               "', side_threshold=" + std::to_string(o.side_threshold) +
               ", blend_exponent=" + std::to_string(o.blend_exponent) + ", depth_test='" +
               (o.depth_test == DepthTest::kCombined ? "combined" : "nearest") +
               "', discard_stretched=" + (o.discard_stretched ? "True" : "False") + ")";
      });

  py::class_<DibrAccumulator>(m, "DibrAccumulator",
                              "Streaming DIBR into one target camera: add_view warps a colour + depth view and "
                              "adds it to running sums (constant memory); result() blends (paper Eq. 3).")
      .def(py::init<const Camera&, float, bool, float>(), py::arg("target_camera"),
           py::arg("stretched_quality") = 0.f, py::arg("stretched_holes") = false, py::arg("depth_tolerance") = 0.f,
           "Visibility across views (cpp/kernels/dibr/blend.h; all off = RVS): stretched_quality in [0, 1] "
           "(fragments with q below it are stretched: never mixed into unstretched content), "
           "stretched_holes (pixels only stretched fragments cover become holes), depth_tolerance "
           "(relative: a nearer fragment replaces the sums, a farther one is dropped).")
      .def("add_view", &DibrAccumulator::AddView, py::arg("color"), py::arg("depth"), py::arg("camera"),
           py::arg("options") = WarpOptions(),
           "color float32 (H, W, 3) linear, depth float32 (H, W) (pinhole: z, equirect: ray distance; 0 = "
           "unknown, +inf = at infinity), camera: _core.Camera of size W x H. GIL released.")
      .def("result", &DibrAccumulator::Result, py::arg("srgb_to_linear") = false,
           "(color (H, W, 3) f32, depth (H, W) f32 (0 in holes), confidence (H, W) f32 = sum over views of "
           "the kept triangle quality in (0, 1], hole (H, W) bool). srgb_to_linear: the added colours were "
           "sRGB encodings (blend space 'srgb'); the blended colour is decoded inside the resolve with the "
           "curve of _core.srgb_to_linear (read from a table of it in [0, 1]: within 1e-6 of srgb_to_linear of "
           "result()'s colour; holes stay 0). GIL released.")
      .def("reset", &DibrAccumulator::Reset, "Forget every view added.")
      .def_property_readonly("num_views", &DibrAccumulator::NumViews)
      .def_property_readonly("last_add_ms", &DibrAccumulator::LastMs,
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
        CheckCounts(counts);
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

  m.attr("WARP_SURFACE") = int(kMaskSurface);
  m.attr("WARP_DISOCCLUDED") = int(kMaskDisoccluded);
  m.attr("WARP_UNCOVERED") = int(kMaskUncovered);
  m.def(
      "warp_with_holes",
      [](const py::object& color_obj, const py::object& depth_obj, const Camera& camera, const Camera& target,
         float stretch_threshold, float depth_jump) {
        HoleWarpOptions options;
        options.stretch_threshold = CheckStretch(stretch_threshold);
        options.depth_jump = CheckJump(depth_jump);
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
        return HoleResult(c, d, mk, counts);
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
        options.stretch_threshold = CheckStretch(stretch_threshold);
        options.depth_jump = CheckJump(depth_jump);
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
        return HoleResult(c, d, mk, counts);
      },
      py::arg("color"), py::arg("depth"), py::arg("flow"), py::arg("stretch_threshold") = kDefaultStretchThreshold,
      py::arg("depth_jump") = kDefaultDepthJump,
      "Warp one RGB-D image by a per-pixel motion field with background-depth holes (forward_warp.h, "
      "flow form): flow float32 (H, W, 2) = target - source position in pixels (x, y); depth orders "
      "the fragments (larger = farther; 0 = unknown). Returns (color, depth, mask) as warp_with_holes, "
      "of the input's size. GIL released.");
}

}  // namespace ibr::bind
