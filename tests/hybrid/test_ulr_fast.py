"""The fast paths of the hybrid renderer's per-pixel kernels: ULR's SIMD loop over
views against its scalar reference path (and its AVX2 loop against its SSE2 one), and the
selection blur against a NumPy reference
(cpp/kernels/hybrid/hybrid.cpp; docs/ulr.md "Conventions and limits")."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ibrtools import _core, look_at
from ibrtools.camera import Camera
from ibrtools.errors import BadValueError

from resample_ref import bilinear, catmull_rom

pytestmark = [pytest.mark.asan]


def _scene(n_views=7, size=(67, 45), seed=0):
    """A novel camera looking at a tilted, bumpy surface (depth per pixel) and n_views pinhole
    views around it with random colour images and depth maps of the same surface (plus a box in
    front of part of it in some views, so the occlusion test drops views)."""
    rng = np.random.default_rng(seed)
    w, h = size
    novel = Camera.from_fov(w, h, 50, look_at([0.1, -0.2, 0], [0, 0, 6]))
    gdepth = (6.0 + 0.3 * np.sin(np.arange(w)[None, :] / 5.0) + 0.02 * np.arange(h)[:, None]).astype(np.float32)
    gdepth[:3] = 0.0  # no hit: no ULR
    # World points of the G-buffer, to give each view a consistent depth map by projecting them.
    cam = novel.to_core()
    views = []
    for i in range(n_views):
        ang = 2 * np.pi * i / n_views
        eye = [1.2 * np.cos(ang), 0.8 * np.sin(ang), 0.3 * i / n_views]
        c = Camera.from_fov(w + 3 * i, h + 2 * i, 55, look_at(eye, [0, 0, 6]))
        col = rng.random((c.height, c.width, 3), dtype=np.float32)
        # The view's depth: the novel G-buffer's surface is roughly at z = 6 in the view too;
        # a relative 1 % perturbation keeps most pixels within the 2 % test, some outside.
        dep = np.full((c.height, c.width), 6.0, np.float32) * (1 + 0.03 * rng.random((c.height, c.width))).astype(np.float32)
        if i % 3 == 1:
            dep[: c.height // 2, : c.width // 2] = 2.0  # an occluder in this view
        views.append((c.to_core(), col, dep))
    normal = np.zeros((h, w, 3), np.float32)
    normal[..., 2] = -1.0  # facing the cameras
    return cam, gdepth, views, normal


@pytest.mark.parametrize("n_views", [1, 4, 7, 13])
def test_fast_ulr_matches_the_scalar_reference(n_views):
    """Float projections (fast) against double (reference): positions differ by ~1e-4 px, so a
    depth test exactly at its 2 % tolerance may flip; we allow 1 % of the pixels to differ in
    the view count and require colours within 1e-3 elsewhere (measured on the 1280x720 bench
    frames: at most 2 pixels of 716 k differ by more than 1e-3, PSNR against the reference
    >= 97.8 dB, docs/ulr.md)."""
    cam, gdepth, views, normal = _scene(n_views)
    for nrm in (None, normal):
        cf, nf = _core.ulr_blend(cam, gdepth, views, normal=nrm)
        cr, nr = _core.ulr_blend(cam, gdepth, views, normal=nrm, reference=True)
        assert nr.max() > 0, "the setup must exercise the blend"
        same = nf == nr
        assert same.mean() >= 0.99
        assert np.abs(cf - cr)[same].max() <= 1e-3
        assert (nf[:3] == 0).all() and (cf[:3] == 0).all()


def test_fast_ulr_with_a_mask_and_k():
    cam, gdepth, views, normal = _scene(9)
    mask = np.zeros(gdepth.shape, bool)
    mask[10:30, 5:50] = True
    for k in (1, 2, 4, 6):
        cf, nf = _core.ulr_blend(cam, gdepth, views, normal=normal, pixel_mask=mask, k=k)
        cr, nr = _core.ulr_blend(cam, gdepth, views, normal=normal, pixel_mask=mask, k=k, reference=True)
        assert (nf[~mask] == 0).all() and (cf[~mask] == 0).all()
        same = nf == nr
        assert same.mean() >= 0.99 and np.abs(cf - cr)[same].max() <= 1e-3


def test_equirect_input_views_take_the_scalar_path():
    """The fast path is pinhole only: any equirect view sends the whole frame to the reference
    path, so the two calls agree bit for bit."""
    cam, gdepth, views, normal = _scene(4)
    pano = Camera.equirect(64, 32, cam_from_world=look_at([0, 0, 0], [0, 0, 6])).to_core()
    views = views + [(pano, np.ones((32, 64, 3), np.float32), np.full((32, 64), 6.0, np.float32))]
    cf, nf = _core.ulr_blend(cam, gdepth, views, normal=normal)
    cr, nr = _core.ulr_blend(cam, gdepth, views, normal=normal, reference=True)
    np.testing.assert_array_equal(nf, nr)
    np.testing.assert_array_equal(cf, cr)


@pytest.mark.parametrize("n_views", [1, 4, 7, 8, 12, 13, 16, 17])
def test_avx512_avx2_and_sse2_view_loops_give_the_same_bits(n_views):
    """The per-view loop runs 16 views per AVX-512F step (when the CPU has it; simd="auto"), or 8
    per AVX2 step and the rest 4 at a time in SSE2 (simd="avx2"), or SSE2 only (simd="sse2"); the
    depth test gathers 16 (AVX-512F) or 8 (AVX2) views' depths a step, or reads them one at a time
    (sse2): the same IEEE operations lane for lane, no FMA, so the same image and counts, bit for
    bit. View counts around the 4 / 8 / 16 boundaries (the gathers' masked lanes past the last view);
    the views' depth maps differ in size and some fail the depth test. "auto" follows the engine's
    switch: with set_warp_isa("baseline") it is the SSE2 path. On a CPU without AVX-512 / AVX2 the
    calls take the narrower loop and the test holds trivially for them."""
    cam, gdepth, views, normal = _scene(n_views, seed=n_views)
    try:
        for nrm in (None, normal):
            cs, ns = _core.ulr_blend(cam, gdepth, views, normal=nrm, simd="sse2")
            assert ns.max() > 0
            for isa, simd in (("auto", "auto"), ("auto", "avx2"), ("baseline", "auto"), ("baseline", "avx2")):
                _core.set_warp_isa(isa)
                c, n = _core.ulr_blend(cam, gdepth, views, normal=nrm, simd=simd)
                np.testing.assert_array_equal(n, ns)
                np.testing.assert_array_equal(c, cs)
    finally:
        _core.set_warp_isa("auto")


@pytest.mark.parametrize("k", [1, 3, 4, 5])
def test_eight_pixel_selection_equals_the_per_pixel_one(k):
    """With AVX2 and k = 4 the fast path selects the views of eight pixels at once (one per lane,
    UlrSelect4x8Avx2); simd="sse2" selects pixel by pixel (UlrSelect). Equal penalties must keep
    the lower view index first in both: every view appears three times (the same camera and depth,
    other colours), so each pixel's penalties tie in threes and their order sets the order of the
    blend's sum (and, for k = 1, which copy is kept). A pixel mask leaves groups of eight partly
    live, and the width (67) ends rows inside a group. Bit for bit; other k take the per-pixel
    selection in both calls."""
    cam, gdepth, views, normal = _scene(4, seed=3)
    rng = np.random.default_rng(4)
    copies = [[(c, rng.random(col.shape, dtype=np.float32), dep) for c, col, dep in views] for _ in range(2)]
    views = [v for triple in zip(views, *copies) for v in triple]
    mask = rng.random(gdepth.shape) < 0.6
    for nrm in (None, normal):
        for pm in (None, mask):
            cs, ns = _core.ulr_blend(cam, gdepth, views, normal=nrm, pixel_mask=pm, k=k, simd="sse2")
            assert ns.max() > 0
            for simd in ("auto", "avx2"):
                c, n = _core.ulr_blend(cam, gdepth, views, normal=nrm, pixel_mask=pm, k=k, simd=simd)
                np.testing.assert_array_equal(n, ns)
                np.testing.assert_array_equal(c, cs)
    # The order of equal penalties shows in the image: the copies rotated within each triple
    # (another one first) give other bits.
    rotated = [views[i + j] for i in range(0, len(views), 3) for j in (2, 0, 1)]
    assert not np.array_equal(_core.ulr_blend(cam, gdepth, views, k=k)[0], _core.ulr_blend(cam, gdepth, rotated, k=k)[0])


@pytest.mark.parametrize("resample", ["bilinear", "cubic"])
def test_fast_ulr_reads_the_last_pixel_of_a_view(resample):
    """The SSE2 bilinear and cubic reads load four floats per texel (RGB and the next pixel's red);
    at a view's last pixel the fourth is past the image, so that texel is read channel by channel
    (the sanitizer jobs run this). A view of 3 x 2 pixels seeing the whole G-buffer makes most reads
    touch its last pixel: the fast path agrees with the scalar reference (1e-5: float against
    double positions of the same texels)."""
    w, h = 24, 16
    novel = Camera.from_fov(w, h, 40, look_at([0, 0, 0], [0, 0, 5]))
    gdepth = np.full((h, w), 5.0, np.float32)
    small = Camera.from_fov(3, 2, 60, look_at([0.05, 0.02, 0], [0, 0, 5]))
    col = np.arange(18, dtype=np.float32).reshape(2, 3, 3) / 17
    views = [(small.to_core(), col, np.full((2, 3), 5.0, np.float32))]
    cf, nf = _core.ulr_blend(novel.to_core(), gdepth, views, resample=resample)
    cr, nr = _core.ulr_blend(novel.to_core(), gdepth, views, resample=resample, reference=True)
    np.testing.assert_array_equal(nf, nr)
    assert nf.mean() > 0.5
    assert np.abs(cf - cr).max() <= 1e-5
    # red above the second-to-last texel's (12/17) needs weight on the last one (15/17): read
    assert (cf[..., 0] > col[1, 1, 0] + 0.01).sum() > 10


@pytest.mark.parametrize("resample, ref", [("cubic", catmull_rom), ("bilinear", bilinear)])
@pytest.mark.parametrize("reference", [False, True])
@pytest.mark.parametrize("dx, dy", [(0.25, 0.5), (0.7, 0.1), (-0.4, -0.85)])
def test_ulr_colour_reads_match_numpy(resample, ref, reference, dx, dy):
    """One view and a novel camera at its pose whose principal point is moved by (-dx, -dy): every
    novel pixel centre projects to the view at (x + 0.5 + dx, y + 0.5 + dy), so the blend of the
    one view is its image read there, against an independent NumPy Catmull-Rom (Keys' piecewise
    kernel) or bilinear read, fast and reference paths. Also: a constant image stays constant (the
    weights sum to 1) and a linear ramp is reproduced (Catmull-Rom interpolates linear data)."""
    w, h = 40, 30
    view = Camera.from_fov(w, h, 50, look_at([0, 0, 0], [0, 0, 5]))
    novel = dataclasses.replace(view, cx=view.cx - dx, cy=view.cy - dy)
    gdepth = np.full((h, w), 5.0, np.float32)
    ys, xs = np.mgrid[0:h, 0:w]
    inner = (slice(3, h - 3), slice(3, w - 3))  # every tap inside the image
    rng = np.random.default_rng(3)
    ramp = np.stack([0.01 * xs + 0.02 * ys + 0.1, 0.5 - 0.005 * xs, 0.02 * ys], -1).astype(np.float32)
    for img, exact in ((rng.random((h, w, 3), dtype=np.float32), False), (np.full((h, w, 3), 0.37, np.float32), True),
                       (ramp, True)):
        views = [(view.to_core(), img, np.full((h, w), 5.0, np.float32))]
        col, n = _core.ulr_blend(novel.to_core(), gdepth, views, resample=resample, reference=reference)
        assert (n[inner] == 1).all()
        want = ref(img.astype(np.float64), xs + 0.5 + dx, ys + 0.5 + dy)
        np.testing.assert_allclose(col[inner], want[inner], atol=2e-5)
        if exact:  # constant and linear data come back as they are, at the shifted position
            true = np.stack([0.01 * (xs + dx) + 0.02 * (ys + dy) + 0.1, 0.5 - 0.005 * (xs + dx), 0.02 * (ys + dy)], -1)
            np.testing.assert_allclose(col[inner], (true if img is ramp else img)[inner], atol=2e-5)


def test_cubic_read_does_not_ring_at_a_step():
    """Catmull-Rom rings at a step (negative lobes: under 0 on the dark side, over 1 on the bright
    one); the read is clamped to its 2 x 2 texels' range, so a step from 0 to 1 reads within [0, 1],
    and it is still sharper than bilinear there (nearer the step's sides). A 1 x 1 view (every tap
    the same pixel) reads that pixel."""
    w, h = 20, 14
    view = Camera.from_fov(w, h, 50, look_at([0, 0, 0], [0, 0, 5]))
    novel = dataclasses.replace(view, cx=view.cx - 0.3)
    img = np.zeros((h, w, 3), np.float32)
    img[:, w // 2:] = 1.0
    depth = np.full((h, w), 5.0, np.float32)
    views = [(view.to_core(), img, depth)]
    cub, n = _core.ulr_blend(novel.to_core(), depth, views)
    lin, _ = _core.ulr_blend(novel.to_core(), depth, views, resample="bilinear")
    assert np.isfinite(cub).all() and cub.min() >= 0.0 and cub.max() <= 1.0
    inner = (slice(2, h - 2), slice(2, w - 2))
    assert (np.abs(cub - 0.5)[inner] >= np.abs(lin - 0.5)[inner] - 1e-6).all()  # never blurrier
    assert (np.abs(cub - 0.5)[inner] > np.abs(lin - 0.5)[inner] + 0.01).any()  # sharper at the step
    tiny = Camera.from_fov(1, 1, 80, look_at([0, 0, 0], [0, 0, 5]))
    col, n = _core.ulr_blend(view.to_core(), depth,
                             [(tiny.to_core(), np.full((1, 1, 3), 0.6, np.float32), np.full((1, 1), 5.0, np.float32))])
    assert (n > 0).any() and np.allclose(col[n > 0], 0.6, atol=1e-6)


def test_ulr_resample_rejects_an_unknown_value():
    cam, gdepth, views, _ = _scene(2)
    with pytest.raises(BadValueError, match="resample"):
        _core.ulr_blend(cam, gdepth, views, resample="lanczos")


def test_ulr_simd_rejects_an_unknown_value():
    cam, gdepth, views, _ = _scene(2)
    with pytest.raises(BadValueError, match="simd"):
        _core.ulr_blend(cam, gdepth, views, simd="avx9")


def test_ulr_reference_flag_rejects_a_non_bool():
    cam, gdepth, views, _ = _scene(2)
    with pytest.raises(TypeError):
        _core.ulr_blend(cam, gdepth, views, reference="yes")


def _blur_reference(label, sigma, raw=False):
    """The selection blur in NumPy (horizontal then vertical, edge-clamped, normalised; raw: the
    blurred one-hot planes before the normalisation)."""
    r = int(np.ceil(3 * sigma)) if sigma > 0 else 0
    taps = np.exp(-0.5 * np.arange(-r, r + 1) ** 2 / sigma**2) if r else np.ones(1)
    onehot = np.stack([(label == c) for c in range(3)], -1).astype(np.float64)
    h, w = label.shape
    pad = np.pad(onehot, ((0, 0), (r, r), (0, 0)), mode="edge")
    hor = sum(taps[d] * pad[:, d:d + w] for d in range(2 * r + 1))
    pad = np.pad(hor, ((r, r), (0, 0), (0, 0)), mode="edge")
    ver = sum(taps[d] * pad[d:d + h] for d in range(2 * r + 1))
    if raw:
        return ver
    s = ver.sum(-1, keepdims=True)
    return np.where(s > 0, ver / np.where(s > 0, s, 1), 0.0)


@pytest.mark.parametrize("sigma", [0.0, 0.7, 2.0, 4.0, 16.0])
def test_blur_selection_matches_numpy_and_keeps_the_support(sigma):
    """The vertical-first planar blur against the horizontal-first definition: values within
    1e-6 (float rounding), and the support (weight > 0, which decides where ULR and PVM run)
    identical. Sizes just past the tile and grain boundaries; label 3 (none) contributes to none."""
    rng = np.random.default_rng(1)
    label = rng.choice(np.array([0, 1, 2, 3], np.uint8), size=(37, 53), p=[0.7, 0.05, 0.05, 0.2])
    label[:, :9] = 3
    got = _core.blur_selection(label, sigma)
    ref = _blur_reference(label, sigma)
    assert np.abs(got - ref).max() < 1e-6
    np.testing.assert_array_equal(got > 0, ref > 0)


@pytest.mark.parametrize("min_weight", [0.01, 0.05, 1 / 3])
def test_blur_selection_min_weight_matches_numpy(min_weight):
    """min_weight: the NumPy blur with weights below it set to 0 and the rest normalised again.
    Every pixel with any weight keeps one (the largest of three summing to 1 is >= 1/3), the
    support shrinks (where ULR and PVM run) and min_weight 0 is the plain blur."""
    rng = np.random.default_rng(3)
    label = rng.choice(np.array([0, 1, 2, 3], np.uint8), size=(41, 57), p=[0.6, 0.1, 0.1, 0.2])
    label[:, :12] = 3
    ref = _blur_reference(label, 4.0)
    cut = np.where(ref < min_weight, 0.0, ref)
    s = cut.sum(-1, keepdims=True)
    cut = np.where(s > 0, cut / np.where(s > 0, s, 1), 0.0)
    got = _core.blur_selection(label, 4.0, min_weight)
    assert np.abs(got - cut).max() < 1e-5
    np.testing.assert_array_equal(got.sum(-1) > 0, ref.sum(-1) > 0)  # no pixel loses every method
    assert ((got > 0) & (got < min_weight * (1 - 1e-6))).sum() == 0
    assert (got > 0).sum() < (ref > 0).sum()
    np.testing.assert_array_equal(_core.blur_selection(label, 4.0, 0.0), _core.blur_selection(label, 4.0))
    # Three near-equal weights (rows labelled y mod 3) at the largest min_weight, 1/3: finite,
    # summing to 1 (one weight is always kept; if rounding put all three below, all are kept).
    stripes = np.repeat((np.arange(300) % 3).astype(np.uint8)[:, None], 4, 1)
    got = _core.blur_selection(stripes, 7.0, 1 / 3)
    assert np.isfinite(got).all() and np.abs(got.sum(-1) - 1).max() < 1e-6


@pytest.mark.parametrize("sigma", [8.0, 12.0, 16.0, 32.0])
def test_blur_selection_decimated_is_the_same_gaussian(sigma):
    """decimate=True (the hybrid's blur): block means blurred at 1/f resolution and read back
    bilinearly, against the float64 NumPy blur. On scattered labels (cover >= 80 % everywhere)
    within 1e-2 (the image edges, where the edge clamp replicates single pixels, are the worst) and
    1e-3 on average. Around a lone square in label 3 the blurred planes agree within 1e-3 before
    the normalisation (which divides by the cover: far out in label-3 regions a 1e-4 tail becomes
    weight 1), the normalised weights within 1e-2 where the cover is >= 10 %; exactly 0 past the
    blur's reach."""
    rng = np.random.default_rng(4)
    label = rng.choice(np.array([0, 1, 2, 3], np.uint8), size=(181, 263), p=[0.6, 0.1, 0.1, 0.2])
    got = _core.blur_selection(label, sigma, decimate=True)
    ref = _blur_reference(label, sigma)
    assert np.abs(got - ref).max() < 1e-2  # 20 % label 3, scattered: the cover is >= 1 % everywhere
    assert np.abs(got - ref).mean() < 1e-3
    square = np.full((6 * int(sigma) + 40, 6 * int(sigma) + 48), 3, np.uint8)
    square[:, :20] = 0
    cy, cx = square.shape[0] // 2, square.shape[1] // 2 + 10
    square[cy - 3:cy + 3, cx - 3:cx + 3] = 1
    got = _core.blur_selection(square, sigma, decimate=True)
    ref = _blur_reference(square, sigma)
    cover = _blur_reference(square, sigma, raw=True).sum(-1)
    cover /= cover.max()
    err = np.abs(got - ref).max(-1)
    assert (err * cover).max() < 1e-3  # the blurred planes' own error, before the normalisation
    assert err[cover >= 0.1].max() < 1e-2
    assert (cover < 0.01).sum() > 0  # the test reaches the tails
    far = np.zeros((40, 12 * int(sigma) + 80), np.uint8) + 3
    far[:, :4] = 0
    got = _core.blur_selection(far, sigma, decimate=True)
    assert (got[:, 4 * int(sigma) + 12:] == 0).all()  # past the blur's reach (3 sigma + a block)
    assert np.isfinite(got).all()


@pytest.mark.skipif(not _core.cpu_has_avx2(), reason="this CPU has no AVX2: only the baseline path runs")
def test_blur_selection_avx2_and_sse2_paths_give_the_same_bits():
    """With AVX2 (set_warp_isa "avx2") the blur runs its AVX2 loops (separable passes, the decimated
    read-back's normalisation and min_weight step), with "baseline" the SSE2 / scalar ones: the same
    operations lane for lane, so the same bits, on full-resolution and decimated blurs, widths that
    leave every remainder of 8, min_weight 0 and clipping."""
    rng = np.random.default_rng(8)
    try:
        for h, w in ((1, 1), (5, 7), (33, 64), (47, 131)):
            scattered = rng.choice(np.array([0, 1, 2, 3], np.uint8), size=(h, w), p=[0.5, 0.2, 0.1, 0.2])
            blocky = np.kron(rng.integers(0, 4, (h // 6 + 1, w // 6 + 1)), np.ones((6, 6)))[:h, :w].astype(np.uint8)
            for label in (scattered, blocky):
                for sigma, decimate in ((0.0, False), (2.0, False), (5.0, False), (12.0, True), (24.0, True)):
                    for mw in (0.0, 0.05, 1 / 3):
                        out = {}
                        for isa in ("baseline", "avx2"):
                            _core.set_warp_isa(isa)
                            out[isa] = _core.blur_selection(label, sigma, mw, decimate=decimate)
                        np.testing.assert_array_equal(out["avx2"], out["baseline"],
                                                      err_msg=f"{h}x{w} sigma {sigma} min_weight {mw}")
    finally:
        _core.set_warp_isa("auto")


def test_blur_selection_decimate_below_sigma_8_is_the_full_blur():
    rng = np.random.default_rng(6)
    label = rng.choice(np.array([0, 1, 2, 3], np.uint8), size=(50, 70))
    for sigma in (0.0, 2.0, 7.9):
        np.testing.assert_array_equal(_core.blur_selection(label, sigma, 0.05, decimate=True),
                                      _core.blur_selection(label, sigma, 0.05))


def test_blur_selection_with_a_method_nobody_chose():
    """A label absent from the frame (here ULR) is skipped: its weight is exactly 0 everywhere,
    the others as the NumPy definition."""
    rng = np.random.default_rng(2)
    label = rng.choice(np.array([0, 2, 3], np.uint8), size=(29, 41), p=[0.6, 0.2, 0.2])
    got = _core.blur_selection(label, 3.0)
    assert (got[..., 1] == 0).all()
    assert np.abs(got - _blur_reference(label, 3.0)).max() < 1e-6


def test_blur_selection_rows_of_nothing_stay_empty():
    label = np.full((20, 30), 3, np.uint8)
    label[15:, 10] = 2
    got = _core.blur_selection(label, 1.0)
    assert (got[:8] == 0).all()  # more than 3 sigma away from the only label
    assert got[15:, 10, 2] == pytest.approx(1.0)
