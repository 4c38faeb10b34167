"""Fit the small (5x5) filters of ibrtools' steerable pyramid, once, offline.

    .venv/bin/python tools/fit_steerable_filters.py [--out cpp/kernels/metamers/steerable_taps.h]

Reference: pyrtools' spatial steerable pyramid (Simoncelli & Freeman 1995; filters of
Karasaridis & Simoncelli 1996): ``sp1_filters`` (2 orientations, 9x9 band / lo0 / hi0
filters, 17x17 lofilt) and ``sp3_filters`` (4 orientations). Walton et al. 2021 (Sec. 3.2)
fit 2 x 5 x 5 filters by ADAM on an image loss; we fit all filters of the pyramid (L0, H0,
L1, the K band filters B_k) in the frequency domain by non-linear least squares on two
groups of residuals, sampled on an N x N grid of frequencies:

1. response: F(w) - T(w) for every filter, T the reference filter's frequency response
   (the 5x5 taps cannot reproduce a 9x9 / 17x17 response exactly: this is the fit error);
2. reconstruction (the synthesis filters are the analysis filters flipped, as in the
   reference, so analysis followed by synthesis is F^H F):
     level:  sum_k |B_k(w)|^2 + |L1(w)|^2 / 4 - 1              (pass-through of one level)
             L1*(w) L1(w + a) / 4, a in {(pi,0), (0,pi), (pi,pi)}  (aliasing of the 2x2 decimation)
     top:    |H0(w)|^2 + |L0(w)|^2 - 1
   weighted by --pr-weight (default 4: reconstruction matters more than resemblance).

L1 has a DC gain of 2 (as pyrtools' lofilt): decimation by 2 x 2 then zero-insertion and
filtering by L1 again gives L1(0)^2 / 4 = 1 at DC. All filters are correlation kernels
(out(y, x) = sum f[dy, dx] in(y + dy, x + dx), dy, dx in -2..2), the convention of
pyrtools' ``corrDn``. Band 0 is d/dx-like (responds to vertical edges), band 1 d/dy-like.

After the fit, the script measures the reconstruction error of a 4-level pyramid of a
natural image (scikit-image's astronaut, YCbCr, values in [0, 1], reflect borders) with a
numpy implementation, for our taps and for pyrtools' SteerablePyramidSpace on the same
image, and writes the taps with those figures into the header.
"""
from __future__ import annotations

import argparse
import datetime
from pathlib import Path

import numpy as np
from scipy import ndimage, optimize

ROOT = Path(__file__).resolve().parents[1]
R = 2                      # tap radius: 5x5
T = 2 * R + 1
DC_WEIGHT = 1000.0
BORDER = 16                # pixels from an edge counted as "border" in the error report


def reference_filters(k: int) -> dict[str, np.ndarray]:
    from pyrtools.pyramids.filters import steerable_filters
    f = steerable_filters({2: "sp1_filters", 4: "sp3_filters"}[k])
    n = int(round(np.sqrt(f["bfilts"].shape[0])))
    bands = [f["bfilts"][:, b].reshape(n, n).T for b in range(k)]  # as SteerablePyramidSpace
    return {"L0": np.asarray(f["lo0filt"]), "H0": np.asarray(f["hi0filt"]),
            "L1": np.asarray(f["lofilt"]), "B": bands}


def response(f: np.ndarray, wy: np.ndarray, wx: np.ndarray) -> np.ndarray:
    """Frequency response of a centred correlation kernel at frequencies (wy, wx)."""
    r = f.shape[0] // 2
    d = np.arange(-r, r + 1)
    ey = np.exp(1j * np.multiply.outer(wy, d))   # (..., n)
    ex = np.exp(1j * np.multiply.outer(wx, d))
    return np.einsum("...i,ij,...j->...", ey, f, ex)


def grid(n: int):
    w = 2 * np.pi * np.arange(n) / n - np.pi
    return np.meshgrid(w, w, indexing="ij")


def unpack(p: np.ndarray, k: int):
    f = p.reshape(3 + k, T, T)
    return f[0], f[1], f[2], list(f[3:])


def residuals(p, k, targets, wy, wx, pr_weight):
    l0, h0, l1, bands = unpack(p, k)
    resp = lambda f, dy=0.0, dx=0.0: response(f, wy + dy, wx + dx)
    out = []
    F = {"L0": resp(l0), "H0": resp(h0), "L1": resp(l1)}
    for name in ("L0", "H0", "L1"):
        out.append(F[name] - targets[name])
    FB = [resp(b) for b in bands]
    for fb, tb in zip(FB, targets["B"]):
        out.append(fb - tb)
    level = sum(np.abs(fb) ** 2 for fb in FB) + np.abs(F["L1"]) ** 2 / 4 - 1
    # The input of every level is band-limited like L0 (L0 at level 0, L1 then decimation
    # below): pass-through only has to be 1 where |L0_ref| is not small. Odd band filters
    # cannot pass (pi, pi), so an unweighted residual fights a lost cause there.
    wlev = np.abs(targets["L0"]) ** 2
    out.append(pr_weight * wlev * level)
    for a in ((np.pi, 0.0), (0.0, np.pi), (np.pi, np.pi)):
        out.append(pr_weight * np.conj(F["L1"]) * resp(l1, *a) / 4)
    out.append(pr_weight * (np.abs(F["H0"]) ** 2 + np.abs(F["L0"]) ** 2 - 1))
    # DC gains pinned (weight DC_WEIGHT): a DC error compounds over the levels of the
    # recursion ((L1(0)^2 / 4)^levels) and natural images are mostly DC.
    out.append(DC_WEIGHT * np.array([l0.sum() - 1, h0.sum(), l1.sum() - 2, *[b.sum() for b in bands]]))
    z = np.concatenate([np.ravel(o) for o in out])
    return np.concatenate([z.real, z.imag])


def basis(wy, wx):
    """(M, 25) complex: response of each unit tap at the M grid frequencies."""
    cols = []
    for i in range(T * T):
        e = np.zeros(T * T)
        e[i] = 1
        cols.append(np.ravel(response(e.reshape(T, T), wy, wx)))
    return np.stack(cols, 1)


def jacobian(p, k, targets, wy, wx, pr_weight):
    """Analytic Jacobian of :func:`residuals` (the responses are linear in the taps)."""
    A = basis(wy, wx)
    shifts = ((np.pi, 0.0), (0.0, np.pi), (np.pi, np.pi))
    As = [basis(wy + a[0], wx + a[1]) for a in shifts]
    m, nf = A.shape[0], 3 + k
    f = p.reshape(nf, T * T)
    F = [A @ fi for fi in f]                      # L0, H0, L1, B...
    blocks = []
    for i in range(nf):                           # response residuals
        row = np.zeros((m, nf * T * T), complex)
        row[:, i * T * T:(i + 1) * T * T] = A
        blocks.append(row)
    row = np.zeros((m, nf * T * T), complex)      # level pass-through
    row[:, 2 * T * T:3 * T * T] = 0.5 * (np.conj(F[2])[:, None] * A).real
    for b in range(k):
        i = 3 + b
        row[:, i * T * T:(i + 1) * T * T] = 2 * (np.conj(F[i])[:, None] * A).real
    blocks.append(pr_weight * np.abs(targets["L0"]).reshape(-1, 1) ** 2 * row)
    for Aa in As:                                 # aliasing
        Fa = Aa @ f[2]
        row = np.zeros((m, nf * T * T), complex)
        row[:, 2 * T * T:3 * T * T] = (np.conj(A) * Fa[:, None] + np.conj(F[2])[:, None] * Aa) / 4
        blocks.append(pr_weight * row)
    row = np.zeros((m, nf * T * T), complex)      # top
    for i in (0, 1):
        row[:, i * T * T:(i + 1) * T * T] = 2 * (np.conj(F[i])[:, None] * A).real
    blocks.append(pr_weight * row)
    row = np.zeros((3 + k, nf * T * T), complex)  # DC gains
    for i in range(nf):
        row[i, i * T * T:(i + 1) * T * T] = DC_WEIGHT
    blocks.append(row)
    J = np.concatenate(blocks)
    return np.concatenate([J.real, J.imag])


def initial(k, targets, wy, wx):
    """Per filter, the linear least-squares 5x5 fit of the target response."""
    basis = []
    for i in range(T * T):
        e = np.zeros(T * T)
        e[i] = 1
        basis.append(np.ravel(response(e.reshape(T, T), wy, wx)))
    A = np.stack(basis, 1)
    A = np.concatenate([A.real, A.imag])
    fits = []
    for t in [targets["L0"], targets["H0"], targets["L1"], *targets["B"]]:
        t = np.ravel(t)
        fits.append(np.linalg.lstsq(A, np.concatenate([t.real, t.imag]), rcond=None)[0])
    return np.concatenate(fits)


# --- numpy reference pyramid (used to report the error on an image) ----------------------
def corr(x, f):
    return ndimage.correlate(x, f, mode="mirror")          # mirror = reflect101 = pyrtools reflect1


def analyse(x, l0, h0, l1, bands, levels):
    hi = corr(x, h0)
    lo = corr(x, l0)
    out = []
    for _ in range(levels):
        out.append([corr(lo, b) for b in bands])
        lo = corr(lo, l1)[::2, ::2]
    return hi, out, lo


def synthesise(hi, out, lo, l0, h0, l1, bands):
    flip = lambda f: f[::-1, ::-1]
    for lev in reversed(range(len(out))):
        h, w = out[lev][0].shape
        up = np.zeros((h, w))
        up[::2, ::2] = lo
        lo = corr(up, flip(l1))
        for b, c in zip(bands, out[lev]):
            lo = lo + corr(c, flip(b))
    return corr(lo, flip(l0)) + corr(hi, flip(h0))


def error_report(x, y):
    d = np.abs(x - y)
    inner = d[BORDER:-BORDER, BORDER:-BORDER]
    mask = np.ones_like(d, bool)
    mask[BORDER:-BORDER, BORDER:-BORDER] = False
    edge = d[mask]
    return {"interior_max": inner.max(), "interior_rms": np.sqrt((inner ** 2).mean()),
            "border_max": edge.max(), "border_rms": np.sqrt((edge ** 2).mean())}


def test_image():
    from skimage import data
    rgb = data.astronaut().astype(np.float64) / 255.0
    m = np.array([[0.299, 0.587, 0.114], [-0.168736, -0.331264, 0.5], [0.5, -0.418688, -0.081312]])
    return rgb @ m.T


def image_errors(filters, ycc, levels=4):
    rep = []
    for c in range(3):
        x = ycc[..., c]
        rec = synthesise(*analyse(x, *filters, levels), *filters)
        rep.append(error_report(x, rec))
    return {key: max(r[key] for r in rep) for key in rep[0]}


def pyrtools_errors(ycc, levels=4):
    import pyrtools as pt
    rep = []
    for c in range(3):
        x = ycc[..., c]
        pyr = pt.pyramids.SteerablePyramidSpace(x, height=levels, order=1)
        rep.append(error_report(x, pyr.recon_pyr()))
    return {key: max(r[key] for r in rep) for key in rep[0]}


def symmetry_projector(ref: np.ndarray) -> np.ndarray:
    """(25, 25) projector onto the 5x5 kernels with the reference kernel's symmetries: the
    mean of the signed D4 transforms g with g(ref) = +-ref (a band filter stays odd along its
    direction and even across it, so it stays oriented; L0, H0, L1 stay D4-symmetric)."""
    ops = [lambda f: f, lambda f: f[::-1], lambda f: f[:, ::-1], lambda f: f[::-1, ::-1],
           lambda f: f.T, lambda f: f.T[::-1], lambda f: f.T[:, ::-1], lambda f: f.T[::-1, ::-1]]
    tol = 1e-6 * np.abs(ref).max()
    mats = []
    for g in ops:
        for sign in (1.0, -1.0):
            if np.abs(g(ref) - sign * ref).max() < tol:
                m = np.stack([np.ravel(sign * g(e.reshape(T, T))) for e in np.eye(T * T)], 1)
                mats.append(m)
    return np.mean(mats, 0)


def fit(k: int, n: int, pr_weight: float):
    targets_sp = reference_filters(k)
    wy, wx = grid(n)
    targets = {name: response(targets_sp[name], wy, wx) for name in ("L0", "H0", "L1")}
    targets["B"] = [response(b, wy, wx) for b in targets_sp["B"]]
    refs = [targets_sp["L0"], targets_sp["H0"], targets_sp["L1"], *targets_sp["B"]]
    crop = lambda f: f[f.shape[0] // 2 - R:f.shape[0] // 2 + R + 1, f.shape[1] // 2 - R:f.shape[1] // 2 + R + 1]
    from scipy.linalg import block_diag
    P = block_diag(*[symmetry_projector(crop(f)) for f in refs])
    p0 = P @ initial(k, targets, wy, wx)
    fun = lambda q: residuals(P @ q, k, targets, wy, wx, pr_weight)
    jac = lambda q: jacobian(P @ q, k, targets, wy, wx, pr_weight) @ P
    res = optimize.least_squares(fun, p0, jac=jac, method="trf", x_scale="jac", max_nfev=80)
    l0, h0, l1, bands = unpack(P @ res.x, k)
    # Symmetrise (the reference is D4-symmetric for L0, H0, L1; bands odd/even as the
    # reference), removing the 1e-8 asymmetries the optimiser leaves.
    sym = lambda f: (f + f[::-1] + f[:, ::-1] + f[::-1, ::-1] + f.T + f.T[::-1] + f.T[:, ::-1] + f.T[::-1, ::-1]) / 8
    l0, h0, l1 = sym(l0), sym(h0), sym(l1)
    # Response errors: relative L2 over the frequency grid.
    wy2, wx2 = grid(64)
    rel = {}
    for name, f in (("L0", l0), ("H0", h0), ("L1", l1)):
        t = response(targets_sp[name], wy2, wx2)
        rel[name] = np.linalg.norm(response(f, wy2, wx2) - t) / np.linalg.norm(t)
    for i, b in enumerate(bands):
        t = response(targets_sp["B"][i], wy2, wx2)
        rel[f"B{i}"] = np.linalg.norm(response(b, wy2, wx2) - t) / np.linalg.norm(t)
    FB = [response(b, wy2, wx2) for b in bands]
    L1 = response(l1, wy2, wx2)
    level = sum(np.abs(f) ** 2 for f in FB) + np.abs(L1) ** 2 / 4 - 1
    top = np.abs(response(h0, wy2, wx2)) ** 2 + np.abs(response(l0, wy2, wx2)) ** 2 - 1
    alias = max(np.abs(L1 * response(l1, wy2 + a[0], wx2 + a[1]) / 4).max()
                for a in ((np.pi, 0.0), (0.0, np.pi), (np.pi, np.pi)))
    wl = np.abs(response(targets_sp["L0"], wy2, wx2)) ** 2
    pr = {"level_max": np.abs(wl * level).max(), "top_max": np.abs(top).max(), "alias_max": alias}
    return (l0, h0, l1, bands), rel, pr


def fmt(f: np.ndarray) -> str:
    rows = ["    {" + ", ".join(f"{v: .9e}f" for v in row) + "}" for row in f]
    return "{\n" + ",\n".join(rows) + "}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "cpp" / "kernels" / "metamers" / "steerable_taps.h")
    ap.add_argument("--grid", type=int, default=32, help="frequency grid N x N of the fit (default 32)")
    ap.add_argument("--pr-weight", type=float, default=4.0, help="weight of the reconstruction residuals (default 4)")
    args = ap.parse_args(argv)
    ycc = test_image()
    ref = pyrtools_errors(ycc)
    blocks, notes = [], []
    for k in (2, 4):
        filters, rel, pr = fit(k, args.grid, args.pr_weight)
        img = image_errors(filters, ycc)
        l0, h0, l1, bands = filters
        line = (f"K={k}: response error (relative L2, 64x64 grid) " +
                ", ".join(f"{n} {v:.3f}" for n, v in rel.items()) +
                f"; |L0ref|^2 |level pass-through - 1| max {pr['level_max']:.3f}, |top - 1| max {pr['top_max']:.3f}, "
                f"alias max {pr['alias_max']:.3f}; astronaut YCbCr 4 levels reconstruction: interior "
                f"max {img['interior_max']:.4f} rms {img['interior_rms']:.4f}, border (<{BORDER} px) "
                f"max {img['border_max']:.4f} rms {img['border_rms']:.4f}")
        print(line)
        notes.append(line)
        blocks.append(
            f"template <> struct SteerableTaps<{k}> {{\n"
            f"  static constexpr float kL0[5][5] = {fmt(l0)};\n"
            f"  static constexpr float kH0[5][5] = {fmt(h0)};\n"
            f"  static constexpr float kL1[5][5] = {fmt(l1)};\n"
            f"  static constexpr float kBands[{k}][5][5] = {{\n" +
            ",\n".join("   " + fmt(b) for b in bands) + "};\n};\n")
    refline = (f"pyrtools SteerablePyramidSpace (order 1, reflect1, 9x9/17x17 taps) on the same image: interior "
               f"max {ref['interior_max']:.4f} rms {ref['interior_rms']:.4f}, border max {ref['border_max']:.4f} "
               f"rms {ref['border_rms']:.4f}")
    print(refline)
    comment = "\n".join("// " + s for s in
                        [f"GENERATED by tools/fit_steerable_filters.py (--grid {args.grid} --pr-weight {args.pr_weight})"
                         f" on {datetime.date.today().isoformat()}. Do not edit by hand: re-run the script.",
                         "5x5 correlation kernels of the small-filter steerable pyramid, fitted to pyrtools'",
                         "sp1_filters (K=2) and sp3_filters (K=4); see the script's docstring for the objective.",
                         "Fit error:"] + [f"  {n}" for n in notes] + [f"  reference: {refline}"])
    text = (f"{comment}\n#pragma once\n\nnamespace ibr {{\n\n"
            "// kL0, kH0, kL1: D4-symmetric; kBands[k]: the k-th oriented band filter. L1 has DC gain 2.\n"
            "template <int K> struct SteerableTaps;\n\n" + "\n".join(blocks) + "\n}  // namespace ibr\n")
    args.out.write_text(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
