// Per-sample work of metameric inpainting (dos Anjos et al., "Metameric Inpainting for Image
// Warping", sec. 3.3.1 and 3.4; Walton et al. 2021 sec. 3.4; docs/inpaint.md, "Metameric").
// python/ibrtools/metameric.py orchestrates: steerable analysis, masks and the push-pull of the
// moments are other kernels; these two are the passes in between, per pyramid level with k
// bands (the high-pass residual counts as a band at level 0) of C channels each:
//
// MetamericStackMoments: the push-pull input of the level's moments,
//   out[y, x, i*C + ch] = band_i[y, x, ch],  out[y, x, (k + i)*C + ch] = band_i[y, x, ch]^2.
//
// MetamericComposite: the synthesis inside the level's (dilated) hole mask, in place,
//   band_i[y, x, ch] = mean + sigma * noise_i[yy, xx, ch]   where mask[y, x] != 0,
//   mean = moments[y, x, i*C + ch], sigma = sqrt(max(0, moments[y, x, (k + i)*C + ch] - mean^2))
//   (E[X^2] - E[X]^2 of flat data rounds to small negatives in float32; a NaN difference also
//   gives sigma = 0, so sigma is never NaN). Samples outside the mask are not touched.
//   Noise position: (yy, xx) = (y, x) without flow; with flow (full resolution (H, W, 2), (dx, dy)
//   in pixels, float32 or float64) read at the sample's full-resolution pixel (y*scale, x*scale):
//   yy = rint(y + dy / scale) mod h, xx = rint(x + dx / scale) mod w (round half to even, the
//   result in [0, h) / [0, w): the noise wraps), in double, as numpy's float64 promotion does.
//
// The arithmetic is the float32 numpy expression's, operation by operation (no fused
// multiply-add unless the compiler contracts it, e.g. with -march=native: then ~1 ulp).
// Shapes (row, col, channel), C-contiguous: bands/noise (h, w, C), moments/out (h, w, 2kC),
// mask (h, w) one byte per sample. Bands may not alias moments or noise. The binding
// (cpp/bindings/inpaint.cpp: dtypes, shapes, aliasing) and the front (front.h: values) check
// everything; kernels trust their inputs, never throw and
// never allocate. Multithreaded over rows with ibr::ParallelFor; every sample is independent, so
// the result is identical for any thread count.
#pragma once
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "ibr/image.h"

namespace ibr {

void MetamericStackMoments(const ImageView<const float>* bands, int k, const ImageView<float>& out);

// Row y of MetamericStackMoments' output into `row` (width * 2kC floats); also the level-0 rows
// of PushPullMomentsKernel (pushpull.h), which computes them on the fly instead of storing them.
inline void StackMomentsRow(const ImageView<const float>* bands, int k, int y, float* row) {
  const int c = bands[0].channels, width = bands[0].width;
  const std::ptrdiff_t C = 2 * std::ptrdiff_t(k) * c;
  for (int i = 0; i < k; ++i) {
    const float* b = bands[i].Row(y);
    float* ox = row + i * c;
    float* oq = row + (k + i) * c;
    for (int x = 0; x < width; ++x) {
      for (int ch = 0; ch < c; ++ch) {
        const float v = b[std::ptrdiff_t(x) * c + ch];
        ox[x * C + ch] = v;
        oq[x * C + ch] = v * v;
      }
    }
  }
}

// Flow of the noise (full resolution); exactly one of f32/f64 set, or neither (no flow).
struct MetamericFlow {
  const float* f32 = nullptr;
  const double* f64 = nullptr;
  int height = 0;
  int width = 0;
};

// delta = false: the equation above (bands keep their values outside the mask). delta = true:
// the band's *change* for a fill whose mean is the band's own value (python/ibrtools/metameric.py):
//   band_i[y, x, ch] = sigma * noise_i[yy, xx, ch] where mask[y, x] != 0, 0 elsewhere
// (every sample written), sigma from the moments as above.
void MetamericComposite(const ImageView<const float>& moments, const ImageView<const std::uint8_t>& mask,
                        const ImageView<const float>* noise, const ImageView<float>* bands, int k,
                        const MetamericFlow& flow, int scale, bool delta = false);

// One level's synthesis fused into the push of its moments (pushpull.h
// PushPullMomentsChangeKernel, delta mode only): the moments of a masked sample go straight into
// the change of its bands instead of through a (h, w, 2kC) moments image. `bands` are the
// level's bands, written; noise, flow, scale as for MetamericComposite.
struct MetamericSynth {
  const ImageView<const float>* noise = nullptr;
  const ImageView<float>* bands = nullptr;
  int k = 0;
  MetamericFlow flow;
  int scale = 1;
};
// Row y of every band set to 0 (the change outside the mask).
void MetamericZeroRow(const MetamericSynth& synth, int y);
// The noise position (yy, xx) of sample (y, x) with synth.flow set (MetamericComposite's rule).
void MetamericFlowPosition(const MetamericSynth& synth, int y, int x, int* yy, int* xx);
// The change of sample (y, x) from its moments (2kC floats, the layout of MetamericComposite's
// moments): band_i[y, x, ch] = sigma * noise_i[yy, xx, ch], the same arithmetic as
// MetamericComposite(..., delta = true), so the results are identical bit for bit. Inline: it
// runs once per masked sample inside the push (pushpull.cpp).
inline void MetamericChangeSample(const MetamericSynth& synth, int y, int x, const float* mx) {
  const ImageView<float>* bands = synth.bands;
  const int c = bands[0].channels, k = synth.k, kc = k * c;
  int yy = y, xx = x;
  if (synth.flow.f32 || synth.flow.f64) MetamericFlowPosition(synth, y, x, &yy, &xx);
  for (int i = 0; i < k; ++i) {
    const float* n = &synth.noise[i].At(yy, xx);
    float* b = &bands[i].At(y, x);
    for (int ch = 0; ch < c; ++ch) {
      const float mean = mx[i * c + ch];
      const float sq = mx[kc + i * c + ch];
      const float mm = mean * mean;  // as MetamericComposite
      const float d = sq - mm;
      const float sigma = d > 0.0f ? std::sqrt(d) : 0.0f;
      b[ch] = sigma * n[ch];
    }
  }
}

// out = SrgbEncode(image) for every value (image and out (h, w, C), may be the same array).
void MetamericEncode(const ImageView<const float>& image, const ImageView<float>& out);

// The result of metameric inpainting from its pieces, per pixel:
//   out = image                                      where hole == 0 (copied bit for bit),
//   out = f(base + change)                            where hole != 0,
// f = max(0, SrgbDecode(.)) with decode (negative light does not exist: the display-space noise can
// dip below 0 next to black), the identity without. image, base, change, out (h, w, C); hole (h, w)
// one byte per pixel; out may be the memory of image or of change (not of base).
void MetamericFillHoles(const ImageView<const float>& image, const ImageView<const std::uint8_t>& hole,
                        const ImageView<const float>& base, const ImageView<const float>& change, bool decode,
                        const ImageView<float>& out);

}  // namespace ibr
