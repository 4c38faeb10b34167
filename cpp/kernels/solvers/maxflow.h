// Max-flow / min-cut on a 4-connected pixel grid: the Boykov-Kolmogorov augmenting-path
// algorithm (Y. Boykov, V. Kolmogorov, "An Experimental Comparison of Min-Cut/Max-Flow
// Algorithms for Energy Minimization in Vision", PAMI 2004, section 3: two search trees grown
// from the terminals, augmentation, adoption of orphans), specialised to grids: a node's
// neighbours are implicit (offsets +-1, +-W), its arcs live in one compact array of 4 residual
// capacities per node, and the trees, the active queue and the orphan list are flat arrays
// allocated once per call (no per-node allocation).
//
// Graph: node (y, x) of an H x W grid, index y * W + x.
//   source_cap[n] >= 0: capacity of the arc source -> n; sink_cap[n] >= 0: n -> sink.
//   right[n] >= 0: capacity of the undirected edge (y, x) - (y, x + 1), both directions
//     (column W - 1 ignored); down[n] >= 0: edge (y, x) - (y + 1, x) (row H - 1 ignored).
// Result: the maximum flow (= the minimum cut's capacity = the minimum energy of the binary
// labelling sum_n [label n = sink] source_cap[n] + [label n = source] sink_cap[n]
// + sum_edges [labels differ] cap), and per node 1 when the node is on the sink side of the
// cut, 0 on the source side. Nodes reachable from neither terminal in the residual graph go to
// the source side (as in Kolmogorov's maxflow library and PyMaxflow's get_grid_segments).
//
// Cap = std::int64_t (exact) or double. Kernel: trusts its inputs (checked by the front in
// cpp/bindings/solvers.cpp); never throws, single-threaded (BK is sequential).
#pragma once
#include <cstdint>

namespace ibr {

template <typename Cap>
Cap GridMaxflowKernel(int height, int width, const Cap* source_cap, const Cap* sink_cap, const Cap* right,
                      const Cap* down, std::uint8_t* sink_side);

extern template std::int64_t GridMaxflowKernel<std::int64_t>(int, int, const std::int64_t*, const std::int64_t*,
                                                             const std::int64_t*, const std::int64_t*,
                                                             std::uint8_t*);
extern template double GridMaxflowKernel<double>(int, int, const double*, const double*, const double*,
                                                 const double*, std::uint8_t*);

}  // namespace ibr
