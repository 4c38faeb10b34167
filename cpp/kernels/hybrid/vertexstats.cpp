// Per-vertex colour statistics: the gain estimation's loops (vertexstats.h).
#include "kernels/hybrid/vertexstats.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "ibr/parallel.h"

namespace ibr {

void VertexColourSums(const std::int64_t* index, const double* color, std::int64_t num_samples,
                      const std::int64_t* bounds, int num_views, const double* gains, std::int64_t num_vertices,
                      double* sum, double* sum2) {
  std::fill(sum, sum + 3 * num_vertices, 0.0);
  if (sum2 != nullptr) std::fill(sum2, sum2 + 3 * num_vertices, 0.0);
  // At most 4 vertex ranges (at least 1 << 16 vertices each): each task scans every sample.
  const std::int64_t grain = std::max<std::int64_t>(1 << 16, (num_vertices + 3) / 4);
  ParallelFor(num_vertices, grain, [&](std::int64_t lo, std::int64_t hi) {
    for (int v = 0; v < num_views; ++v) {
      const double* g = gains + 3 * v;
      for (std::int64_t s = bounds[v]; s < bounds[v + 1]; ++s) {
        const std::int64_t i = index[s];
        if (i < lo || i >= hi) continue;
        for (int c = 0; c < 3; ++c) {
          const double x = color[c * num_samples + s] / g[c];
          sum[3 * i + c] += x;
          if (sum2 != nullptr) sum2[3 * i + c] += x * x;
        }
      }
    }
  });
}

void GainMedianRatios(const std::int64_t* index, const double* color, const std::int64_t* bounds, int num_views,
                      const double* gains, const double* mean, double* median, std::int64_t* count) {
  ParallelFor(num_views, 1, [&](std::int64_t vb, std::int64_t ve) {
    std::vector<double> r[3];
    for (std::int64_t v = vb; v < ve; ++v) {
      const double* g = gains + 3 * v;
      for (auto& rc : r) rc.clear();
      for (std::int64_t s = bounds[v]; s < bounds[v + 1]; ++s) {
        const double* m = mean + 3 * index[s];
        if (!(m[0] > 1e-3 && m[1] > 1e-3 && m[2] > 1e-3)) continue;
        double q[3];
        for (int c = 0; c < 3; ++c) q[c] = color[3 * s + c] / g[c] / m[c];
        if (!(std::isfinite(q[0]) && std::isfinite(q[1]) && std::isfinite(q[2]))) continue;
        for (int c = 0; c < 3; ++c) r[c].push_back(q[c]);
      }
      const std::int64_t n = static_cast<std::int64_t>(r[0].size());
      count[v] = n;
      for (int c = 0; c < 3; ++c) {
        double& out = median[3 * v + c];
        if (n == 0) {
          out = 1.0;
          continue;
        }
        auto& x = r[c];
        const std::int64_t h = n / 2;
        std::nth_element(x.begin(), x.begin() + h, x.end());
        const double hi = x[h];
        // Even count: numpy's mean of the two middle values, (a + b) / 2; the lower one is the
        // largest of the values before the h-th after the partition.
        out = n % 2 ? hi : (*std::max_element(x.begin(), x.begin() + h) + hi) / 2.0;
      }
    }
  });
}

}  // namespace ibr
