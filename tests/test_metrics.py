"""Metrics against scikit-image (SSIM, PSNR), numpy (masked variants) and flip-evaluator."""
from __future__ import annotations

import math
import sys

import numpy as np
import pytest
from gil import runs_python_during
from hypothesis import given, settings
from hypothesis import strategies as st
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from ibrtools import _core, metrics
from ibrtools.errors import BadValueError, DtypeError, NotBuiltError, ShapeError
from ibrtools.imageio import linear_to_srgb

pytestmark = [pytest.mark.asan, pytest.mark.kernel]

# Tolerances against scikit-image's SSIM. Our kernel works in float64. Given float64 input,
# skimage does too: the means then agree to ~1e-14 (measured) -> SSIM_TOL = 1e-10, and the maps
# to the float32 rounding of our map (6e-8) -> MAP_TOL = 1e-7. Given float32 input, skimage
# filters in float32, and uxx - ux^2 cancels in low-variance windows: its map then differs from
# the exact one by up to 2.4e-5 (measured on _structured), its mean by < 1e-6 -> SK32_TOL = 1e-4,
# still 10x tighter than the 1e-3 the issue asks for.
SSIM_TOL = 1e-10
MAP_TOL = 1e-7
SK32_TOL = 1e-4


def _pair(shape, seed, noise=0.1):
    rng = np.random.default_rng(seed)
    a = rng.random(shape, dtype=np.float32)
    b = np.clip(a + noise * rng.standard_normal(shape).astype(np.float32), 0, 1).astype(np.float32)
    return a, b


def _structured(shape):
    h, w = shape[:2]
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    checker = (((x // 4) + (y // 4)) % 2).astype(np.float32)
    grad = x / max(w - 1, 1)
    img = 0.6 * checker + 0.4 * grad
    if len(shape) == 3:
        img = np.stack([img, grad, np.flip(checker, 1)], -1)[..., :shape[2]]
    blurred = 0.5 * img + 0.25 * np.roll(img, 1, 0) + 0.25 * np.roll(img, 1, 1)
    return np.ascontiguousarray(img, np.float32), np.ascontiguousarray(blurred, np.float32)


def _sk_ssim(a, b, data_range=1.0, full=False, float32=False):
    """skimage's SSIM, computed in float64 unless float32=True (its behaviour for float32 input)."""
    kw = {"channel_axis": 2} if a.ndim == 3 else {}
    t = np.float32 if float32 else np.float64
    return structural_similarity(a.astype(t), b.astype(t), data_range=data_range, full=full, **kw)


SHAPES = [(7, 7), (7, 13), (13, 7), (31, 45), (70, 33), (33, 17, 3), (101, 64, 3), (9, 8, 1), (40, 41, 2)]


@pytest.mark.parametrize("shape", SHAPES)
def test_ssim_matches_skimage_random(shape):
    a, b = _pair(shape, seed=sum(shape))
    assert abs(metrics.ssim(a, b) - _sk_ssim(a, b)) < SSIM_TOL
    assert abs(metrics.ssim(a, b) - _sk_ssim(a, b, float32=True)) < SK32_TOL


@pytest.mark.parametrize("shape", [(7, 7), (50, 37), (64, 48, 3), (23, 70, 3)])
def test_ssim_matches_skimage_structured_and_map(shape):
    a, b = _structured(shape)
    ours, smap = metrics.ssim(a, b, return_map=True)
    ref, ref_full = _sk_ssim(a, b, full=True)
    assert abs(ours - ref) < SSIM_TOL
    ref_map = ref_full.mean(axis=2) if a.ndim == 3 else ref_full
    assert smap.shape == a.shape[:2] and smap.dtype == np.float32
    # The whole map, border included (scipy "reflect" padding).
    np.testing.assert_allclose(smap, ref_map, atol=MAP_TOL, rtol=0)
    ref32, full32 = _sk_ssim(a, b, full=True, float32=True)
    assert abs(ours - ref32) < SK32_TOL
    np.testing.assert_allclose(smap, full32.mean(axis=2) if a.ndim == 3 else full32, atol=SK32_TOL, rtol=0)


def test_ssim_data_range_and_float64_input():
    a, b = _pair((40, 30, 3), 3)
    a2, b2 = (2 * a - 1).astype(np.float64), (2 * b - 1).astype(np.float64)
    ref = _sk_ssim(a2, b2, data_range=2.0)
    assert abs(metrics.ssim(a2, b2, data_range=2.0) - ref) < SSIM_TOL


def test_ssim_constant_and_identical_images():
    c1 = np.full((20, 20), 0.3, np.float32)
    c2 = np.full((20, 20), 0.7, np.float32)
    # Constant images: variances are 0, SSIM = (2 xy + C1) / (x^2 + y^2 + C1) exactly.
    assert abs(metrics.ssim(c1, c2) - _sk_ssim(c1, c2)) < SSIM_TOL
    C1 = 0.01 ** 2
    x, y = float(np.float32(0.3)), float(np.float32(0.7))
    assert abs(metrics.ssim(c1, c2) - (2 * x * y + C1) / (x * x + y * y + C1)) < 1e-12
    a, _ = _pair((16, 16, 3), 1)
    assert metrics.ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    assert metrics.ssim(c1, c1) == pytest.approx(1.0, abs=1e-12)


def test_ssim_identical_for_any_thread_count():
    # 200 rows = several row bands (SsimBandRows >= 32) with a partial last band.
    a, b = _pair((200, 150, 3), 11)
    try:
        _core.set_num_threads(1)
        one, map_one = metrics.ssim(a, b, return_map=True)
        _core.set_num_threads(2)
        two, map_two = metrics.ssim(a, b, return_map=True)
    finally:
        _core.set_num_threads(0)
    assert one == two
    assert np.array_equal(map_one, map_two)


def test_ssim_covered_is_mean_of_skimage_map():
    a, b = _pair((30, 40, 3), 5)
    mask = np.zeros((30, 40), bool)
    mask[5:20, 2:30] = True
    _, full = _sk_ssim(a, b, full=True)
    ref_map = full.mean(axis=2)
    inner = np.zeros_like(mask)
    inner[3:-3, 3:-3] = True
    expected = ref_map[mask & inner].mean()
    assert abs(metrics.ssim(a, b, mask=mask) - expected) < MAP_TOL  # mean of a float32 map
    # An all-true mask is the plain SSIM; a mask only in the 3-pixel border is empty -> None.
    assert abs(metrics.ssim(a, b, mask=np.ones((30, 40), bool)) - metrics.ssim(a, b)) < 1e-9
    border = ~inner
    assert metrics.ssim(a, b, mask=border) is None
    assert metrics.ssim(a, b, mask=np.zeros((30, 40), bool)) is None


@settings(max_examples=25, deadline=None)
@given(h=st.integers(7, 24), w=st.integers(7, 24), seed=st.integers(0, 10_000),
       scale=st.sampled_from([1e-4, 1.0, 1e3]))
def test_ssim_property_bounded_symmetric(h, w, seed, scale):
    rng = np.random.default_rng(seed)
    a = (rng.random((h, w)) * scale).astype(np.float32)
    b = (rng.random((h, w)) * scale).astype(np.float32)
    s_ab, s_ba = metrics.ssim(a, b, data_range=scale), metrics.ssim(b, a, data_range=scale)
    assert math.isfinite(s_ab) and -1.0 - 1e-9 <= s_ab <= 1.0 + 1e-9
    assert abs(s_ab - s_ba) < 1e-12


def test_ssim_bad_input():
    a, b = _pair((20, 20), 0)
    with pytest.raises(ShapeError, match=r"a and b.*\(20, 20\).*\(20, 21\)"):
        metrics.ssim(a, np.zeros((20, 21), np.float32))
    with pytest.raises(ShapeError, match="at least 7x7"):
        metrics.ssim(np.zeros((1, 30), np.float32), np.zeros((1, 30), np.float32))
    with pytest.raises(ShapeError, match="at least 7x7"):
        metrics.ssim(np.zeros((6, 30, 3), np.float32), np.zeros((6, 30, 3), np.float32))
    with pytest.raises(ShapeError):
        metrics.ssim(np.zeros(30, np.float32), np.zeros(30, np.float32))
    bad = a.copy()
    bad[3, 4] = np.nan
    with pytest.raises(BadValueError, match="NaN"):
        metrics.ssim(a, bad)
    with pytest.raises(DtypeError):
        metrics.ssim([[0.0] * 8] * 8, a)
    with pytest.raises(DtypeError):
        metrics.ssim(a > 0.5, b > 0.5)
    with pytest.raises(BadValueError, match="data_range"):
        metrics.ssim(a, b, data_range=0)
    with pytest.raises(BadValueError, match="data_range"):
        metrics.ssim(a, b, data_range=float("nan"))
    with pytest.raises(ShapeError, match="mask"):
        metrics.ssim(a, b, mask=np.ones((20, 19), bool))
    with pytest.raises(DtypeError, match="mask"):
        metrics.ssim(a, b, mask=np.ones((20, 20), np.uint8))


def test_core_ssim_front_checks():
    a, b = _pair((20, 20, 3), 0)
    with pytest.raises(DtypeError, match="a: expected float32"):
        _core.ssim(a.astype(np.float64), b)
    with pytest.raises(ShapeError, match=r"a \(20, 20, 3\) and b \(20, 20\)"):
        _core.ssim(a, b[..., 0].copy())
    with pytest.raises(ShapeError, match="C-contiguous"):
        _core.ssim(a[:, ::-1], b)
    with pytest.raises(BadValueError, match="b: contains 1 NaN"):
        bb = b.copy()
        bb[0, 0, 0] = np.inf
        _core.ssim(a, bb)
    with pytest.raises(BadValueError, match="win_size"):
        _core.ssim(a, b, 1.0, False, 4)
    with pytest.raises(BadValueError, match="data_range"):
        _core.ssim(a, b, -1.0)


def test_core_ssim_releases_the_gil():
    # While the worker thread is inside the kernel, the main thread must be able to run:
    # any main-thread timestamp strictly inside the call proves the GIL was released.
    a, b = _pair((2048, 2048), 2)  # ~25-50 ms on 2 cores: long enough for the check on a fast machine
    assert runs_python_during(lambda: _core.ssim(a, b, 1.0, True)), "no Python ran during the kernel (or it lasted < 20 ms)"


# --- PSNR / MSE ------------------------------------------------------------------------------
@pytest.mark.parametrize("shape", [(1, 5), (13, 7), (32, 24, 3)])
def test_psnr_matches_skimage(shape):
    a, b = _pair(shape, 7)
    # Given float64, skimage accumulates in float64 like us: agreement to rounding (1e-9 dB).
    a64, b64 = a.astype(np.float64), b.astype(np.float64)
    assert metrics.psnr(a, b) == pytest.approx(peak_signal_noise_ratio(a64, b64, data_range=1.0), abs=1e-9)
    assert metrics.psnr(a64 * 255, b64 * 255, data_range=255) == pytest.approx(
        peak_signal_noise_ratio(a64 * 255, b64 * 255, data_range=255), abs=1e-9)
    # Given float32 it computes the MSE in float32 (relative error ~1e-7 -> ~1e-6 dB).
    assert metrics.psnr(a, b) == pytest.approx(peak_signal_noise_ratio(a, b, data_range=1.0), abs=1e-5)


def test_psnr_covered_and_edge_cases():
    a, b = _pair((16, 20, 3), 9)
    mask = np.zeros((16, 20), bool)
    mask[2:9, 4:17] = True
    d = a[mask].astype(np.float64) - b[mask]
    assert metrics.mse(a, b, mask) == pytest.approx(np.mean(d * d), rel=1e-12)
    assert metrics.psnr(a, b, mask=mask) == pytest.approx(10 * np.log10(1 / np.mean(d * d)), rel=1e-12)
    assert metrics.psnr(a, a) == math.inf
    assert metrics.psnr(a, b, mask=np.zeros((16, 20), bool)) is None
    assert metrics.mse(a, b, mask=np.zeros((16, 20), bool)) is None


def test_psnr_bad_input():
    a, b = _pair((8, 8), 0)
    with pytest.raises(ShapeError, match="a and b"):
        metrics.psnr(a, b[:7])
    with pytest.raises(BadValueError, match="a: contains NaN"):
        metrics.psnr(np.where(a > 0.5, np.nan, a), b)
    with pytest.raises(BadValueError, match="data_range"):
        metrics.psnr(a, b, data_range=-2)
    with pytest.raises(DtypeError):
        metrics.psnr(a, "b")
    with pytest.raises(DtypeError, match="data_range"):
        metrics.psnr(a, b, data_range="one")
    with pytest.raises(ShapeError):
        metrics.mse(np.zeros((2, 2, 2, 2)), np.zeros((2, 2, 2, 2)))
    with pytest.raises(ShapeError, match="mask"):
        metrics.mse(a, b, mask=np.ones((8, 8, 1), bool))


# --- coverage / compare / flip -----------------------------------------------------------------
def test_coverage():
    holes = np.zeros((4, 5), bool)
    holes[0, :] = True
    assert metrics.coverage(hole_mask=holes) == pytest.approx(0.75)
    assert metrics.coverage(~holes) == pytest.approx(0.75)
    with pytest.raises(BadValueError):
        metrics.coverage()
    with pytest.raises(BadValueError):
        metrics.coverage(holes, hole_mask=holes)
    with pytest.raises(DtypeError):
        metrics.coverage(holes.astype(np.float32))
    with pytest.raises(ShapeError):
        metrics.coverage(np.zeros((0, 3), bool))


def test_compare_on_srgb_values():
    a, b = _pair((24, 32, 3), 4)
    holes = np.zeros((24, 32), bool)
    holes[:, :8] = True
    mask = np.ones((24, 32), bool)
    mask[20:, :] = False
    m = metrics.compare(a, b, mask=mask, hole_mask=holes)
    sa, sb = linear_to_srgb(a), linear_to_srgb(b)
    assert m["psnr"] == pytest.approx(
        peak_signal_noise_ratio(sb.astype(np.float64), sa.astype(np.float64), data_range=1.0), abs=1e-9)
    assert abs(m["ssim"] - _sk_ssim(sa, sb)) < SSIM_TOL
    assert m["coverage"] == pytest.approx(0.75)
    region = mask & ~holes
    assert m["psnr_covered"] == pytest.approx(metrics.psnr(sa, sb, mask=region), abs=1e-12)
    assert m["ssim_covered"] == pytest.approx(metrics.ssim(sa, sb, mask=region), abs=1e-12)
    assert ("flip" in m) == metrics.flip_available()
    assert all(v is None or not math.isnan(v) for v in m.values())


def test_compare_scores_only_what_is_asked():
    a, b = _pair((24, 32, 3), 4)
    holes = np.zeros((24, 32), bool)
    holes[:, :8] = True
    full = metrics.compare(a, b, hole_mask=holes)
    for spec, keys in (("psnr", {"psnr", "psnr_covered"}), ("ssim", {"ssim", "ssim_covered"}), ("none", set()),
                       ("PSNR, ssim", {"psnr", "psnr_covered", "ssim", "ssim_covered"})):
        m = metrics.compare(a, b, hole_mask=holes, scores=metrics.parse_scores(spec))
        assert set(m) == keys | {"coverage"}, spec
        assert all(m[k] == full[k] for k in m)  # the same values as the full comparison
    assert metrics.parse_scores("all") == metrics.SCORES and metrics.parse_scores(["ssim", "psnr"]) == ("psnr", "ssim")
    for bad in ("psnr,lpips", "", "psnr,", 3):
        with pytest.raises((BadValueError, DtypeError), match="metrics: expected all, none or a comma list"):
            metrics.parse_scores(bad)


def test_compare_identical_and_empty_region():
    a, _ = _pair((16, 16, 3), 1)
    m = metrics.compare(a, a.copy(), hole_mask=np.ones((16, 16), bool))
    assert m["psnr"] == math.inf and m["ssim"] == pytest.approx(1.0)
    assert m["coverage"] == 0.0
    assert m["psnr_covered"] is None and m["ssim_covered"] is None
    m = metrics.compare(a, a.copy())
    assert m["coverage"] == 1.0 and m["psnr_covered"] == math.inf


def test_compare_bad_input():
    a, b = _pair((16, 16, 3), 1)
    with pytest.raises(ShapeError, match="rendered and reference"):
        metrics.compare(a, b[:, :15])
    with pytest.raises(ShapeError, match="RGB"):
        metrics.compare(a[..., 0], b[..., 0])
    with pytest.raises(ShapeError, match="hole_mask"):
        metrics.compare(a, b, hole_mask=np.zeros((3, 3), bool))
    with pytest.raises(BadValueError, match="reference"):
        metrics.compare(a, np.full_like(b, np.nan))


def test_flip_matches_flip_evaluator():
    fe = pytest.importorskip("flip_evaluator", reason="optional extra 'flip' not installed")
    a, b = _pair((32, 40, 3), 6)
    ours, fmap = metrics.flip(a, b, return_map=True)
    _, ref, _ = fe.evaluate(linear_to_srgb(b), linear_to_srgb(a), "LDR", applyMagma=False)
    assert ours == pytest.approx(float(ref), abs=1e-7)
    assert fmap.shape == (32, 40)
    assert metrics.flip(a, a) == pytest.approx(0.0, abs=1e-7)
    with pytest.raises(ShapeError):
        metrics.flip(a[..., :2].copy(), b[..., :2].copy())


def test_flip_absent_raises_not_built(monkeypatch):
    monkeypatch.setitem(sys.modules, "flip_evaluator", None)  # makes the import fail
    a, b = _pair((16, 16, 3), 1)
    assert not metrics.flip_available()
    with pytest.raises(NotBuiltError, match="flip-evaluator"):
        metrics.flip(a, b)
    assert "flip" not in metrics.compare(a, b)
