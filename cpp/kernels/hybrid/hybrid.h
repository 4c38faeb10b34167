// Hybrid IBR rendering kernels (Prakash et al. 2021, "Hybrid Image-based Rendering for Free-view
// Synthesis", sec. 3.3 and 6): G-buffer attribute interpolation for the textured mesh (TM),
// per-pixel Unstructured Lumigraph blending (ULR) at the global mesh's visible points, the
// per-pixel method selection of Fig. 7, the blur of the selection mask and the composite.
//
// Conventions (cpp/ibr/camera.h): OpenCV camera axes, pixel (u, v) has its centre at
// (u + 0.5, v + 0.5); "depth" is the scene model's depth: z for a pinhole camera, distance along
// the ray for an equirect one, 0 = unknown / no surface. Images are row-major (H, W[, C]) float32.
// Kernels never throw or allocate policy: the binding (cpp/bindings/hybrid.cpp) checks
// shapes and values and allocates every output.
#pragma once
#include <cstdint>

#include <glm/glm.hpp>

#include "ibr/camera.h"
#include "ibr/image.h"

namespace ibr {

// ---- TM: G-buffer attributes ---------------------------------------------------------------
// out(pixel, c) = (1 - u - v) a[f0, c] + u a[f1, c] + v a[f2, c] for the hit face f = prim_id
// (Embree's barycentrics, cpp/kernels/raycast/raycast.h); 0 where prim_id < 0. attrib is (num_vertices,
// channels), faces (M, 3), prim ids already checked to lie in [-1, M). A hit face with a vertex
// index outside [0, num_vertices) is left 0 and not read: returns the smallest such pixel, else -1.
std::int64_t InterpolateVertexAttribute(const std::int32_t* prim_id, const float* bary, std::int64_t num_pixels,
                                        const std::int32_t* faces, const float* attrib, std::int64_t num_vertices,
                                        int channels, float* out);

// ---- per-pixel ULR --------------------------------------------------------------------------
struct UlrInputView {
  Camera camera;
  ImageView<const float> color;  // (h, w, 3) linear RGB (harmonised when available)
  ImageView<const float> depth;  // (h, w) the view's depth (z / distance), 0 = unknown
};

enum class UlrSimd { kAuto, kSse2, kAvx2 };

// ULR's tuning. The defaults and bounds are defined here only: the binding's argument defaults and
// Python's ULR method (_core.ULR_DEFAULT_K, ULR_DEFAULT_RESOLUTION_WEIGHT, ULR_DEFAULT_DEPTH_TOL,
// ULR_MAX_K) read them; the decimal defaults are doubles so that Python sees 0.005, not float 0.005's
// double value. Check() (defined by the front, front.cpp) throws BadValueError for a value out of range.
struct UlrOptions {
  static constexpr int kMaxK = 64;  // the per-pixel selection lists of the kernels have this size
  static constexpr int kDefaultK = 4;
  static constexpr double kDefaultResolutionWeight = 0.5;
  // 0.5 %: chosen on the selection scenes (docs/hybrid.md).
  static constexpr double kDefaultDepthTol = 0.005;

  int k = kDefaultK;  // views kept per pixel (UlrSelect: the k-th gets weight 0), 1 .. kMaxK
  float resolution_weight = static_cast<float>(kDefaultResolutionWeight);  // UlrPenalty's resolution term, >= 0
  // Occlusion test: the input view sees the point when its depth at the point's (nearest) pixel
  // agrees with the point's depth in that view within depth_tol * view depth (relative: depth
  // maps and the global mesh err in proportion to distance); >= 0.
  float depth_tol = static_cast<float>(kDefaultDepthTol);
  // Input views behind the surface (angle between the G-buffer normal and the direction to the
  // view >= 90 degrees) are skipped when a normal is given.
  // The scalar reference path (double projections, one view at a time) instead of the fast path
  // (float, SIMD over views; used when every input view is pinhole). Tests compare the two.
  bool reference = false;
  // Colour reads: Catmull-Rom (resample.h; sharper: a bilinear read at sub-pixel positions is a
  // 2-tap box per axis, and the blend of several views piles the blurs up) or bilinear (false).
  bool cubic = true;
  // The fast path's per-view loop: AVX-512F (16 views per step) when the CPU has it, else AVX2 (8),
  // else SSE2 (4); its depth test likewise gathers 16 or 8 views' depths a step, or reads them one
  // at a time with SSE2; with AVX2 the view selection (k = 4) and the Catmull-Rom weights run eight
  // pixels / reads at once. kAuto follows the engine's switch (UseAvx2, cpp/ibr/simd.h:
  // _core.set_warp_isa("baseline") gives SSE2), kAvx2 stops at AVX2, kSse2 forces SSE2 (tests: all
  // give the same bits).
  UlrSimd simd = UlrSimd::kAuto;

  // k in 1 .. kMaxK, resolution_weight and depth_tol finite and >= 0.
  void Check() const;
};

// For every pixel with gbuffer_depth > 0 (and pixel_mask != 0 when a mask is given): the world
// point p = centre + depth * ray; penalties UlrPenalty(p, novel centre, view centre) of every
// input view; the best k by UlrSelect among the views that see p: the back-face (when a normal
// is given), behind-the-camera and outside-the-image tests are done for every view with the
// penalties; the depth test (a read in the view's depth map) lazily: the best k are tested,
// failing ones dropped and the selection redone.
// color_out = sum_j w_j * bilinear(view_j colour at p's projection) (edge-clamped), count_out =
// the number of views with positive weight (0 = no view sees p: colour 0, the caller falls back
// to TM). Pixels not computed get colour 0 and count 0. normal may be empty (no back-face test).
// When every input view is pinhole (and not options.reference) the penalties and the cheap tests
// run eight views at a time in AVX2 when the CPU has it and four at a time in SSE2 otherwise (the
// same bits), in float with the projection folded into one 3x4 matrix per view, and the depth
// test done, without branches, for every view that passed the cheap tests before one selection
// (the same views pass as with the lazy test, so the same selection); else the scalar path
// (double) runs. Float rounding may flip a depth test at its tolerance (tests/hybrid/test_ulr_fast.py).
void UlrBlend(const Camera& novel, ImageView<const float> gbuffer_depth, ImageView<const float> normal,
              const std::uint8_t* pixel_mask, const UlrInputView* views, int num_views, const UlrOptions& options,
              ImageView<float> color_out, ImageView<std::uint8_t> count_out);

// ---- hybrid selection (Fig. 7) --------------------------------------------------------------
enum HybridLabel : std::uint8_t { kLabelTm = 0, kLabelUlr = 1, kLabelPvm = 2, kLabelNone = 3 };

struct HybridSelectOptions {
  float geo_threshold = 0.03f;  // |PVM depth - global depth| above this -> PVM (3 cm in scene units)
  float tau_var = 0.82f;        // view-dependent texture above this -> ULR
};  // the paper's values; --method hybrid passes its own (hybrid/method.py HYBRID_DEFAULTS: tau_var -1)

// Per pixel, with global hit = gbuffer_depth > 0:
//   !inside_grid                                              -> ULR (kLabelNone if no global hit)
//   pvm_valid && (!hit || |pvm_depth - gbuffer_depth| > geo)  -> PVM
//   !hit                                                      -> kLabelNone (nothing to render)
//   vd > tau_var                                              -> ULR
//   else                                                      -> TM
// Null inputs: inside_grid = every pixel inside the grid; pvm_valid (and pvm_depth) = no PVM
// candidate anywhere; vd = 0 everywhere.
void HybridSelect(ImageView<const float> gbuffer_depth, const std::uint8_t* inside_grid, const std::uint8_t* pvm_valid,
                  const float* pvm_depth, const float* vd, const HybridSelectOptions& options,
                  ImageView<std::uint8_t> label_out);

// Blurs the one-hot selection (TM, ULR, PVM) with a separable Gaussian of standard deviation
// sigma pixels (radius ceil(3 sigma), edge-clamped; sigma = 0: no blur) and normalises the three
// weights to sum 1 where any is positive. kLabelNone contributes to none (its pixels get the
// weights of their neighbours, or all 0). Then a normalised weight below min_weight (in [0, 1/3]:
// the largest of three weights summing to 1 is >= 1/3, so one is always kept) becomes 0 and the
// others are normalised again: a method's colour is needed only where its weight is > 0, and the
// Gaussian's tail would otherwise ask for it 3 sigma beyond every pixel that chose it, at weights
// (1e-3) that cannot show in the composite. min_weight 0: the plain blur. weights_out (H, W, 3) =
// (tm, ulr, pvm); scratch holds 3 * H * W floats (unread, may be null, when the blur is decimated).
// decimate: for a wide blur (sigma >= 8: f = BlurSelectionFactor(sigma) > 1) the blur runs at 1 / f
// of the resolution on f x f block means and is read back bilinearly, with the variances matched
// (a Gaussian of the same sigma to ~1e-3 in the weights; ~10x less work at sigma 16, where the full
// blur has 97 taps a pass); the weights' support then is the blur's at the lower resolution.
// AVX2 loops where UseAvx2 (cpp/ibr/simd.h) allows; the same bits as the SSE2 / scalar ones.
void BlurSelection(ImageView<const std::uint8_t> label, float sigma, float min_weight, float* scratch,
                   ImageView<float> weights_out, bool decimate = false);

// A floor on the PVM weight of blurred selection weights (H, W, 3) = (tm, ulr, pvm), in place:
// where the weights sum to > 0 and pvm < floor, pvm becomes floor and tm, ulr are scaled by
// (1 - floor) / (1 - pvm), so the three still sum to 1 (pixels with no weight stay 0). floor in
// [0, 1]; 0 leaves the weights as they are. The composite then mixes the PVM colour into every
// pixel that has one (its fallback, ULR, where the PVM has no candidate): the hybrid's pvm_floor,
// which the mix stage fits per scene (python/ibrtools/hybrid/method.py, docs/hybrid.md).
void FloorPvmWeight(ImageView<float> weights, float floor);

// The block size of BlurSelection's decimated form: 1 (full resolution) below sigma 8, else
// min(4, floor(sigma / 4)).
int BlurSelectionFactor(float sigma);

// Where the composite needs ULR and PVM colours, from the blurred weights (H, W, 3) = (tm, ulr,
// pvm) and the PVM's valid pixels (pvm_valid: it has candidates): need_pvm = pvm weight > 0 and
// valid; need_ulr = ulr weight > 0, or pvm weight > 0 without valid PVM (its fallback). Returns
// the counts of both in counts[0] (ulr), counts[1] (pvm).
void HybridNeeds(ImageView<const float> weights, const std::uint8_t* pvm_valid, std::uint8_t* need_ulr,
                 std::uint8_t* need_pvm, std::int64_t counts[2]);

// The frame's other outputs: hole = label none (no mesh hit and no PVM candidate: no method has a
// colour there, whatever weight the blur spread to it; the composite is 0); depth = the PVM depth
// where the label is PVM, else the G-buffer's; selection (H, W, 3) = the weights as colours (red
// PVM, green TM, blue ULR), 0 at holes; counts[4] = the pixels of each label (tm, ulr, pvm, none).
void HybridFrameOutputs(ImageView<const std::uint8_t> label, ImageView<const float> weights, const float* gbuffer_depth,
                        const float* pvm_depth, std::uint8_t* hole, float* depth, float* selection,
                        std::int64_t counts[4]);

// color = w_tm * tm + w_ulr * ulr' + w_pvm * pvm', where a method without a result at the pixel
// falls back: ulr' = ulr where ulr_count > 0 else tm; pvm' = pvm where pvm_valid else ulr'.
// Pixels whose weights are all 0 get colour 0. ulr / pvm (and their masks) may be null (weight
// moved to the fallback).
void HybridComposite(ImageView<const float> weights, ImageView<const float> tm, const float* ulr,
                     const std::uint8_t* ulr_count, const float* pvm, const std::uint8_t* pvm_valid,
                     ImageView<float> color_out);

}  // namespace ibr
