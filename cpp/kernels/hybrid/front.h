// The hybrid family's checked front (Python: ibrtools.hybrid, ibrtools.hybrid.method through
// cpp/bindings/hybrid.cpp): the PVM renderer, which owns the checked tiles, the input views and
// the per-frame buffers and runs the five stages of pvm_render.h with their times; the checks of
// UlrOptions (hybrid.h) are defined here too. The checks throw the typed errors of cpp/ibr/errors.h.
// Callable from C++ without Python; the binding only converts arrays and calls these. The arrays
// are borrowed: the caller keeps them alive as long as the renderer.
#pragma once
#include <cstdint>
#include <vector>

#include "ibr/camera.h"
#include "kernels/hybrid/pvm_render.h"

namespace ibr {

// The first of n G-buffer pixels whose hit a per-pixel read cannot index: prim_id outside [-1, m)
// (-1 = no hit), or a hit (prim_id >= 0) with a non-finite barycentric (bary (n, 2)); -1 if none.
std::int64_t HybridFindBadHit(const std::int32_t* prim_id, const float* bary, std::int64_t n, std::int64_t m);

// Throws BadValueError unless coarse, sub >= 1 with coarse * sub <= 4096.
void PvmCheckGridSize(int coarse, int sub);
// Throws BadValueError unless origin is finite and cell finite and > 0 (3 numbers each).
void PvmCheckGridGeometry(const double origin[3], const double cell[3]);
// Throws BadValueError unless 1 <= num_views <= 32767.
void PvmCheckNumViews(int num_views);

// The tiles of tiles.npz (docs/FORMAT.md) as borrowed arrays with their sizes.
struct PvmTileInputs {
  const float* vertices = nullptr;             // (V, 3)
  std::int64_t num_vertices = 0;
  const std::int32_t* faces = nullptr;         // (F, 3)
  std::int64_t num_faces = 0;
  const std::int64_t* face_offsets = nullptr;  // (T + 1,)
  const std::int64_t* vertex_offsets = nullptr;  // (T + 1,)
  const std::int32_t* tile_view = nullptr;     // (T,)
  const std::int32_t* tile_cell = nullptr;     // (T, 3)
  const float* tile_bounds = nullptr;          // (T, 2, 3)
  std::int64_t num_tiles = 0;
  const std::int64_t* coarse_offsets = nullptr;  // (coarse^3 + 1,)
  double origin[3] = {0, 0, 0}, cell[3] = {1, 1, 1};
  int coarse = 1, sub = 1;
};

// The renderer's tuning: the kernels' options (defaults: pvm_render.h) with the view angle limit in
// degrees (render.max_angle is derived from it by Resolved()).
struct PvmRendererOptions {
  PvmRenderOptions render;
  float max_angle_deg = 55.f;  // a view whose ray to the fine cell makes a larger angle is skipped; >= 180: none
  // Throws BadValueError for a value outside its range (finite, > 0 or >= 0 as the kernels need;
  // free_space_tol < 1; radius_sigmas * sigma <= 64 pixels; max_tiles 1..255; max_candidates and
  // min_views 1..kPvmMaxCandidates; ulr_k 1..UlrOptions::kMaxK; filter_step 1..16; ray_stride >= 0;
  // margin 0..32).
  void Check() const;
  PvmRenderOptions Resolved() const;  // render, with max_angle in radians
};

enum class PvmRenderMode { kFull, kDepth, kResolve };

struct PvmRenderStats {
  double ms[5] = {0, 0, 0, 0, 0};  // voxel lookup, tile sort, per-view depth pass, cluster + blend, spatial filter
  std::int64_t visible_coarse = 0, tiles = 0, triangles = 0;
};

// The candidate lists of the last frame, copied out (for tests and inspection).
struct PvmCandidateBuffers {
  std::uint8_t* count = nullptr;  // (H, W)
  float* depth = nullptr;         // (H, W, K)
  std::int16_t* view = nullptr;   // (H, W, K)
  float* stretch = nullptr;       // (H, W, K) log2 s in octaves, or null
  std::uint8_t* n_fg = nullptr;   // (H, W) cluster sizes, or null
  std::uint8_t* n_bg = nullptr;
};

class PvmRenderer {
 public:
  // Checks the tiles' indices and values once (BadValueError) and computes each face's area in its
  // own view (the stretch term). images (H_v, W_v, 3) linear RGB and depths (H_v, W_v) (empty: no
  // free-space count) per camera, enabled one byte per camera.
  PvmRenderer(const PvmTileInputs& tiles, std::vector<Camera> cameras, std::vector<const float*> images,
              std::vector<const float*> depths, std::vector<std::uint8_t> enabled);

  // Whether the frame holds a depth pass of this camera (the input of a kResolve render).
  bool HasDepthPass(const Camera& camera) const;

  // One frame (camera pinhole, of size H x W; the caller checks both and, for kResolve,
  // HasDepthPass). gbuffer (H, W) z or null; mask (H, W) one byte per pixel or null. Outputs (H, W[, 3]).
  // kDepth: stages 1-4 without colours, the frame kept; kResolve: the masked colours of the kept
  // depth pass (stages 4-5).
  PvmRenderStats Render(const Camera& camera, const float* gbuffer, const std::uint8_t* mask,
                        const PvmRenderOptions& options, PvmRenderMode mode, float* color, float* depth, float* vote,
                        std::uint8_t* valid, std::uint8_t* inside);

  // Throws BadValueError unless the last frame has h x w pixels and k candidates a pixel.
  void CheckCandidates(int h, int w, int k) const;
  bool HasStretch(int h, int w, int k) const;   // the last frame has stretch codes
  bool HasClusters(int h, int w) const;         // the last frame clustered every pixel
  void CopyCandidates(int h, int w, int k, const PvmCandidateBuffers& out) const;

 private:
  std::vector<Camera> cameras_;
  std::vector<const float*> image_ptrs_;
  std::vector<const float*> depth_ptrs_;  // empty: no free-space count
  std::vector<std::uint8_t> enabled_;
  std::vector<float> face_src_log2_;      // PvmFaceSourceLog2Area of the tiles
  PvmTileArrays tiles_;
  PvmFrame frame_;
  bool depth_frame_ = false;  // frame_ holds the candidate lists of depth_camera_
  Camera depth_camera_;
};

}  // namespace ibr
