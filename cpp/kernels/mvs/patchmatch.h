// PatchMatch multi-view stereo: a plane hypothesis (depth, normal) per pixel of a reference view,
// found by red/black checkerboard propagation and random refinement (Galliani, Lasinger and
// Schindler 2015, "Massively Parallel Multiview Stereopsis by Surface Normal Diffusion" = Gipuma,
// sec. 3; Xu and Tao 2019, ACMH) with a bilaterally weighted NCC over a sparsely sampled window,
// aggregated robustly over the source views (the mean of the best K, Gipuma sec. 3.2), and an
// optional geometric term: the forward-backward reprojection error against the sources' own depth
// (Schonberger et al. 2016, "Pixelwise View Selection for Unstructured Multi-View Stereo", sec.
// 4.4, COLMAP's geometric stage).
//
// Conventions (cpp/ibr/camera.h): pinhole cameras, OpenCV axes, pixel (u, v) centred at
// (u + 0.5, v + 0.5); depth is z in the reference camera; normals are unit vectors in the
// reference camera's axes, facing it (n . ray < 0). Grey images are float32 (H, W) in [0, 1].
//
// The plane through X = z K_r^-1 p with normal n maps reference pixel q to source pixel
// H q with H = K_s (R + t n^T / c) K_r^-1, c = n . X (< 0), (R, t) = source_from_reference
// (the plane-induced homography; Hartley and Zisserman, Multiple View Geometry, eq. 13.2, with
// the plane written n . X = c).
//
// Matching cost of a hypothesis against one source: 1 - NCC, NCC weighted per window sample i by
// w_i = exp(-(g_i - g_centre)^2 / (2 sigma_color^2) - |offset_i|^2 / (2 sigma_spatial^2))
// (bilateral weights of the reference window, Gipuma eq. 2 / ACMH eq. 3); 2 (the maximum) when the
// hypothesis' centre leaves the source image, lies behind it, or the source window has no
// variance. Aggregated cost: the mean of the best min(best_k, sources) source costs. A reference
// window whose weighted variance is below min_variance (textureless) is never matched: the pixel
// keeps cost 2 and depth 0 (unknown).
//
// Determinism: every random number is a hash of (seed, iteration, pixel, draw), and a half pass
// updates only pixels of one checkerboard colour from pixels of the other, so the result is the
// same, bit for bit, for any thread count and any partition of the rows.
#pragma once
#include <cstdint>
#include <vector>

#include "ibr/camera.h"
#include "ibr/image.h"

namespace ibr::mvs {

struct PatchMatchOptions {
  int window_radius = 5;        // the matching window is (2 r + 1)^2 pixels: 11 x 11
  int window_step = 2;          // sampled every `step` pixels (6 x 6 = 36 samples)
  float sigma_color = 0.12f;    // bilateral weight, grey units (0..1)
  float sigma_spatial = 5.0f;   // bilateral weight, pixels
  int iterations = 6;           // each: a red and a black half pass
  int first_iteration = 0;      // the refinement schedule's start (ranges halve per iteration): a
                                //   pass that continues another starts where it stopped
  bool refine_only = false;     // a pass that refines a converged result (a finer level, the
                                //   geometric pass): per pixel the 4 nearest neighbours, a random
                                //   normal and 3 perturbations (not 8 neighbours, 2 random, 3)
  int best_k = 3;               // source costs aggregated (the best K of them)
  double min_depth = 0.0;       // hypotheses' depth range (z, > 0): random draws are uniform in
  double max_depth = 0.0;       //   inverse depth over it
  std::uint64_t seed = 0;
  float min_variance = 1e-4f;   // reference windows with less weighted grey variance are unknown
  float geom_weight = 0.0f;     // > 0: cost += geom_weight * min(fb_error_px, geom_max_error)
  float geom_max_error = 3.0f;  //   per source that has depth
};

struct SourceView {
  ImageView<const float> grey;   // (Hs, Ws)
  Camera camera;                 // pinhole
  ImageView<const float> depth;  // (Hs, Ws) z-depth, 0 = unknown; empty: no geometric term for it
};

struct PatchMatchStats {
  std::int64_t evaluations = 0;  // (pixel, hypothesis, source) matching-cost evaluations
  std::int64_t textureless = 0;  // pixels never matched (reference window below min_variance)
};

// Runs options.iterations of propagation + refinement on (depth, normal, cost). `initialised`:
// depth/normal hold starting hypotheses (depth <= 0 or non-finite: drawn at random), else every
// pixel starts at random. Outputs: depth (H, W), normal (H, W, 3), cost (H, W) in [0, 2].
PatchMatchStats PatchMatch(const ImageView<const float>& ref_grey, const Camera& ref_cam,
                           const std::vector<SourceView>& sources, const PatchMatchOptions& options,
                           bool initialised, ImageView<float> depth, ImageView<float> normal,
                           ImageView<float> cost);

// Forward-backward consistency of a reference depth map against the sources' depth maps
// (COLMAP's filter, Schonberger et al. 2016 sec. 4.5): for each pixel with depth, the number of
// sources whose own depth at the projection maps back to within max_error_px of the pixel and to
// within max_rel_depth of its depth, seen under a triangulation angle of at least
// min_angle_deg. Writes count (H, W) as float (0 where the depth is unknown).
void ConsistentViews(const ImageView<const float>& ref_depth, const Camera& ref_cam,
                     const std::vector<SourceView>& sources, float max_error_px, float max_rel_depth,
                     float min_angle_deg, ImageView<float> count);

}  // namespace ibr::mvs
