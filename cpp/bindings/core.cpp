// Bindings of cpp/ibr: cameras, thread control, error translation.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "array.h"
#include "ibr/camera.h"
#include "ibr/errors.h"
#include "ibr/parallel.h"
#include "module.h"

namespace ibr::bind {

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
}

}  // namespace ibr::bind
