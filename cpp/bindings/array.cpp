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

}  // namespace ibr::bind
