// Binding of the hybrid rendering kernels (cpp/kernels/hybrid/hybrid.h, cpp/kernels/hybrid/ulr.h):
// _core.interpolate_vertex_attribute (TM colour / view-dependent texture from the G-buffer),
// _core.sample_atlas (TM colour from the texture atlas at the G-buffer's hits),
// _core.ulr_penalty / _core.ulr_select (the shared ULR ranking, for tests and Python callers),
// _core.ulr_blend (per-pixel ULR), _core.hybrid_select, _core.blur_selection,
// _core.hybrid_composite. Thin: checks arrays (array.h) and values, allocates the outputs,
// releases the GIL around the kernels.
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "array.h"
#include "ibr/camera.h"
#include "ibr/errors.h"
#include "kernels/hybrid/atlas8.h"
#include "kernels/hybrid/gbuffer_raster.h"
#include "kernels/hybrid/hybrid.h"
#include "kernels/hybrid/ulr.h"
#include "module.h"

namespace ibr::bind {
namespace {

using FArray = py::array_t<float, py::array::c_style>;

void CheckLabels(const py::array_t<std::uint8_t, py::array::c_style>& label) {
  const std::uint8_t* l = label.data();
  for (py::ssize_t i = 0; i < label.size(); ++i) {
    if (l[i] > kLabelNone) throw BadValueError("label: values must be 0 (TM), 1 (ULR), 2 (PVM) or 3 (none)");
  }
}

const std::uint8_t* BoolData(const py::array_t<bool, py::array::c_style>& a) {
  return reinterpret_cast<const std::uint8_t*>(a.data());
}

float CheckFinite(double v, const char* name, double lo) {
  if (!std::isfinite(v) || v < lo) {
    throw BadValueError(std::string(name) + ": expected a finite number >= " + std::to_string(lo) + ", got " +
                        std::to_string(v));
  }
  return static_cast<float>(v);
}

// The G-buffer hits a per-pixel read indexes: prim ids in [-1, m) (-1 = no hit) and, at the hits,
// finite barycentrics (a non-finite one would make the interpolated position undefined).
void CheckHits(const py::array_t<std::int32_t, py::array::c_style>& prim,
               const py::array_t<float, py::array::c_style>& bary, py::ssize_t m) {
  const auto w = prim.shape(1);
  const std::int32_t* p = prim.data();
  const float* ba = bary.data();
  for (py::ssize_t i = 0; i < prim.size(); ++i) {
    if (p[i] < -1 || p[i] >= m) {
      throw BadValueError("prim_id: " + std::to_string(p[i]) + " is not a face index in [-1, " + std::to_string(m) +
                          ")");
    }
    if (p[i] >= 0 && !(std::isfinite(ba[2 * i]) && std::isfinite(ba[2 * i + 1]))) {
      throw BadValueError("bary: expected finite barycentrics where prim_id >= 0, got (" + std::to_string(ba[2 * i]) +
                          ", " + std::to_string(ba[2 * i + 1]) + ") at pixel (" + std::to_string(i / w) + ", " +
                          std::to_string(i % w) + ")");
    }
  }
}

FArray InterpolateVertexAttributeBinding(const py::object& prim_obj, const py::object& bary_obj,
                                         const py::object& faces_obj, const py::object& attrib_obj) {
  auto prim = CheckArray<std::int32_t>(prim_obj, "prim_id", {{"H", -1}, {"W", -1}});
  const auto h = prim.shape(0), w = prim.shape(1);
  auto bary = CheckArray<float>(bary_obj, "bary", {{"H", h}, {"W", w}, {"2", 2}});
  auto faces = CheckArray<std::int32_t>(faces_obj, "faces", {{"M", -1}, {"3", 3}});
  py::array a = py::reinterpret_borrow<py::array>(attrib_obj);
  const bool one_channel = py::isinstance<py::array>(attrib_obj) && a.ndim() == 1;
  auto attrib = one_channel ? CheckArray<float>(attrib_obj, "attrib", {{"N", -1}})
                            : CheckArray<float>(attrib_obj, "attrib", {{"N", -1}, {"C", -1}});
  const auto n = attrib.shape(0);
  const int channels = one_channel ? 1 : static_cast<int>(attrib.shape(1));
  if (channels < 1) throw ShapeError("attrib: expected at least one channel, got 0");
  CheckHits(prim, bary, faces.shape(0));
  FArray out = one_channel ? NewArray<float>({h, w}) : NewArray<float>({h, w, channels});
  std::int64_t bad = -1;  // a hit face with a vertex index out of range (not read; faces no pixel hits are not read)
  {
    py::gil_scoped_release release;
    bad = InterpolateVertexAttribute(prim.data(), bary.data(), static_cast<std::int64_t>(h) * w, faces.data(),
                                     attrib.data(), n, channels, out.mutable_data());
  }
  if (bad >= 0) {
    const std::int32_t* fv = faces.data() + 3 * static_cast<py::ssize_t>(prim.data()[bad]);
    throw BadValueError("faces: face " + std::to_string(prim.data()[bad]) + " (hit at pixel (" +
                        std::to_string(bad / w) + ", " + std::to_string(bad % w) + ")) has vertex indices (" +
                        std::to_string(fv[0]) + ", " + std::to_string(fv[1]) + ", " + std::to_string(fv[2]) +
                        "), expected each in [0, " + std::to_string(n) + ")");
  }
  return out;
}

FArray SampleAtlasBinding(const py::object& prim_obj, const py::object& bary_obj, const py::object& uv_obj,
                          const py::object& atlas_obj) {
  auto prim = CheckArray<std::int32_t>(prim_obj, "prim_id", {{"H", -1}, {"W", -1}});
  const auto h = prim.shape(0), w = prim.shape(1);
  auto bary = CheckArray<float>(bary_obj, "bary", {{"H", h}, {"W", w}, {"2", 2}});
  auto uv = CheckArray<float>(uv_obj, "uv", {{"M", -1}, {"3", 3}, {"2", 2}});
  // float32 (h, w, 3) linear RGB, or uint8 (h, w, 4) sRGB RGBA (kernels/hybrid/atlas8.h).
  const bool srgb8 = py::isinstance<py::array>(atlas_obj) &&
                     py::reinterpret_borrow<py::array>(atlas_obj).dtype().is(py::dtype::of<std::uint8_t>());
  py::array_t<float, py::array::c_style> atlas;
  py::array_t<std::uint8_t, py::array::c_style> atlas8;
  if (srgb8) {
    atlas8 = CheckArray<std::uint8_t>(atlas_obj, "atlas", {{"h", -1}, {"w", -1}, {"4", 4}});
  } else {
    atlas = CheckArray<float>(atlas_obj, "atlas", {{"h", -1}, {"w", -1}, {"3", 3}});
  }
  const auto ah = srgb8 ? atlas8.shape(0) : atlas.shape(0), aw = srgb8 ? atlas8.shape(1) : atlas.shape(1);
  if (ah < 1 || aw < 1) {
    throw ShapeError("atlas: expected at least 1 x 1 texels, got " + std::to_string(ah) + " x " + std::to_string(aw));
  }
  CheckHits(prim, bary, uv.shape(0));
  FArray out = NewArray<float>({h, w, py::ssize_t(3)});
  std::int64_t bad = -1;  // a hit whose face uv are not finite (the kernel reads no texel there)
  {
    py::gil_scoped_release release;
    if (srgb8) {
      bad = SampleAtlasSrgb8(prim.data(), bary.data(), static_cast<std::int64_t>(h) * w, uv.data(),
                             ConstViewOf(atlas8), out.mutable_data());
    } else {
      bad = SampleAtlas(prim.data(), bary.data(), static_cast<std::int64_t>(h) * w, uv.data(), ConstViewOf(atlas),
                        out.mutable_data());
    }
  }
  if (bad >= 0) {
    throw BadValueError("uv: expected finite coordinates, face " + std::to_string(prim.data()[bad]) +
                        " (hit at pixel (" + std::to_string(bad / w) + ", " + std::to_string(bad % w) +
                        ")) has a non-finite one");
  }
  return out;
}

// The input views of ULR and of the texture bake: each (camera, colour (h, w, 3), depth (h, w)) with
// (h, w) the camera's size; the checked arrays are appended to `keep` (the views point into them).
std::vector<UlrInputView> InputViews(const py::list& views_obj, std::vector<FArray>& keep) {
  std::vector<UlrInputView> views;
  for (std::size_t i = 0; i < views_obj.size(); ++i) {
    const std::string nm = "views[" + std::to_string(i) + "]";
    py::handle item = views_obj[i];
    if (!py::isinstance<py::tuple>(item) || py::len(item) != 3) throw DtypeError(nm + ": expected a (camera, color, depth) tuple");
    py::tuple t = py::reinterpret_borrow<py::tuple>(item);
    if (!py::isinstance<Camera>(t[0])) throw DtypeError(nm + "[0]: expected a _core.Camera");
    UlrInputView v;
    v.camera = t[0].cast<Camera>();
    if (v.camera.width < 1 || v.camera.height < 1) throw ShapeError(nm + ": expected a camera of at least 1 x 1 pixels");
    const std::string cn = nm + ".color", dn = nm + ".depth";
    auto c = CheckArray<float>(t[1], cn.c_str(), {{"h", v.camera.height}, {"w", v.camera.width}, {"3", 3}});
    auto d = CheckArray<float>(t[2], dn.c_str(), {{"h", v.camera.height}, {"w", v.camera.width}});
    v.color = ConstViewOf(c);
    v.depth = ConstViewOf(d);
    keep.push_back(c);
    keep.push_back(d);
    views.push_back(v);
  }
  return views;
}

// _core.point_colors (kernels/hybrid/atlas8.h PointColors): the texture bake's ULR-weighted colour at points.
py::tuple PointColorsBinding(const py::object& points_obj, const py::object& normals_obj, const py::list& views_obj,
                             int k, double depth_tol) {
  if (k < 1) throw BadValueError("k: expected >= 1 views per point, got " + std::to_string(k));
  PointColorOptions opt;
  opt.k = k;
  opt.depth_tol = CheckFinite(depth_tol, "depth_tol", 0.0);
  auto points = CheckArray<double>(points_obj, "points", {{"N", -1}, {"3", 3}});
  const auto n = points.shape(0);
  auto normals = CheckArray<double>(normals_obj, "normals", {{"N", n}, {"3", 3}});
  if (views_obj.size() == 0) throw BadValueError("views: expected at least one (camera, color, depth)");
  std::vector<FArray> keep;
  const std::vector<UlrInputView> views = InputViews(views_obj, keep);
  FArray color = NewArray<float>({n, py::ssize_t(3)});
  auto seen = py::array_t<std::int32_t, py::array::c_style>(std::vector<py::ssize_t>{n});
  {
    py::gil_scoped_release release;
    PointColors(points.data(), normals.data(), static_cast<std::int64_t>(n), views.data(),
                static_cast<int>(views.size()), opt, color.mutable_data(), seen.mutable_data());
  }
  return py::make_tuple(color, seen);
}

// _core.texel_points (kernels/hybrid/atlas8.h TexelPoints): the used texels of a band of atlas rows,
// their barycentrics, surface points and unit normals.
py::tuple TexelPointsBinding(const py::object& fot_obj, int row0, const py::object& uv_obj,
                             const py::object& vertices_obj, const py::object& faces_obj,
                             const py::object& normals_obj) {
  auto fot = CheckArray<std::int32_t>(fot_obj, "face_of_texel", {{"rows", -1}, {"W", -1}});
  auto faces = CheckArray<std::int32_t>(faces_obj, "faces", {{"M", -1}, {"3", 3}});
  const py::ssize_t m = faces.shape(0);
  auto uv = CheckArray<float>(uv_obj, "uv", {{"M", m}, {"3", 3}, {"2", 2}});
  auto vertices = CheckArray<float>(vertices_obj, "vertices", {{"N", -1}, {"3", 3}});
  const py::ssize_t nv = vertices.shape(0);
  auto normals = CheckArray<float>(normals_obj, "normals", {{"N", nv}, {"3", 3}});
  if (row0 < 0) throw BadValueError("row0: expected >= 0, got " + std::to_string(row0));
  const py::ssize_t rows = fot.shape(0), width = fot.shape(1);
  const std::int32_t* fo = fot.data();
  for (py::ssize_t i = 0; i < rows * width; ++i) {
    if (fo[i] < -1 || fo[i] >= m) {
      throw BadValueError("face_of_texel: face " + std::to_string(fo[i]) + " out of range [-1, " + std::to_string(m) +
                          ")");
    }
  }
  const std::int32_t* f = faces.data();
  for (py::ssize_t i = 0; i < 3 * m; ++i) {
    if (f[i] < 0 || f[i] >= nv) {
      throw BadValueError("faces: vertex " + std::to_string(f[i]) + " out of range [0, " + std::to_string(nv) + ")");
    }
  }
  std::vector<std::int64_t> row_start(static_cast<std::size_t>(rows) + 1);
  TexelRowStarts(fo, static_cast<int>(rows), static_cast<int>(width), row_start.data());
  const py::ssize_t t = row_start.back();
  auto ys = NewArray<std::int64_t>({t});
  auto xs = NewArray<std::int64_t>({t});
  auto face = NewArray<std::int32_t>({t});
  auto bary = NewArray<double>({t, py::ssize_t(3)});
  auto pts = NewArray<double>({t, py::ssize_t(3)});
  auto nrm = NewArray<double>({t, py::ssize_t(3)});
  {
    py::gil_scoped_release release;
    TexelPoints(fo, row_start.data(), static_cast<int>(rows), static_cast<int>(width), row0, uv.data(),
                vertices.data(), faces.data(), normals.data(), ys.mutable_data(), xs.mutable_data(),
                face.mutable_data(), bary.mutable_data(), pts.mutable_data(), nrm.mutable_data());
  }
  return py::make_tuple(ys, xs, face, bary, pts, nrm);
}

py::dict RasterGBufferBinding(const Camera& camera, const py::object& vertices_obj, const py::object& faces_obj,
                              bool normal) {
  if (camera.model != CameraModel::kPinhole) {
    throw BadValueError("raster_gbuffer: pinhole cameras only (use the ray caster for equirect)");
  }
  if (camera.width < 1 || camera.height < 1) throw BadValueError("raster_gbuffer: the camera has no pixels");
  auto vertices = CheckArray<float>(vertices_obj, "vertices", {{"N", -1}, {"3", 3}});
  auto faces = CheckArray<std::int32_t>(faces_obj, "faces", {{"M", -1}, {"3", 3}});
  const auto n = vertices.shape(0), m = faces.shape(0);
  {
    const float* v = vertices.data();
    for (py::ssize_t i = 0; i < 3 * n; ++i) {
      if (!std::isfinite(v[i])) throw BadValueError("vertices: expected finite coordinates");
    }
    const std::int32_t* f = faces.data();
    for (py::ssize_t i = 0; i < 3 * m; ++i) {
      if (f[i] < 0 || f[i] >= n) {
        throw BadValueError("faces: index " + std::to_string(f[i]) + " out of range for " + std::to_string(n) +
                            " vertices");
      }
    }
  }
  const py::ssize_t h = camera.height, w = camera.width;
  FArray depth = NewArray<float>({h, w});
  auto prim = NewArray<std::int32_t>({h, w});
  FArray bary = NewArray<float>({h, w, py::ssize_t(2)});
  FArray nrm = normal ? NewArray<float>({h, w, py::ssize_t(3)}) : FArray();
  {
    py::gil_scoped_release release;
    RasterGBuffer(camera, vertices.data(), n, faces.data(), m, depth.mutable_data(), prim.mutable_data(),
                  bary.mutable_data(), normal ? nrm.mutable_data() : nullptr);
  }
  py::dict out;
  out["depth"] = depth;
  out["prim_id"] = prim;
  out["bary"] = bary;
  if (normal) out["normal"] = nrm;
  return out;
}

py::tuple UlrBlendBinding(const Camera& novel, const py::object& depth_obj, const py::list& views_obj,
                          const py::object& normal_obj, const py::object& mask_obj, int k, double resolution_weight,
                          double depth_tol, const std::string& resample, bool reference, const std::string& simd) {
  if (k < 1 || k > 64) throw BadValueError("k: expected 1 .. 64 views per pixel, got " + std::to_string(k));
  UlrOptions opt;
  opt.k = k;
  opt.resolution_weight = CheckFinite(resolution_weight, "resolution_weight", 0.0);
  opt.depth_tol = CheckFinite(depth_tol, "depth_tol", 0.0);
  opt.reference = reference;
  opt.cubic = ParseResample(resample);
  if (simd == "sse2") {
    opt.simd = UlrSimd::kSse2;
  } else if (simd == "avx2") {
    opt.simd = UlrSimd::kAvx2;
  } else if (simd != "auto") {
    throw BadValueError("simd: expected 'auto', 'avx2' or 'sse2', got '" + simd + "'");
  }
  auto depth = CheckArray<float>(depth_obj, "gbuffer_depth", {{"H", novel.height}, {"W", novel.width}});
  const auto h = depth.shape(0), w = depth.shape(1);
  FArray normal;
  if (!normal_obj.is_none()) normal = CheckArray<float>(normal_obj, "normal", {{"H", h}, {"W", w}, {"3", 3}});
  py::array_t<bool, py::array::c_style> mask;
  if (!mask_obj.is_none()) mask = CheckArray<bool>(mask_obj, "pixel_mask", {{"H", h}, {"W", w}});
  std::vector<FArray> keep;
  const std::vector<UlrInputView> views = InputViews(views_obj, keep);
  FArray color = NewArray<float>({h, w, 3});
  auto count = py::array_t<std::uint8_t, py::array::c_style>(std::vector<py::ssize_t>{h, w});
  {
    py::gil_scoped_release release;
    UlrBlend(novel, ConstViewOf(depth), normal_obj.is_none() ? ImageView<const float>() : ConstViewOf(normal),
             mask_obj.is_none() ? nullptr : BoolData(mask), views.data(), static_cast<int>(views.size()), opt,
             ViewOf(color), ViewOf(count));
  }
  return py::make_tuple(color, count);
}

py::array_t<std::uint8_t> HybridSelectBinding(const py::object& depth_obj, const py::object& inside_obj,
                                              const py::object& valid_obj, const py::object& pvm_depth_obj,
                                              const py::object& vd_obj, double geo_threshold, double tau_var) {
  auto depth = CheckArray<float>(depth_obj, "gbuffer_depth", {{"H", -1}, {"W", -1}});
  const auto h = depth.shape(0), w = depth.shape(1);
  HybridSelectOptions opt;
  opt.geo_threshold = CheckFinite(geo_threshold, "geo_threshold", 0.0);
  if (!std::isfinite(tau_var)) throw BadValueError("tau_var: expected a finite number, got " + std::to_string(tau_var));
  opt.tau_var = static_cast<float>(tau_var);
  py::array_t<bool, py::array::c_style> inside, valid;
  FArray pvm_depth, vd;
  if (!inside_obj.is_none()) inside = CheckArray<bool>(inside_obj, "inside_grid", {{"H", h}, {"W", w}});
  if (valid_obj.is_none() != pvm_depth_obj.is_none()) {
    throw BadValueError("pvm_valid and pvm_depth: give both or neither");
  }
  if (!valid_obj.is_none()) {
    valid = CheckArray<bool>(valid_obj, "pvm_valid", {{"H", h}, {"W", w}});
    pvm_depth = CheckArray<float>(pvm_depth_obj, "pvm_depth", {{"H", h}, {"W", w}});
  }
  if (!vd_obj.is_none()) vd = CheckArray<float>(vd_obj, "vd", {{"H", h}, {"W", w}});
  auto label = py::array_t<std::uint8_t, py::array::c_style>(std::vector<py::ssize_t>{h, w});
  {
    py::gil_scoped_release release;
    HybridSelect(ConstViewOf(depth), inside_obj.is_none() ? nullptr : BoolData(inside),
                 valid_obj.is_none() ? nullptr : BoolData(valid), valid_obj.is_none() ? nullptr : pvm_depth.data(),
                 vd_obj.is_none() ? nullptr : vd.data(), opt, ViewOf(label));
  }
  return label;
}

FArray BlurSelectionBinding(const py::object& label_obj, double sigma, double min_weight, bool decimate,
                            double pvm_floor) {
  auto label = CheckArray<std::uint8_t>(label_obj, "label", {{"H", -1}, {"W", -1}});
  const float s = CheckFinite(sigma, "sigma_blur", 0.0);
  if (s > 1000.f) throw BadValueError("sigma_blur: expected <= 1000 pixels, got " + std::to_string(sigma));
  const float mw = CheckFinite(min_weight, "min_weight", 0.0);
  if (!(min_weight <= 1.0 / 3.0))
    throw BadValueError("min_weight: expected a weight in [0, 1/3], got " + std::to_string(min_weight));
  const float floor = CheckFinite(pvm_floor, "pvm_floor", 0.0);
  if (!(pvm_floor <= 1.0)) throw BadValueError("pvm_floor: expected a weight in [0, 1], got " + std::to_string(pvm_floor));
  const auto h = label.shape(0), w = label.shape(1);
  CheckLabels(label);
  FArray out = NewArray<float>({h, w, 3});
  // The full-resolution blur's planes (written before read); the decimated one needs none.
  std::unique_ptr<float[]> scratch;
  if (!decimate || BlurSelectionFactor(s) == 1) scratch.reset(new float[static_cast<std::size_t>(h) * w * 3]);
  {
    py::gil_scoped_release release;
    BlurSelection(ConstViewOf(label), s, mw, scratch.get(), ViewOf(out), decimate);
    FloorPvmWeight(ViewOf(out), floor);
  }
  return out;
}

FArray HybridCompositeBinding(const py::object& weights_obj, const py::object& tm_obj, const py::object& ulr_obj,
                              const py::object& ulr_count_obj, const py::object& pvm_obj, const py::object& valid_obj) {
  auto weights = CheckArray<float>(weights_obj, "weights", {{"H", -1}, {"W", -1}, {"3", 3}});
  const auto h = weights.shape(0), w = weights.shape(1);
  auto tm = CheckArray<float>(tm_obj, "tm", {{"H", h}, {"W", w}, {"3", 3}});
  if (ulr_obj.is_none() != ulr_count_obj.is_none()) throw BadValueError("ulr and ulr_count: give both or neither");
  if (pvm_obj.is_none() != valid_obj.is_none()) throw BadValueError("pvm and pvm_valid: give both or neither");
  FArray ulr, pvm;
  py::array_t<std::uint8_t, py::array::c_style> count;
  py::array_t<bool, py::array::c_style> valid;
  if (!ulr_obj.is_none()) {
    ulr = CheckArray<float>(ulr_obj, "ulr", {{"H", h}, {"W", w}, {"3", 3}});
    count = CheckArray<std::uint8_t>(ulr_count_obj, "ulr_count", {{"H", h}, {"W", w}});
  }
  if (!pvm_obj.is_none()) {
    pvm = CheckArray<float>(pvm_obj, "pvm", {{"H", h}, {"W", w}, {"3", 3}});
    valid = CheckArray<bool>(valid_obj, "pvm_valid", {{"H", h}, {"W", w}});
  }
  FArray out = NewArray<float>({h, w, 3});
  {
    py::gil_scoped_release release;
    HybridComposite(ConstViewOf(weights), ConstViewOf(tm), ulr_obj.is_none() ? nullptr : ulr.data(),
                    ulr_obj.is_none() ? nullptr : count.data(), pvm_obj.is_none() ? nullptr : pvm.data(),
                    pvm_obj.is_none() ? nullptr : BoolData(valid), ViewOf(out));
  }
  return out;
}

py::tuple HybridNeedsBinding(const py::object& weights_obj, const py::object& valid_obj) {
  auto weights = CheckArray<float>(weights_obj, "weights", {{"H", -1}, {"W", -1}, {"3", 3}});
  const auto h = weights.shape(0), w = weights.shape(1);
  auto valid = CheckArray<bool>(valid_obj, "pvm_valid", {{"H", h}, {"W", w}});
  auto need_ulr = NewArray<bool>({h, w});
  auto need_pvm = NewArray<bool>({h, w});
  std::int64_t counts[2] = {0, 0};
  {
    py::gil_scoped_release release;
    HybridNeeds(ConstViewOf(weights), BoolData(valid), reinterpret_cast<std::uint8_t*>(need_ulr.mutable_data()),
                reinterpret_cast<std::uint8_t*>(need_pvm.mutable_data()), counts);
  }
  return py::make_tuple(need_ulr, need_pvm, counts[0], counts[1]);
}

py::dict HybridFrameOutputsBinding(const py::object& label_obj, const py::object& weights_obj,
                                   const py::object& gdepth_obj, const py::object& pvm_depth_obj) {
  auto label = CheckArray<std::uint8_t>(label_obj, "label", {{"H", -1}, {"W", -1}});
  const auto h = label.shape(0), w = label.shape(1);
  CheckLabels(label);
  auto weights = CheckArray<float>(weights_obj, "weights", {{"H", h}, {"W", w}, {"3", 3}});
  auto gdepth = CheckArray<float>(gdepth_obj, "gbuffer_depth", {{"H", h}, {"W", w}});
  auto pdepth = CheckArray<float>(pvm_depth_obj, "pvm_depth", {{"H", h}, {"W", w}});
  auto hole = NewArray<bool>({h, w});
  FArray depth = NewArray<float>({h, w});
  FArray selection = NewArray<float>({h, w, 3});
  std::int64_t counts[4] = {0, 0, 0, 0};
  {
    py::gil_scoped_release release;
    HybridFrameOutputs(ConstViewOf(label), ConstViewOf(weights), gdepth.data(), pdepth.data(),
                       reinterpret_cast<std::uint8_t*>(hole.mutable_data()), depth.mutable_data(),
                       selection.mutable_data(), counts);
  }
  py::dict out;
  out["hole"] = hole;
  out["depth"] = depth;
  out["selection"] = selection;
  out["label_counts"] = py::make_tuple(counts[0], counts[1], counts[2], counts[3]);
  return out;
}

}  // namespace

void BindHybridRender(py::module_& m) {
  m.def("interpolate_vertex_attribute", &InterpolateVertexAttributeBinding, py::arg("prim_id"), py::arg("bary"),
        py::arg("faces"), py::arg("attrib"),
        "Per-vertex attribute (N,) or (N, C) float32 interpolated at each pixel's hit (prim_id (H, W) int32, "
        "-1 = none; bary (H, W, 2) Embree (u, v)): (H, W) or (H, W, C), 0 where nothing is hit.");
  m.def("raster_gbuffer", &RasterGBufferBinding, py::arg("camera"), py::arg("vertices"), py::arg("faces"),
        py::kw_only(), py::arg("normal") = true,
        "G-buffer of a triangle mesh by rasterisation (pinhole cameras): the nearest face at each pixel centre, "
        "as the Embree ray caster gives it. vertices (N, 3) float32 world, faces (M, 3) int32. Returns a dict: depth "
        "(H, W) float32 z (0 = no hit), prim_id (H, W) int32 (-1), bary (H, W, 2) float32 Embree (u, v), and with "
        "normal=True the unit geometric normal (H, W, 3) in world axes facing the camera.");
  m.def("sample_atlas", &SampleAtlasBinding, py::arg("prim_id"), py::arg("bary"), py::arg("uv"), py::arg("atlas"),
        "TM colour from a texture atlas: atlas (h, w, 3) float32 linear RGB, or (h, w, 4) uint8 sRGB RGBA (decoded to "
        "linear per texel, alpha unused), read bilinearly (edge-clamped) at each pixel's hit "
        "(prim_id (H, W) int32, -1 = none; bary (H, W, 2) Embree (u, v)) at the face's uv (M, 3, 2) float32 in atlas "
        "pixels (x right, y down, centres at +0.5): (H, W, 3), 0 where nothing is hit. The hits' barycentrics and "
        "their faces' uv must be finite.");
  m.def("texel_points", &TexelPointsBinding, py::arg("face_of_texel"), py::arg("row0"), py::arg("uv"),
        py::arg("vertices"), py::arg("faces"), py::arg("normals"),
        "The used texels of atlas rows row0.. (face_of_texel (rows, W) int32, -1 = unused; kernels/hybrid/atlas8.h "
        "TexelPoints), row-major: (ys (T,) int64 absolute rows, xs (T,) int64, face (T,) int32, bary (T, 3) float64 "
        "of the texel centre in the face's chart uv (M, 3, 2), clamped to the face; points (T, 3) float64 on the "
        "mesh (vertices (N, 3) float32, faces (M, 3) int32), unit normals (T, 3) float64 of normals (N, 3) float32).");
  m.def("point_colors", &PointColorsBinding, py::arg("points"), py::arg("normals"), py::arg("views"), py::kw_only(),
        py::arg("k") = 4, py::arg("depth_tol") = 0.02,
        "ULR-weighted colour of the views at surface points (the texture bake; kernels/hybrid/atlas8.h PointColors): "
        "points, normals (N, 3) float64 (unit normals), views = [(camera, color (h, w, 3), depth (h, w)), ...] -> "
        "(color (N, 3) float32, 0 where no view sees the point; seen (N,) int32 views that see it).");
  m.def(
      "ulr_penalty",
      [](const std::vector<float>& p, const std::vector<float>& c_novel, const std::vector<float>& c_view,
         double resolution_weight, bool fast) {
        if (p.size() != 3 || c_novel.size() != 3 || c_view.size() != 3) {
          throw ShapeError("ulr_penalty: p, c_novel and c_view must have 3 coordinates each");
        }
        const glm::vec3 pp(p[0], p[1], p[2]), cn(c_novel[0], c_novel[1], c_novel[2]);
        const glm::vec3 cv(c_view[0], c_view[1], c_view[2]);
        if (fast) return UlrPenaltyFast(pp, cn - pp, glm::length(cn - pp), cv, static_cast<float>(resolution_weight));
        return UlrPenalty(pp, cn, cv, static_cast<float>(resolution_weight));
      },
      py::arg("p"), py::arg("c_novel"), py::arg("c_view"), py::arg("resolution_weight") = 0.5, py::arg("fast") = false,
      "ULR penalty (cpp/kernels/hybrid/ulr.h): angle + resolution_weight * max(0, |c_view-p|/|c_novel-p| - 1); "
      "fast=True: the per-pixel kernel's version (polynomial atan2, within 2e-5).");
  m.def(
      "ulr_select",
      [](const py::object& pen_obj, int k) {
        auto pen = CheckArray<float>(pen_obj, "penalty", {{"n", -1}});
        if (k < 1 || k > 64) throw BadValueError("k: expected 1 .. 64, got " + std::to_string(k));
        std::vector<int> idx(k);
        std::vector<float> wt(k);
        const int mm = UlrSelect(pen.data(), static_cast<int>(pen.shape(0)), k, idx.data(), wt.data());
        idx.resize(mm);
        wt.resize(mm);
        return py::make_tuple(idx, wt);
      },
      py::arg("penalty"), py::arg("k"),
      "The k smallest finite penalties (cpp/kernels/hybrid/ulr.h UlrSelect): (indices, weights summing to 1).");
  m.def("ulr_blend", &UlrBlendBinding, py::arg("camera"), py::arg("gbuffer_depth"), py::arg("views"), py::kw_only(),
        py::arg("normal") = py::none(), py::arg("pixel_mask") = py::none(), py::arg("k") = 4,
        py::arg("resolution_weight") = 0.5, py::arg("depth_tol") = 0.005, py::arg("resample") = "cubic",
        py::arg("reference") = false, py::arg("simd") = "auto",
        "Per-pixel ULR at the G-buffer's points: views = [(camera, color, depth), ...] -> (color (H, W, 3), "
        "count (H, W) uint8 views used, 0 = none sees the point). resample: the views' colour reads, 'cubic' "
        "(Catmull-Rom, clamped to the 2 x 2 texels' range) or 'bilinear'. reference=True: the scalar reference path "
        "(double projections) instead of the fast one (float, SIMD over views; pinhole views only). "
        "simd='auto' follows set_warp_isa (AVX-512 / AVX2 where the CPU has them, SSE2 under 'baseline'); "
        "'avx2' / 'sse2': the fast path at most AVX2 / in SSE2 even where the CPU has more (the same bits; for tests).");
  m.def("hybrid_select", &HybridSelectBinding, py::arg("gbuffer_depth"), py::kw_only(),
        py::arg("inside_grid") = py::none(), py::arg("pvm_valid") = py::none(), py::arg("pvm_depth") = py::none(),
        py::arg("vd") = py::none(), py::arg("geo_threshold") = 0.03, py::arg("tau_var") = 0.82,
        "Per-pixel method (Prakash et al. 2021 Fig. 7): uint8 (H, W) 0 TM, 1 ULR, 2 PVM, 3 nothing to render. "
        "Defaults: the paper's values; --method hybrid passes its own (render/hybrid.py HYBRID_DEFAULTS: tau_var 0).");
  m.def("blur_selection", &BlurSelectionBinding, py::arg("label"), py::arg("sigma_blur"), py::arg("min_weight") = 0.0,
        py::arg("decimate") = false, py::arg("pvm_floor") = 0.0,
        "Gaussian-blurred one-hot selection weights (H, W, 3) = (TM, ULR, PVM), normalised to sum 1; "
        "weights below min_weight (<= 1/3) set to 0 and the rest normalised again. decimate: for sigma_blur >= 8, "
        "blur at 1/f resolution (f = min(4, sigma_blur // 4)) on block means and read back bilinearly "
        "(the same Gaussian to ~1e-3). AVX2 loops as set_warp_isa allows (the same bits). pvm_floor (in [0, 1]): "
        "last, where the weights sum to > 0 and PVM's is below it, PVM's becomes pvm_floor and TM's and ULR's are "
        "scaled by (1 - pvm_floor) / (1 - pvm) (0: no change).");
  m.def("hybrid_composite", &HybridCompositeBinding, py::arg("weights"), py::arg("tm"), py::kw_only(),
        py::arg("ulr") = py::none(), py::arg("ulr_count") = py::none(), py::arg("pvm") = py::none(),
        py::arg("pvm_valid") = py::none(),
        "Composite of TM, ULR and PVM colours by the selection weights, with fallbacks (PVM -> ULR -> TM).");
  m.def("hybrid_needs", &HybridNeedsBinding, py::arg("weights"), py::arg("pvm_valid"),
        "Where the composite needs colours: (need_ulr, need_pvm, n_ulr, n_pvm). need_pvm = PVM weight > 0 and "
        "pvm_valid; need_ulr = ULR weight > 0, or PVM weight > 0 where the PVM is not valid.");
  m.def("hybrid_frame_outputs", &HybridFrameOutputsBinding, py::arg("label"), py::arg("weights"),
        py::arg("gbuffer_depth"), py::arg("pvm_depth"),
        "The hybrid frame's hole (label none, no weight), depth (PVM's where the label is PVM, else the G-buffer's), "
        "selection image (red PVM, green TM, blue ULR weights) and label_counts (tm, ulr, pvm, none).");
}

}  // namespace ibr::bind
