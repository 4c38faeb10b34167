// Push-pull hole filling; equations and conventions in pushpull.h.
#include "kernels/inpaint/pushpull.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <type_traits>
#include <vector>

#include "ibr/parallel.h"
#include "ibr/simd.h"
#include "kernels/inpaint/metameric.h"

namespace ibr {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// Unknown depth (the engine marks it NaN or 0; infinite and negative values count as unknown too)
// never sets a block's reference depth.
inline bool Known(float d) { return std::isfinite(d) && d > 0.0f; }

// Rows per task so that a task has at least kMinPixelsPerTask pixels; depends on the size only.
std::int64_t RowGrain(int width) {
  return std::max<std::int64_t>(1, kMinPixelsPerTask / std::max(1, width));
}

// One pyramid level >= 1: colour (h, w, C) normalised, validity (h, w), depth (h, w) or null.
struct Level {
  int h = 0, w = 0;
  float* c = nullptr;
  float* v = nullptr;
  float* d = nullptr;
};

// Level 0 seen as a pull source: validity from the hole mask (one byte per pixel). A source's
// CRow(y, scratch) returns row y's C interleaved channels; sources that compute their rows
// (kMaterialises) write them into `scratch` (w * C floats), the others ignore it.
struct InputSource {
  static constexpr bool kMaterialises = false;
  const ImageView<const float>& image;
  const ImageView<const std::uint8_t>& hole;
  const ImageView<const float>& depth;
  int h() const { return image.height; }
  int w() const { return image.width; }
  int channels() const { return image.channels; }
  const float* CRow(int y, float*) const { return image.Row(y); }
  const std::uint8_t* VRow(int y) const { return hole.Row(y); }
  static float V(const std::uint8_t* row, int x) { return row[x] ? 0.0f : 1.0f; }
  const float* DRow(int y) const { return depth.Empty() ? nullptr : depth.Row(y); }
  InputSource WithoutDepth(const ImageView<const float>& none) const { return {image, hole, none}; }
};

// Level 0 of the moments of k bands (pushpull.h PushPullMomentsKernel): row y is
// [X_0 .. X_{k-1}, X_0^2 .. X_{k-1}^2] of the bands' C channels each, computed on the fly.
struct MomentsSource {
  static constexpr bool kMaterialises = true;
  const ImageView<const float>* bands;
  int k;
  const ImageView<const std::uint8_t>& hole;
  const ImageView<const float>& depth;
  int h() const { return hole.height; }
  int w() const { return hole.width; }
  int channels() const { return 2 * k * bands[0].channels; }
  const float* CRow(int y, float* scratch) const {
    StackMomentsRow(bands, k, y, scratch);
    return scratch;
  }
  const std::uint8_t* VRow(int y) const { return hole.Row(y); }
  static float V(const std::uint8_t* row, int x) { return row[x] ? 0.0f : 1.0f; }
  const float* DRow(int y) const { return depth.Empty() ? nullptr : depth.Row(y); }
  MomentsSource WithoutDepth(const ImageView<const float>& none) const { return {bands, k, hole, none}; }
};

struct LevelSource {
  static constexpr bool kMaterialises = false;
  const Level& l;
  int channels_;
  int h() const { return l.h; }
  int w() const { return l.w; }
  int channels() const { return channels_; }
  const float* CRow(int y, float*) const { return l.c + std::ptrdiff_t(y) * l.w * channels_; }
  const float* VRow(int y) const { return l.v + std::ptrdiff_t(y) * l.w; }
  static float V(const float* row, int x) { return row[x]; }
  const float* DRow(int y) const { return l.d ? l.d + std::ptrdiff_t(y) * l.w : nullptr; }
};

// PULL (Alg. 1 lines 1-12) of `src` into `dst` (dst.h = ceil(src.h / 2), same for w).
template <int kC, class Src>
void Pull(const Src& src, int channels, bool depth_aware, float threshold, const Level& dst) {
  const int C = kC > 0 ? kC : channels;
  ParallelFor(dst.h, RowGrain(dst.w), [&](std::int64_t y0, std::int64_t y1) {
    float acc[kC > 0 ? kC : 1];
    std::vector<float> acc_dyn(kC > 0 ? 0 : C);
    float* sum = kC > 0 ? acc : acc_dyn.data();
    std::vector<float> rows(Src::kMaterialises ? 2 * std::size_t(src.w()) * C : 0);
    for (int Y = static_cast<int>(y0); Y < static_cast<int>(y1); ++Y) {
      const int sy0 = 2 * Y, sy1 = std::min(2 * Y + 1, src.h() - 1);
      const bool has_row1 = sy1 != sy0;
      const float* c0 = src.CRow(sy0, rows.data());
      const float* c1 = has_row1 ? src.CRow(sy1, rows.data() + (rows.empty() ? 0 : std::size_t(src.w()) * C)) : c0;
      const auto* v0 = src.VRow(sy0);
      const auto* v1 = src.VRow(sy1);
      const float* d0 = depth_aware ? src.DRow(sy0) : nullptr;
      const float* d1 = depth_aware ? src.DRow(sy1) : nullptr;
      float* out_c = dst.c + std::ptrdiff_t(Y) * dst.w * C;
      float* out_v = dst.v + std::ptrdiff_t(Y) * dst.w;
      float* out_d = depth_aware ? dst.d + std::ptrdiff_t(Y) * dst.w : nullptr;
      for (int X = 0; X < dst.w; ++X) {
        const int sx0 = 2 * X, sx1 = std::min(2 * X + 1, src.w() - 1);
        const bool has_col1 = sx1 != sx0;
        // The (up to) four children; the duplicates at odd borders do not exist.
        const bool exists[4] = {true, has_col1, has_row1, has_row1 && has_col1};
        const int n = 1 + has_col1 + has_row1 + (has_row1 && has_col1);
        float v[4] = {Src::V(v0, sx0), has_col1 ? Src::V(v0, sx1) : 0.0f, has_row1 ? Src::V(v1, sx0) : 0.0f,
                      (has_row1 && has_col1) ? Src::V(v1, sx1) : 0.0f};
        const float* cp[4] = {c0 + sx0 * C, c0 + sx1 * C, c1 + sx0 * C, c1 + sx1 * C};
        if (depth_aware) {
          const float d[4] = {d0[sx0], d0[sx1], d1[sx0], d1[sx1]};
          // Background reference: the farthest known depth (the paper's reversed-Z "min").
          float ref = -1.0f;
          for (int i = 0; i < 4; ++i) {
            if (exists[i] && Known(d[i])) ref = std::max(ref, d[i]);
          }
          for (int i = 0; i < 4; ++i) {
            if (Known(d[i]) && ref - d[i] > threshold) v[i] = 0.0f;  // Alg. 1 lines 4-6
          }
          out_d[X] = ref > 0.0f ? ref : kNaN;  // line 10
        }
        float* out = out_c + std::ptrdiff_t(X) * C;
        if (n == 4 && v[0] == 1.0f && v[1] == 1.0f && v[2] == 1.0f && v[3] == 1.0f) {
          // Common case (no hole, nothing rejected): the plain 2x2 mean.
          for (int k = 0; k < C; ++k) out[k] = 0.25f * ((cp[0][k] + cp[1][k]) + (cp[2][k] + cp[3][k]));
          out_v[X] = 1.0f;
          continue;
        }
        float wsum = 0.0f;
        for (int k = 0; k < C; ++k) sum[k] = 0.0f;
        for (int i = 0; i < 4; ++i) {
          if (v[i] > 0.0f) {  // never touch the colour of a hole (it may be anything)
            for (int k = 0; k < C; ++k) sum[k] += v[i] * cp[i][k];
            wsum += v[i];
          }
        }
        if (wsum > 0.0f) {
          const float inv = 1.0f / wsum;
          for (int k = 0; k < C; ++k) out[k] = sum[k] * inv;
        } else {
          for (int k = 0; k < C; ++k) out[k] = 0.0f;
        }
        out_v[X] = wsum / static_cast<float>(n);  // partial validity (line 9)
      }
    }
  });
}

// PULL of level 0 of the moments (MomentsSource) into level 1: Pull's arithmetic, operation by
// operation (so the same values bit for bit), but the children's [X, X^2] are read from the bands
// and squared in registers instead of being stacked into rows of 2kC floats first (measured: the
// stacking was about a third of this pass).
template <int kC, int kK = 0, int kCh = 0>
void PullMoments(const MomentsSource& src, bool depth_aware, float threshold, const Level& dst) {
  const int C = kC > 0 ? kC : src.channels();
  const int k = kK > 0 ? kK : src.k, c = kCh > 0 ? kCh : src.bands[0].channels, kc = k * c;
  const int sh = src.h(), sw = src.w();
  ParallelFor(dst.h, RowGrain(dst.w), [&](std::int64_t y0, std::int64_t y1) {
    float acc[kC > 0 ? kC : 1];
    std::vector<float> acc_dyn(kC > 0 ? 0 : C);
    float* sum = kC > 0 ? acc : acc_dyn.data();
    for (int Y = static_cast<int>(y0); Y < static_cast<int>(y1); ++Y) {
      const int sy0 = 2 * Y, sy1 = std::min(2 * Y + 1, sh - 1);
      const bool has_row1 = sy1 != sy0;
      const std::uint8_t* v0 = src.VRow(sy0);
      const std::uint8_t* v1 = src.VRow(sy1);
      const float* d0 = depth_aware ? src.DRow(sy0) : nullptr;
      const float* d1 = depth_aware ? src.DRow(sy1) : nullptr;
      float* out_c = dst.c + std::ptrdiff_t(Y) * dst.w * C;
      float* out_v = dst.v + std::ptrdiff_t(Y) * dst.w;
      float* out_d = depth_aware ? dst.d + std::ptrdiff_t(Y) * dst.w : nullptr;
      for (int X = 0; X < dst.w; ++X) {
        const int sx0 = 2 * X, sx1 = std::min(2 * X + 1, sw - 1);
        const bool has_col1 = sx1 != sx0;
        const bool exists[4] = {true, has_col1, has_row1, has_row1 && has_col1};
        const int n = 1 + has_col1 + has_row1 + (has_row1 && has_col1);
        float v[4] = {MomentsSource::V(v0, sx0), has_col1 ? MomentsSource::V(v0, sx1) : 0.0f,
                      has_row1 ? MomentsSource::V(v1, sx0) : 0.0f,
                      (has_row1 && has_col1) ? MomentsSource::V(v1, sx1) : 0.0f};
        if (depth_aware) {
          const float d[4] = {d0[sx0], d0[sx1], d1[sx0], d1[sx1]};
          float ref = -1.0f;
          for (int i = 0; i < 4; ++i) {
            if (exists[i] && Known(d[i])) ref = std::max(ref, d[i]);
          }
          for (int i = 0; i < 4; ++i) {
            if (Known(d[i]) && ref - d[i] > threshold) v[i] = 0.0f;
          }
          out_d[X] = ref > 0.0f ? ref : kNaN;
        }
        float* out = out_c + std::ptrdiff_t(X) * C;
        const std::ptrdiff_t o00 = std::ptrdiff_t(sx0) * c, o01 = std::ptrdiff_t(sx1) * c;
        if (n == 4 && v[0] == 1.0f && v[1] == 1.0f && v[2] == 1.0f && v[3] == 1.0f) {
          for (int b = 0; b < k; ++b) {
            const float* r0 = src.bands[b].Row(sy0);
            const float* r1 = src.bands[b].Row(sy1);
            for (int ch = 0; ch < c; ++ch) {
              const float x0 = r0[o00 + ch], x1 = r0[o01 + ch], x2 = r1[o00 + ch], x3 = r1[o01 + ch];
              out[b * c + ch] = 0.25f * ((x0 + x1) + (x2 + x3));
              const float q0 = x0 * x0, q1 = x1 * x1, q2 = x2 * x2, q3 = x3 * x3;
              out[kc + b * c + ch] = 0.25f * ((q0 + q1) + (q2 + q3));
            }
          }
          out_v[X] = 1.0f;
          continue;
        }
        float wsum = 0.0f;
        for (int q = 0; q < C; ++q) sum[q] = 0.0f;
        for (int i = 0; i < 4; ++i) {
          if (!(v[i] > 0.0f)) continue;  // never touch the colour of a hole
          const int yy = i < 2 ? sy0 : sy1;
          const std::ptrdiff_t ox = (i & 1) ? o01 : o00;
          for (int b = 0; b < k; ++b) {
            const float* r = src.bands[b].Row(yy) + ox;
            for (int ch = 0; ch < c; ++ch) {
              const float x = r[ch], q = x * x;
              sum[b * c + ch] += v[i] * x;
              sum[kc + b * c + ch] += v[i] * q;
            }
          }
          wsum += v[i];
        }
        if (wsum > 0.0f) {
          const float inv = 1.0f / wsum;
          for (int q = 0; q < C; ++q) out[q] = sum[q] * inv;
        } else {
          for (int q = 0; q < C; ++q) out[q] = 0.0f;
        }
        out_v[X] = wsum / static_cast<float>(n);
      }
    }
  });
}

// Bilinear up-sampling taps from a coarse axis of size n_coarse to fine index i: pixel centres
// at +0.5 give the fine centre (i + 0.5) / 2 - 0.5 in coarse pixels, i.e. 3/4 of the parent and
// 1/4 of its neighbour on i's side, clamped at the border.
struct Taps {
  std::vector<int> i0, i1;  // weight 0.75, 0.25
};
Taps MakeTaps(int n_fine, int n_coarse) {
  Taps t;
  t.i0.resize(n_fine);
  t.i1.resize(n_fine);
  for (int i = 0; i < n_fine; ++i) {
    const int k = i / 2;
    const int nb = (i % 2 == 0) ? k - 1 : k + 1;
    t.i0[i] = k;
    t.i1[i] = std::clamp(nb, 0, n_coarse - 1);
  }
  return t;
}

// up(filled coarse) at fine (y, x), written to u[C].
template <int kC>
inline void Up(const Level& coarse, int C_dyn, const Taps& ty, const Taps& tx, int y, int x, float* u) {
  const int C = kC > 0 ? kC : C_dyn;
  const float* r0 = coarse.c + std::ptrdiff_t(ty.i0[y]) * coarse.w * C;
  const float* r1 = coarse.c + std::ptrdiff_t(ty.i1[y]) * coarse.w * C;
  const std::ptrdiff_t a = std::ptrdiff_t(tx.i0[x]) * C, b = std::ptrdiff_t(tx.i1[x]) * C;
  for (int k = 0; k < C; ++k) {
    u[k] = 0.5625f * r0[a + k] + 0.1875f * (r0[b + k] + r1[a + k]) + 0.0625f * r1[b + k];
  }
}

// PUSH (Alg. 1 lines 13-16) into level `fine` (>= 1) from the filled `coarse`, in place.
template <int kC>
void Push(const Level& coarse, int channels, float gamma, const Level& fine) {
  const int C = kC > 0 ? kC : channels;
  const Taps ty = MakeTaps(fine.h, coarse.h), tx = MakeTaps(fine.w, coarse.w);
  ParallelFor(fine.h, RowGrain(fine.w), [&](std::int64_t y0, std::int64_t y1) {
    float ubuf[kC > 0 ? kC : 1];
    std::vector<float> udyn(kC > 0 ? 0 : C);
    float* u = kC > 0 ? ubuf : udyn.data();
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      for (int x = 0; x < fine.w; ++x) {
        const std::ptrdiff_t p = std::ptrdiff_t(y) * fine.w + x;
        const float v = fine.v[p];
        const float a = v <= 0.0f ? 0.0f
                        : gamma == 0.0f ? 1.0f
                        : gamma == 0.5f ? std::sqrt(v)
                                        : std::pow(v, gamma);
        if (a >= 1.0f) continue;
        Up<kC>(coarse, C, ty, tx, y, x, u);
        float* c = fine.c + p * C;
        for (int k = 0; k < C; ++k) c[k] = a * c[k] + (1.0f - a) * u[k];
      }
    }
  });
}

// Level 0: copy the image outside holes (exact), up(filled level 1) inside.
// Row y of the source into out's row y (exact).
template <class Src>
void CopyRow(const Src& src, int y, const ImageView<float>& out) {
  float* o = out.Row(y);
  const float* r = src.CRow(y, o);
  if (r != o) std::memcpy(o, r, sizeof(float) * std::size_t(src.w()) * src.channels());
}

// Where the level-0 fill of a hole pixel goes. OutSink: straight into `out` (push-pull's result).
// ChangeSink (metameric, PushPullMomentsChangeKernel): the pixel's moments go through the
// metameric composite (metameric.h MetamericChangeSample) into the bands, and each row of the
// bands is first cleared (the change is 0 outside the mask). Row(y) is called once per row
// before its pixels; Begin returns where the pixel's C values are written, End consumes them.
struct OutSink {
  const ImageView<float>& out;
  void Row(int) const {}
  float* Begin(int y, int x, float*) const { return &out.At(y, x, 0); }
  void End(int, int, const float*) const {}
};

// OutSink restricted to the pixels where `write` is non-zero (PushPullKernel's write mask).
struct MaskedOutSink {
  const ImageView<float>& out;
  const ImageView<const std::uint8_t>& write;
  void Row(int) const {}
  float* Begin(int y, int x, float* scratch) const { return write.At(y, x) ? &out.At(y, x, 0) : scratch; }
  void End(int, int, const float*) const {}
};

struct ChangeSink {
  const MetamericSynth& synth;
  void Row(int y) const { MetamericZeroRow(synth, y); }
  float* Begin(int, int, float* scratch) const { return scratch; }
  void End(int y, int x, const float* moments) const { MetamericChangeSample(synth, y, x, moments); }
};

template <int kC, class Src, class Sink>
void PushToOutput(const Level& coarse, const Src& src, bool holes_only, const ImageView<float>& out,
                  const Sink& sink) {
  const int C = kC > 0 ? kC : src.channels();
  const int height = src.h(), width = src.w();
  const Taps ty = MakeTaps(height, coarse.h), tx = MakeTaps(width, coarse.w);
  ParallelFor(height, RowGrain(width), [&](std::int64_t y0, std::int64_t y1) {
    float ubuf[kC > 0 ? kC : 1];
    std::vector<float> udyn(kC > 0 ? 0 : C);
    float* scratch = kC > 0 ? ubuf : udyn.data();
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const std::uint8_t* hrow = src.VRow(y);
      if (!holes_only) CopyRow(src, y, out);
      sink.Row(y);
      for (int x = 0; x < width; ++x) {
        if (hrow[x]) {
          float* u = sink.Begin(y, x, scratch);
          Up<kC>(coarse, C, ty, tx, y, x, u);
          sink.End(y, x, u);
        }
      }
    }
  });
}

// A level is complete when every pixel keeps its own colour in the push (a = 1): coarser levels
// cannot change it, so the pull stops there.
bool Complete(const Level& l, float gamma) {
  const std::ptrdiff_t n = std::ptrdiff_t(l.h) * l.w;
  if (gamma == 0.0f) return std::none_of(l.v, l.v + n, [](float v) { return v <= 0.0f; });
  return std::all_of(l.v, l.v + n, [](float v) { return v >= 1.0f; });
}

template <int kC, class Src, class Sink>
PushPullStatus Run(const Src& src, const PushPullOptions& options, const ImageView<float>& out, const Sink& sink) {
  const int C = src.channels();
  const ImageView<const std::uint8_t>& hole = src.hole;
  const ImageView<const float>& depth = src.depth;
  const int height = src.h(), width = src.w();
  const std::size_t n0 = std::size_t(height) * width;
  const std::uint8_t* h0 = hole.data;
  if (std::all_of(h0, h0 + n0, [](std::uint8_t b) { return b != 0; })) return PushPullStatus::kNoValidPixel;
  if (std::none_of(h0, h0 + n0, [](std::uint8_t b) { return b != 0; })) {
    if (!options.holes_only) {
      ParallelFor(height, RowGrain(width), [&](std::int64_t y0, std::int64_t y1) {
        for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) CopyRow(src, y, out);
      });
    }
    ParallelFor(height, RowGrain(width), [&](std::int64_t y0, std::int64_t y1) {
      for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) sink.Row(y);
    });
    return PushPullStatus::kNoHole;
  }
  const bool depth_aware = options.depth_aware && !depth.Empty();
  float threshold = 0.0f;
  if (depth_aware) {
    // "0.04 of the normalised depth": normalise by the range of known depth in this image.
    // Per-row-band min/max, combined in order (min/max do not depend on the order anyway).
    const std::int64_t grain = RowGrain(width);
    const std::int64_t bands = (height + grain - 1) / grain;
    std::vector<float> band_lo(bands, std::numeric_limits<float>::infinity()), band_hi(bands, -1.0f);
    ParallelFor(bands, 1, [&](std::int64_t b0, std::int64_t b1) {
      for (std::int64_t b = b0; b < b1; ++b) {
        float blo = std::numeric_limits<float>::infinity(), bhi = -1.0f;
        const std::size_t i0 = std::size_t(b * grain) * width;
        const std::size_t i1 = std::min(n0, std::size_t((b + 1) * grain) * width);
        for (std::size_t i = i0; i < i1; ++i) {
          const float d = depth.data[i];
          if (Known(d)) {
            blo = std::min(blo, d);
            bhi = std::max(bhi, d);
          }
        }
        band_lo[b] = blo;
        band_hi[b] = bhi;
      }
    });
    const float lo = *std::min_element(band_lo.begin(), band_lo.end());
    const float hi = *std::max_element(band_hi.begin(), band_hi.end());
    threshold = hi >= lo ? options.depth_threshold * (hi - lo) : 0.0f;
  }

  // Sizes of levels 1..L (down to 1x1) and one scratch block for all of them.
  std::vector<Level> levels;
  std::size_t total = 0;
  for (int h = height, w = width; h > 1 || w > 1;) {
    h = (h + 1) / 2;
    w = (w + 1) / 2;
    Level l;
    l.h = h;
    l.w = w;
    levels.push_back(l);
    total += std::size_t(h) * w * (C + 1 + (depth_aware ? 1 : 0));
  }
  std::unique_ptr<float[]> scratch(new float[total]);  // every value is written before it is read
  std::size_t offset = 0;
  for (Level& l : levels) {
    const std::size_t n = std::size_t(l.h) * l.w;
    l.c = scratch.get() + offset;
    offset += n * C;
    l.v = scratch.get() + offset;
    offset += n;
    if (depth_aware) {
      l.d = scratch.get() + offset;
      offset += n;
    }
  }

  // PULL until a level is complete (or the 1x1 top).
  std::size_t top = 0;
  for (std::size_t i = 0; i < levels.size(); ++i) {
    if (i == 0) {
      if constexpr (std::is_same<Src, MomentsSource>::value) {
        // 3-channel (YCbCr) bands: the band and channel loops unrolled at compile time.
        if constexpr (kC > 0 && kC % 6 == 0) {
          if (src.bands[0].channels == 3) {
            PullMoments<kC, kC / 6, 3>(src, depth_aware, threshold, levels[0]);
          } else {
            PullMoments<kC>(src, depth_aware, threshold, levels[0]);
          }
        } else {
          PullMoments<kC>(src, depth_aware, threshold, levels[0]);
        }
      } else {
        Pull<kC>(src, C, depth_aware, threshold, levels[0]);
      }
    } else {
      Pull<kC>(LevelSource{levels[i - 1], C}, C, depth_aware, threshold, levels[i]);
    }
    top = i;
    if (Complete(levels[i], options.gamma)) break;
  }
  const Level& t = levels[top];
  if (Complete(t, 0.0f)) {
    // PUSH: the top keeps its colour (nothing coarser to mix with).
    for (std::size_t i = top; i-- > 0;) Push<kC>(levels[i + 1], C, options.gamma, levels[i]);
    PushToOutput<kC>(levels[0], src, options.holes_only, out, sink);
    return PushPullStatus::kOk;
  }
  // Only the 1x1 top can be incomplete here. Classic: impossible (the image has a valid pixel).
  // Depth-aware: the depth test dropped every valid sample at some scale (the farthest depth in
  // the image is hole only). Classic fallback, per hole pixel (pushpull.h): the top's colour is
  // 0, so the push gives F0 = the part of the fill that came from depth-aware data; the same push
  // of the indicator "has data" (1 where v > 0, top 0) gives s, the weight of that part; the
  // weight 1 - s the empty top would get goes to the classic fill of the same pixel.
  if (!depth_aware) return PushPullStatus::kNoValidPixel;
  std::size_t total_s = 0;
  for (const Level& l : levels) total_s += std::size_t(l.h) * l.w;
  std::unique_ptr<float[]> s_scratch(new float[total_s]);
  std::vector<Level> s_levels(levels.size());
  std::size_t s_offset = 0;
  for (std::size_t i = 0; i < levels.size(); ++i) {
    const std::size_t n = std::size_t(levels[i].h) * levels[i].w;
    s_levels[i] = Level{levels[i].h, levels[i].w, s_scratch.get() + s_offset, levels[i].v, nullptr};
    s_offset += n;
    for (std::size_t p = 0; p < n; ++p) s_levels[i].c[p] = levels[i].v[p] > 0.0f ? 1.0f : 0.0f;
  }
  for (int k = 0; k < C; ++k) t.c[k] = 0.0f;  // top: v = 0 (Pull wrote colour 0 already)
  for (std::size_t i = top; i-- > 0;) {
    Push<kC>(levels[i + 1], C, options.gamma, levels[i]);
    Push<1>(s_levels[i + 1], 1, options.gamma, s_levels[i]);
  }
  PushPullOptions classic;
  classic.depth_aware = false;
  classic.gamma = 0.0f;
  classic.holes_only = options.holes_only;
  const ImageView<const float> no_depth;
  // The classic fill goes to `out` (OutSink), or, for a sink that consumes the values, to a
  // buffer of its own (only on this rare path).
  constexpr bool kToOut = std::is_same<Sink, OutSink>::value;
  std::unique_ptr<float[]> classic_buf(kToOut ? nullptr : new float[n0 * C]);
  const ImageView<float> cls = kToOut ? out : ImageView<float>(classic_buf.get(), height, width, C);
  Run<kC>(src.WithoutDepth(no_depth), classic, cls, OutSink{cls});  // kOk: the image has a valid pixel
  const Level& f1 = levels[0];
  const Level& s1 = s_levels[0];
  const Taps ty = MakeTaps(height, f1.h), tx = MakeTaps(width, f1.w);
  ParallelFor(height, RowGrain(width), [&](std::int64_t y0, std::int64_t y1) {
    float fbuf[kC > 0 ? kC : 1], ubuf[kC > 0 ? kC : 1];
    std::vector<float> fdyn(kC > 0 ? 0 : C), udyn(kC > 0 ? 0 : C);
    float* f = kC > 0 ? fbuf : fdyn.data();
    float* pixel_buf = kC > 0 ? ubuf : udyn.data();
    for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y) {
      const std::uint8_t* hrow = hole.Row(y);
      sink.Row(y);
      for (int x = 0; x < width; ++x) {
        if (!hrow[x]) continue;
        float s;
        Up<kC>(f1, C, ty, tx, y, x, f);
        Up<1>(s1, 1, ty, tx, y, x, &s);
        // s = 0 (no depth-aware data reaches the pixel): f = 0 exactly and out stays classic.
        const float* c = &cls.At(y, x, 0);
        float* o = sink.Begin(y, x, pixel_buf);
        for (int k = 0; k < C; ++k) o[k] = f[k] + (1.0f - s) * c[k];
        sink.End(y, x, o);
      }
    }
  });
  return PushPullStatus::kClassicFallback;
}

// Number of NaN / inf among row[0..n): on the bits (exponent all ones), branch-free; built for AVX2
// and the portable default (IBR_AVX2_CLONES, cpp/ibr/simd.h; integer work only, so the same count
// either way).
IBR_AVX2_CLONES std::int64_t CountNonFiniteRun(const float* row, std::ptrdiff_t n) {
  std::int32_t bad = 0;
  for (std::ptrdiff_t i = 0; i < n; ++i) {
    std::uint32_t bits;
    std::memcpy(&bits, &row[i], sizeof bits);
    bad += (bits & 0x7f800000u) == 0x7f800000u;
  }
  return bad;
}

// [X, X^2] of 2 or 3 RGB/YCbCr bands (2 or 4 orientations, the high-pass at level 0): a fixed
// channel count lets the compiler unroll and vectorise the per-pixel loops. Moments are only
// filled in the holes.
template <class Sink>
PushPullStatus RunMoments(const MomentsSource& src, PushPullOptions o, const ImageView<float>& out,
                          const Sink& sink) {
  o.holes_only = true;
  switch (src.channels()) {
    case 12: return Run<12>(src, o, out, sink);
    case 18: return Run<18>(src, o, out, sink);
    case 24: return Run<24>(src, o, out, sink);
    case 30: return Run<30>(src, o, out, sink);
    default: return Run<0>(src, o, out, sink);
  }
}

}  // namespace

namespace {

template <class Sink>
PushPullStatus RunImage(const InputSource& src, const PushPullOptions& options, const ImageView<float>& out,
                        const Sink& sink) {
  switch (src.channels()) {
    case 1: return Run<1>(src, options, out, sink);
    case 2: return Run<2>(src, options, out, sink);
    case 3: return Run<3>(src, options, out, sink);
    case 4: return Run<4>(src, options, out, sink);
    default: return Run<0>(src, options, out, sink);
  }
}

}  // namespace

PushPullStatus PushPullKernel(const ImageView<const float>& image,
                              const ImageView<const std::uint8_t>& hole,
                              const ImageView<const float>& depth, const PushPullOptions& options,
                              const ImageView<float>& out, const ImageView<const std::uint8_t>& write) {
  const InputSource src{image, hole, depth};
  if (!write.Empty() && options.holes_only) return RunImage(src, options, out, MaskedOutSink{out, write});
  return RunImage(src, options, out, OutSink{out});
}

PushPullStatus PushPullMomentsKernel(const ImageView<const float>* bands, int k,
                                     const ImageView<const std::uint8_t>& hole,
                                     const ImageView<const float>& depth, const PushPullOptions& options,
                                     const ImageView<float>& out) {
  const MomentsSource src{bands, k, hole, depth};
  return RunMoments(src, options, out, OutSink{out});
}

PushPullStatus PushPullMomentsChangeKernel(const ImageView<const float>* bands, int k,
                                           const ImageView<const std::uint8_t>& hole,
                                           const ImageView<const float>& depth, const PushPullOptions& options,
                                           const MetamericSynth& synth) {
  const MomentsSource src{bands, k, hole, depth};
  const ImageView<float> none;  // holes_only: never written (the sink takes the values)
  return RunMoments(src, options, none, ChangeSink{synth});
}

std::int64_t CountNonFiniteOutsideHoles(const ImageView<const float>& image,
                                        const ImageView<const std::uint8_t>& hole) {
  const int rows_per_chunk = static_cast<int>(RowGrain(image.width * image.channels));
  const int chunks = (image.height + rows_per_chunk - 1) / rows_per_chunk;
  std::vector<std::int64_t> counts(std::max(0, chunks), 0);
  ParallelFor(chunks, 1, [&](std::int64_t c0, std::int64_t c1) {
    for (std::int64_t c = c0; c < c1; ++c) {
      std::int64_t n = 0;
      const int y0 = static_cast<int>(c) * rows_per_chunk;
      const int y1 = std::min(image.height, y0 + rows_per_chunk);
      for (int y = y0; y < y1; ++y) {
        const float* row = image.Row(y);
        const std::uint8_t* hrow = hole.Row(y);
        // The common case first: no non-finite value anywhere in the row (one contiguous,
        // vectorised scan); only a row that has some is counted pixel by pixel below.
        if (CountNonFiniteRun(row, std::ptrdiff_t(image.width) * image.channels) == 0) continue;
        // Branch-free (vectorisable): a float is NaN or inf when its exponent bits are all ones.
        const int C = image.channels;
        for (int x = 0; x < image.width; ++x) {
          std::int32_t bad = 0;
          for (int k = 0; k < C; ++k) {
            std::uint32_t bits;
            std::memcpy(&bits, &row[std::ptrdiff_t(x) * C + k], sizeof bits);
            bad += (bits & 0x7f800000u) == 0x7f800000u;
          }
          n += hrow[x] ? 0 : bad;
        }
      }
      counts[c] = n;
    }
  });
  std::int64_t n = 0;
  for (std::int64_t c : counts) n += c;
  return n;
}

}  // namespace ibr
