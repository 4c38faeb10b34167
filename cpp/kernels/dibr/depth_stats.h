// Order statistics of a depth map's valid values (finite, > 0), exactly, without sorting or copying
// them: the depth range of every input view of view selection (python/ibrtools/dibr/view_selection.py
// depth_range: min, max and the 1st / 99th percentiles that bound the outliers) costs one
// np.partition of the valid values otherwise, ~20 ms per 1080p view in each frame of a video.
//
// Positive finite floats order as their bit patterns (uint32), so the value of rank r (0-based,
// ascending) is found by a two-pass radix select: pass 1 counts the valid values by their top 16
// bits (and finds the count, min and max); the bin holding rank r and r's rank inside it follow
// from the running sum; pass 2 gathers that bin's values and picks the rank among them
// (nth_element). Multithreaded over fixed chunks of values; the counts are integers and the values
// order statistics, so the result is the same for any thread count.
#pragma once
#include <cstdint>
#include <vector>

namespace ibr {

struct DepthOrderStats {
  std::int64_t count = 0;  // valid values
  float min = 0, max = 0;  // of the valid values (0, 0 when there are none)
  std::vector<std::int64_t> ranks;  // per quantile q: floor((count - 1) q) and the next rank, as numpy's
  std::vector<float> values;        // quantile ("linear") picks them; the values of those ranks
};

// The valid values' count, min, max and, for each of the quantiles (in [0, 1]), the two ranks of
// numpy.quantile's linear method (h = (count - 1) q; floor(h) and floor(h) + 1; both count - 1 when
// h >= count - 1, both 0 when h < 0) and their values. n values at `depth`.
DepthOrderStats ValidDepthOrderStats(const float* depth, std::int64_t n, const std::vector<double>& quantiles);

}  // namespace ibr
