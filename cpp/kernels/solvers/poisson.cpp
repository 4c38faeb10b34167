// Poisson blending by multigrid-preconditioned CG (see poisson.h).
//
// Storage: every level keeps its cells in a row-major array with a one-cell ring of zeros
// around it (stride w + 2), so neighbour reads never need bounds checks: a ring cell has
// mask 0, weight 0 and value 0. Cells outside the mask carry diag = inv_diag = 0 and weight 0
// to every neighbour, so they stay 0 through smoothing and never couple to masked cells.
#include "kernels/solvers/poisson.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "ibr/parallel.h"

namespace ibr {
namespace {

constexpr std::int64_t kCoarsestCells = 64;

// Operator and V-cycle vectors in float32: the preconditioner need not be exact (PCG's own
// vectors and sums are float64), and the V-cycle is memory-bound, so half the bytes is ~half
// the time. Weights and diagonals are small integers (exact in float32).
struct Level {
  int h = 0, w = 0, stride = 0;
  std::vector<std::uint8_t> m;
  std::vector<float> diag, inv_diag, wr, wd;  // wr: weight to (y, x + 1); wd: to (y + 1, x)
  std::vector<float> x, b;
  std::int64_t Index(int row, int col) const { return std::int64_t(row + 1) * stride + (col + 1); }
  std::int64_t Size() const { return std::int64_t(h + 2) * stride; }
  void Allocate() {
    stride = w + 2;
    // One more zero row below the ring: the fused residual-restriction evaluates the stencil at
    // ring cells of the bottom row (children past an odd-sized grid), which read one row further.
    const std::int64_t n = Size() + stride;
    m.assign(n, 0);
    diag.assign(n, 0.0f);
    inv_diag.assign(n, 0.0f);
    wr.assign(n, 0.0f);
    wd.assign(n, 0.0f);
    x.assign(n, 0.0f);
    b.assign(n, 0.0f);
  }
};

std::int64_t RowGrain(int w) { return std::max<std::int64_t>(1, kMinPixelsPerTask / std::max(1, w)); }

template <typename Fn>
void ForRows(const Level& L, Fn&& fn) {
  if (std::int64_t(L.h) * L.w < 2 * kMinPixelsPerTask) {
    for (int y = 0; y < L.h; ++y) fn(y);
    return;
  }
  ParallelFor(L.h, RowGrain(L.w), [&](std::int64_t y0, std::int64_t y1) {
    for (std::int64_t y = y0; y < y1; ++y) fn(static_cast<int>(y));
  });
}

// Deterministic sum: per row, then the rows in order.
template <typename Fn>
double SumRows(const Level& L, std::vector<double>& partial, Fn&& fn) {
  partial.assign(L.h, 0.0);
  ForRows(L, [&](int y) { partial[y] = fn(y); });
  double s = 0.0;
  for (double v : partial) s += v;
  return s;
}

template <typename T>
T ApplyAt(const Level& L, const T* v, std::int64_t p) {
  const std::int64_t s = L.stride;
  return T(L.diag[p]) * v[p] - T(L.wr[p]) * v[p + 1] - T(L.wr[p - 1]) * v[p - 1] - T(L.wd[p]) * v[p + s] -
         T(L.wd[p - s]) * v[p - s];
}

// The first half sweep from x = 0: red cells x = b / diag (their neighbours are all black,
// still 0), black cells set to 0 -- one pass instead of a fill and a sweep.
void SmoothRedFromZero(Level& L) {
  ForRows(L, [&](int y) {
    const float* __restrict b = L.b.data() + L.Index(y, 0);
    const float* __restrict inv = L.inv_diag.data() + L.Index(y, 0);
    float* __restrict x = L.x.data() + L.Index(y, 0);
    const int red = y & 1;  // (y + c) % 2 == 0
    for (int c = 0; c < L.w; ++c) x[c] = ((c & 1) == red) ? b[c] * inv[c] : 0.0f;
  });
}

// One red-black Gauss-Seidel half sweep over the cells with (y + x) % 2 == colour.
void SmoothColour(Level& L, int colour) {
  ForRows(L, [&](int y) {
    const std::int64_t s = L.stride;
    const float* __restrict b = L.b.data();
    const float* __restrict wr = L.wr.data();
    const float* __restrict wd = L.wd.data();
    const float* __restrict inv = L.inv_diag.data();
    float* __restrict x = L.x.data();
    for (int c = (y + colour) & 1; c < L.w; c += 2) {
      const std::int64_t p = L.Index(y, c);
      x[p] = (b[p] + wr[p] * x[p + 1] + wr[p - 1] * x[p - 1] + wd[p] * x[p + s] + wd[p - s] * x[p - s]) * inv[p];
    }
  });
}

struct Coarsest {
  std::vector<std::int64_t> cells;  // padded indices of the masked cells
  std::vector<double> chol;         // lower-triangular n x n
  std::vector<double> tmp;

};

Level Coarsen(const Level& f) {
  Level c;
  c.h = (f.h + 1) / 2;
  c.w = (f.w + 1) / 2;
  c.Allocate();
  for (int Y = 0; Y < c.h; ++Y) {
    for (int X = 0; X < c.w; ++X) {
      // Children (2Y + a, 2X + b); those past the fine grid read the zero ring.
      const std::int64_t p00 = f.Index(2 * Y, 2 * X), p01 = p00 + 1, p10 = p00 + f.stride, p11 = p10 + 1;
      const bool any = f.m[p00] | f.m[p01] | f.m[p10] | f.m[p11];
      const std::int64_t q = c.Index(Y, X);
      if (!any) continue;
      c.m[q] = 1;
      // Galerkin P^T A P with piecewise-constant P: diagonal = sum of the children's row sums
      // inside the aggregate = sum diag - 2 * (internal edge weights).
      const float internal = f.wr[p00] + f.wr[p10] + f.wd[p00] + f.wd[p01];
      c.diag[q] = f.diag[p00] + f.diag[p01] + f.diag[p10] + f.diag[p11] - 2.0 * internal;
      c.inv_diag[q] = c.diag[q] > 0 ? 1.0f / c.diag[q] : 0.0f;
      c.wr[q] = (2 * X + 1 < f.w) ? f.wr[p01] + f.wr[p11] : 0.0f;
      c.wd[q] = (2 * Y + 1 < f.h) ? f.wd[p10] + f.wd[p11] : 0.0f;
    }
  }
  return c;
}

void FactorCoarsest(const Level& L, Coarsest& cs) {
  cs.cells.clear();
  for (int y = 0; y < L.h; ++y)
    for (int x = 0; x < L.w; ++x)
      if (L.m[L.Index(y, x)]) cs.cells.push_back(L.Index(y, x));
  const std::size_t n = cs.cells.size();
  std::vector<double> a(n * n, 0.0);
  for (std::size_t i = 0; i < n; ++i) {
    const std::int64_t p = cs.cells[i];
    a[i * n + i] = L.diag[p];
    for (std::size_t j = 0; j < n; ++j) {
      const std::int64_t q = cs.cells[j];
      if (q == p + 1) a[i * n + j] = -L.wr[p];
      if (q == p - 1) a[i * n + j] = -L.wr[q];
      if (q == p + L.stride) a[i * n + j] = -L.wd[p];
      if (q == p - L.stride) a[i * n + j] = -L.wd[q];
    }
  }
  // Cholesky A = L L^T (SPD: P^T A P of an SPD A with P of full column rank).
  for (std::size_t j = 0; j < n; ++j) {
    double d = a[j * n + j];
    for (std::size_t k = 0; k < j; ++k) d -= a[j * n + k] * a[j * n + k];
    d = std::sqrt(std::max(d, 1e-300));
    a[j * n + j] = d;
    for (std::size_t i = j + 1; i < n; ++i) {
      double s = a[i * n + j];
      for (std::size_t k = 0; k < j; ++k) s -= a[i * n + k] * a[j * n + k];
      a[i * n + j] = s / d;
    }
  }
  cs.chol = std::move(a);
  cs.tmp.assign(n, 0.0);
}

void SolveCoarsest(Level& L, Coarsest& cs) {
  const std::size_t n = cs.cells.size();
  const double* a = cs.chol.data();
  std::vector<double>& t = cs.tmp;
  for (std::size_t i = 0; i < n; ++i) {
    double s = L.b[cs.cells[i]];
    for (std::size_t k = 0; k < i; ++k) s -= a[i * n + k] * t[k];
    t[i] = s / a[i * n + i];
  }
  for (std::size_t ii = n; ii-- > 0;) {
    double s = t[ii];
    for (std::size_t k = ii + 1; k < n; ++k) s -= a[k * n + ii] * t[k];
    t[ii] = s / a[ii * n + ii];
  }
  std::fill(L.x.begin(), L.x.end(), 0.0f);
  for (std::size_t i = 0; i < n; ++i) L.x[cs.cells[i]] = static_cast<float>(t[i]);
}

class Multigrid {
 public:
  Multigrid(std::vector<Level>&& levels, const PoissonOptions& o) : levels_(std::move(levels)), o_(o) {
    FactorCoarsest(levels_.back(), coarsest_);
  }
  Level& Fine() { return levels_[0]; }
  // levels_[0].x = V-cycle applied to levels_[0].b.
  void Apply() { VCycle(0); }

 private:
  void VCycle(std::size_t l) {
    Level& L = levels_[l];
    if (l + 1 == levels_.size()) {
      SolveCoarsest(L, coarsest_);
      return;
    }
    SmoothRedFromZero(L);
    SmoothColour(L, 1);
    for (int s = 1; s < o_.smooth_sweeps; ++s) {
      SmoothColour(L, 0);
      SmoothColour(L, 1);
    }
    // Residual and restriction fused (R = P^T sums the 2 x 2 children): no residual array.
    Level& C = levels_[l + 1];
    ForRows(C, [&](int Y) {
      const float* x = L.x.data();
      for (int X = 0; X < C.w; ++X) {
        const std::int64_t p00 = L.Index(2 * Y, 2 * X), p10 = p00 + L.stride;
        float sum = 0.0f;
        for (const std::int64_t p : {p00, p00 + 1, p10, p10 + 1}) sum += L.b[p] - ApplyAt(L, x, p);
        C.b[C.Index(Y, X)] = sum;
      }
    });
    VCycle(l + 1);
    const float scale = static_cast<float>(o_.coarse_scale);
    ForRows(L, [&](int y) {
      const float* xc = C.x.data() + C.Index(y / 2, 0);
      float* x = L.x.data() + L.Index(y, 0);
      const std::uint8_t* m = L.m.data() + L.Index(y, 0);
      for (int c = 0; c < L.w; ++c) x[c] += m[c] ? scale * xc[c / 2] : 0.0f;
    });
    for (int s = 0; s < o_.smooth_sweeps; ++s) {
      SmoothColour(L, 1);
      SmoothColour(L, 0);
    }
  }

  std::vector<Level> levels_;
  PoissonOptions o_;
  Coarsest coarsest_;
};

}  // namespace

PoissonStats PoissonBlendKernel(const ImageView<const float>& boundary, const ImageView<const float>& source,
                                const ImageView<const std::uint8_t>& mask, const PoissonOptions& options,
                                const ImageView<float>& out) {
  PoissonStats stats;
  const int H = boundary.height, W = boundary.width, C = boundary.channels;
  // Outside the mask: the boundary image.
  ParallelFor(H, RowGrain(W * C), [&](std::int64_t y0, std::int64_t y1) {
    for (std::int64_t y = y0; y < y1; ++y) {
      std::copy(boundary.Row(int(y)), boundary.Row(int(y)) + std::int64_t(W) * C, out.Row(int(y)));
    }
  });
  // Bounding box of the mask: the solver's domain.
  int by0 = H, by1 = -1, bx0 = W, bx1 = -1;
  for (int y = 0; y < H; ++y) {
    const std::uint8_t* m = mask.Row(y);
    for (int x = 0; x < W; ++x) {
      if (m[x]) {
        by0 = std::min(by0, y);
        by1 = std::max(by1, y);
        bx0 = std::min(bx0, x);
        bx1 = std::max(bx1, x);
        ++stats.unknowns;
      }
    }
  }
  if (stats.unknowns == 0) return stats;

  std::vector<Level> levels(1);
  Level& F = levels[0];
  F.h = by1 - by0 + 1;
  F.w = bx1 - bx0 + 1;
  F.Allocate();
  auto in_mask = [&](int gy, int gx) { return gy >= 0 && gy < H && gx >= 0 && gx < W && mask.Row(gy)[gx] != 0; };
  for (int y = 0; y < F.h; ++y) {
    for (int x = 0; x < F.w; ++x) {
      const int gy = by0 + y, gx = bx0 + x;
      if (!in_mask(gy, gx)) continue;
      const std::int64_t p = F.Index(y, x);
      F.m[p] = 1;
      F.diag[p] = (gx > 0) + (gx + 1 < W) + (gy > 0) + (gy + 1 < H);
      F.inv_diag[p] = 1.0f / F.diag[p];
      F.wr[p] = in_mask(gy, gx + 1) ? 1.0f : 0.0f;
      F.wd[p] = in_mask(gy + 1, gx) ? 1.0f : 0.0f;
    }
  }
  while (std::int64_t(levels.back().h) * levels.back().w > kCoarsestCells) {
    Level c = Coarsen(levels.back());
    levels.push_back(std::move(c));
  }
  Multigrid mg(std::move(levels), options);
  Level& L = mg.Fine();
  const std::int64_t n = L.Size();
  std::vector<double> rhs(n, 0.0), sol(n, 0.0), dir(n, 0.0), adir(n, 0.0), res(n, 0.0), partial;
  float* vb = L.b.data();         // the V-cycle's input: the residual in float32
  const float* z = L.x.data();    // and its output

  for (int ch = 0; ch < C; ++ch) {
    // Right-hand side (Perez et al. eq. 7 with v_pq = s_p - s_q) and the initial guess (source).
    ForRows(L, [&](int y) {
      for (int x = 0; x < L.w; ++x) {
        const std::int64_t p = L.Index(y, x);
        if (!L.m[p]) continue;
        const int gy = by0 + y, gx = bx0 + x;
        const double sp = source.At(gy, gx, ch);
        double b = 0.0;
        const int ny[4] = {gy, gy, gy - 1, gy + 1}, nx[4] = {gx - 1, gx + 1, gx, gx};
        for (int k = 0; k < 4; ++k) {
          if (ny[k] < 0 || ny[k] >= H || nx[k] < 0 || nx[k] >= W) continue;
          b += sp - double(source.At(ny[k], nx[k], ch));
          if (!mask.Row(ny[k])[nx[k]]) b += double(boundary.At(ny[k], nx[k], ch));
        }
        rhs[p] = b;
        sol[p] = sp;
      }
    });
    const double bnorm = std::sqrt(SumRows(L, partial, [&](int y) {
      double s = 0.0;
      for (int x = 0; x < L.w; ++x) s += rhs[L.Index(y, x)] * rhs[L.Index(y, x)];
      return s;
    }));
    int it = 0;
    double rel = 0.0;
    if (bnorm == 0.0) {
      std::fill(sol.begin(), sol.end(), 0.0);  // A f = 0 has the unique solution 0
    } else {
      double* r = res.data();
      // PCG restarted from the true residual when the recurrence's residual has drifted below
      // the tolerance while the true one has not (rare; float32 preconditioner round-off).
      for (int attempt = 0; attempt < 3; ++attempt) {
        double rr = SumRows(L, partial, [&](int y) {
          double s = 0.0;
          for (int x = 0; x < L.w; ++x) {
            const std::int64_t p = L.Index(y, x);
            r[p] = rhs[p] - ApplyAt(L, sol.data(), p);
            vb[p] = static_cast<float>(r[p]);
            s += r[p] * r[p];
          }
          return s;
        });
        const double target = options.tol * bnorm;
        double rz = 0.0;
        if (std::sqrt(rr) > target) {
          mg.Apply();
          rz = SumRows(L, partial, [&](int y) {
            double s = 0.0;
            for (int x = 0; x < L.w; ++x) {
              const std::int64_t p = L.Index(y, x);
              dir[p] = z[p];
              s += r[p] * double(z[p]);
            }
            return s;
          });
        }
        while (std::sqrt(rr) > target && it < options.max_iter) {
          ++it;
          const double pap = SumRows(L, partial, [&](int y) {
            double s = 0.0;
            for (int x = 0; x < L.w; ++x) {
              const std::int64_t p = L.Index(y, x);
              adir[p] = ApplyAt(L, dir.data(), p);
              s += dir[p] * adir[p];
            }
            return s;
          });
          if (!(pap > 0.0)) break;  // exact solution reached (or breakdown): stop
          const double alpha = rz / pap;
          rr = SumRows(L, partial, [&](int y) {
            double s = 0.0;
            for (int x = 0; x < L.w; ++x) {
              const std::int64_t p = L.Index(y, x);
              sol[p] += alpha * dir[p];
              r[p] -= alpha * adir[p];
              vb[p] = static_cast<float>(r[p]);
              s += r[p] * r[p];
            }
            return s;
          });
          if (std::sqrt(rr) <= target) break;
          mg.Apply();
          const double rz_new = SumRows(L, partial, [&](int y) {
            double s = 0.0;
            for (int x = 0; x < L.w; ++x) {
              const std::int64_t p = L.Index(y, x);
              s += r[p] * double(z[p]);
            }
            return s;
          });
          const double beta = rz_new / rz;
          rz = rz_new;
          ForRows(L, [&](int y) {
            for (int x = 0; x < L.w; ++x) {
              const std::int64_t p = L.Index(y, x);
              dir[p] = double(z[p]) + beta * dir[p];
            }
          });
        }
        // The true residual of the returned solution (not the recurrence's).
        const double true_rr = SumRows(L, partial, [&](int y) {
          double s = 0.0;
          for (int x = 0; x < L.w; ++x) {
            const std::int64_t p = L.Index(y, x);
            const double e = L.m[p] ? rhs[p] - ApplyAt(L, sol.data(), p) : 0.0;
            s += e * e;
          }
          return s;
        });
        rel = std::sqrt(true_rr) / bnorm;
        if (rel <= options.tol || it >= options.max_iter) break;
      }
    }
    stats.iterations = std::max(stats.iterations, it);
    stats.relative_residual = std::max(stats.relative_residual, rel);
    if (!(rel <= options.tol)) stats.converged = false;
    ForRows(L, [&](int y) {
      for (int x = 0; x < L.w; ++x) {
        const std::int64_t p = L.Index(y, x);
        if (L.m[p]) out.At(by0 + y, bx0 + x, ch) = static_cast<float>(sol[p]);
      }
    });
  }
  return stats;
}

}  // namespace ibr
