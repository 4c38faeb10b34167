"""Multi-view harmonisation (Prakash et al. 2021, sec. 4.1 and 4.2).
docs/harmonise.md states the energy, the thresholds and where we deviate from the paper.

Per input view, in linear RGB (``diffuse="exposure"``, the default, replaces step 1's ratio field
and step 3 by one division per view: the view over the exposure part of its global gain, split
from view-dependent shading by :func:`ibrtools.hybrid.gainmodel.exposure_gains`, the texture
stage's model; the mask and the view-dependent texture as below. ``diffuse="local"``: the paper's
steps 1-3. docs/harmonise.md "Diffuse step" gives the measurements that chose the default):

1. **Diffuse harmonisation** (sec. 4.1). T = the mesh colour rendered into the view (Embree,
   :class:`~ibrtools.raycast.reference.ReferenceRenderer`): by default (``t_source="views"``) the
   per-vertex mean of the views' colours after each view's global gain is divided out
   (:func:`~ibrtools.hybrid.variance.vertex_statistics`), interpolated over the visible
   triangle; ``t_source="mesh"`` uses the mesh's own vertex colours / texture (ambient 1, no
   lights). Why not the mesh's own colour by default: a ULR-blended texture of differently
   exposed views has an exposure that varies over the surface with the blend weights, and the
   harmonised images would inherit it. Per pixel and channel the scale
   s = (G * (W T)) / (G * (W I)), G a Gaussian of sigma = ``sigma_frac`` (3 %) of the image's
   larger side, W = 1 for pixels that take part: covered by the mesh, not within ``edge_px`` of a
   depth discontinuity (T mixes surfaces there), not saturated (luminance in the image's top or
   bottom ``saturated_pct`` = 2 %), not view-dependent (the variance mesh interpolated into the
   view exceeds ``vd_variance_frac`` = 10 % of the colour range in a channel). Dividing both blurs
   by the same G * W is the normalised convolution (Knutsson & Westin 1993): excluded pixels do
   not bias the ratio. Where no weighted pixel is near (G * W < 1e-3), s is the view's global gain
   (median of T / I over the weighted pixels). Harmonised image Hm = s I.
2. **View-dependent mask by graph cut** (sec. 4.2). Binary labels per pixel, 1 = view-dependent
   (keep the original), 0 = diffuse. The diffuse prediction P of a pixel is the per-channel
   median of the ``neighbours`` (4) nearest views' colours at the pixel's surface point (mesh
   depth, projected, depth-tested, bilinear), every view corrected by its *global* gain only; a
   highlight is seen at a point by few views, texture detail by all. Departure
   e = max over channels of G_1 * (g I - P) / range (g the view's global gain, G_1 a Gaussian of
   ``departure_blur`` = 1 px, range the inputs' 1st-99th percentile range per channel): how much
   brighter than the other views the pixel is (highlights add light). Energy, minimised exactly by
   :func:`ibrtools.solvers.grid_maxflow` (int64 capacities in thousandths of the range):
       E(L) = sum_p [L_p = 0] max(0, e_p - tau) + [L_p = 1] max(0, tau - e_p)
              + lambda sum_{p~q} [L_p != L_q]
   tau = ``data_threshold`` (0.10), lambda = ``smoothness`` (0.05); pixels the mesh does not
   cover cannot be view-dependent; pixels with no evidence (next to depth edges, seen by no other
   view) get e = tau - 0.02; the outside of the image counts as label 0. This is digital
   photomontage's (Agarwala et al. 2004) data term "distance to a predicted colour", signed, with
   its Potts seam cost. The mask is the cut "and" the saturated-bright or high-variance regions of
   step 1, grown by ``region_grow_frac`` (1 %) of the larger side (they are rasterised from a
   per-vertex field and are coarser than a small highlight).
3. **Poisson re-injection** (sec. 4.2): inside the mask, the image whose gradients are the
   original's with Hm as the boundary condition (:func:`ibrtools.solvers.poisson_blend`, per
   4-connected region of the mask on its box, relative residual ``poisson_tol`` = 1e-6);
   negative values clamped to 0.
4. **View-dependent texture**: per vertex of the mesh, the average of the masks of the views that
   see it (bilinear at the vertex's projection, equal weights; visibility as in the variance
   mesh), in [0, 1].

**Skip**: when every view's global per-channel gain (median of T / I over the weighted pixels)
is within ``skip_threshold`` (2 %, in log) of the views' mean, the views already agree and the
images are returned unchanged with ``skipped_reason`` set (``force=True`` overrides). With
``t_source="mesh"`` and an unshaded albedo texture this test is meaningless (the ratio of an
albedo to a shaded image is not a gain).
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.ndimage import binary_dilation, gaussian_filter

from ibrtools.checks import check_float
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.mesh import Mesh
from ibrtools.scene import Scene
from ibrtools.solvers import grid_maxflow, poisson_blend
from ibrtools.hybrid.gainmodel import exposure_gains, gain_halves
from ibrtools.hybrid.variance import DEPTH_TOL, check_inputs, vertex_statistics, visible_samples

LUMA = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 weights of linear RGB
NO_EVIDENCE_BIAS = 0.02  # departure (fraction of range) below tau given to pixels with no evidence
DIFFUSE_MODES = ("exposure", "local")


@dataclass(frozen=True)
class HarmoniseParams:
    """Parameters (hashed into the stage's cache key). Defaults from the paper where it gives them."""

    sigma_frac: float = 0.03        # Gaussian sigma = 3 % of the image's larger side (paper)
    saturated_pct: float = 2.0      # top / bottom 2 % of luminance are "saturated" (paper)
    vd_variance_frac: float = 0.10  # view-dependent where variance-mesh std > 10 % of range (paper)
    data_threshold: float = 0.10    # tau: departure (fraction of range) where both labels cost the same
    smoothness: float = 0.05        # lambda: Potts cost per 4-neighbour label change, same units
    departure_blur: float = 1.0     # Gaussian sigma (pixels) on the departure before the data term
    neighbours: int = 4             # other views (nearest camera centres) in the diffuse prediction
    prediction_quantile: float = 0.5  # of the neighbours' colours: 0.5 = median
    edge_px: int = 1                # no data term within this many pixels of a depth discontinuity
    region_grow_frac: float = 0.01  # saturated / high-variance regions grown by 1 % of the larger side
    skip_threshold: float = 0.02    # skip when every view's log gain is within 2 % of the mean
    poisson_tol: float = 1e-6       # relative residual of the re-injection
    depth_tol: float = DEPTH_TOL    # vertex visibility (vd texture)
    t_source: str = "views"         # T: "views" = gain-compensated per-vertex mean of the views; "mesh"
    force: bool = False             # harmonise even when the views agree
    # "exposure": each view divided by the exposure part of its global gain (gainmodel.py), the
    # mask kept; "local": the paper's Gaussian ratio field to T and Poisson re-injection in the
    # mask. "exposure" by default: better in PSNR, SSIM and FLIP on both selection scenes
    # (docs/harmonise.md "Diffuse step: exposure or local").
    diffuse: str = "exposure"

    def __post_init__(self) -> None:
        for name in ("sigma_frac", "saturated_pct", "vd_variance_frac", "data_threshold", "smoothness",
                     "departure_blur", "prediction_quantile", "region_grow_frac", "skip_threshold", "poisson_tol", "depth_tol"):
            v = check_float(getattr(self, name), name, 0.0)
            if name in ("sigma_frac", "poisson_tol", "depth_tol") and not v > 0:
                raise BadValueError(f"{name}: expected > 0, got {v}")
        if not (isinstance(self.neighbours, (int, np.integer)) and self.neighbours >= 1):
            raise BadValueError(f"neighbours: expected an integer >= 1, got {self.neighbours!r}")
        if not (isinstance(self.edge_px, (int, np.integer)) and 0 <= self.edge_px <= 64):
            raise BadValueError(f"edge_px: expected an integer in [0, 64], got {self.edge_px!r}")
        if self.t_source not in ("views", "mesh"):
            raise BadValueError(f"t_source: expected 'views' or 'mesh', got {self.t_source!r}")
        if self.diffuse not in DIFFUSE_MODES:
            raise BadValueError(f"diffuse: expected one of {DIFFUSE_MODES}, got {self.diffuse!r}")
        if not self.saturated_pct < 50:
            raise BadValueError(f"saturated_pct: expected < 50, got {self.saturated_pct}")
        if not self.poisson_tol < 1:
            raise BadValueError(f"poisson_tol: expected < 1, got {self.poisson_tol}")


@dataclass
class HarmoniseResult:
    images: dict[str, np.ndarray]
    masks: dict[str, np.ndarray]
    vd_texture: np.ndarray
    stats: dict = field(default_factory=dict)
    skipped_reason: str | None = None


def _depth_edges(depth: np.ndarray, hit: np.ndarray, px: int) -> np.ndarray:
    """Pixels within ``px`` of a silhouette or crease in depth (relative step > 5 %), where the
    mesh colour T mixes surfaces and cannot predict the image."""
    d = np.where(hit, depth, 0.0).astype(np.float64)
    e = np.zeros(d.shape, bool)
    for a, b in ((d[:, 1:], d[:, :-1]), (d[1:], d[:-1])):
        step = np.abs(a - b) > 0.05 * np.maximum(np.minimum(a, b), 1e-9)
        step |= (a > 0) != (b > 0)
        if a.shape[1] != d.shape[1]:
            e[:, 1:] |= step
            e[:, :-1] |= step
        else:
            e[1:] |= step
            e[:-1] |= step
    return binary_dilation(e, iterations=px) if px > 0 and e.any() else e


def _render_t(renderer, cam, std: np.ndarray, faces: np.ndarray, colors: np.ndarray | None):
    """T (the vertex ``colors`` interpolated, or the mesh's own colour when None), the
    coverage, the variance mesh interpolated into the view, and the mesh's depth. The per-vertex
    fields are interpolated over the rendered triangles by ``_core.interpolate_vertex_attribute``."""
    from ibrtools import _core

    names = ("depth", "prim_id", "bary", "hit") + (("color",) if colors is None else ())
    out = renderer.render(cam, outputs=names, lights=[], ambient=1.0)
    vals = std if colors is None else np.concatenate([std, colors], axis=1)  # one pass for both
    field = _core.interpolate_vertex_attribute(out["prim_id"], np.ascontiguousarray(out["bary"], np.float32),
                                               faces, np.ascontiguousarray(vals, np.float32))
    std_pix = field[..., :3]
    t = out["color"] if colors is None else field[..., 3:]
    return t, out["hit"], std_pix, out["depth"]


def _saturated(img: np.ndarray, hit: np.ndarray, p: HarmoniseParams):
    """The image's saturated-dark and saturated-bright pixels: luminance in the bottom / top
    ``saturated_pct`` of the covered pixels."""
    lum = img.astype(np.float64) @ LUMA
    if hit.any():
        lo, hi = np.percentile(lum[hit], [p.saturated_pct, 100 - p.saturated_pct])
    else:
        lo, hi = -np.inf, np.inf
    return lum <= lo, lum >= hi


def _weights(sat: tuple, hit: np.ndarray, std_pix: np.ndarray, rng_c: np.ndarray, p: HarmoniseParams):
    sat_lo, sat_hi = sat
    thr = p.vd_variance_frac * rng_c
    high_var = (std_pix[..., 0] > thr[0]) | (std_pix[..., 1] > thr[1]) | (std_pix[..., 2] > thr[2])
    high_var &= hit
    valid = hit & ~sat_lo & ~sat_hi & ~high_var
    return valid, sat_hi & hit, high_var


def _gain_pixels(img, t, valid) -> np.ndarray:
    """The weighted pixels where T / I is defined (both > 1e-3 in every channel)."""
    ok = valid.copy()
    for c in range(3):  # per channel: numpy's reductions over a last axis of 3 are slow
        ok &= (img[..., c] > 1e-3) & (t[..., c] > 1e-3)
    return ok


def _global_gain(img, t, valid) -> np.ndarray:
    """Median of T / I per channel over the weighted pixels (1 where there are too few)."""
    ok = _gain_pixels(img, t, valid)
    if ok.sum() < 16:
        return np.ones(3)
    return np.median(t[ok].astype(np.float64) / img[ok], axis=0)


def _half_gains(img, t, valid, whole: np.ndarray) -> np.ndarray:
    """(4, 3): the median of T / I on the left, right, top and bottom halves of the image
    (gainmodel.gain_halves; ``whole`` = :func:`_global_gain` for a half with too few pixels)."""
    ok = _gain_pixels(img, t, valid)
    ys, xs = np.nonzero(ok)
    h, w = ok.shape
    return gain_halves(t[ok].astype(np.float64) / img[ok], xs + 0.5, ys + 0.5, w, h, whole)


SCALE_LEVEL_SIGMA = 4.0  # the reduced-resolution blur keeps sigma / factor >= 4 px (factor <= 8)
SCALE_MAX_FACTOR = 8


def _scale_factor(sigma: float) -> int:
    """Down-sampling factor of the normalised convolution: sigma / factor >= SCALE_LEVEL_SIGMA px."""
    return int(max(1, min(SCALE_MAX_FACTOR, math.floor(sigma / SCALE_LEVEL_SIGMA))))


def _resize(a: np.ndarray, w: int, h: int, interpolation: int) -> np.ndarray:
    import cv2

    out = cv2.resize(np.ascontiguousarray(a), (w, h), interpolation=interpolation)
    return out.reshape(h, w, *a.shape[2:])


def _scale_field(img, t, valid, sigma, fallback, factor: int | None = None) -> np.ndarray:
    """s = (G * (W T)) / (G * (W I)) per channel, fallback where G * W < 1e-3 or the
    denominator is ~0. The three blurred fields are smooth (sigma = 3 % of the image's larger
    side, ~35 px at 1 MP), so they are computed at 1/``factor`` resolution (default
    :func:`_scale_factor`): W, W T, W I are box-averaged over f x f blocks (cv2 INTER_AREA, the
    image edge-replicated to a multiple of f), blurred with a Gaussian of sigma / f (scipy,
    "nearest" like the full-resolution blur), up-sampled bilinearly (cv2 INTER_LINEAR maps pixel
    centres (x + 0.5) / f - 0.5: the blocks' centres), and the ratio is taken at full resolution.
    The box and the bilinear kernel add variance (f^2 / 12 + f^2 / 6 per axis) to sigma^2: < 3 %
    of sigma for f <= sigma / 4. Against the full-resolution scipy result (``factor=1``) the
    scale differs by < 1 % except in the few pixels where G * W crosses the fallback threshold
    (tests/hybrid/test_harmonise.py states the bound)."""
    import cv2

    f = _scale_factor(sigma) if factor is None else int(factor)
    h, w = valid.shape
    wt = valid.astype(np.float32)
    fields = [wt, t * wt[..., None], img * wt[..., None]]
    if f > 1:
        hp, wp = -(-h // f) * f, -(-w // f) * f
        if (hp, wp) != (h, w):
            fields = [cv2.copyMakeBorder(x, 0, hp - h, 0, wp - w, cv2.BORDER_REPLICATE).reshape(hp, wp, *x.shape[2:])
                      for x in fields]
        fields = [_resize(x, wp // f, hp // f, cv2.INTER_AREA) for x in fields]
    s = sigma / f
    fields = [gaussian_filter(x, (s, s) + (0,) * (x.ndim - 2), mode="nearest") for x in fields]
    if f > 1:
        fields = [_resize(x, wp, hp, cv2.INTER_LINEAR)[:h, :w] for x in fields]
    support, num, den = fields
    ok = (support > 1e-3)[..., None] & (den > 1e-6)
    return np.where(ok, num / np.where(ok, den, 1.0), fallback.astype(np.float32)).astype(np.float32)


def _nearest_others(j: int, cams, count: int) -> list[int]:
    """The ``count`` views whose centres are nearest view j's (stable order on ties)."""
    centres = np.array([c.centre for c in cams])
    order = np.argsort(np.linalg.norm(centres - cams[j].centre, axis=1), kind="stable")
    return [int(k) for k in order if k != j][:count]


def _cross_view_prediction(j: int, cams, depths, hms, hits, p: HarmoniseParams, depth_tol: float):
    """The diffuse prediction of view j's pixels from the other views: each pixel's surface point
    (the mesh's depth) projected into the ``neighbours`` nearest views that see it (depth test
    against their mesh depth), their colours ``hms`` sampled bilinearly, the per-channel
    quantile (median) taken -- the C++ kernel ``_core.cross_view_prediction``
    (cpp/kernels/hybrid/harmonise.h; multithreaded, the same arithmetic as the numpy reference in
    tests/hybrid/test_harmonise.py). A highlight is seen at a surface point by few views, so the median
    of the others is its diffuse colour; texture detail, unlike in the mesh colour T, is in every
    view alike. Returns (prediction (H, W, 3) float32, n_seen (H, W) int32)."""
    from ibrtools import _core

    others = _nearest_others(j, cams, p.neighbours)
    depth = np.where(hits[j], depths[j], 0.0).astype(np.float32)
    return _core.cross_view_prediction(
        cams[j].to_core(), depth, [cams[k].to_core() for k in others],
        [np.ascontiguousarray(depths[k], np.float32) for k in others],
        [np.ascontiguousarray(hms[k], np.float32) for k in others], float(depth_tol), float(p.prediction_quantile))


def _vd_cut(hm, t, hit, edges, rng_c, p: HarmoniseParams) -> np.ndarray:
    import cv2

    # float32 throughout (the inputs' precision); the blur is cv2's separable Gaussian with
    # replicated borders, the same kernel as scipy's (radius 4 sigma, "nearest").
    diff = (hm - t) * (1.0 / rng_c).astype(np.float32)
    if p.departure_blur > 0:
        diff = cv2.GaussianBlur(diff.astype(np.float32), (0, 0), sigmaX=p.departure_blur, sigmaY=p.departure_blur,
                                borderType=cv2.BORDER_REPLICATE).reshape(diff.shape)
    e = np.maximum(np.maximum(diff[..., 0], diff[..., 1]), diff[..., 2])
    # No evidence (next to depth discontinuities, or seen by no other view): a slight preference
    # for "diffuse", so that such pixels follow their neighbours and never form a region alone.
    e[edges] = p.data_threshold - NO_EVIDENCE_BIAS
    k = 1000.0  # capacities in thousandths of the range: int64, exact cut
    d0 = np.round(k * np.maximum(0.0, e - p.data_threshold)).astype(np.int64)
    d1 = np.round(k * np.maximum(0.0, p.data_threshold - e)).astype(np.int64)
    d1[~hit] = np.int64(10 ** 9)  # not covered by the mesh: never view-dependent
    d0[~hit] = 0
    lam = np.full(hit.shape, int(round(k * p.smoothness)), np.int64)
    # Outside the image counts as diffuse: a label change at the image border pays the Potts
    # cost too, so a region is not cheaper to mark just because the frame cuts it.
    for border in (d1[0], d1[-1], d1[:, 0], d1[:, -1]):
        border += lam[0, 0]
    # Label 1 (view-dependent) = sink side, which pays source_cap.
    _, vd = grid_maxflow(d1, d0, lam, lam.copy())
    return vd


def _poisson_by_region(boundary: np.ndarray, source: np.ndarray, mask: np.ndarray, tol: float):
    """:func:`ibrtools.solvers.poisson_blend` solved per 4-connected region of ``mask``, each
    on its bounding box plus one pixel (clamped to the image). The same linear system: regions
    are not 4-adjacent, so they share no unknown and no boundary pixel, and the box holds every
    4-neighbour of the region's pixels (image-border Neumann where the box meets the image
    border). Each region reaches ``tol`` relative to its own right-hand side, so the whole does
    too. The solver's work scales with its grid: ~1.5 % masked pixels in ~100 regions of a 1 MP
    image cost ~10x less this way. Returns (image, info merged over the regions)."""
    from scipy.ndimage import find_objects, label

    h, w = mask.shape
    lab, _ = label(mask)
    out = boundary.copy()
    merged = {"iterations": 0, "relative_residual": 0.0, "converged": True, "unknowns": 0, "regions": 0}
    for i, sl in enumerate(find_objects(lab)):
        if sl is None:
            continue
        y0, y1 = max(sl[0].start - 1, 0), min(sl[0].stop + 1, h)
        x0, x1 = max(sl[1].start - 1, 0), min(sl[1].stop + 1, w)
        m = lab[y0:y1, x0:x1] == i + 1
        o, info = poisson_blend(np.ascontiguousarray(boundary[y0:y1, x0:x1]),
                                np.ascontiguousarray(source[y0:y1, x0:x1]), m, tol=tol)
        out[y0:y1, x0:x1][m] = o[m]
        merged["iterations"] = max(merged["iterations"], int(info["iterations"]))
        merged["relative_residual"] = max(merged["relative_residual"], float(info["relative_residual"]))
        merged["converged"] = bool(merged["converged"] and info["converged"])
        merged["unknowns"] += int(info.get("unknowns", m.sum()))
        merged["regions"] += 1
    return out, merged


def colour_range(scene: Scene, gains: dict | None = None) -> np.ndarray:
    """Per-channel colour range of the inputs (times their per-view ``gains`` when given): 99th
    minus 1st percentile over all views (sub-sampled), floored at 1e-3."""
    samples = []
    for v in scene.views:
        c = v.color if gains is None else v.color * gains[v.name].astype(np.float32)
        step = max(1, int(math.sqrt(c.shape[0] * c.shape[1] / 20000)))
        samples.append(c[::step, ::step].reshape(-1, 3))
    s = np.concatenate(samples)
    lo, hi = np.percentile(s, [1, 99], axis=0)
    return np.maximum(hi - lo, 1e-3)


def harmonise(scene: Scene, mesh: Mesh, std: np.ndarray, params: HarmoniseParams | None = None, *,
              colors: np.ndarray | None = None) -> HarmoniseResult:
    """Harmonise the views of ``scene`` against ``mesh``'s colour (module docstring).

    ``std``: (N, 3) float32 per-vertex standard deviation (:func:`ibrtools.hybrid.variance.variance_mesh`).
    ``colors``: optional (N, 3) per-vertex colours for T (e.g. ``vertex_statistics(...)["mean"]``,
    saves recomputing it); else T follows ``params.t_source``.
    Returns :class:`HarmoniseResult`: images (view -> (H, W, 3) float32), masks (view -> (H, W)
    bool view-dependent mask), vd_texture ((N,) float32 in [0, 1]), stats, and skipped_reason
    (str) when the views already agree photometrically (then the images are the inputs and the
    masks empty).
    """
    from ibrtools.raycast.reference import ReferenceRenderer

    params = HarmoniseParams() if params is None else params
    if not isinstance(params, HarmoniseParams):
        raise DtypeError(f"params: expected HarmoniseParams or None, got {type(params).__name__}")
    check_inputs(scene, mesh)
    if not isinstance(std, np.ndarray):
        raise DtypeError(f"std: expected a float32 numpy array of shape (N, 3), got {type(std).__name__}")
    if std.shape != (len(mesh.vertices), 3):
        raise ShapeError(f"std: expected shape (N, 3) = ({len(mesh.vertices)}, 3) (one row per mesh vertex), "
                         f"got {std.shape}")
    std = std.astype(np.float32)
    if not np.all(np.isfinite(std)) or (std < 0).any():
        raise BadValueError("std: expected finite values >= 0")
    if colors is not None:
        if not isinstance(colors, np.ndarray):
            raise DtypeError(f"colors: expected a float32 numpy array of shape (N, 3), got {type(colors).__name__}")
        if colors.shape != (len(mesh.vertices), 3):
            raise ShapeError(f"colors: expected shape (N, 3) = ({len(mesh.vertices)}, 3), got {colors.shape}")
        colors = colors.astype(np.float32)
    t0 = time.perf_counter()
    renderer = ReferenceRenderer(mesh)
    rng_c = colour_range(scene)
    if colors is None and params.t_source == "views":
        # The mesh colour of a capture is a blend of differently exposed views (ULR weights vary
        # over the surface, so does its exposure); the gain-compensated mean is consistent.
        colors = vertex_statistics(scene, mesh, depth_tol=params.depth_tol, renderer=renderer)["mean"]

    # Pass 1: render T, weights and global gains (the skip test needs every view's gain).
    per_view = {}
    for v in scene.views:
        img = np.ascontiguousarray(v.color, np.float32)
        t, hit, std_pix, depth = _render_t(renderer, v.camera, std, mesh.faces, colors)
        sat = _saturated(img, hit, params)
        valid, sat_hi, high_var = _weights(sat, hit, std_pix, rng_c, params)
        edges = _depth_edges(depth, hit, params.edge_px)
        valid &= ~edges  # T mixes surfaces at depth edges: no evidence for the ratio there
        per_view[v.name] = [img, t, hit, valid, sat_hi, high_var, _global_gain(img, t, valid), edges, depth,
                            std_pix, sat]
    # The range of the *gain-corrected* colours (a strongly over-exposed view must not widen it:
    # every threshold is a fraction of it), then the weights again with that range.
    rng_c = colour_range(scene, {n: pv[6] for n, pv in per_view.items()})
    for pv in per_view.values():
        valid, pv[4], pv[5] = _weights(pv[10], pv[2], pv[9], rng_c, params)
        pv[3] = valid & ~pv[7]
    log_g = np.log(np.array([pv[6] for pv in per_view.values()]))
    spread = float(np.abs(log_g - log_g.mean(0)).max()) if len(log_g) else 0.0
    stats: dict = {"params": asdict(params), "colour_range": rng_c.tolist(), "gain_spread_log": spread,
                   "views": {}}
    if spread < params.skip_threshold and not params.force:
        reason = (f"views agree photometrically: largest per-view gain deviation {100 * spread:.2f} % "
                  f"< {100 * params.skip_threshold:.1f} %")
        stats["time_s"] = time.perf_counter() - t0
        return HarmoniseResult({n: pv[0] for n, pv in per_view.items()},
                               {n: np.zeros(pv[2].shape, bool) for n, pv in per_view.items()},
                               np.zeros(len(mesh.vertices), np.float32), stats, reason)

    # Pass 2: diffuse harmonisation of every view (the cut's prediction needs all of them).
    hms = {}
    exposure: dict = {}  # "exposure" mode: the gain divided out of each view
    if params.diffuse == "local":
        for name, (img, t, hit, valid, sat_hi, high_var, gain, edges, depth, _, _) in per_view.items():
            h, w = hit.shape
            hms[name] = img * _scale_field(img, t, valid, params.sigma_frac * max(h, w), gain)
    else:
        # The part of the global gains that looks like exposure (the texture stage's model, so the
        # atlas and these images share one exposure): a gain that follows the viewing direction
        # smoothly is shading, which the images keep, and what is not global (the halves of the
        # image disagree) is shrunk away. The view's gain is T / I; the model's, I / T.
        cams_by_name = {n: scene.view(n).camera for n in per_view}
        halves = {n: 1.0 / _half_gains(pv[0], pv[1], pv[3], pv[6]) for n, pv in per_view.items()}
        exposure, gain_rec = exposure_gains({n: 1.0 / pv[6] for n, pv in per_view.items()}, cams_by_name,
                                            half_gains=halves)
        stats["gain_model"] = gain_rec["model"]
        stats["gain_ratio"] = gain_rec["ratio"]
        stats["gain_shrink"] = gain_rec["shrink"]
        for name, pv in per_view.items():
            hms[name] = pv[0] / np.asarray(exposure[name], np.float32)
    # Pass 3: view-dependent mask and Poisson re-injection.
    names = list(per_view)
    cams = [scene.view(n).camera for n in names]
    depths = [per_view[n][8] for n in names]
    hits = [per_view[n][2] for n in names]
    # The cut compares each view with the others after their *global* gains only: the local
    # Gaussian-ratio field can be off by a few % where the weighted pixels are far (e.g. a
    # sphere's excluded bright top), and that must not read as view dependence.
    globally = {n: per_view[n][0] * per_view[n][6].astype(np.float32) for n in names}
    hm_list = [globally[n] for n in names]
    images, masks = {}, {}
    for j, name in enumerate(names):
        img, t, hit, valid, sat_hi, high_var, gain, edges, depth, _, _ = per_view[name]
        hm = hms[name]
        pred, n_seen = _cross_view_prediction(j, cams, depths, hm_list, hits, params, params.depth_tol)
        # A point no other view sees cannot be compared: no evidence either way there (the mesh
        # colour is no substitute: its vertices may lie outside every image at the frame's edge).
        pred = np.where((n_seen > 0)[..., None], pred, globally[name])  # (no departure to blur in)
        cut = _vd_cut(globally[name], pred, hit, edges | (n_seen == 0), rng_c, params)
        # The regions come from a per-vertex field rasterised at the mesh's resolution: grown by
        # ~1 % of the image so that a highlight smaller than a triangle is not cut off at its rim.
        regions = sat_hi | high_var
        grow = int(round(params.region_grow_frac * max(hit.shape)))
        if grow > 0 and regions.any():
            regions = binary_dilation(regions, iterations=grow)
        mask = cut & regions
        info: dict | None = None  # no re-injection in "exposure" mode: hm is the original, scaled
        if params.diffuse == "exposure":
            out = hm.astype(np.float32)
        elif mask.any() and not mask.all():
            out, info = _poisson_by_region(np.ascontiguousarray(hm, np.float32), img, mask, params.poisson_tol)
        else:
            out, info = hm.astype(np.float32), {"iterations": 0, "relative_residual": 0.0, "converged": True}
        # No negative light: the re-injected gradients can undershoot next to a dark boundary.
        np.maximum(out, 0.0, out=out)
        images[name], masks[name] = out, mask
        stats["views"][name] = {"gain": gain.tolist(), "weighted_fraction": float(valid.mean()),
                                "high_variance_fraction": float(high_var.mean()), "cut_fraction": float(cut.mean()),
                                "mask_fraction": float(mask.mean()), "poisson": info,
                                "exposure_gain": exposure[name].tolist() if exposure else None}

    # View-dependent texture: masks averaged per vertex over the views that see it.
    n = len(mesh.vertices)
    acc, cnt = np.zeros(n), np.zeros(n)
    fmasks = {k: m.astype(np.float32) for k, m in masks.items()}
    for s in visible_samples(scene, mesh, renderer, params.depth_tol, images=fmasks,
                             depths={n: per_view[n][8] for n in names}):
        acc += np.bincount(s.index, weights=s.color.astype(np.float64), minlength=n)
        cnt += np.bincount(s.index, minlength=n)
    vd_texture = (acc / np.maximum(cnt, 1)).astype(np.float32)
    stats["time_s"] = time.perf_counter() - t0
    return HarmoniseResult(images, masks, vd_texture, stats, None)


def vd_at_points(vertices: np.ndarray, vd_texture: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The view-dependent texture (per vertex of ``vertices``) at ``points`` (P, 3): the value of
    the nearest vertex (scipy cKDTree). Used for the render mesh, whose vertices are vertices of the
    dense mesh (a coarser densification of the same given mesh), so the lookup is exact there."""
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, np.float64)
    vd = np.asarray(vd_texture, np.float32)
    pts = np.asarray(points, np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise ShapeError(f"vertices: expected shape (N >= 1, 3), got {v.shape}")
    if vd.shape != (len(v),):
        raise ShapeError(f"vd_texture: expected shape ({len(v)},), got {vd.shape}")
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ShapeError(f"points: expected shape (P, 3), got {pts.shape}")
    if len(pts) == 0:
        return np.zeros(0, np.float32)
    _, idx = cKDTree(v).query(pts, k=1)
    return np.ascontiguousarray(vd[idx], np.float32)
