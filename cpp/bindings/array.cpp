#include "array.h"

namespace ibr::bind {

std::string DescribeShape(const py::array& a) {
  std::ostringstream s;
  s << "(";
  for (py::ssize_t i = 0; i < a.ndim(); ++i) s << (i ? ", " : "") << a.shape(i);
  s << (a.ndim() == 1 ? ",)" : ")");
  return s.str();
}

std::string DescribeExpected(const std::vector<Dim>& dims) {
  std::ostringstream names, sizes;
  names << "(";
  sizes << "(";
  for (std::size_t i = 0; i < dims.size(); ++i) {
    names << (i ? ", " : "") << dims[i].name;
    if (dims[i].size >= 0) sizes << (i ? ", " : "") << dims[i].size;
    else sizes << (i ? ", " : "") << dims[i].name;
  }
  names << (dims.size() == 1 ? ",)" : ")");
  sizes << (dims.size() == 1 ? ",)" : ")");
  const std::string n = names.str(), s = sizes.str();
  return n == s ? n : n + " = " + s;
}

std::vector<py::array_t<float, py::array::c_style>> CheckArrayList(const py::handle& obj, const char* name,
                                                                    py::ssize_t h, py::ssize_t w, py::ssize_t c,
                                                                    bool writable) {
  if (!py::isinstance<py::list>(obj) && !py::isinstance<py::tuple>(obj)) {
    throw DtypeError(std::string(name) + ": expected a list of float32 (h, w, C) arrays, got " +
                     std::string(py::str(py::type::of(obj).attr("__name__"))));
  }
  std::vector<py::array_t<float, py::array::c_style>> out;
  for (py::handle item : obj) {
    const std::string item_name = std::string(name) + "[" + std::to_string(out.size()) + "]";
    auto a = CheckArray<float>(item, item_name.c_str(), {{"h", h}, {"w", w}, {"C", c}}, writable);
    h = a.shape(0);
    w = a.shape(1);
    c = a.shape(2);
    out.push_back(a);
  }
  if (out.empty()) throw ShapeError(std::string(name) + ": expected at least one array, got an empty list");
  if (h < 1 || w < 1 || c < 1) {
    throw ShapeError(std::string(name) + ": expected at least 1 sample and 1 channel, got shape " +
                     DescribeShape(out[0]));
  }
  return out;
}

std::vector<py::array_t<float, py::array::c_style>> CheckPairedArrayList(
    const py::handle& obj, const char* name, const std::vector<py::array_t<float, py::array::c_style>>& first,
    const char* first_name) {
  auto out = CheckArrayList(obj, name, first[0].shape(0), first[0].shape(1), first[0].shape(2), false);
  if (out.size() != first.size()) {
    throw ShapeError(std::string(name) + ": expected one array per " + first_name + " array (" +
                     std::to_string(first.size()) + "), got " + std::to_string(out.size()));
  }
  return out;
}

bool Overlaps(const py::array& a, const py::array& b) {
  const char* a0 = static_cast<const char*>(a.data());
  const char* b0 = static_cast<const char*>(b.data());
  return a0 < b0 + b.nbytes() && b0 < a0 + a.nbytes();
}

bool ParseResample(const std::string& resample) {
  if (resample != "cubic" && resample != "bilinear") {
    throw BadValueError("resample: expected 'cubic' or 'bilinear', got '" + resample + "'");
  }
  return resample == "cubic";
}

}  // namespace ibr::bind
