// One Bind* function per family (cpp/kernels/<family>/ <-> cpp/bindings/<family>.cpp); module.cpp
// calls them all.
#pragma once
#include <pybind11/pybind11.h>

namespace ibr::bind {
namespace py = pybind11;
void BindCore(py::module_& m);
void BindRaycast(py::module_& m);
void BindMetrics(py::module_& m);
void BindDibr(py::module_& m);
void BindInpaint(py::module_& m);
void BindMetamers(py::module_& m);
void BindSolvers(py::module_& m);
void BindDepthwarp(py::module_& m);
void BindHybrid(py::module_& m);
void BindMvs(py::module_& m);
}  // namespace ibr::bind
