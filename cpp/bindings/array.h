// The one boundary helper for arrays (every binding checks its arrays here, once): checks dtype, ndim, shape and
// C-contiguity once, with messages that name the argument and say what was expected, e.g.
//   "depth: expected float32 array of shape (H, W) = (1080, 1920), got float64 (1080, 1920, 1)".
// No conversion ever happens: a silent copy would lose writes and hide mistakes.
#pragma once
#include <initializer_list>
#include <sstream>
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "ibr/camera.h"
#include "ibr/errors.h"
#include "ibr/image.h"

namespace ibr::bind {
namespace py = pybind11;

// One expected dimension: a symbolic name ("H") and a size, or -1 for "any size".
struct Dim {
  const char* name;
  py::ssize_t size;
};

template <typename T> const char* DtypeName();
template <> inline const char* DtypeName<float>() { return "float32"; }
template <> inline const char* DtypeName<double>() { return "float64"; }
template <> inline const char* DtypeName<std::int32_t>() { return "int32"; }
template <> inline const char* DtypeName<std::int64_t>() { return "int64"; }
template <> inline const char* DtypeName<std::uint32_t>() { return "uint32"; }
template <> inline const char* DtypeName<std::uint16_t>() { return "uint16"; }
template <> inline const char* DtypeName<std::uint8_t>() { return "uint8"; }
template <> inline const char* DtypeName<bool>() { return "bool"; }

std::string DescribeShape(const py::array& a);
std::string DescribeExpected(const std::vector<Dim>& dims);

// Checks `obj` and returns it as a typed, C-contiguous array (no copy). Sizes of -1 in
// `dims` accept anything; `writable` also requires a writeable array.
template <typename T>
py::array_t<T, py::array::c_style> CheckArray(const py::handle& obj, const char* name,
                                               const std::vector<Dim>& dims,
                                               bool writable = false) {
  if (!py::isinstance<py::array>(obj)) {
    throw DtypeError(std::string(name) + ": expected a numpy " + DtypeName<T>() + " array of shape " +
                     DescribeExpected(dims) + ", got " + std::string(py::str(py::type::of(obj).attr("__name__"))));
  }
  py::array a = py::reinterpret_borrow<py::array>(obj);
  // equal, not is: an unpickled array (Dask, multiprocessing) has an equal dtype that is
  // another object than numpy's builtin one.
  const bool dtype_ok = a.dtype().equal(py::dtype::of<T>());
  bool shape_ok = a.ndim() == static_cast<py::ssize_t>(dims.size());
  for (std::size_t i = 0; shape_ok && i < dims.size(); ++i) {
    if (dims[i].size >= 0 && a.shape(i) != dims[i].size) shape_ok = false;
  }
  if (!dtype_ok || !shape_ok) {
    std::string msg = std::string(name) + ": expected " + DtypeName<T>() + " array of shape " +
                      DescribeExpected(dims) + ", got " + std::string(py::str(a.dtype())) + " " +
                      DescribeShape(a);
    if (!dtype_ok) throw DtypeError(msg);
    throw ShapeError(msg);
  }
  if (!(a.flags() & py::array::c_style)) {
    throw ShapeError(std::string(name) + ": expected a C-contiguous array (use numpy.ascontiguousarray), got strides " +
                     std::string(py::str(py::make_tuple(a.strides(0)))) + "...");
  }
  if (writable && !a.writeable()) {
    throw BadValueError(std::string(name) + ": expected a writeable array, got a read-only one");
  }
  return py::reinterpret_borrow<py::array_t<T, py::array::c_style>>(a);
}

// Image view over a checked (H, W) or (H, W, C) array.
template <typename T>
ImageView<T> ViewOf(py::array_t<T, py::array::c_style>& a) {
  const int c = a.ndim() == 3 ? static_cast<int>(a.shape(2)) : 1;
  return ImageView<T>(a.mutable_data(), static_cast<int>(a.shape(0)), static_cast<int>(a.shape(1)), c);
}
template <typename T>
ImageView<const T> ConstViewOf(const py::array_t<T, py::array::c_style>& a) {
  const int c = a.ndim() == 3 ? static_cast<int>(a.shape(2)) : 1;
  return ImageView<const T>(a.data(), static_cast<int>(a.shape(0)), static_cast<int>(a.shape(1)), c);
}

// A new, uninitialised numpy array owned by Python (kernels write into it: no copy back).
template <typename T>
py::array_t<T, py::array::c_style> NewArray(std::initializer_list<py::ssize_t> shape) {
  return py::array_t<T, py::array::c_style>(std::vector<py::ssize_t>(shape));
}

// A non-empty list (or tuple) of float32 (h, w, C) arrays of one shape; h, w, c = -1 take the
// first array's size. `writable` for arrays the kernel writes in place.
std::vector<py::array_t<float, py::array::c_style>> CheckArrayList(const py::handle& obj, const char* name,
                                                                    py::ssize_t h, py::ssize_t w, py::ssize_t c,
                                                                    bool writable);

// A second list of arrays that pairs one to one with `first` (same count, same shape each).
std::vector<py::array_t<float, py::array::c_style>> CheckPairedArrayList(
    const py::handle& obj, const char* name, const std::vector<py::array_t<float, py::array::c_style>>& first,
    const char* first_name);

// Whether two arrays' memory ranges overlap (an in-place output must not alias an input).
bool Overlaps(const py::array& a, const py::array& b);

// The `resample` argument of the ULR and PVM colour reads: "cubic" (Catmull-Rom,
// ibr/resample.h) -> true, "bilinear" -> false; anything else is a BadValueError.
bool ParseResample(const std::string& resample);

}  // namespace ibr::bind
