// Rendering per-view meshes (PVM) stored as tiles of the two-level voxel grid, with clustered
// depth filtering (Prakash et al. 2021, "Hybrid Image-based Rendering for Free-view Synthesis",
// sec. 5.1-5.2 and Eq. 1-2). The tiles come from the preprocessing stage (cpp/kernels/hybrid/pvm.h,
// docs/preprocess.md); Python front: python/ibrtools/hybrid/pvm_render.py; docs/pvm_render.md.
//
// Stages of one frame (each a function below; the binding times them separately):
//  1. PvmVisibleCoarse  "voxel lookup": coarse cells that hold visible surface. With a G-buffer
//     (z of the global mesh per pixel, 0 = no hit) every hit pixel is unprojected and its coarse
//     cell marked, then the marks are dilated by `margin` cells (a 1-cell margin catches surface
//     the global mesh misses just in front of / behind what it has). With ray_stride > 0, also the
//     cells that the rays of every ray_stride-th pixel and row cross in front of the G-buffer's
//     surface (to the grid's far side where the G-buffer is empty): an object the global mesh
//     lacks (the case PVMs are for) is otherwise not looked up when it is more than `margin`
//     cells in front of the surface behind it. Without a G-buffer, every coarse
//     cell whose finite box is not entirely outside one plane of the camera frustum.
//  2. PvmSelectTiles    "tile sort": per fine cell of a visible coarse cell, the tiles of enabled
//     views ranked by the ULR penalty (ulr.h) of their view for the fine cell's centre and the
//     novel camera; the best `max_tiles` are kept with their rank 0..max_tiles-1. Views whose
//     angle at the cell centre (between the rays to the view and to the novel camera) exceeds
//     max_angle are left out: with a sparse capture "the top 12" would otherwise include views
//     from the far side, which see the background behind what the novel camera sees.
//  3. PvmRasterise      "per-view depth pass": the kept tiles' triangles rasterised into per-pixel
//     candidate lists of at most `max_candidates` entries (z, view, rank). Pixel centres at
//     +0.5, the engine's rasteriser core (cpp/ibr/raster.h: vertices snapped to 1/256 px, top-left
//     fill rule), z interpolated perspective-correctly (1/z affine in the screen).
//     One entry per view and pixel holding that view's nearest fragment (a per-view depth test);
//     a new view arriving at a full list replaces the entry of the worst (rank, view) when its
//     own is better. Back faces (seen from the other side than from their own view) are
//     skipped; triangles with a vertex closer than `near` are clipped against the plane z = near
//     (Sutherland-Hodgman, cut points computed from an edge's lexicographically smaller end) and
//     their part in front drawn, and so are triangles reaching beyond the rasteriser's guard
//     band (2^20 px, clipped to it in screen space). The image
//     is cut into bands of kBandRows rows; kept tiles are binned into the bands their projected
//     AABB covers (in kept order); each band is one task that projects a tile's vertices once
//     and draws its triangles clipped to the band, in that order: results are identical for
//     any thread count, and no per-triangle buffer is ever built.
//     Off the global mesh (PvmDropOffMesh, timed with this stage): where the G-buffer has no
//     surface (z 0, NaN or inf), a pixel's list is emptied when it holds fewer than `min_views`
//     entries (= views, one entry per view): the global mesh, fused from every view's depth, has
//     nothing there, and a surface one view alone puts there is not confirmed by any other (at
//     silhouettes it is the per-view mesh's own edge reaching past the object). Without a
//     G-buffer, or min_views 1, no list is emptied (the paper: any candidate counts).
//  4. PvmCluster        "cluster & blend": per pixel 2-means on the candidate depths
//     (initialised at the smallest and largest; assignment to the nearer mean, ties to the
//     foreground; at most 16 iterations), merged into one cluster when the two means differ by
//     at most merge_rel * the foreground mean (identical depths -> one cluster). Per cluster the
//     ULR-weighted colour of its candidates (UlrSelect with k = ulr_k over the candidates'
//     penalties at their own surface points; the k-th, of weight 0, is not read); a candidate's
//     colour is its view's image sampled (Catmull-Rom with options.cubic, else bilinearly) at the
//     projection of the candidate's surface point (projective texturing of the PVM by its own
//     image).
//     Stretch (ours; stretch_weight > 0, with tiles.face_src_log2): each candidate's penalty gains
//     stretch_weight x max(0, log2 s - stretch_free), s = the doubled area of its triangle in the
//     target (pixels^2, the rasteriser's) over that in its own view (PvmFaceSourceLog2Area), kept
//     per candidate by PvmRasterise in 1/16 octaves (StretchCode; the fragment that wins the list
//     slot writes it). A per-view mesh triangle magnified in the target carries little of its
//     image's detail: a sheet its mesh spans across a depth edge, or a surface its view sees at
//     a grazing angle. Near-clipped pieces carry none (128: s = 1).
//     Free space (free_space, with views.depths): a background candidate counts in #N_bg (Eq. 1,
//     Eq. 2) only when its view sees past the foreground point P (the foreground mean on the
//     pixel's ray): P projects into the view, no pixel of the 3 x 3 around P's projection has a
//     depth < (1 - free_space_tol) x P's depth in the view (P hidden: the view sees a surface
//     behind P that is really there but says nothing about P), and more than half of them have a
//     depth > (1 + free_space_point_tol) x P's depth or none (0, NaN or inf). A view whose depth
//     there is P's own sees P itself: its background candidate comes from its mesh's depth-edge
//     cut (a thin surface at a grazing angle), not from free space. With no counted background
//     candidate the pixel has one cluster (the foreground: its colour is the foreground members' blend).
//     Seen through (tau_empty > 0, with free space): a one-cluster pixel (no counted background)
//     whose point P is seen past (as above) by at least tau_empty x n_fg of the enabled views that
//     have no candidate on the pixel's ray and lie within max_angle of the novel camera's ray at P
//     has its list emptied (no surface: not valid). Those views' meshes put nothing on the ray near
//     P; the candidates are sheets that the per-view meshes of views seeing a gap's inner walls
//     obliquely span across it (lego's technic-beam holes).
//  5. PvmFilter         "spatial filter": Eq. 1, W_{i,k} = sum_{j in Omega_i} sum_{k'} G_sigma(i, j)
//     exp(-alpha |d_{j,k'} - d_{i,k}|) #N_{j,k'} (the paper writes d_{j,k'} - d_{i,k}; the
//     absolute value makes the falloff symmetric), Omega_i the window of radius
//     R = ceil(radius_sigmas * sigma / step) * step sampled every `filter_step` pixels per axis
//     (step 2: 7 x 7 of the 13 x 13 neighbours for sigma 3; the Gaussian weights are those of
//     the sampled offsets, so W is a subsampled Eq. 1 and only W_1 / W_0 matters); colour = sum_k W^gamma c_k / sum_k W^gamma. Depth by the
//     vote of Eq. 2: d_bg when #bg >= tau_depth * #fg, else d_fg; vote = the winning cluster's
//     share of the candidates. filtered = false: the foreground cluster's colour (PVM-H-like
//     baseline without the spatial filter). Pixels with one cluster take its colour either way.
//
// Kernels trust their inputs (the binding cpp/bindings/hybrid.cpp checks them) and never
// throw; buffers live in PvmFrame, reused from frame to frame.
#pragma once
#include <cstdint>
#include <vector>

#include "ibr/camera.h"
#include "kernels/hybrid/pvm.h"

namespace ibr {

constexpr int kPvmMaxCandidates = 16;  // hard limit of the per-pixel candidate list
constexpr int kBandRows = 32;          // rasteriser band height (16 -> 32: fewer bands per tile)

// A candidate's stretch code (PvmFrame.cand_stretch): log2 of its triangle's magnification in
// steps of 1 / kStretchSteps octave, offset by kStretchZero (no magnification), clamped to 0 .. 255.
constexpr int kStretchZero = 128, kStretchSteps = 16;
inline float StretchOctaves(std::uint8_t code) {
  return (static_cast<float>(code) - static_cast<float>(kStretchZero)) * (1.f / kStretchSteps);
}

// Read-only views of the tiles.npz arrays (docs/FORMAT.md "cache/pvm").
struct PvmTileArrays {
  const float* vertices = nullptr;            // (V, 3) world
  const std::int32_t* faces = nullptr;        // (F, 3) indices into vertices
  const std::int64_t* face_offsets = nullptr; // (T + 1,)
  const std::int64_t* vertex_offsets = nullptr;  // (T + 1,) a tile's faces index only its vertex range
  const float* tile_bounds = nullptr;         // (T, 2, 3) AABB
  const std::int32_t* tile_view = nullptr;    // (T,) index into the views
  const std::int32_t* tile_cell = nullptr;    // (T, 3) fine cell
  const std::int64_t* coarse_offsets = nullptr;  // (coarse^3 + 1,)
  std::int64_t num_tiles = 0;
  // (F,) log2 of each face's doubled area in its own view's image, pixels^2 (PvmFaceSourceLog2Area;
  // NaN where a vertex does not project); nullptr: no stretch term (PvmRenderOptions.stretch_weight).
  const float* face_src_log2 = nullptr;
  PvmGrid grid{};
  // Finite box of the surface (lo xyz, hi xyz; world): the bounds of the tiles, padded. A pixel is
  // inside_grid when its ray meets this box. Not the grid's own box: the fine cells are cubes
  // (pvm.py grid_bounds), so the grid extends far beyond a flat scene along its short axes.
  double box[6] = {0, 0, 0, 0, 0, 0};
};

// The input views the tiles refer to: cameras, linear RGB float images (H_v, W_v, 3) and which
// views may be used (held-out views are disabled).
struct PvmViews {
  int count = 0;
  const Camera* cameras = nullptr;
  const float* const* images = nullptr;
  const std::uint8_t* enabled = nullptr;
  // Per view its depth map (H_v, W_v) as the view's convention (z for pinhole, ray distance for
  // equirect; 0, NaN or inf = nothing seen), for the free-space count; nullptr: not given.
  const float* const* depths = nullptr;
};

struct PvmRenderOptions {
  int max_tiles = 12;        // tiles kept per fine voxel (paper: 12)
  int max_candidates = 12;   // candidates per pixel (<= kPvmMaxCandidates)
  int margin = 1;            // dilation of the G-buffer's coarse cells, in cells
  int ray_stride = 8;        // cells in front of the G-buffer on every ray_stride-th ray (0 = off)
  int ulr_k = 3;             // ULR k within a cluster (weight 0 at the k-th; pvm_render.py DEFAULTS)
  float resolution_weight = 0.5f;  // ULR resolution penalty weight (ulr.h)
  float max_angle = 3.15f;   // radians: a view whose ray to the fine cell's centre makes a larger angle
                             // with the novel camera's is not ranked for that cell (> pi: no limit)
  float near = 1e-3f;        // triangles are clipped against the plane z = near (scene units)
  bool cull_back = true;     // skip triangles seen from their back
  float merge_rel = 0.02f;   // one cluster when |d_bg - d_fg| <= merge_rel * d_fg
  float sigma = 3.f;         // Eq. 1 spatial Gaussian, pixels
  float alpha = 7.f;         // Eq. 1 depth falloff per scene unit
  float gamma = 7.f;         // cluster blend power
  float radius_sigmas = 2.f; // filter window radius R = ceil(radius_sigmas * sigma / step) * step
  int filter_step = 2;       // Eq. 1 sums every filter_step-th neighbour per axis (1 = all)
  float tau_depth = 0.83f;   // Eq. 2
  bool free_space = true;    // count a background candidate only when its view sees past the foreground (needs views.depths)
  float free_space_tol = 0.02f;  // relative: the view's depth must be >= (1 - tol) x the foreground point's depth
  float free_space_point_tol = 0.005f;  // relative: and mostly > (1 + point_tol) x it (within: the view sees the point)
  float tau_empty = 2.f;     // with free_space: a one-cluster pixel is empty when >= tau_empty x n_fg views see past it (0: off)
  int min_views = 2;         // where the G-buffer is empty: candidate lists of fewer views are emptied (1: none are)
  // Stretch term (ours): a candidate's ULR penalty gains stretch_weight x max(0, log2 s - stretch_free),
  // s = the area of its triangle in the target over its area in its own view (a per-view mesh
  // triangle magnified: a sheet across a depth edge, or a surface its view sees at a grazing angle;
  // pvm_render.md "Stretch"). 0: off, the paper's ULR weights. Needs tiles.face_src_log2.
  float stretch_weight = 0.1f;
  float stretch_free = 0.f;  // octaves of magnification without a penalty
  bool filtered = true;
  bool cubic = true;         // candidate colours read with Catmull-Rom (resample.h, as the ULR blend), else bilinear
};

// Per-frame buffers (sized by the functions).
struct PvmFrame {
  std::vector<std::uint8_t> visible;      // (coarse^3,)
  std::vector<std::int64_t> tiles;        // kept tiles in (coarse cell, fine cell, rank) order
  std::vector<std::uint8_t> tile_rank;    // rank of each kept tile in its fine cell
  std::vector<float> cand_depth;          // (H * W * K)
  std::vector<std::int16_t> cand_view;
  std::vector<std::uint8_t> cand_rank;
  std::vector<std::uint8_t> cand_stretch;  // (H * W * K) stretch code of the candidate's triangle (kStretchZero: none)
  bool stretch_codes = false;             // cand_stretch holds codes (the stretch term was on in PvmRasterise)
  std::vector<std::uint8_t> cand_count;   // (H * W)
  std::vector<std::uint32_t> cand_seen;   // (H * W) bit (view & 31) set when a view of that class is in the list
  std::vector<float> d_fg, d_bg;          // (H * W) cluster mean depths
  std::vector<std::uint8_t> n_fg, n_bg;   // cluster sizes (0 = none)
  std::vector<float> c_fg, c_bg;          // (H * W * 3) cluster colours
  std::vector<std::uint16_t> bg_bits;     // (H * W) bit i set: candidate i is in the background cluster
  bool clusters_everywhere = false;       // d/n/bg_bits hold this frame's clusters at every pixel
  std::vector<std::uint8_t> inside;       // (H * W) inside_grid of the last PvmFilter that computed it
  std::int64_t triangles = 0;             // triangles drawn (summed over the bands they touch)
};

// log2 of the doubled area (pixels^2) of every tile face in its own view's image (tile_view):
// out (F,) float; NaN where a vertex does not project into the view, -inf for a zero area
// (infinitely stretched wherever it is drawn). Computed once per set of tiles (the binding).
void PvmFaceSourceLog2Area(const PvmTileArrays& tiles, const Camera* cameras, float* out);

// Stage 1. gbuffer_depth (H, W) z or nullptr; visible gets coarse^3 bytes (1 = visible).
void PvmVisibleCoarse(const PvmGrid& grid, const Camera& camera, const float* gbuffer_depth, int margin,
                      int ray_stride, std::vector<std::uint8_t>& visible);
// Stage 2.
void PvmSelectTiles(const PvmTileArrays& tiles, const PvmViews& views, const std::vector<std::uint8_t>& visible,
                    const Camera& camera, const PvmRenderOptions& options, PvmFrame& frame);
// Stage 3. camera must be pinhole.
void PvmRasterise(const PvmTileArrays& tiles, const PvmViews& views, const Camera& camera,
                  const PvmRenderOptions& options, PvmFrame& frame);
// Stage 3, continued: gbuffer_depth (H, W) z (camera's size); where it has no surface, lists of
// fewer than min_views entries get count 0. No-op for gbuffer_depth nullptr or min_views <= 1.
void PvmDropOffMesh(const Camera& camera, const float* gbuffer_depth, int min_views, PvmFrame& frame);
// Stage 4. pixel_mask (H, W) or nullptr = all pixels. colours = false: the clusters' depths
// and sizes only (no image sampling; the hybrid method's depth pass). The clusters (depths,
// sizes) are computed on the mask dilated by the filter radius (Eq. 1 reads the neighbours'),
// the colours only on the mask (the filter reads a pixel's own colours only).
// reuse_clusters = true and frame.clusters_everywhere (a PvmCluster without mask ran after the
// last PvmRasterise): only the masked pixels' colours are computed, from the kept clusters (the
// 2-means is not redone); the other pixels' colours are left unspecified. Otherwise ignored.
void PvmCluster(const PvmViews& views, const Camera& camera, const std::uint8_t* pixel_mask,
                const PvmRenderOptions& options, bool colours, PvmFrame& frame, bool reuse_clusters = false);
// Stage 5. box: PvmTileArrays::box. Outputs (H, W, 3) color, (H, W) depth, vote, valid and inside_grid; pixels outside
// the mask or without candidates get colour 0, depth 0, vote 0, valid 0. colours = false after a
// PvmCluster without colours: no Eq. 1 (colour stays 0), depth / vote / valid as usual.
// inside_grid is kept in frame.inside; reuse_inside = true (same camera as the PvmFilter that
// computed it, e.g. resolve after a depth pass): copied from there instead of the per-pixel ray-box test.
void PvmFilter(const double* box, const Camera& camera, const std::uint8_t* pixel_mask,
               const PvmRenderOptions& options, bool colours, PvmFrame& frame, float* color, float* depth, float* vote,
               std::uint8_t* valid, std::uint8_t* inside_grid, bool reuse_inside = false);

}  // namespace ibr
