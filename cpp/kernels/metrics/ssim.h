// SSIM (Wang, Bovik, Sheikh, Simoncelli 2004, "Image quality assessment: from error
// visibility to structural similarity", eq. 13) with exactly the definition of
// scikit-image's default `skimage.metrics.structural_similarity`:
//   * a win x win uniform (box) window, win = 7 by default (not Wang's 11x11 Gaussian);
//   * local means ux, uy and second moments uxx, uyy, uxy by scipy.ndimage.uniform_filter
//     with mode "reflect" (half-sample symmetric: d c b a | a b c d | d c b a);
//   * sample covariances: v = N / (N - 1) * (uxx - ux * ux), N = win * win;
//   * C1 = (K1 R)^2, C2 = (K2 R)^2 with R = data_range, K1 = 0.01, K2 = 0.03;
//   * S = (2 ux uy + C1)(2 vxy + C2) / ((ux^2 + uy^2 + C1)(vx + vy + C2));
//   * mean SSIM = mean of S over the image cropped by (win - 1) / 2 on every side (the border
//     values, which depend on the reflection, are excluded); colour = mean over channels of
//     the per-channel means (skimage's channel_axis), which is the mean over all cropped
//     (pixel, channel) values since every channel has the same count.
// Deviation: all filtering and the SSIM formula are evaluated in float64 (skimage works in
// float32 for float32 input), so we agree with skimage to ~1e-6, not bit for bit.
//
// Inputs are (H, W) or (H, W, C) float32 images, row-major, channel-interleaved, same shape,
// H >= win and W >= win, finite values. The binding (cpp/bindings/metrics.cpp: shapes) and the
// front (front.h: options, values) check all that.
#pragma once
#include <cstdint>

#include "ibr/image.h"

namespace ibr {

struct SsimOptions {
  int win_size = 7;               // odd, >= 3
  double k1 = 0.01;
  double k2 = 0.03;
  double data_range = 1.0;        // R: max - min of the value range (1 for [0, 1] images)
  bool sample_covariance = true;  // N / (N - 1) normalisation, skimage's default
};

// Rows per parallel task: depends only on the image size (never on the thread count), so
// the sums, the running-sum restart points and the result are identical for any thread count.
int SsimBandRows(int height, int width);

// Returns the mean SSIM of a and b. When `map` is not empty ((H, W), 1 channel) it receives
// the per-pixel SSIM averaged over channels, including the reflected border (skimage's
// `full=True` S, channel mean). Multithreaded over row bands with ibr::ParallelFor.
double SsimKernel(const ImageView<const float>& a, const ImageView<const float>& b,
                  const SsimOptions& options, const ImageView<float>& map);

// Number of non-finite values (NaN or +-inf) in n floats; multithreaded.
std::int64_t CountNonFinite(const float* data, std::int64_t n);

}  // namespace ibr
