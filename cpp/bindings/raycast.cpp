#include "module.h"
namespace ibr::bind {
void BindRaycast(py::module_& m) {}
}  // namespace ibr::bind
