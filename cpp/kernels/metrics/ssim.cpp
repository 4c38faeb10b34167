#include "kernels/metrics/ssim.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "ibr/parallel.h"

namespace ibr {
namespace {

// scipy.ndimage "reflect" boundary: -1 -> 0, -2 -> 1, n -> n - 1, n + 1 -> n - 2. Valid for
// |overshoot| <= n, which holds because n >= win > radius.
inline int Reflect(int i, int n) {
  if (i < 0) return -i - 1;
  if (i >= n) return 2 * n - i - 1;
  return i;
}

// Vertical running box sums of one channel for one output row: the five moments x, y, xx, yy,
// xy summed over rows [y - r, y + r] (reflected), one value per column. Stored padded by r
// columns on each side (reflected too) so that the horizontal pass needs no branches.
struct ColumnSums {
  int width = 0, radius = 0;
  std::vector<double> sx, sy, sxx, syy, sxy;  // each width + 2 * radius

  ColumnSums(int w, int r) : width(w), radius(r) {
    const std::size_t n = std::size_t(w) + 2 * std::size_t(r);
    sx.assign(n, 0.0), sy.assign(n, 0.0), sxx.assign(n, 0.0), syy.assign(n, 0.0), sxy.assign(n, 0.0);
  }

  // Adds sign * (row of a, row of b) for channel c into the unpadded part.
  void AddRow(const float* ra, const float* rb, int channels, int c, double sign) {
    double* __restrict px = sx.data() + radius;
    double* __restrict py = sy.data() + radius;
    double* __restrict pxx = sxx.data() + radius;
    double* __restrict pyy = syy.data() + radius;
    double* __restrict pxy = sxy.data() + radius;
    for (int x = 0; x < width; ++x) {
      const double va = ra[std::ptrdiff_t(x) * channels + c];
      const double vb = rb[std::ptrdiff_t(x) * channels + c];
      px[x] += sign * va;
      py[x] += sign * vb;
      pxx[x] += sign * (va * va);
      pyy[x] += sign * (vb * vb);
      pxy[x] += sign * (va * vb);
    }
  }

  void Clear() {
    std::fill(sx.begin(), sx.end(), 0.0), std::fill(sy.begin(), sy.end(), 0.0);
    std::fill(sxx.begin(), sxx.end(), 0.0), std::fill(syy.begin(), syy.end(), 0.0);
    std::fill(sxy.begin(), sxy.end(), 0.0);
  }

  // Fills the padding columns by reflection of the unpadded ones.
  void Pad() {
    for (std::vector<double>* v : {&sx, &sy, &sxx, &syy, &sxy}) {
      double* p = v->data() + radius;
      for (int k = 1; k <= radius; ++k) {
        p[-k] = p[Reflect(-k, width)];
        p[width - 1 + k] = p[Reflect(width - 1 + k, width)];
      }
    }
  }
};

}  // namespace

int SsimBandRows(int height, int width) {
  // At least 32 rows (the 2r rows of start-up per band stay a small overhead) and at least
  // kMinPixelsPerTask pixels per task.
  const std::int64_t by_pixels = (kMinPixelsPerTask + std::max(width, 1) - 1) / std::max(width, 1);
  return static_cast<int>(std::max<std::int64_t>(32, std::min<std::int64_t>(by_pixels, std::max(height, 1))));
}

double SsimKernel(const ImageView<const float>& a, const ImageView<const float>& b,
                  const SsimOptions& options, const ImageView<float>& map) {
  const int h = a.height, w = a.width, channels = a.channels;
  const int r = (options.win_size - 1) / 2;
  const double np = double(options.win_size) * options.win_size;
  const double inv_np = 1.0 / np;
  const double cov_norm = options.sample_covariance ? np / (np - 1.0) : 1.0;
  const double c1 = (options.k1 * options.data_range) * (options.k1 * options.data_range);
  const double c2 = (options.k2 * options.data_range) * (options.k2 * options.data_range);
  const int band = SsimBandRows(h, w);
  const std::int64_t num_bands = (h + band - 1) / band;
  std::vector<double> band_sums(static_cast<std::size_t>(num_bands), 0.0);
  const bool want_map = !map.Empty();

  ParallelFor(h, band, [&](std::int64_t y_begin, std::int64_t y_end) {
    const int y0 = static_cast<int>(y_begin), y1 = static_cast<int>(y_end);
    std::vector<ColumnSums> cols(static_cast<std::size_t>(channels), ColumnSums(w, r));
    std::vector<double> row_ssim(static_cast<std::size_t>(w));
    double sum = 0.0;  // over the cropped interior of this band, all channels
    for (int y = y0; y < y1; ++y) {
      std::fill(row_ssim.begin(), row_ssim.end(), 0.0);
      for (int c = 0; c < channels; ++c) {
        ColumnSums& cs = cols[static_cast<std::size_t>(c)];
        if (y == y0) {
          // Start of the band: the full window. Later rows slide it (running sums).
          cs.Clear();
          for (int k = -r; k <= r; ++k) {
            const int yy = Reflect(y + k, h);
            cs.AddRow(a.Row(yy), b.Row(yy), channels, c, 1.0);
          }
        } else {
          const int y_in = Reflect(y + r, h), y_out = Reflect(y - r - 1, h);
          cs.AddRow(a.Row(y_in), b.Row(y_in), channels, c, 1.0);
          cs.AddRow(a.Row(y_out), b.Row(y_out), channels, c, -1.0);
        }
        cs.Pad();
        // Horizontal pass: a direct (2r + 1)-tap sum (vectorisable), then the SSIM formula.
        const double* __restrict px = cs.sx.data();
        const double* __restrict py = cs.sy.data();
        const double* __restrict pxx = cs.sxx.data();
        const double* __restrict pyy = cs.syy.data();
        const double* __restrict pxy = cs.sxy.data();
        double* __restrict out = row_ssim.data();
        for (int x = 0; x < w; ++x) {
          double mx = 0, my = 0, mxx = 0, myy = 0, mxy = 0;
          for (int k = 0; k <= 2 * r; ++k) {
            mx += px[x + k], my += py[x + k], mxx += pxx[x + k], myy += pyy[x + k], mxy += pxy[x + k];
          }
          mx *= inv_np, my *= inv_np, mxx *= inv_np, myy *= inv_np, mxy *= inv_np;
          const double vx = cov_norm * (mxx - mx * mx);
          const double vy = cov_norm * (myy - my * my);
          const double vxy = cov_norm * (mxy - mx * my);
          // Denominator >= C1 * (C2 - rounding) > 0 because data_range > 0 (checked by the front).
          out[x] += ((2.0 * mx * my + c1) * (2.0 * vxy + c2)) /
                    ((mx * mx + my * my + c1) * (vx + vy + c2));
        }
      }
      if (y >= r && y < h - r) {
        for (int x = r; x < w - r; ++x) sum += row_ssim[static_cast<std::size_t>(x)];
      }
      if (want_map) {
        float* m = map.Row(y);
        const double inv_c = 1.0 / channels;
        for (int x = 0; x < w; ++x) m[x] = static_cast<float>(row_ssim[static_cast<std::size_t>(x)] * inv_c);
      }
    }
    band_sums[static_cast<std::size_t>(y0 / band)] = sum;
  });

  // Reduce in band order: the same sum for any thread count.
  double total = 0.0;
  for (double s : band_sums) total += s;
  const double count = double(h - 2 * r) * double(w - 2 * r) * channels;
  return total / count;
}

std::int64_t CountNonFinite(const float* data, std::int64_t n) {
  constexpr std::int64_t kGrain = 1 << 18;
  const std::int64_t chunks = (n + kGrain - 1) / kGrain;
  std::vector<std::int64_t> counts(static_cast<std::size_t>(std::max<std::int64_t>(chunks, 0)), 0);
  ParallelFor(n, kGrain, [&](std::int64_t begin, std::int64_t end) {
    std::int64_t bad = 0;
    for (std::int64_t i = begin; i < end; ++i) bad += std::isfinite(data[i]) ? 0 : 1;
    counts[static_cast<std::size_t>(begin / kGrain)] = bad;
  });
  std::int64_t total = 0;
  for (std::int64_t c : counts) total += c;
  return total;
}

}  // namespace ibr
