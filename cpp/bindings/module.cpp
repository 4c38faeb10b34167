#include "module.h"

PYBIND11_MODULE(_core, m) {
  m.doc() =
      "ibrtools C++ engine. Layers, top to bottom: cli -> ibrtools (Python) -> _core (these bindings) -> "
      "the kernel families' fronts and kernels (cpp/kernels/<family>/) -> cpp/ibr; nothing reaches upwards";
  ibr::bind::BindCore(m);
  ibr::bind::BindRaycast(m);
  ibr::bind::BindMetrics(m);
  ibr::bind::BindDibr(m);
  ibr::bind::BindInpaint(m);
  ibr::bind::BindMetamers(m);
  ibr::bind::BindSolvers(m);
  ibr::bind::BindDepthwarp(m);
  ibr::bind::BindHybrid(m);
  ibr::bind::BindMvs(m);
}
