// The hybrid family's front (front.h) and the checks of its options (hybrid.h).
#include "kernels/hybrid/front.h"

#include <algorithm>
#include <chrono>
#include <climits>
#include <cmath>
#include <string>
#include <utility>

#include "ibr/errors.h"
#include "kernels/hybrid/hybrid.h"

namespace ibr {
namespace {

void CheckFiniteAtLeast(float v, const char* name, double lo) {
  if (!std::isfinite(v) || v < lo) {
    throw BadValueError(std::string(name) + ": expected a finite number >= " + std::to_string(lo) + ", got " +
                        std::to_string(v));
  }
}

bool SameCamera(const Camera& a, const Camera& b) {
  if (a.model != b.model || a.width != b.width || a.height != b.height || a.fx != b.fx || a.fy != b.fy ||
      a.cx != b.cx || a.cy != b.cy || a.trans != b.trans)
    return false;
  for (int c = 0; c < 3; ++c)
    if (a.rot[c] != b.rot[c]) return false;
  return true;
}

void FiniteMin(float v, const char* name, float lo, bool strict) {
  if (!std::isfinite(v) || (strict ? !(v > lo) : !(v >= lo))) {
    throw BadValueError(std::string(name) + ": expected a finite number " + (strict ? "> " : ">= ") +
                        std::to_string(lo) + ", got " + std::to_string(v));
  }
}

}  // namespace

void UlrOptions::Check() const {
  if (k < 1 || k > kMaxK) {
    throw BadValueError("k: expected 1 .. " + std::to_string(kMaxK) + " views per pixel, got " + std::to_string(k));
  }
  CheckFiniteAtLeast(resolution_weight, "resolution_weight", 0.0);
  CheckFiniteAtLeast(depth_tol, "depth_tol", 0.0);
}


std::int64_t HybridFindBadHit(const std::int32_t* p, const float* ba, std::int64_t n, std::int64_t m) {
  for (std::int64_t i = 0; i < n; ++i) {
    if (p[i] < -1 || p[i] >= m) return i;
    if (p[i] >= 0 && !(std::isfinite(ba[2 * i]) && std::isfinite(ba[2 * i + 1]))) return i;
  }
  return -1;
}

void PvmCheckGridSize(int coarse, int sub) {
  if (coarse < 1 || sub < 1 || static_cast<std::int64_t>(coarse) * sub > 4096) {
    throw BadValueError("coarse, sub: expected >= 1 with coarse * sub <= 4096, got " + std::to_string(coarse) + ", " +
                        std::to_string(sub));
  }
}

void PvmCheckGridGeometry(const double origin[3], const double cell[3]) {
  for (int a = 0; a < 3; ++a) {
    if (!std::isfinite(origin[a]) || !(cell[a] > 0.0) || !std::isfinite(cell[a])) {
      throw BadValueError("origin, cell: expected finite numbers with cell > 0");
    }
  }
}

void PvmCheckNumViews(int nv) {
  if (nv < 1 || nv > 32767) throw BadValueError("cameras: expected 1 .. 32767 views, got " + std::to_string(nv));
}

void PvmRendererOptions::Check() const {
  const PvmRenderOptions& o = render;
  FiniteMin(o.sigma, "sigma", 0.f, true);
  FiniteMin(o.alpha, "alpha", 0.f, false);
  FiniteMin(o.gamma, "gamma", 0.f, true);
  FiniteMin(o.tau_depth, "tau_depth", 0.f, false);
  FiniteMin(o.merge_rel, "merge_rel", 0.f, false);
  FiniteMin(o.radius_sigmas, "radius_sigmas", 0.f, false);
  FiniteMin(o.near, "near", 0.f, true);
  FiniteMin(max_angle_deg, "max_angle", 0.f, true);
  FiniteMin(o.free_space_tol, "free_space_tol", 0.f, false);
  if (o.free_space_tol >= 1.f) throw BadValueError("free_space_tol: expected < 1, got " + std::to_string(o.free_space_tol));
  FiniteMin(o.free_space_point_tol, "free_space_point_tol", 0.f, false);
  FiniteMin(o.tau_empty, "tau_empty", 0.f, false);
  FiniteMin(o.stretch_weight, "stretch_weight", 0.f, false);
  FiniteMin(o.stretch_free, "stretch_free", 0.f, false);
  if (o.radius_sigmas * o.sigma > 64.f) throw BadValueError("radius_sigmas * sigma: expected <= 64 pixels");
  if (o.max_tiles < 1 || o.max_tiles > 255) {
    throw BadValueError("max_tiles: expected 1 .. 255, got " + std::to_string(o.max_tiles));
  }
  if (o.max_candidates < 1 || o.max_candidates > kPvmMaxCandidates) {
    throw BadValueError("max_candidates: expected 1 .. " + std::to_string(kPvmMaxCandidates) + ", got " +
                        std::to_string(o.max_candidates));
  }
  if (o.ulr_k < 1 || o.ulr_k > UlrOptions::kMaxK) {
    throw BadValueError("ulr_k: expected 1 .. " + std::to_string(UlrOptions::kMaxK) + ", got " + std::to_string(o.ulr_k));
  }
  if (o.filter_step < 1 || o.filter_step > 16) {
    throw BadValueError("filter_step: expected 1 .. 16, got " + std::to_string(o.filter_step));
  }
  if (o.min_views < 1 || o.min_views > kPvmMaxCandidates) {
    throw BadValueError("min_views: expected 1 .. " + std::to_string(kPvmMaxCandidates) + ", got " +
                        std::to_string(o.min_views));
  }
  if (o.ray_stride < 0) throw BadValueError("ray_stride: expected >= 0, got " + std::to_string(o.ray_stride));
  if (o.margin < 0 || o.margin > 32) throw BadValueError("margin: expected 0 .. 32, got " + std::to_string(o.margin));
}

PvmRenderOptions PvmRendererOptions::Resolved() const {
  PvmRenderOptions o = render;
  o.max_angle = max_angle_deg >= 180.f ? 3.15f : max_angle_deg * 3.14159265f / 180.f;
  return o;
}

PvmRenderer::PvmRenderer(const PvmTileInputs& t, std::vector<Camera> cameras, std::vector<const float*> images,
                         std::vector<const float*> depths, std::vector<std::uint8_t> enabled)
    : cameras_(std::move(cameras)),
      image_ptrs_(std::move(images)),
      depth_ptrs_(std::move(depths)),
      enabled_(std::move(enabled)) {
  const int nv = static_cast<int>(cameras_.size());
  const std::int64_t nt = t.num_tiles;
  const std::int64_t nc = static_cast<std::int64_t>(t.coarse) * t.coarse * t.coarse;
  // Index checks, once.
  const std::int64_t n_vert = t.num_vertices, n_face = t.num_faces;
  if (n_face > INT32_MAX) throw BadValueError("faces: expected at most 2^31 - 1 faces, got " + std::to_string(n_face));
  const std::int32_t* f = t.faces;
  for (std::int64_t i = 0; i < 3 * n_face; ++i) {
    if (f[i] < 0 || f[i] >= n_vert) throw BadValueError("faces: index out of range [0, " + std::to_string(n_vert) + ")");
  }
  const float* vp = t.vertices;
  for (std::int64_t i = 0; i < 3 * n_vert; ++i) {
    if (!std::isfinite(vp[i])) throw BadValueError("vertices: expected finite coordinates");
  }
  const std::int64_t* fo = t.face_offsets;
  const std::int64_t* vo = t.vertex_offsets;
  if (fo[0] != 0 || fo[nt] != n_face) throw BadValueError("face_offsets: expected 0 .. F");
  if (vo[0] != 0 || vo[nt] != n_vert) throw BadValueError("vertex_offsets: expected 0 .. V");
  const float* tb = t.tile_bounds;
  for (std::int64_t i = 0; i < 6 * nt; ++i) {
    if (!std::isfinite(tb[i])) throw BadValueError("tile_bounds: expected finite numbers");
  }
  for (std::int64_t ti = 0; ti < nt; ++ti) {
    if (fo[ti + 1] < fo[ti]) throw BadValueError("face_offsets: expected non-decreasing");
    if (vo[ti + 1] < vo[ti]) throw BadValueError("vertex_offsets: expected non-decreasing");
    for (std::int64_t i = 3 * fo[ti]; i < 3 * fo[ti + 1]; ++i) {
      if (f[i] < vo[ti] || f[i] >= vo[ti + 1]) {
        throw BadValueError("faces: tile " + std::to_string(ti) + " indexes a vertex outside its vertex range");
      }
    }
    const std::int32_t v = t.tile_view[ti];
    if (v < 0 || v >= nv) throw BadValueError("tile_view: view index out of range [0, " + std::to_string(nv) + ")");
    for (int a = 0; a < 3; ++a) {
      const std::int32_t c = t.tile_cell[3 * ti + a];
      if (c < 0 || c >= t.coarse * t.sub) throw BadValueError("tile_cell: fine cell out of range");
    }
  }
  const std::int64_t* co = t.coarse_offsets;
  if (co[0] != 0 || co[nc] != nt) throw BadValueError("coarse_offsets: expected 0 .. T");
  for (std::int64_t c = 0; c < nc; ++c) {
    if (co[c + 1] < co[c]) throw BadValueError("coarse_offsets: expected non-decreasing");
  }
  tiles_.vertices = t.vertices;
  tiles_.faces = t.faces;
  tiles_.face_offsets = t.face_offsets;
  tiles_.vertex_offsets = t.vertex_offsets;
  tiles_.tile_bounds = t.tile_bounds;
  tiles_.tile_view = t.tile_view;
  tiles_.tile_cell = t.tile_cell;
  tiles_.coarse_offsets = t.coarse_offsets;
  tiles_.num_tiles = nt;
  for (int a = 0; a < 3; ++a) {
    tiles_.grid.origin[a] = t.origin[a];
    tiles_.grid.cell[a] = t.cell[a];
  }
  tiles_.grid.coarse = t.coarse;
  tiles_.grid.sub = t.sub;
  // Each face's area in its own view (the stretch term): once, here (lego's 6.1 M faces: ~0.1 s).
  face_src_log2_.resize(static_cast<std::size_t>(n_face));
  PvmFaceSourceLog2Area(tiles_, cameras_.data(), face_src_log2_.data());
  tiles_.face_src_log2 = face_src_log2_.data();
  // inside_grid's box: the union of the tiles' AABBs (= the bounds of the PVM vertices), each side
  // padded by 1e-4 of its extent (an axis flatter than 1e-6 of the largest: of the largest), as
  // grid_bounds pads the grid; no tiles: the grid's box.
  double lo[3] = {HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi[3] = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
  for (std::int64_t i = 0; i < nt; ++i) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], static_cast<double>(tb[6 * i + a]));
      hi[a] = std::max(hi[a], static_cast<double>(tb[6 * i + 3 + a]));
    }
  }
  if (nt > 0) {
    const double big = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
    for (int a = 0; a < 3; ++a) {
      const double ext = hi[a] - lo[a] > 1e-6 * big ? hi[a] - lo[a] : big;
      tiles_.box[a] = lo[a] - 1e-4 * ext;
      tiles_.box[3 + a] = hi[a] + 1e-4 * ext;
    }
  } else {
    for (int a = 0; a < 3; ++a) {
      tiles_.box[a] = t.origin[a];
      tiles_.box[3 + a] = t.origin[a] + t.cell[a] * t.coarse * t.sub;
    }
  }
}

bool PvmRenderer::HasDepthPass(const Camera& camera) const { return depth_frame_ && SameCamera(camera, depth_camera_); }

PvmRenderStats PvmRenderer::Render(const Camera& camera, const float* gptr, const std::uint8_t* mptr,
                                   const PvmRenderOptions& o, PvmRenderMode mode, float* color, float* depth,
                                   float* vote, std::uint8_t* valid, std::uint8_t* inside) {
  const bool depth_only = mode == PvmRenderMode::kDepth, resolve = mode == PvmRenderMode::kResolve;
  PvmViews views;
  views.count = static_cast<int>(cameras_.size());
  views.cameras = cameras_.data();
  views.images = image_ptrs_.data();
  views.enabled = enabled_.data();
  views.depths = depth_ptrs_.empty() ? nullptr : depth_ptrs_.data();
  PvmRenderStats stats;
  double* ms = stats.ms;
  using Clock = std::chrono::steady_clock;
  auto t = Clock::now();
  auto lap = [&](int i) {
    const auto now = Clock::now();
    ms[i] = std::chrono::duration<double, std::milli>(now - t).count();
    t = now;
  };
  if (!resolve) {
    PvmVisibleCoarse(tiles_.grid, camera, gptr, o.margin, o.ray_stride, frame_.visible);
    lap(0);
    PvmSelectTiles(tiles_, views, frame_.visible, camera, o, frame_);
    lap(1);
    PvmRasterise(tiles_, views, camera, o, frame_);
    PvmDropOffMesh(camera, gptr, o.min_views, frame_);
    lap(2);
  }
  // resolve: the depth pass clustered every pixel (it takes no mask); only the masked colours remain.
  PvmCluster(views, camera, mptr, o, !depth_only, frame_, resolve);
  lap(3);
  PvmFilter(tiles_.box, camera, mptr, o, !depth_only, frame_, color, depth, vote, valid, inside, resolve);
  lap(4);
  if (!resolve) {
    depth_frame_ = true;  // the candidate lists of this camera stay for resolve calls
    depth_camera_ = camera;
  }
  for (std::uint8_t v : frame_.visible) stats.visible_coarse += v;
  stats.tiles = static_cast<std::int64_t>(frame_.tiles.size());
  stats.triangles = frame_.triangles;
  return stats;
}

void PvmRenderer::CheckCandidates(int h, int w, int k) const {
  const std::size_t npix = static_cast<std::size_t>(h) * static_cast<std::size_t>(w);
  if (frame_.cand_count.size() != npix || frame_.cand_depth.size() != npix * static_cast<std::size_t>(k)) {
    throw BadValueError("candidates: no frame of that size and max_candidates rendered yet");
  }
}

bool PvmRenderer::HasStretch(int h, int w, int k) const {
  const std::size_t npix = static_cast<std::size_t>(h) * static_cast<std::size_t>(w);
  return frame_.stretch_codes && frame_.cand_stretch.size() == npix * static_cast<std::size_t>(k);
}

bool PvmRenderer::HasClusters(int h, int w) const {
  return frame_.clusters_everywhere && frame_.n_fg.size() == static_cast<std::size_t>(h) * static_cast<std::size_t>(w);
}

void PvmRenderer::CopyCandidates(int h, int w, int k, const PvmCandidateBuffers& out) const {
  CheckCandidates(h, w, k);
  std::copy(frame_.cand_count.begin(), frame_.cand_count.end(), out.count);
  std::copy(frame_.cand_depth.begin(), frame_.cand_depth.end(), out.depth);
  std::copy(frame_.cand_view.begin(), frame_.cand_view.end(), out.view);
  if (out.stretch && HasStretch(h, w, k)) {  // log2 s in octaves, as the penalty reads the codes
    std::transform(frame_.cand_stretch.begin(), frame_.cand_stretch.end(), out.stretch, StretchOctaves);
  }
  if (out.n_fg && out.n_bg && HasClusters(h, w)) {  // cluster sizes #N_fg, #N_bg (Eq. 1, 2)
    std::copy(frame_.n_fg.begin(), frame_.n_fg.end(), out.n_fg);
    std::copy(frame_.n_bg.begin(), frame_.n_bg.end(), out.n_bg);
  }
}

}  // namespace ibr
