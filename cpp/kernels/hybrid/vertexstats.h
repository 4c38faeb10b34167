// Per-vertex colour statistics of the views (python/ibrtools/hybrid/variance.py
// vertex_statistics; docs/harmonise.md): the two loops of its gain estimation, which alternates
// per-view gains (medians of colour ratios) and per-vertex means until the gains settle.
//
// Samples: S colour samples, those of view v at [bounds[v], bounds[v + 1]), in view order; each
// names its vertex (index, in [0, n)) and has a colour (float64). Gains: (V, 3) per view and channel.
//
// VertexColourSums: per vertex and channel, the sum of color / gain of its samples (and of the
// squares, when sum2 is given), accumulated in sample order in float64: the same bits as numpy's
// bincount(index, weights=color / gain) per channel (and weights=(color / gain) ** 2). color is
// stored channel by channel, (3, S). Parallel over vertex ranges (each thread reads every sample
// and adds those of its vertices, so each vertex's order is the sample order whatever the threads).
//
// GainMedianRatios: per view v, over its shared samples (rows [bounds[v], bounds[v + 1]) of
// index / color (S', 3), row-major here) whose vertex mean is > 1e-3 in every channel and whose
// three ratios are finite, the per-channel median of color / gain_v / mean (numpy's median: the
// middle value, or the mean of the two middle values for an even count); count[v] = those rows.
// median[v] is 1 where count[v] == 0. Parallel over views.
#pragma once
#include <cstdint>

namespace ibr {

void VertexColourSums(const std::int64_t* index, const double* color, std::int64_t num_samples,
                      const std::int64_t* bounds, int num_views, const double* gains, std::int64_t num_vertices,
                      double* sum, double* sum2);

void GainMedianRatios(const std::int64_t* index, const double* color, const std::int64_t* bounds, int num_views,
                      const double* gains, const double* mean, double* median, std::int64_t* count);

}  // namespace ibr
