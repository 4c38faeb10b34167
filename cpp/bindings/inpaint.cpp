// Bindings of cpp/kernels/inpaint/pushpull.h: the checking front (shapes, dtypes, finiteness outside the
// holes, options) and the call with the GIL released. Python: ibrtools.inpaint.
#include <cmath>
#include <string>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "array.h"
#include "ibr/errors.h"
#include "kernels/inpaint/pushpull.h"
#include "module.h"
#include "pushpull_args.h"

namespace ibr::bind {
namespace {

using FloatArray = py::array_t<float, py::array::c_style>;

// The hole mask as one byte per pixel: bool or uint8 (non-zero = hole), (H, W), C-contiguous.
ImageView<const std::uint8_t> HoleView(const py::handle& obj, py::ssize_t h, py::ssize_t w, py::object* keep) {
  if (py::isinstance<py::array>(obj) &&
      py::reinterpret_borrow<py::array>(obj).dtype().equal(py::dtype::of<std::uint8_t>())) {
    auto a = CheckArray<std::uint8_t>(obj, "hole", {{"H", h}, {"W", w}});
    *keep = a;
    return ImageView<const std::uint8_t>(a.data(), static_cast<int>(h), static_cast<int>(w), 1);
  }
  auto a = CheckArray<bool>(obj, "hole", {{"H", h}, {"W", w}});
  *keep = a;
  return ImageView<const std::uint8_t>(reinterpret_cast<const std::uint8_t*>(a.data()), static_cast<int>(h),
                                       static_cast<int>(w), 1);
}

}  // namespace

void BindInpaint(py::module_& m) {
  m.def(
      "pushpull",
      [](py::handle image_obj, py::handle hole_obj, py::handle depth_obj, double depth_threshold,
         double gamma, py::handle out_obj, bool holes_only) {
        const bool has_c = py::isinstance<py::array>(image_obj) &&
                           py::reinterpret_borrow<py::array>(image_obj).ndim() == 3;
        FloatArray image = has_c ? CheckArray<float>(image_obj, "image", {{"H", -1}, {"W", -1}, {"C", -1}})
                                 : CheckArray<float>(image_obj, "image", {{"H", -1}, {"W", -1}});
        const py::ssize_t h = image.shape(0), w = image.shape(1), c = has_c ? image.shape(2) : 1;
        if (h < 1 || w < 1 || c < 1) {
          throw ShapeError("image: expected at least 1 pixel and 1 channel, got shape " + DescribeShape(image));
        }
        py::object hole_keep;
        const ImageView<const std::uint8_t> hole = HoleView(hole_obj, h, w, &hole_keep);
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
        PushPullStatus status;
        {
          py::gil_scoped_release release;
          const std::int64_t bad = CountNonFiniteOutsideHoles(image_view, hole);
          if (bad) {
            throw BadValueError("image: contains " + std::to_string(bad) +
                                " NaN or infinite values outside the holes");
          }
          status = PushPullKernel(image_view, hole, depth_view, options, out_view);
        }
        if (status == PushPullStatus::kNoValidPixel) {
          throw BadValueError("hole: every pixel is a hole; push-pull needs at least one pixel outside the holes");
        }
        return py::make_tuple(out, status == PushPullStatus::kNoHole);
      },
      py::arg("image"), py::arg("hole"), py::arg("depth") = py::none(), py::arg("depth_threshold") = 0.04,
      py::arg("gamma") = 0.0, py::arg("out") = py::none(), py::arg("holes_only") = false,
      "Push-pull hole filling (cpp/kernels/inpaint/pushpull.h). image float32 (H, W) or (H, W, C); hole bool or "
      "uint8 (H, W), non-zero = hole; depth float32 (H, W) or None (classic); out: None (a new array) or "
      "a writeable float32 array of image's shape to fill (image itself with holes_only: in place); holes_only: "
      "write the hole pixels of out only. "
      "Returns (out, no_hole) where no_hole says the image had no hole.");
}

}  // namespace ibr::bind
