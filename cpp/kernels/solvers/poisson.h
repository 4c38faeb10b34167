// Poisson image editing (P. Perez, M. Gangnet, A. Blake, "Poisson Image Editing", SIGGRAPH
// 2003, eq. 7 with the guidance field v_pq = s_p - s_q of eq. 11, "seamless cloning"): inside the
// mask Omega, find f whose discrete Laplacian equals the source's, with the boundary image's
// values f*_q on the outer border of Omega:
//   for p in Omega:  |N_p| f_p - sum_{q in N_p, q in Omega} f_q
//                      = sum_{q in N_p, q not in Omega} f*_q + sum_{q in N_p} (s_p - s_q)
// N_p = the 4-neighbours of p inside the image (a mask touching the image border gets the
// natural Neumann condition there, as in Perez et al.). Outside Omega, out = boundary.
// The system is symmetric positive definite unless Omega is the whole image (no Dirichlet
// border; the front refuses that case).
//
// Solver: preconditioned conjugate gradients (float64 vectors and accumulations), the
// preconditioner one multigrid V-cycle on the masked grid (in the spirit of McAdams, Sifakis,
// Teran, "A parallel multigrid Poisson solver for fluids simulation on large grids", SCA 2010):
//   - levels by 2 x 2 aggregation of the pixel grid; the coarse operator is the Galerkin product
//     P^T A P with P = piecewise-constant prolongation (R = P^T sums the 4 children), which on a
//     masked grid is again a 5-point stencil with variable weights (edge weight = number of fine
//     edges between two aggregates) -- exact at irregular mask borders, no special cases;
//   - red-black Gauss-Seidel, forward (red, black) before and reversed (black, red) after the
//     coarse correction, so the V-cycle is a symmetric operator as CG requires; the coarse
//     correction is scaled by `coarse_scale` (piecewise-constant aggregation under-corrects
//     smooth errors by about 2x; any scale in (0, 2) keeps the preconditioner SPD);
//   - coarsest level (<= 64 cells) solved exactly by a dense Cholesky factorisation.
// Stopping: ||b - A f||_2 <= tol * ||b||_2 per channel (the relative residual reported), or
// max_iter iterations. Initial guess: the source inside Omega.
// Threads: ibr::ParallelFor over rows; every reduction is summed per row then in row order,
// so the result is identical for any thread count.
//
// Shapes: boundary, source, out (H, W, C) float32 (C >= 1); mask (H, W) one byte per pixel
// (non-zero = inside Omega). Kernel: trusts its inputs (checked by cpp/bindings/solvers.cpp).
#pragma once
#include <cstdint>

#include "ibr/image.h"

namespace ibr {

struct PoissonOptions {
  double tol = 1e-6;           // relative residual ||b - A f|| / ||b|| to reach, per channel
  int max_iter = 200;          // PCG iterations per channel at most
  int smooth_sweeps = 1;       // red-black Gauss-Seidel sweeps before and after the coarse correction
  double coarse_scale = 1.8;   // scale of the coarse-grid correction (see above), in (0, 2)
};

struct PoissonStats {
  int iterations = 0;             // the largest PCG iteration count over the channels
  double relative_residual = 0;   // the largest final relative residual over the channels
  bool converged = true;          // every channel reached tol
  std::int64_t unknowns = 0;      // pixels inside the mask
};

// Writes out (boundary copied outside the mask, the solution inside). out may not alias inputs.
PoissonStats PoissonBlendKernel(const ImageView<const float>& boundary, const ImageView<const float>& source,
                                const ImageView<const std::uint8_t>& mask, const PoissonOptions& options,
                                const ImageView<float>& out);

}  // namespace ibr
