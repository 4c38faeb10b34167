// The inpaint family's bindings (dtypes, shapes, aliasing; the value checks are the front's,
// cpp/kernels/inpaint/front.h): push-pull hole filling (cpp/kernels/inpaint/pushpull.h), the
// per-sample passes of metameric inpainting (metameric.h) and the background lookup (background.h).
// Python: ibrtools.inpaint.pushpull, ibrtools.inpaint.metameric, ibrtools.inpaint.background.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "array.h"
#include "ibr/errors.h"
#include "kernels/inpaint/background.h"
#include "kernels/inpaint/clean.h"
#include "kernels/inpaint/front.h"
#include "kernels/inpaint/hole_sides.h"
#include "kernels/inpaint/metameric.h"
#include "kernels/inpaint/pushpull.h"
#include "module.h"

// The push-pull options of a binding's arguments, shared by ibrtools.inpaint.pushpull.pushpull
// (inpaint.cpp) and the moments push-pulls of metameric inpainting (metameric.cpp): depth None
// (classic push-pull) or float32 (h, w) (depth-aware, Alg. 1 of dos Anjos et al.), gamma and
// depth_threshold finite and >= 0; one-line errors naming the argument.
namespace ibr::bind {

// `depth` receives the checked depth array (kept alive by the caller) when depth_obj is not None.
inline PushPullOptions CheckPushPullArgs(py::handle depth_obj, py::ssize_t h, py::ssize_t w, double depth_threshold,
                                         double gamma, py::array_t<float, py::array::c_style>* depth) {
  const PushPullOptions options = InpaintPushPullOptions(!depth_obj.is_none(), depth_threshold, gamma);
  if (options.depth_aware) *depth = CheckArray<float>(depth_obj, "depth", {{"H", h}, {"W", w}});
  return options;
}

}  // namespace ibr::bind

// Bindings of cpp/kernels/inpaint/pushpull.h: the checking front (shapes, dtypes, finiteness outside the
// holes, options) and the call with the GIL released. Python: ibrtools.inpaint.pushpull.
namespace ibr::bind {
namespace {

using FloatArray = py::array_t<float, py::array::c_style>;

// A mask as one byte per pixel: bool or uint8 (non-zero = true), (H, W), C-contiguous.
ImageView<const std::uint8_t> MaskView(const py::handle& obj, const char* name, py::ssize_t h, py::ssize_t w,
                                       py::object* keep) {
  if (py::isinstance<py::array>(obj) &&
      py::reinterpret_borrow<py::array>(obj).dtype().equal(py::dtype::of<std::uint8_t>())) {
    auto a = CheckArray<std::uint8_t>(obj, name, {{"H", h}, {"W", w}});
    *keep = a;
    return ImageView<const std::uint8_t>(a.data(), static_cast<int>(h), static_cast<int>(w), 1);
  }
  auto a = CheckArray<bool>(obj, name, {{"H", h}, {"W", w}});
  *keep = a;
  return ImageView<const std::uint8_t>(reinterpret_cast<const std::uint8_t*>(a.data()), static_cast<int>(h),
                                       static_cast<int>(w), 1);
}

}  // namespace

// Binding of cpp/kernels/inpaint/background.h: the checking front (each input's arrays against its
// camera's size, the target's hole and colour) and the call with the GIL released.
static void BindBackground(py::module_& m) {
  m.def(
      "background_lookup",
      [](const Camera& target, py::sequence inputs_obj, py::handle hole_obj, py::handle color_obj, double near,
         double far) {
        const py::ssize_t h = target.height, w = target.width;
        py::object hole_keep;
        const ImageView<const std::uint8_t> hole = MaskView(hole_obj, "hole", h, w, &hole_keep);
        FloatArray color = CheckArray<float>(color_obj, "color", {{"H", h}, {"W", w}, {"3", 3}}, true);
        std::vector<BackgroundInput> inputs;
        std::vector<py::object> keep;
        for (py::ssize_t i = 0; i < static_cast<py::ssize_t>(py::len(inputs_obj)); ++i) {
          const std::string at = "inputs[" + std::to_string(i) + "]";
          py::object item = inputs_obj[i];
          if (!py::isinstance<py::tuple>(item) || py::len(item) != 4) {
            throw DtypeError(at + ": expected a tuple (camera, depth, clear, color)");
          }
          py::tuple t = item.cast<py::tuple>();
          BackgroundInput in;
          in.camera = t[0].cast<const Camera&>();
          const py::ssize_t ih = in.camera.height, iw = in.camera.width;
          FloatArray depth = CheckArray<float>(t[1], (at + ".depth").c_str(), {{"h", ih}, {"w", iw}});
          py::object clear_keep;
          in.clear = MaskView(t[2], (at + ".clear").c_str(), ih, iw, &clear_keep);
          FloatArray rgb = CheckArray<float>(t[3], (at + ".color").c_str(), {{"h", ih}, {"w", iw}, {"3", 3}});
          if (Overlaps(color, depth) || Overlaps(color, rgb)) {
            throw BadValueError("color: shares memory with " + at + " (it is written)");
          }
          in.depth = ConstViewOf(depth);
          in.color = ConstViewOf(rgb);
          keep.push_back(depth);
          keep.push_back(clear_keep);
          keep.push_back(rgb);
          inputs.push_back(in);
        }
        if (!(std::isfinite(near) && std::isfinite(far) && near >= 0.0 && far >= 0.0)) {
          throw BadValueError("near, far: expected finite depths >= 0 (0: no ray test), got " + std::to_string(near) +
                              ", " + std::to_string(far));
        }
        BackgroundRay ray;
        ray.near = near;
        ray.far = far;
        auto state = NewArray<std::uint8_t>({h, w});
        {
          py::gil_scoped_release release;
          BackgroundLookupKernel(target, inputs.data(), static_cast<int>(inputs.size()), ray, hole, ViewOf(color),
                                 ViewOf(state));
        }
        return state;
      },
      py::arg("target"), py::arg("inputs"), py::arg("hole"), py::arg("color"), py::kw_only(), py::arg("near") = 0.0,
      py::arg("far") = 0.0,
      "The background at infinity looked up in the inputs, in their order (cpp/kernels/inpaint/background.h). "
      "target: Camera; inputs: a sequence of (Camera, depth float32 (h, w), clear bool (h, w), color float32 "
      "(h, w, 3)); hole bool or uint8 (H, W); color float32 (H, W, 3), written in place at the background "
      "pixels found; near < far (> 0): the ray test between these target depths (0, 0: none). Returns state "
      "uint8 (H, W): at the hole pixels 0 undecided, 1 a surface, 2 background (colour written); 0 elsewhere.");
}

// Binding of cpp/kernels/inpaint/clean.h: the checking front and the call with the GIL released.
static void BindCleanColor(py::module_& m) {
  m.def(
      "clean_color",
      [](py::handle color_obj, py::handle hole_obj) {
        FloatArray color = CheckArray<float>(color_obj, "color", {{"H", -1}, {"W", -1}, {"C", -1}});
        const py::ssize_t h = color.shape(0), w = color.shape(1), c = color.shape(2);
        py::object hole_keep;
        const std::uint8_t* hole = nullptr;
        if (!hole_obj.is_none()) hole = MaskView(hole_obj, "hole", h, w, &hole_keep).data;
        FloatArray out = NewArray<float>({h, w, c});
        const float* in = color.data();
        float* o = out.mutable_data();
        py::gil_scoped_release release;
        CleanColorKernel(in, hole, std::int64_t(h) * w, static_cast<int>(c), o);
        return out;
      },
      py::arg("color"), py::arg("hole") = py::none(),
      "A method's colour as written (cpp/kernels/inpaint/clean.h): color float32 (H, W, C); NaN and +-inf -> 0, "
      "every channel of a hole pixel (hole bool or uint8 (H, W), or None) -> 0. Returns a new float32 array.");
}

// Binding of cpp/kernels/inpaint/hole_sides.h: the array checks and the front's call with the GIL released.
static void BindHoleSides(py::module_& m) {
  m.def(
      "hole_sides",
      [](py::handle hole_obj, py::handle background_obj, py::handle known_depth_obj, double occluder_ratio) {
        FloatArray known = CheckArray<float>(known_depth_obj, "known_depth", {{"H", -1}, {"W", -1}});
        const py::ssize_t h = known.shape(0), w = known.shape(1);
        py::object hole_keep, bg_keep;
        const ImageView<const std::uint8_t> hole = MaskView(hole_obj, "hole", h, w, &hole_keep);
        const ImageView<const std::uint8_t> bg = MaskView(background_obj, "background", h, w, &bg_keep);
        auto sides = NewArray<std::uint8_t>({h, w});
        FloatArray around = NewArray<float>({h, w});
        {
          py::gil_scoped_release release;
          InpaintHoleSides(hole, bg, ConstViewOf(known), occluder_ratio, ViewOf(sides), ViewOf(around));
        }
        return py::make_tuple(sides, around);
      },
      py::arg("hole"), py::arg("background"), py::arg("known_depth"), py::arg("occluder_ratio"),
      "The nearest covered pixels left, right, above and below each hole pixel (cpp/kernels/inpaint/hole_sides.h). "
      "hole, background bool or uint8 (H, W); known_depth float32 (H, W); occluder_ratio 0 or > 1. Returns (sides "
      "uint8 (H, W) = 2 bits per side, left, right, up, down from bit 0: SIDE_NONE, SIDE_BACKGROUND, SIDE_SURFACE "
      "or SIDE_OCCLUDER; around float32 (H, W) = the largest known_depth of the sides), 0 outside the holes.");
  m.attr("SIDE_NONE") = kSideNone;
  m.attr("SIDE_BACKGROUND") = kSideBackground;
  m.attr("SIDE_SURFACE") = kSideSurface;
  m.attr("SIDE_OCCLUDER") = kSideOccluder;
}

static void BindPushPull(py::module_& m) {
  m.def(
      "pushpull",
      [](py::handle image_obj, py::handle hole_obj, py::handle depth_obj, double depth_threshold,
         double gamma, py::handle out_obj, bool holes_only, py::handle write_obj) {
        const bool has_c = py::isinstance<py::array>(image_obj) &&
                           py::reinterpret_borrow<py::array>(image_obj).ndim() == 3;
        FloatArray image = has_c ? CheckArray<float>(image_obj, "image", {{"H", -1}, {"W", -1}, {"C", -1}})
                                 : CheckArray<float>(image_obj, "image", {{"H", -1}, {"W", -1}});
        const py::ssize_t h = image.shape(0), w = image.shape(1), c = has_c ? image.shape(2) : 1;
        if (h < 1 || w < 1 || c < 1) {
          throw ShapeError("image: expected at least 1 pixel and 1 channel, got shape " + DescribeShape(image));
        }
        py::object hole_keep;
        const ImageView<const std::uint8_t> hole = MaskView(hole_obj, "hole", h, w, &hole_keep);
        FloatArray depth;
        PushPullOptions options = CheckPushPullArgs(depth_obj, h, w, depth_threshold, gamma, &depth);
        const ImageView<const float> depth_view = options.depth_aware ? ConstViewOf(depth) : ImageView<const float>();
        const ImageView<const float> image_view(image.data(), static_cast<int>(h), static_cast<int>(w),
                                                static_cast<int>(c));
        options.holes_only = holes_only;
        FloatArray out;
        if (out_obj.is_none()) {
          out = has_c ? NewArray<float>({h, w, c}) : NewArray<float>({h, w});
        } else {
          out = has_c ? CheckArray<float>(out_obj, "out", {{"H", h}, {"W", w}, {"C", c}}, true)
                      : CheckArray<float>(out_obj, "out", {{"H", h}, {"W", w}}, true);
          // In place (out is image itself) only with holes_only: the kernel then reads the pixels outside
          // the holes and writes those inside them (pushpull.h).
          const bool in_place = holes_only && out.data() == image.data();
          if ((Overlaps(out, image) && !in_place) || (depth_obj.is_none() ? false : Overlaps(out, depth)) ||
              Overlaps(out, py::reinterpret_borrow<py::array>(hole_keep))) {
            throw BadValueError("out: shares memory with image, hole or depth (it is written; out may be image "
                                "itself with holes_only=True)");
          }
        }
        const ImageView<float> out_view(out.mutable_data(), static_cast<int>(h), static_cast<int>(w),
                                        static_cast<int>(c));
        py::object write_keep;
        const ImageView<const std::uint8_t> write =
            write_obj.is_none() ? ImageView<const std::uint8_t>() : MaskView(write_obj, "write", h, w, &write_keep);
        if (!write_obj.is_none() && Overlaps(out, py::reinterpret_borrow<py::array>(write_keep))) {
          throw BadValueError("out: shares memory with write (it is written)");
        }
        bool no_hole;
        {
          py::gil_scoped_release release;
          no_hole = InpaintPushPull(image_view, hole, depth_view, options, out_view, write);
        }
        return py::make_tuple(out, no_hole);
      },
      py::arg("image"), py::arg("hole"), py::arg("depth") = py::none(), py::arg("depth_threshold") = 0.04,
      py::arg("gamma") = 0.0, py::arg("out") = py::none(), py::arg("holes_only") = false,
      py::arg("write") = py::none(),
      "Push-pull hole filling (cpp/kernels/inpaint/pushpull.h). image float32 (H, W) or (H, W, C); hole bool or "
      "uint8 (H, W), non-zero = hole; depth float32 (H, W) or None (classic); out: None (a new array) or "
      "a writeable float32 array of image's shape to fill (image itself with holes_only: in place); holes_only: "
      "write the hole pixels of out only; write: None or bool / uint8 (H, W), with holes_only: write only the "
      "hole pixels where it is set. "
      "Returns (out, no_hole) where no_hole says the image had no hole.");
}

}  // namespace ibr::bind

// Bindings of cpp/kernels/inpaint/metameric.h: the checking front (dtypes, shapes of every band, mask,
// flow, scale, no aliasing of written bands) and the calls with the GIL released.
// Python: ibrtools.inpaint.metameric (private helpers of metameric()).
namespace ibr::bind {
namespace {

using FloatArray = py::array_t<float, py::array::c_style>;

void CheckNoAlias(const std::vector<FloatArray>& written, const std::vector<py::array>& others, const char* name,
                  bool indexed) {
  for (std::size_t i = 0; i < written.size(); ++i) {
    for (std::size_t j = 0; j < others.size(); ++j) {
      if (Overlaps(written[i], others[j])) {
        throw BadValueError(std::string(name) + (indexed ? "[" + std::to_string(i) + "]" : std::string()) +
                            ": shares memory with another argument of the call (it is written in place)");
      }
    }
  }
}

// Bands written in place must not share memory with each other.
void CheckBandsDistinct(const std::vector<FloatArray>& bands) {
  for (std::size_t i = 0; i < bands.size(); ++i) {
    for (std::size_t j = 0; j < bands.size(); ++j) {
      if (i != j && Overlaps(bands[i], bands[j])) {
        throw BadValueError("bands[" + std::to_string(i) + "]: shares memory with bands[" + std::to_string(j) +
                            "] (each is written in place)");
      }
    }
  }
}

// The noise flow of a level of h x w samples at `scale`: None, or float32/float64 (H, W, 2), then
// the front's checks (InpaintCheckFlow: size and finiteness). `keep` holds the checked array.
MetamericFlow CheckFlow(py::handle flow_obj, py::ssize_t h, py::ssize_t w, int scale, py::array* keep) {
  MetamericFlow flow;
  if (flow_obj.is_none()) {
    InpaintCheckFlow(flow, static_cast<int>(h), static_cast<int>(w), scale);
    return flow;
  }
  py::array& flow_arr = *keep;
  const bool f64 = py::isinstance<py::array>(flow_obj) &&
                   py::reinterpret_borrow<py::array>(flow_obj).dtype().equal(py::dtype::of<double>());
  if (f64) {
    auto a = CheckArray<double>(flow_obj, "flow", {{"H", -1}, {"W", -1}, {"2", 2}});
    flow.f64 = a.data();
    flow_arr = a;
  } else {
    auto a = CheckArray<float>(flow_obj, "flow", {{"H", -1}, {"W", -1}, {"2", 2}});
    flow.f32 = a.data();
    flow_arr = a;
  }
  flow.height = static_cast<int>(flow_arr.shape(0));
  flow.width = static_cast<int>(flow_arr.shape(1));
  py::gil_scoped_release release;
  InpaintCheckFlow(flow, static_cast<int>(h), static_cast<int>(w), scale);
  return flow;
}

}  // namespace

static void BindMetameric(py::module_& m) {
  m.def(
      "metameric_stack_moments",
      [](py::handle bands_obj, py::handle out_obj) {
        std::vector<FloatArray> bands = CheckArrayList(bands_obj, "bands", -1, -1, -1, false);
        const py::ssize_t h = bands[0].shape(0), w = bands[0].shape(1), c = bands[0].shape(2);
        const py::ssize_t k = static_cast<py::ssize_t>(bands.size());
        FloatArray out = CheckArray<float>(out_obj, "out", {{"h", h}, {"w", w}, {"2kC", 2 * k * c}}, true);
        std::vector<py::array> ins(bands.begin(), bands.end());
        CheckNoAlias({out}, ins, "out", false);
        std::vector<ImageView<const float>> views;
        for (FloatArray& b : bands) views.push_back(ConstViewOf(b));
        const ImageView<float> out_view = ViewOf(out);
        py::gil_scoped_release release;
        MetamericStackMoments(views.data(), static_cast<int>(k), out_view);
      },
      py::arg("bands"), py::arg("out"),
      "Push-pull input of one level's moments (cpp/kernels/inpaint/metameric.h): bands = k float32 (h, w, C) "
      "arrays; writes out float32 (h, w, 2kC) = [X_0..X_{k-1}, X_0^2..X_{k-1}^2] along the channels.");

  m.def(
      "metameric_pushpull_moments",
      [](py::handle bands_obj, py::handle hole_obj, py::handle depth_obj, double depth_threshold, double gamma,
         py::handle out_obj) {
        std::vector<FloatArray> bands = CheckArrayList(bands_obj, "bands", -1, -1, -1, false);
        const py::ssize_t h = bands[0].shape(0), w = bands[0].shape(1), c = bands[0].shape(2);
        const py::ssize_t k = static_cast<py::ssize_t>(bands.size());
        auto hole = CheckArray<std::uint8_t>(hole_obj, "mask", {{"h", h}, {"w", w}});
        FloatArray out = CheckArray<float>(out_obj, "out", {{"h", h}, {"w", w}, {"2kC", 2 * k * c}}, true);
        FloatArray depth;
        const PushPullOptions options = CheckPushPullArgs(depth_obj, h, w, depth_threshold, gamma, &depth);
        std::vector<py::array> ins(bands.begin(), bands.end());
        ins.push_back(hole);
        if (options.depth_aware) ins.push_back(depth);
        CheckNoAlias({out}, ins, "out", false);
        std::vector<ImageView<const float>> views;
        for (FloatArray& b : bands) views.push_back(ConstViewOf(b));
        const ImageView<const std::uint8_t> hole_view = ConstViewOf(hole);
        const ImageView<const float> depth_view = options.depth_aware ? ConstViewOf(depth) : ImageView<const float>();
        const ImageView<float> out_view = ViewOf(out);
        py::gil_scoped_release release;
        InpaintPushPullMoments(views.data(), static_cast<int>(k), hole_view, depth_view, options, out_view);
      },
      py::arg("bands"), py::arg("mask"), py::arg("depth"), py::arg("depth_threshold"), py::arg("gamma"),
      py::arg("out"),
      "Push-pull of one level's moments (cpp/kernels/inpaint/pushpull.h PushPullMomentsKernel): bands = k float32 "
      "(h, w, C) arrays; mask uint8 (h, w), non-zero = fill; depth float32 (h, w) or None (classic); writes "
      "the masked samples of out float32 (h, w, 2kC): push-pull of [X_0..X_{k-1}, X_0^2..X_{k-1}^2].");

  m.def(
      "metameric_composite",
      [](py::handle moments_obj, py::handle mask_obj, py::handle noise_obj, py::handle bands_obj,
         py::handle flow_obj, int scale, bool delta) {
        std::vector<FloatArray> bands = CheckArrayList(bands_obj, "bands", -1, -1, -1, true);
        const py::ssize_t h = bands[0].shape(0), w = bands[0].shape(1), c = bands[0].shape(2);
        const py::ssize_t k = static_cast<py::ssize_t>(bands.size());
        std::vector<FloatArray> noise = CheckPairedArrayList(noise_obj, "noise", bands, "band");
        FloatArray moments = CheckArray<float>(moments_obj, "moments", {{"h", h}, {"w", w}, {"2kC", 2 * k * c}});
        py::array mask_arr;
        if (py::isinstance<py::array>(mask_obj) &&
            py::reinterpret_borrow<py::array>(mask_obj).dtype().equal(py::dtype::of<std::uint8_t>())) {
          mask_arr = CheckArray<std::uint8_t>(mask_obj, "mask", {{"h", h}, {"w", w}});
        } else {
          mask_arr = CheckArray<bool>(mask_obj, "mask", {{"h", h}, {"w", w}});
        }
        py::array flow_arr;
        const MetamericFlow flow = CheckFlow(flow_obj, h, w, scale, &flow_arr);
        std::vector<py::array> others(noise.begin(), noise.end());
        others.push_back(moments);
        others.push_back(mask_arr);
        if (flow_arr) others.push_back(flow_arr);
        CheckBandsDistinct(bands);
        CheckNoAlias(bands, others, "bands", true);
        std::vector<ImageView<const float>> noise_views;
        for (FloatArray& n : noise) noise_views.push_back(ConstViewOf(n));
        std::vector<ImageView<float>> band_views;
        for (FloatArray& b : bands) band_views.push_back(ViewOf(b));
        const ImageView<const float> moments_view = ConstViewOf(moments);
        const ImageView<const std::uint8_t> mask_view(static_cast<const std::uint8_t*>(mask_arr.data()),
                                                      static_cast<int>(h), static_cast<int>(w), 1);
        py::gil_scoped_release release;
        MetamericComposite(moments_view, mask_view, noise_views.data(), band_views.data(), static_cast<int>(k),
                           flow, scale, delta);
      },
      py::arg("moments"), py::arg("mask"), py::arg("noise"), py::arg("bands"), py::arg("flow") = py::none(),
      py::arg("scale") = 1, py::arg("delta") = false,
      "Metameric synthesis of one level in place (cpp/kernels/inpaint/metameric.h): where mask (bool or uint8 (h, w)) "
      "is set, bands[i] = mean + sqrt(max(0, E[X^2] - mean^2)) * noise[i] at the (flow-moved, wrapped) "
      "noise position, with mean, E[X^2] from moments float32 (h, w, 2kC); flow None or float32/float64 "
      "full-resolution (H, W, 2), read at (y * scale, x * scale). delta=True: bands[i] = sigma * noise[i] "
      "where mask is set and 0 elsewhere (the band's change when the fill's mean is the band itself).");

  m.def(
      "metameric_pushpull_change",
      [](py::handle bands_obj, py::handle mask_obj, py::handle depth_obj, double depth_threshold, double gamma,
         py::handle noise_obj, py::handle flow_obj, int scale, bool check_finite) {
        std::vector<FloatArray> bands = CheckArrayList(bands_obj, "bands", -1, -1, -1, true);
        const py::ssize_t h = bands[0].shape(0), w = bands[0].shape(1);
        const py::ssize_t k = static_cast<py::ssize_t>(bands.size());
        std::vector<FloatArray> noise = CheckPairedArrayList(noise_obj, "noise", bands, "band");
        auto mask = CheckArray<std::uint8_t>(mask_obj, "mask", {{"h", h}, {"w", w}});
        FloatArray depth;
        const PushPullOptions options = CheckPushPullArgs(depth_obj, h, w, depth_threshold, gamma, &depth);
        py::array flow_arr;
        const MetamericFlow flow = CheckFlow(flow_obj, h, w, scale, &flow_arr);
        CheckBandsDistinct(bands);
        std::vector<py::array> others(noise.begin(), noise.end());
        others.push_back(mask);
        if (options.depth_aware) others.push_back(depth);
        if (flow_arr) others.push_back(flow_arr);
        CheckNoAlias(bands, others, "bands", true);
        std::vector<ImageView<const float>> views;
        std::vector<ImageView<float>> band_views;
        for (FloatArray& b : bands) {
          views.push_back(ConstViewOf(b));
          band_views.push_back(ViewOf(b));
        }
        std::vector<ImageView<const float>> noise_views;
        for (FloatArray& n : noise) noise_views.push_back(ConstViewOf(n));
        const ImageView<const std::uint8_t> mask_view = ConstViewOf(mask);
        const ImageView<const float> depth_view = options.depth_aware ? ConstViewOf(depth) : ImageView<const float>();
        MetamericSynth synth;
        synth.noise = noise_views.data();
        synth.bands = band_views.data();
        synth.k = static_cast<int>(k);
        synth.flow = flow;
        synth.scale = scale;
        py::gil_scoped_release release;
        InpaintPushPullChange(views.data(), static_cast<int>(k), mask_view, depth_view, options, synth, check_finite);
      },
      py::arg("bands"), py::arg("mask"), py::arg("depth"), py::arg("depth_threshold"), py::arg("gamma"),
      py::arg("noise"), py::arg("flow") = py::none(), py::arg("scale") = 1, py::arg("check_finite") = true,
      "One level of metameric synthesis in place (cpp/kernels/inpaint/pushpull.h PushPullMomentsChangeKernel): "
      "metameric_pushpull_moments then metameric_composite(..., delta=True) without the moments image, the "
      "same values bit for bit. bands k float32 (h, w, C) arrays, read, then overwritten with their change "
      "(sigma * noise where mask (uint8 (h, w)) is set, 0 elsewhere); depth float32 (h, w) or None; noise k "
      "float32 (h, w, C); flow None or float32/float64 full-resolution (H, W, 2), read at (y * scale, x * scale). "
      "Raises BadValueError when every sample is masked (the bands are then left as they were) and, with "
      "check_finite (default), for NaN or infinite band values outside the mask; check_finite=False skips that "
      "scan for callers whose bands come from analysing a finite image (ibrtools.inpaint.metameric: the pre-fill is "
      "checked finite by push-pull's front).");

  m.def(
      "metameric_encode",
      [](py::handle image_obj) {
        FloatArray image = CheckArray<float>(image_obj, "image", {{"H", -1}, {"W", -1}, {"C", -1}});
        const py::ssize_t h = image.shape(0), w = image.shape(1), c = image.shape(2);
        FloatArray out = NewArray<float>({h, w, c});
        const ImageView<const float> in_view = ConstViewOf(image);
        const ImageView<float> out_view = ViewOf(out);
        py::gil_scoped_release release;
        MetamericEncode(in_view, out_view);
        return out;
      },
      py::arg("image"),
      "Display encoding of metameric synthesis (cpp/ibr/colour.h SrgbEncode): the sRGB curve of every "
      "value of image float32 (H, W, C), odd-extended to negatives and unbounded above; NaN stays NaN. Returns "
      "a new float32 (H, W, C) array.");

  m.def(
      "metameric_fill_holes",
      [](py::handle image_obj, py::handle hole_obj, py::handle base_obj, py::handle change_obj, bool decode,
         py::handle out_obj) {
        FloatArray image = CheckArray<float>(image_obj, "image", {{"H", -1}, {"W", -1}, {"C", -1}});
        const py::ssize_t h = image.shape(0), w = image.shape(1), c = image.shape(2);
        py::array hole_arr;
        if (py::isinstance<py::array>(hole_obj) &&
            py::reinterpret_borrow<py::array>(hole_obj).dtype().equal(py::dtype::of<std::uint8_t>())) {
          hole_arr = CheckArray<std::uint8_t>(hole_obj, "hole", {{"H", h}, {"W", w}});
        } else {
          hole_arr = CheckArray<bool>(hole_obj, "hole", {{"H", h}, {"W", w}});
        }
        FloatArray base = CheckArray<float>(base_obj, "base", {{"H", h}, {"W", w}, {"C", c}});
        FloatArray change = CheckArray<float>(change_obj, "change", {{"H", h}, {"W", w}, {"C", c}});
        FloatArray out;
        if (out_obj.is_none()) {
          out = NewArray<float>({h, w, c});
        } else {
          out = CheckArray<float>(out_obj, "out", {{"H", h}, {"W", w}, {"C", c}}, true);
          // out may be exactly image's or change's memory (read before written, pixel by pixel), nothing
          // else of the call's.
          auto same = [](const py::array& a, const py::array& b) { return a.data() == b.data(); };
          if ((Overlaps(out, image) && !same(out, image)) || (Overlaps(out, change) && !same(out, change)) ||
              Overlaps(out, base) || Overlaps(out, hole_arr)) {
            throw BadValueError("out: shares memory with base or hole, or overlaps image or change without being "
                                "the same array");
          }
        }
        const ImageView<const float> image_view = ConstViewOf(image), base_view = ConstViewOf(base),
                                     change_view = ConstViewOf(change);
        const ImageView<const std::uint8_t> hole_view(static_cast<const std::uint8_t*>(hole_arr.data()),
                                                      static_cast<int>(h), static_cast<int>(w), 1);
        const ImageView<float> out_view = ViewOf(out);
        py::gil_scoped_release release;
        MetamericFillHoles(image_view, hole_view, base_view, change_view, decode, out_view);
        return out;
      },
      py::arg("image"), py::arg("hole"), py::arg("base"), py::arg("change"), py::arg("decode"),
      py::arg("out") = py::none(),
      "The result of metameric inpainting (cpp/kernels/inpaint/metameric.h MetamericFillHoles): image where hole (bool or "
      "uint8 (H, W)) is 0, base + change inside the holes (decoded from the display encoding and clamped at 0 with "
      "decode=True); image, base, change float32 (H, W, C). Returns out: a new float32 (H, W, C) array, or the given "
      "writeable one, which may be image or change itself (not base).");
}

}  // namespace ibr::bind

namespace ibr::bind {

void BindInpaint(py::module_& m) {
  BindPushPull(m);
  BindMetameric(m);
  BindBackground(m);
  BindHoleSides(m);
  BindCleanColor(m);
}

}  // namespace ibr::bind
