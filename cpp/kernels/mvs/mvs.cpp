#include "kernels/mvs/mvs.h"

#include <cmath>
#include <string>

#include "ibr/errors.h"

namespace ibr::mvs {
namespace {

std::string Num(double v) {
  std::string s = std::to_string(v);
  while (s.size() > 1 && s.back() == '0') s.pop_back();
  if (!s.empty() && s.back() == '.') s.pop_back();
  return s;
}

void CheckCamera(const Camera& c, int h, int w, const std::string& what) {
  if (c.model != CameraModel::kPinhole) throw BadValueError(what + ": multi-view stereo needs pinhole cameras");
  if (c.width != w || c.height != h) {
    throw ShapeError(what + ": image is " + std::to_string(w) + "x" + std::to_string(h) + ", its camera " +
                     std::to_string(c.width) + "x" + std::to_string(c.height));
  }
  if (w < 2 || h < 2) throw ShapeError(what + ": expected at least 2 x 2 pixels");
  if (!(c.fx > 0) || !(c.fy > 0) || !std::isfinite(c.cx) || !std::isfinite(c.cy)) {
    throw BadValueError(what + ": expected a positive finite focal length");
  }
}

void CheckViews(const ImageView<const float>& ref, const Camera& ref_cam, const std::vector<SourceView>& sources) {
  CheckCamera(ref_cam, ref.height, ref.width, "reference view");
  if (sources.empty() || static_cast<int>(sources.size()) > kMaxSourceViews) {
    throw BadValueError("sources: expected 1.." + std::to_string(kMaxSourceViews) + " source views, got " +
                        std::to_string(sources.size()));
  }
  for (std::size_t i = 0; i < sources.size(); ++i) {
    const SourceView& s = sources[i];
    const std::string what = "source " + std::to_string(i);
    CheckCamera(s.camera, s.grey.height, s.grey.width, what);
    if (!s.depth.Empty() && (s.depth.height != s.grey.height || s.depth.width != s.grey.width)) {
      throw ShapeError(what + ": expected a depth map of its image's size");
    }
    const glm::dvec3 d = s.camera.CentreInWorld() - ref_cam.CentreInWorld();
    if (!(glm::length(d) > 0)) {
      throw BadValueError(what + ": its camera centre coincides with the reference's (no baseline, no depth)");
    }
  }
}

}  // namespace

void CheckOptions(const PatchMatchOptions& o) {
  auto bad = [](const std::string& name, const std::string& want, double got) {
    throw BadValueError("mvs." + name + ": expected " + want + ", got " + Num(got));
  };
  if (o.window_radius < 1 || o.window_radius > kMaxWindowRadius) {
    bad("window_radius", "1.." + std::to_string(kMaxWindowRadius), o.window_radius);
  }
  if (o.window_step < 1 || o.window_step > o.window_radius) bad("window_step", "1..window_radius", o.window_step);
  if ((2 * o.window_radius / o.window_step + 1) * (2 * o.window_radius / o.window_step + 1) > 256) {
    bad("window_step", "a step that samples at most 256 window pixels", o.window_step);
  }
  if (!(o.sigma_color > 0) || !std::isfinite(o.sigma_color)) bad("sigma_color", "a positive number", o.sigma_color);
  if (!(o.sigma_spatial > 0) || !std::isfinite(o.sigma_spatial)) {
    bad("sigma_spatial", "a positive number", o.sigma_spatial);
  }
  if (o.iterations < 0 || o.iterations > kMaxIterations) {
    bad("iterations", "0.." + std::to_string(kMaxIterations), o.iterations);
  }
  if (o.first_iteration < 0 || o.first_iteration > kMaxIterations) {
    bad("first_iteration", "0.." + std::to_string(kMaxIterations), o.first_iteration);
  }
  if (o.best_k < 1 || o.best_k > kMaxSourceViews) bad("best_k", "1.." + std::to_string(kMaxSourceViews), o.best_k);
  if (!(o.min_depth > 0) || !std::isfinite(o.min_depth)) bad("min_depth", "a positive finite depth", o.min_depth);
  if (!(o.max_depth > o.min_depth) || !std::isfinite(o.max_depth)) {
    bad("max_depth", "a finite depth above min_depth (" + Num(o.min_depth) + ")", o.max_depth);
  }
  if (!(o.min_variance >= 0) || !std::isfinite(o.min_variance)) bad("min_variance", ">= 0", o.min_variance);
  if (!(o.geom_weight >= 0) || !std::isfinite(o.geom_weight)) bad("geom_weight", ">= 0", o.geom_weight);
  if (!(o.geom_max_error > 0) || !std::isfinite(o.geom_max_error)) {
    bad("geom_max_error", "a positive number of pixels", o.geom_max_error);
  }
}

PatchMatchStats RunPatchMatch(const ImageView<const float>& ref_grey, const Camera& ref_cam,
                              const std::vector<SourceView>& sources, const PatchMatchOptions& options,
                              bool initialised, ImageView<float> depth, ImageView<float> normal,
                              ImageView<float> cost) {
  CheckOptions(options);
  CheckViews(ref_grey, ref_cam, sources);
  const int h = ref_grey.height, w = ref_grey.width;
  if (depth.height != h || depth.width != w || cost.height != h || cost.width != w || normal.height != h ||
      normal.width != w || normal.channels != 3) {
    throw ShapeError("depth, normal, cost: expected (H, W), (H, W, 3), (H, W) of the reference view");
  }
  return PatchMatch(ref_grey, ref_cam, sources, options, initialised, depth, normal, cost);
}

void RunConsistentViews(const ImageView<const float>& ref_depth, const Camera& ref_cam,
                        const std::vector<SourceView>& sources, float max_error_px, float max_rel_depth,
                        float min_angle_deg, ImageView<float> count) {
  CheckCamera(ref_cam, ref_depth.height, ref_depth.width, "reference view");
  for (std::size_t i = 0; i < sources.size(); ++i) {
    const SourceView& s = sources[i];
    CheckCamera(s.camera, s.depth.height, s.depth.width, "source " + std::to_string(i));
  }
  if (!(max_error_px > 0) || !(max_rel_depth > 0) || !(min_angle_deg >= 0) || !std::isfinite(max_error_px) ||
      !std::isfinite(max_rel_depth) || !std::isfinite(min_angle_deg)) {
    throw BadValueError("consistency: expected max_error_px > 0, max_rel_depth > 0, min_angle_deg >= 0");
  }
  ConsistentViews(ref_depth, ref_cam, sources, max_error_px, max_rel_depth, min_angle_deg, count);
}

}  // namespace ibr::mvs
