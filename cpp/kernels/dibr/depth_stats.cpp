// Order statistics of valid depth (depth_stats.h).
#include "kernels/dibr/depth_stats.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "ibr/parallel.h"

namespace ibr {
namespace {

constexpr std::int64_t kMinChunk = std::int64_t(1) << 18;  // values per task, at least
constexpr std::int64_t kMaxChunks = 16;                    // tasks (a 256 KB count table each)
constexpr int kBins = 1 << 16;

inline bool Valid(float d) { return std::isfinite(d) && d > 0.0f; }

inline std::uint32_t Bits(float d) {
  std::uint32_t b;
  std::memcpy(&b, &d, sizeof b);
  return b;
}

}  // namespace

DepthOrderStats ValidDepthOrderStats(const float* depth, std::int64_t n, const std::vector<double>& quantiles) {
  DepthOrderStats out;
  // Chunks from n alone (not the thread count): the same partition, the same result, on any machine.
  const std::int64_t chunks = std::min(kMaxChunks, (n + kMinChunk - 1) / kMinChunk);
  const std::int64_t kChunk = chunks > 0 ? (n + chunks - 1) / chunks : 1;
  // Pass 1: per chunk, the counts by the top 16 bits, the count, min and max.
  std::vector<std::uint32_t> hist(std::size_t(std::max<std::int64_t>(chunks, 0)) * kBins, 0);
  std::vector<std::int64_t> counts(std::max<std::int64_t>(chunks, 0), 0);
  std::vector<float> mins(counts.size(), std::numeric_limits<float>::infinity()), maxs(counts.size(), 0.0f);
  ParallelFor(chunks, 1, [&](std::int64_t c0, std::int64_t c1) {
    for (std::int64_t c = c0; c < c1; ++c) {
      std::uint32_t* h = hist.data() + std::size_t(c) * kBins;
      std::int64_t k = 0;
      float lo = std::numeric_limits<float>::infinity(), hi = 0.0f;
      const std::int64_t i1 = std::min(n, (c + 1) * kChunk);
      for (std::int64_t i = c * kChunk; i < i1; ++i) {
        const float d = depth[i];
        if (!Valid(d)) continue;
        ++h[Bits(d) >> 16];
        ++k;
        lo = std::min(lo, d);
        hi = std::max(hi, d);
      }
      counts[c] = k, mins[c] = lo, maxs[c] = hi;
    }
  });
  for (std::size_t c = 0; c < counts.size(); ++c) {
    out.count += counts[c];
    if (counts[c] > 0) {
      out.min = out.count == counts[c] ? mins[c] : std::min(out.min, mins[c]);
      out.max = std::max(out.max, maxs[c]);
    }
  }
  if (out.count == 0) return out;
  // The ranks numpy.quantile (linear) reads: h = (count - 1) q, floor(h) and the next one.
  const double last = double(out.count - 1);
  for (const double q : quantiles) {
    const double h = last * q;
    std::int64_t prev = static_cast<std::int64_t>(std::floor(h)), next = prev + 1;
    if (h >= last) prev = next = out.count - 1;
    if (h < 0) prev = next = 0;
    out.ranks.push_back(prev);
    out.ranks.push_back(next);
  }
  // The top bins of the ranks (the counts summed over the chunks, in order: integers) ...
  std::vector<std::uint64_t> total(kBins, 0);
  for (std::size_t c = 0; c < counts.size(); ++c) {
    const std::uint32_t* h = hist.data() + c * kBins;
    for (int b = 0; b < kBins; ++b) total[b] += h[b];
  }
  std::vector<float> values_by_rank(out.ranks.size(), 0.0f);
  std::vector<int> bin_of(out.ranks.size());
  std::vector<std::int64_t> rank_in_bin(out.ranks.size());
  for (std::size_t r = 0; r < out.ranks.size(); ++r) {
    std::int64_t below = 0;
    int b = 0;
    while (below + std::int64_t(total[b]) <= out.ranks[r]) below += std::int64_t(total[b++]);
    bin_of[r] = b, rank_in_bin[r] = out.ranks[r] - below;
  }
  // ... and pass 2, one scan for every distinct top bin: a bin spans 1/128 of a binade, so it
  // usually holds few values, gathered per chunk at the offsets pass 1's counts give, and the
  // rank's value picked by nth_element (an order statistic: any algorithm gives it); a bin of
  // more than kGather values (depth of one plane) is counted by the low 16 bits instead, per chunk.
  constexpr std::int64_t kGather = std::int64_t(1) << 19;
  std::vector<int> bins(bin_of);
  std::sort(bins.begin(), bins.end());
  bins.erase(std::unique(bins.begin(), bins.end()), bins.end());
  const std::size_t nb = bins.size();
  std::vector<std::vector<float>> members(nb);
  std::vector<std::vector<std::uint32_t>> low(nb);          // counted bins: chunks x kBins
  std::vector<std::int64_t> offset(std::size_t(chunks) * nb, 0);  // gathered bins: chunk c's first slot
  for (std::size_t j = 0; j < nb; ++j) {
    const std::int64_t size = std::int64_t(total[bins[j]]);
    if (size <= kGather) {
      members[j].resize(std::size_t(size));
      for (std::int64_t c = 1; c < chunks; ++c) {
        offset[std::size_t(c) * nb + j] = offset[std::size_t(c - 1) * nb + j] + hist[std::size_t(c - 1) * kBins + bins[j]];
      }
    } else {
      low[j].assign(std::size_t(chunks) * kBins, 0);
    }
  }
  ParallelFor(chunks, 1, [&](std::int64_t c0, std::int64_t c1) {
    for (std::int64_t c = c0; c < c1; ++c) {
      std::vector<std::int64_t> at(offset.begin() + c * std::int64_t(nb), offset.begin() + (c + 1) * std::int64_t(nb));
      const std::int64_t i1 = std::min(n, (c + 1) * kChunk);
      for (std::int64_t i = c * kChunk; i < i1; ++i) {
        const float d = depth[i];
        if (!Valid(d)) continue;
        const std::uint32_t bits = Bits(d);
        const int top = static_cast<int>(bits >> 16);
        for (std::size_t j = 0; j < nb; ++j) {
          if (bins[j] != top) continue;
          if (low[j].empty()) {
            members[j][std::size_t(at[j]++)] = d;
          } else {
            ++low[j][std::size_t(c) * kBins + (bits & 0xFFFFu)];
          }
        }
      }
    }
  });
  for (std::size_t r = 0; r < out.ranks.size(); ++r) {
    const std::size_t j = std::size_t(std::lower_bound(bins.begin(), bins.end(), bin_of[r]) - bins.begin());
    float value;
    if (low[j].empty()) {
      std::nth_element(members[j].begin(), members[j].begin() + rank_in_bin[r], members[j].end());
      value = members[j][std::size_t(rank_in_bin[r])];
    } else {
      std::int64_t below = 0;
      std::uint32_t b = 0;
      for (;; ++b) {
        std::int64_t k = 0;
        for (std::int64_t c = 0; c < chunks; ++c) k += low[j][std::size_t(c) * kBins + b];
        if (below + k > rank_in_bin[r]) break;
        below += k;
      }
      const std::uint32_t bits = (std::uint32_t(bins[j]) << 16) | b;
      std::memcpy(&value, &bits, sizeof value);
    }
    values_by_rank[r] = value;
  }
  out.values = values_by_rank;
  return out;
}

}  // namespace ibr
