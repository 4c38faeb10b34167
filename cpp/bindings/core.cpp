// Bindings of cpp/ibr: cameras, thread control, error translation, the sRGB curves (colour.h).
#include <cstdint>
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "array.h"
#include "ibr/camera.h"
#include "ibr/colour.h"
#include "ibr/errors.h"
#include "ibr/parallel.h"
#include "ibr/simd.h"  // UseAvx2: the process-wide instruction set
#include "module.h"

namespace ibr::bind {
namespace {

// `values` checked: a C-contiguous float32 array of any shape.
py::array_t<float, py::array::c_style> CheckedValues(const py::handle& values_obj) {
  if (!py::isinstance<py::array>(values_obj)) {
    throw DtypeError("values: expected a numpy float32 array, got " +
                     std::string(py::str(py::type::of(values_obj).attr("__name__"))));
  }
  const py::array a = py::reinterpret_borrow<py::array>(values_obj);
  if (!a.dtype().equal(py::dtype::of<float>())) {
    throw DtypeError("values: expected a float32 array, got " + std::string(py::str(a.dtype())) + " " +
                     DescribeShape(a));
  }
  if (!(a.flags() & py::array::c_style)) {
    throw ShapeError("values: expected a C-contiguous array (use numpy.ascontiguousarray)");
  }
  return py::reinterpret_borrow<py::array_t<float, py::array::c_style>>(a);
}

// out = kernel(values) for a C-contiguous float32 array of any shape (a new array of its shape),
// with the GIL released.
py::array_t<float> MapValues(const py::handle& values_obj, void (*kernel)(const float*, float*, std::int64_t)) {
  const auto values = CheckedValues(values_obj);
  py::array_t<float> out(std::vector<py::ssize_t>(values.shape(), values.shape() + values.ndim()));
  const float* in = values.data();
  float* o = out.mutable_data();
  const std::int64_t n = values.size();
  py::gil_scoped_release release;
  kernel(in, o, n);
  return out;
}

// LinearToSrgbUnclipped on the instruction set the warp uses (set_warp_isa: tests compare both).
void EncodeUnclippedActiveIsa(const float* in, float* out, std::int64_t n) {
  LinearToSrgbUnclipped(in, out, n, UseAvx2());
}

}  // namespace

void BindCore(py::module_& m) {
  // C++ front errors become the typed Python errors of ibrtools.errors.
  py::register_exception_translator([](std::exception_ptr p) {
    auto raise = [](const char* cls, const char* what) {
      py::object errors = py::module_::import("ibrtools.errors");
      PyErr_SetString(errors.attr(cls).ptr(), what);
    };
    try {
      if (p) std::rethrow_exception(p);
    } catch (const ShapeError& e) {
      raise("ShapeError", e.what());
    } catch (const DtypeError& e) {
      raise("DtypeError", e.what());
    } catch (const BadValueError& e) {
      raise("BadValueError", e.what());
    } catch (const InternalError& e) {
      raise("InternalError", e.what());
    }
  });

  m.def("set_num_threads", &SetNumThreads, py::arg("num_threads"),
        "Limit the engine's threads for every later call (0 = all cores).");
  m.def("get_num_threads", &GetNumThreads, "The engine's current thread limit.");

  py::enum_<CameraModel>(m, "CameraModel")
      .value("PINHOLE", CameraModel::kPinhole)
      .value("EQUIRECT", CameraModel::kEquirect);

  // The C++ camera; built from ibrtools.Camera by Camera.to_core(), which has validated it.
  py::class_<Camera>(m, "Camera")
      .def(py::init([](CameraModel model, int width, int height, py::object params_obj,
                       py::object cam_from_world_obj) {
             auto params = CheckArray<double>(params_obj, "params", {{"4", 4}});
             auto pose = CheckArray<double>(cam_from_world_obj, "cam_from_world", {{"4", 4}, {"4", 4}});
             if (width <= 0 || height <= 0) {
               throw BadValueError("camera: width and height must be positive, got " +
                                   std::to_string(width) + "x" + std::to_string(height));
             }
             Camera c;
             c.model = model;
             c.width = width;
             c.height = height;
             const double* p = params.data();
             if (model == CameraModel::kPinhole) {
               c.fx = p[0], c.fy = p[1], c.cx = p[2], c.cy = p[3];
             } else {
               c.lon_min = p[0], c.lon_max = p[1], c.lat_min = p[2], c.lat_max = p[3];
             }
             const double* t = pose.data();
             for (int r = 0; r < 3; ++r) {
               for (int col = 0; col < 3; ++col) c.rot[col][r] = t[r * 4 + col];
               c.trans[r] = t[r * 4 + 3];
             }
             return c;
           }),
           py::arg("model"), py::arg("width"), py::arg("height"), py::arg("params"),
           py::arg("cam_from_world"),
           "params: (fx, fy, cx, cy) for PINHOLE, (lon_min, lon_max, lat_min, lat_max) in radians "
           "for EQUIRECT; cam_from_world: float64 (4, 4).")
      .def_readonly("model", &Camera::model)
      .def_readonly("width", &Camera::width)
      .def_readonly("height", &Camera::height)
      .def("project", [](const Camera& c, double x, double y, double z) {
             double u = 0, v = 0, d = 0;
             const bool ok = c.ProjectCam(c.CamFromWorld({x, y, z}), &u, &v, &d);
             return py::make_tuple(ok, u, v, d);
           }, py::arg("x"), py::arg("y"), py::arg("z"),
           "Project one world point: (ok, x_img, y_img, depth). For tests and debugging.");

  m.def(
      "linear_to_srgb", [](py::handle values) { return MapValues(values, LinearToSrgb); }, py::arg("values"),
      "The display encoding of linear colour (cpp/ibr/colour.h LinearToSrgb; Python: "
      "ibrtools.imageio.linear_to_srgb): the IEC 61966-2-1 sRGB curve of every value of a C-contiguous "
      "float32 array of any shape, clamped to [0, 1] first, NaN -> 0; within 1e-6 (relative) of the exact "
      "curve. Returns a new float32 array of the same shape.");
  m.def(
      "linear_to_srgb8",
      [](py::handle values_obj) {
        const auto values = CheckedValues(values_obj);
        py::array_t<std::uint8_t> out(std::vector<py::ssize_t>(values.shape(), values.shape() + values.ndim()));
        const float* in = values.data();
        std::uint8_t* o = out.mutable_data();
        const std::int64_t n = values.size();
        py::gil_scoped_release release;
        LinearToSrgb8(in, o, n);
        return out;
      },
      py::arg("values"),
      "linear_to_srgb's values as 8-bit codes in one pass (cpp/ibr/colour.h LinearToSrgb8; Python: "
      "ibrtools.imageio.srgb8): round(linear_to_srgb(values) * 255), ties to even, the same bits as numpy's. "
      "values: C-contiguous float32 of any shape; returns uint8 of the same shape.");
  m.def(
      "lookup_codes",
      [](py::handle codes_obj, py::handle table_obj) {
        if (!py::isinstance<py::array>(codes_obj)) {
          throw DtypeError("codes: expected a numpy uint8 or uint16 array, got " +
                           std::string(py::str(py::type::of(codes_obj).attr("__name__"))));
        }
        const py::array codes = py::reinterpret_borrow<py::array>(codes_obj);
        const bool u8 = codes.dtype().equal(py::dtype::of<std::uint8_t>());
        if (!u8 && !codes.dtype().equal(py::dtype::of<std::uint16_t>())) {
          throw DtypeError("codes: expected a uint8 or uint16 array, got " + std::string(py::str(codes.dtype())) +
                           " " + DescribeShape(codes));
        }
        if (!(codes.flags() & py::array::c_style)) {
          throw ShapeError("codes: expected a C-contiguous array (use numpy.ascontiguousarray)");
        }
        const py::ssize_t entries = u8 ? 256 : 65536;
        const auto table = CheckArray<float>(table_obj, "table", {{"N", entries}});
        py::array_t<float> out(std::vector<py::ssize_t>(codes.shape(), codes.shape() + codes.ndim()));
        const std::int64_t n = codes.size();
        float* o = out.mutable_data();
        const float* t = table.data();
        const void* c = codes.data();
        py::gil_scoped_release release;
        if (u8) {
          LookupCodes(static_cast<const std::uint8_t*>(c), t, o, n);
        } else {
          LookupCodes(static_cast<const std::uint16_t*>(c), t, o, n);
        }
        return out;
      },
      py::arg("codes"), py::arg("table"),
      "The value of every stored code (cpp/ibr/colour.h LookupCodes; Python: ibrtools.imageio.read_image): "
      "codes uint8 or uint16, C-contiguous, any shape; table float32 (256,) for uint8 or (65536,) for uint16. "
      "Returns a new float32 array of the codes' shape, out[i] = table[codes[i]].");
  m.def(
      "srgb_encode_unclipped", [](py::handle values) { return MapValues(values, EncodeUnclippedActiveIsa); },
      py::arg("values"),
      "The sRGB encoding of linear colour for blending in sRGB space (cpp/ibr/colour.h "
      "LinearToSrgbUnclipped; Python: ibrtools.dibr.method.srgb_encode): the IEC 61966-2-1 curve of every value "
      "of a C-contiguous float32 array of any shape, negative values and -inf -> 0, not clipped above 1, +inf "
      "stays +inf, NaN stays NaN; within 1e-6 of the exact curve (absolute in [0, 1], relative above), exact at 0 "
      "and 1. A table in [0, 1] "
      "(AVX2 gathers when set_warp_isa allows: the same bits either way). Returns a new float32 array of the "
      "same shape.");
  m.def(
      "yuv_to_linear_rgb",
      [](py::handle y_obj, py::handle cb_obj, py::handle cr_obj, int bits, double kr, double kb, bool full_range) {
        YuvCheckArgs(bits, kr, kb);
        const bool wide = py::isinstance<py::array>(y_obj) &&
                          py::reinterpret_borrow<py::array>(y_obj).dtype().equal(py::dtype::of<std::uint16_t>());
        const bool chroma = !cb_obj.is_none() || !cr_obj.is_none();
        auto run = [&](auto tag) -> py::array_t<float> {
          using T = decltype(tag);
          auto y = CheckArray<T>(y_obj, "y", {{"H", -1}, {"W", -1}});
          const py::ssize_t h = y.shape(0), w = y.shape(1);
          py::array_t<T, py::array::c_style> cb, cr;
          if (chroma) {
            cb = CheckArray<T>(cb_obj, "cb", {{"(H+1)/2", (h + 1) / 2}, {"(W+1)/2", (w + 1) / 2}});
            cr = CheckArray<T>(cr_obj, "cr", {{"(H+1)/2", (h + 1) / 2}, {"(W+1)/2", (w + 1) / 2}});
          }
          auto out = NewArray<float>({h, w, 3});
          const T* py_ = y.data();
          const T* pb = chroma ? cb.data() : nullptr;
          const T* pr = chroma ? cr.data() : nullptr;
          float* o = out.mutable_data();
          py::gil_scoped_release release;
          YuvToLinearRgb<T>(py_, pb, pr, static_cast<int>(h), static_cast<int>(w), bits, kr, kb, full_range, o);
          return out;
        };
        return wide ? run(std::uint16_t{}) : run(std::uint8_t{});
      },
      py::arg("y"), py::arg("cb"), py::arg("cr"), py::arg("bits"), py::arg("kr"), py::arg("kb"),
      py::arg("full_range") = false,
      "Y'CbCr planes to linear RGB (cpp/ibr/colour.h YuvToLinearRgb; Python: ibrtools.formats.yuv.yuv_to_rgb, "
      "which it computes bit for bit): y uint8 or uint16 (H, W); cb, cr the same dtype "
      "((H+1)/2, (W+1)/2), or both None (4:0:0). Returns a new float32 (H, W, 3) array.");
  m.def(
      "linear_rgb_to_yuv",
      [](py::handle rgb_obj, int bits, double kr, double kb, bool full_range) {
        YuvCheckArgs(bits, kr, kb, 8);
        auto rgb = CheckArray<float>(rgb_obj, "rgb", {{"H", -1}, {"W", -1}, {"3", 3}});
        const py::ssize_t h = rgb.shape(0), w = rgb.shape(1);
        if (h < 1 || w < 1) throw ShapeError("rgb: expected at least 1 x 1 pixels, got " + DescribeShape(rgb));
        auto run = [&](auto tag) -> py::tuple {
          using T = decltype(tag);
          auto y = NewArray<T>({h, w});
          auto cb = NewArray<T>({(h + 1) / 2, (w + 1) / 2});
          auto cr = NewArray<T>({(h + 1) / 2, (w + 1) / 2});
          const float* in = rgb.data();
          T *py_ = y.mutable_data(), *pb = cb.mutable_data(), *pr = cr.mutable_data();
          {
            py::gil_scoped_release release;
            LinearRgbToYuv<T>(in, static_cast<int>(h), static_cast<int>(w), bits, kr, kb, full_range, py_, pb, pr);
          }
          return py::make_tuple(y, cb, cr);
        };
        return bits > 8 ? run(std::uint16_t{}) : run(std::uint8_t{});
      },
      py::arg("rgb"), py::arg("bits"), py::arg("kr"), py::arg("kb"), py::arg("full_range") = false,
      "Linear RGB to Y'CbCr 4:2:0 planes (cpp/ibr/colour.h LinearRgbToYuv; Python: "
      "ibrtools.formats.yuv.rgb_to_yuv, which it computes bit for bit): rgb float32 (H, W, 3), bits 8..16. "
      "Returns (y (H, W), cb, cr ((H+1)/2, (W+1)/2)), uint8 for 8 bits, else uint16.");
  m.def(
      "srgb_to_linear", [](py::handle values) { return MapValues(values, SrgbToLinear); }, py::arg("values"),
      "The decoding of stored sRGB colour (cpp/ibr/colour.h SrgbToLinear; Python: "
      "ibrtools.imageio.srgb_to_linear): v / 12.92 for v <= 0.04045 (negative values included), "
      "((v + 0.055) / 1.055)^2.4 above (beyond 1 too), NaN stays NaN, for every value of a C-contiguous float32 "
      "array of any shape; within 1e-5 (relative) of the exact curve. Returns a new float32 array of the same "
      "shape.");
}

}  // namespace ibr::bind
