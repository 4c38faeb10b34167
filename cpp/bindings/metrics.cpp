#include "module.h"
namespace ibr::bind {
void BindMetrics(py::module_& m) {}
}  // namespace ibr::bind
