#include "module.h"

PYBIND11_MODULE(_core, m) {
  m.doc() = "ibrtools C++ engine (see DESIGN.md: cli -> ibrtools -> _core -> cpp/ibr -> cpp/kernels)";
  ibr::bind::BindCore(m);
  ibr::bind::BindRaycast(m);
  ibr::bind::BindMetrics(m);
  ibr::bind::BindDibr(m);
  ibr::bind::BindInpaint(m);
  ibr::bind::BindSteerable(m);
  ibr::bind::BindMetameric(m);
  ibr::bind::BindMip(m);
  ibr::bind::BindSolvers(m);
  ibr::bind::BindDepthwarp(m);
  ibr::bind::BindCulling(m);
  ibr::bind::BindHybrid(m);
  ibr::bind::BindHybridRender(m);
  ibr::bind::BindPvmRender(m);
  ibr::bind::BindHarmonise(m);
  ibr::bind::BindMvs(m);
}
