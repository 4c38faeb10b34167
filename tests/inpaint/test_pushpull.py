"""Push-pull hole filling (cpp/kernels/inpaint/pushpull.*, ibrtools.inpaint.pushpull): exact answers, an
independent numpy reference, the depth-aware variant's edge stopping, determinism, bad input."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from ibrtools import _core
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.inpaint import inpaint, pushpull
from conftest import synth_scene_dir

pytestmark = [pytest.mark.asan, pytest.mark.kernel]


# --- independent reference: classic push-pull in numpy, vectorised per level ----------------
def _ref_pull(c: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    h, w = v.shape
    H, W = (h + 1) // 2, (w + 1) // 2
    # Pad to even size with zero-validity, zero-count children (they do not exist).
    cp = np.zeros((2 * H, 2 * W, c.shape[2]), np.float64)
    vp = np.zeros((2 * H, 2 * W), np.float64)
    ex = np.zeros((2 * H, 2 * W), np.float64)
    cp[:h, :w] = c
    vp[:h, :w] = v
    ex[:h, :w] = 1
    blocks = lambda a: a.reshape(H, 2, W, 2, *a.shape[2:]).sum(axis=(1, 3))  # noqa: E731
    wsum = blocks(vp)
    csum = blocks(cp * vp[..., None])
    n = blocks(ex)
    cout = np.where(wsum[..., None] > 0, csum / np.maximum(wsum, 1e-30)[..., None], 0.0)
    return cout, wsum / n


def _ref_up(c: np.ndarray, h: int, w: int) -> np.ndarray:
    def taps(n_fine, n_coarse):
        i = np.arange(n_fine)
        k = i // 2
        nb = np.clip(np.where(i % 2 == 0, k - 1, k + 1), 0, n_coarse - 1)
        return k, nb
    y0, y1 = taps(h, c.shape[0])
    x0, x1 = taps(w, c.shape[1])
    rows = 0.75 * c[y0] + 0.25 * c[y1]
    return 0.75 * rows[:, x0] + 0.25 * rows[:, x1]


def reference_pushpull(image: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """Classic push-pull (pull: validity-weighted 2x2 mean with partial validity; push: pixels
    with no valid data take the bilinear up-sampled coarser level), in float64."""
    img = image.reshape(*image.shape[:2], -1).astype(np.float64)
    levels = [(img, (~hole).astype(np.float64))]
    while levels[-1][1].shape != (1, 1) and not np.all(levels[-1][1] > 0):
        levels.append(_ref_pull(*levels[-1]))
    filled = levels[-1][0]
    for c, v in reversed(levels[:-1]):
        up = _ref_up(filled, *v.shape)
        filled = np.where(v[..., None] > 0, c, up)
    return filled.reshape(image.shape)


def _scene(h=64, w=64):
    """A foreground disc (value 1, depth 2) over a checkerboard background (0.2/0.4, mean 0.3,
    depth 10), with a hole to the right of the disc, touching it, that carries background depth
    (what the warper writes into disocclusions)."""
    yy, xx = np.mgrid[:h, :w]
    img = np.where(((yy // 2 + xx // 2) % 2) == 0, 0.2, 0.4).astype(np.float32)
    depth = np.full((h, w), 10.0, np.float32)
    disc = (yy - 32) ** 2 + (xx - 24) ** 2 < 12 ** 2
    img[disc] = 1.0
    depth[disc] = 2.0
    hole = np.zeros((h, w), bool)
    hole[20:44, 36:48] = True
    hole &= ~disc
    return img, depth, hole


# --- exact answers --------------------------------------------------------------------------
@pytest.mark.parametrize("channels", [None, 1, 3, 5])
def test_no_hole_is_identity(channels):
    rng = np.random.default_rng(1)
    shape = (17, 23) if channels is None else (17, 23, channels)
    img = rng.random(shape, dtype=np.float32)
    hole = np.zeros((17, 23), bool)
    for d in (None, rng.random((17, 23), dtype=np.float32) + 1):
        out = pushpull(img, hole, d)
        assert out.dtype == np.float32 and out.shape == img.shape
        assert np.array_equal(out, img)
        assert not np.shares_memory(out, img)


@pytest.mark.parametrize("depth_aware", [False, True])
def test_constant_stays_constant_and_outside_is_exact(depth_aware):
    rng = np.random.default_rng(2)
    img = np.full((33, 41, 3), 0.37, np.float32)
    img[..., 1] = 0.81
    hole = rng.random((33, 41)) < 0.4
    hole[5:25, 7:30] = True
    img[hole] = np.nan  # never read
    depth = (1 + rng.random((33, 41))).astype(np.float32) if depth_aware else None
    out = pushpull(img, hole, depth)
    assert np.all(np.isfinite(out))
    # Convex combinations of one value: exact up to float32 rounding of weights summing to 1.
    np.testing.assert_allclose(out[hole], np.broadcast_to([0.37, 0.81, 0.37], out[hole].shape), atol=1e-6)
    assert np.array_equal(out[~hole], img[~hole])


@pytest.mark.parametrize("shape", [(1, 1), (1, 2), (2, 1), (1, 37), (37, 1), (3, 3), (5, 2), (31, 17), (64, 65)])
def test_matches_numpy_reference(shape):
    rng = np.random.default_rng(hash(shape) % 2**32)
    img = rng.random((*shape, 3), dtype=np.float32)
    hole = rng.random(shape) < 0.5
    hole.flat[rng.integers(hole.size)] = False  # at least one valid pixel
    out = pushpull(img, hole)
    ref = reference_pushpull(img, hole)
    # float32 kernel vs float64 reference: a few roundings per level on values in [0, 1].
    np.testing.assert_allclose(out, ref, atol=1e-5, rtol=0)
    assert np.array_equal(out[~hole], img[~hole])


def test_large_hole_matches_reference():
    rng = np.random.default_rng(3)
    img = rng.random((70, 90, 2), dtype=np.float32)
    hole = np.zeros((70, 90), bool)
    hole[10:60, 20:85] = True
    np.testing.assert_allclose(pushpull(img, hole), reference_pushpull(img, hole), atol=1e-5, rtol=0)


def test_single_valid_pixel_fills_everything():
    img = np.zeros((9, 14, 3), np.float32)
    img[4, 7] = [0.1, 0.5, 0.9]
    hole = np.ones((9, 14), bool)
    hole[4, 7] = False
    out = pushpull(img, hole)
    np.testing.assert_allclose(out.reshape(-1, 3), np.tile([0.1, 0.5, 0.9], (9 * 14, 1)), atol=1e-6)


# --- depth-aware: no foreground bleed -------------------------------------------------------
def test_depth_aware_takes_background_classic_bleeds():
    img, depth, hole = _scene()
    classic = pushpull(img, hole)
    aware = pushpull(img, hole, depth)
    bg_mean = 0.3
    # Classic mixes the disc (1.0) in: the hole's mean is pulled far above the background's.
    assert classic[hole].mean() > bg_mean + 0.1
    # Depth-aware keeps to the background: the pull drops the disc wherever a block also holds
    # background depth. What is left is Alg. 1's bilinear push reading a coarse all-disc pixel
    # for hole pixels next to the disc edge (1/16 to 9/16 weight on the first pixel column), so
    # the mean sits within 0.02 of the background's (measured 0.3135) against classic's 0.47.
    assert abs(aware[hole].mean() - bg_mean) < 0.02
    far = hole.copy()
    far[:, :40] = False  # 4+ pixels from the disc edge
    assert abs(aware[far].mean() - bg_mean) < 0.01
    assert np.array_equal(aware[~hole], img[~hole])


def test_depth_aware_gamma_and_threshold():
    img, depth, hole = _scene()
    # A threshold above the whole depth range turns the depth test off: the fill then differs
    # from the depth-aware one and bleeds like classic.
    off = pushpull(img, hole, depth, depth_threshold=1.5)
    assert off[hole].mean() > 0.3 + 0.1
    # gamma = 0 with the depth test off is exactly classic (a = 1 for any valid data).
    np.testing.assert_array_equal(pushpull(img, hole, depth, depth_threshold=1.5, gamma=0.0), pushpull(img, hole))
    # Larger gamma = blurrier (more weight on coarser levels): the fill gets smoother.
    g1 = pushpull(img, hole, depth, gamma=1.0)
    g0 = pushpull(img, hole, depth, gamma=0.0)
    assert np.all(np.isfinite(g1)) and np.all(np.isfinite(g0))
    assert np.abs(np.diff(g1, axis=1))[hole[:, 1:]].mean() <= np.abs(np.diff(g0, axis=1))[hole[:, 1:]].mean()


def test_unknown_depth_is_ignored():
    img, depth, hole = _scene()
    depth[hole] = np.nan  # a warper that does not write background depth into holes
    depth[0, :5] = 0.0
    out = pushpull(img, hole, depth)
    assert np.all(np.isfinite(out))
    assert np.array_equal(out[~hole], img[~hole])


def _far_ground_scene(h=32, w=40):
    """Far ground hidden behind an object: every valid pixel is foreground (textured, depth
    2-2.1) and the hole carries a background depth (10) beyond every one of them, so Alg. 1's
    depth test drops every valid sample at some scale and its 1x1 top has no data (this raised
    "no background data" before the classic fallback, pushpull.h)."""
    rng = np.random.default_rng(7)
    img = rng.random((h, w, 3), dtype=np.float32)
    depth = (2 + 0.1 * rng.random((h, w))).astype(np.float32)
    hole = np.zeros((h, w), bool)
    hole[4:h - 4, 5:w - 7] = True
    depth[hole] = 10.0
    img[hole] = np.nan  # never read
    return img, depth, hole


def test_background_beyond_every_valid_pixel_falls_back_to_classic():
    # The smallest case: the one valid pixel is far in front of the background-depth hole.
    img = np.ones((1, 2), np.float32)
    hole = np.array([[False, True]])
    depth = np.array([[1.0, 10.0]], np.float32)
    np.testing.assert_array_equal(pushpull(img, hole, depth), pushpull(img, hole))

    img, depth, hole = _far_ground_scene()
    classic = pushpull(img, hole)
    for gamma in (0.0, 0.5, 1.0):
        out = pushpull(img, hole, depth, gamma=gamma)
        assert np.all(np.isfinite(out))
        assert np.array_equal(out[~hole], img[~hole])
        # Inside the hole, 4+ px from its border, no depth-aware data reaches the pixel (s = 0):
        # the fill is the classic one bit for bit (F0 = 0 and 1 - s = 1 exactly, pushpull.h).
        inner = np.zeros_like(hole)
        inner[8:-8, 9:-11] = True
        assert np.array_equal(out[inner], classic[inner])
        # Next to the border, Alg. 1's data and the classic fill mix: both are convex
        # combinations of valid pixels, so the result stays within their range (1e-6: float32
        # rounding of weights summing to 1).
        lo, hi = img[~hole].min(axis=0), img[~hole].max(axis=0)
        assert np.all(out[hole] >= lo - 1e-6) and np.all(out[hole] <= hi + 1e-6)
    # An all-hole image still has nothing to fill from, depth or not.
    with pytest.raises(BadValueError, match="every pixel is a hole"):
        pushpull(img, np.ones_like(hole), depth)


def test_classic_fallback_is_thread_count_deterministic():
    img, depth, hole = _far_ground_scene(160, 300)  # several row tasks per level at 2-3 threads
    before = _core.get_num_threads()
    try:
        results = []
        for n in (1, 2, 3):
            _core.set_num_threads(n)
            results.append(pushpull(img, hole, depth))
    finally:
        _core.set_num_threads(0 if before >= 2 else before)
    assert all(np.array_equal(r, results[0]) for r in results[1:])


# --- threads --------------------------------------------------------------------------------
def test_thread_count_determinism():
    rng = np.random.default_rng(4)
    img = rng.random((301, 517, 3), dtype=np.float32)
    hole = rng.random((301, 517)) < 0.3
    hole[50:200, 100:300] = True
    depth = (1 + rng.random((301, 517))).astype(np.float32)
    before = _core.get_num_threads()
    try:
        results = []
        for n in (1, 2, 3):
            _core.set_num_threads(n)
            results.append((pushpull(img, hole), pushpull(img, hole, depth)))
    finally:
        _core.set_num_threads(0 if before >= 2 else before)
    for a, b in results[1:]:
        assert np.array_equal(a, results[0][0])
        assert np.array_equal(b, results[0][1])


def test_runs_from_two_python_threads():
    # The GIL is released: two threads get the same answer as one call (and may overlap).
    rng = np.random.default_rng(5)
    img = rng.random((256, 256, 3), dtype=np.float32)
    hole = rng.random((256, 256)) < 0.2
    expect = pushpull(img, hole)
    out = [None, None]

    def work(i):
        out[i] = pushpull(img, hole)

    ts = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert all(np.array_equal(o, expect) for o in out)


@pytest.mark.parametrize("channels", [12, 18, 24, 30])
def test_specialised_channel_counts_match_one_channel_runs(channels):
    # Many channels (the metameric moments' counts) take the generic channel loop; the channels
    # are independent, so each must equal the 1-channel run of that channel (1e-6: float32
    # rounding only, the operations per channel are the same).
    img, depth, hole = _scene(40, 52)
    rng = np.random.default_rng(channels)
    x = rng.random((40, 52, channels), dtype=np.float32)
    for d in (None, depth):
        out = pushpull(x, hole, d)
        for k in (0, channels // 2, channels - 1):
            np.testing.assert_allclose(out[..., k], pushpull(np.ascontiguousarray(x[..., k]), hole, d), atol=1e-6)


@pytest.mark.parametrize("depth_aware", [False, True])
def test_out_and_holes_only(depth_aware):
    img, depth, hole = _far_ground_scene() if depth_aware else _scene()
    d = depth if depth_aware else None
    args = (0.04, 0.5) if depth_aware else (0.0, 0.0)  # the far-ground scene takes the classic fallback too
    full = pushpull(img, hole, d, gamma=args[1]) if depth_aware else pushpull(img, hole)
    out = np.full_like(img, -7.0)
    got, no_hole = _core.pushpull(img, hole, d, *args, out=out, holes_only=True)
    assert got is out and not no_hole
    assert np.array_equal(out[hole], full[hole])           # the fill, bit for bit
    assert np.all(out[~hole] == -7.0)                      # the rest untouched
    out2 = np.empty_like(img)
    _core.pushpull(img, hole, d, *args, out=out2)          # holes_only off: the whole image
    assert np.array_equal(out2, full)
    # No hole: nothing to write with holes_only.
    out3 = np.full_like(img, -7.0)
    clean = np.nan_to_num(img)  # the far-ground image has NaN in its (now absent) holes
    assert _core.pushpull(clean, np.zeros_like(hole), d, *args, out=out3, holes_only=True)[1]
    assert np.all(out3 == -7.0)
    # In place (out is image itself, holes_only): the holes get the same fill, the rest is kept;
    # the far-ground scene also runs the classic fallback in place.
    inplace = img.copy()
    got, _ = _core.pushpull(inplace, hole, d, *args, out=inplace, holes_only=True)
    assert got is inplace
    assert np.array_equal(inplace[hole], full[hole]) and np.array_equal(inplace[~hole], img[~hole])


@pytest.mark.parametrize("depth_aware", [False, True])
def test_write_mask_fills_only_its_pixels(depth_aware):
    # write: a part of the holes is filled (complete.py: the surface holes), the other hole pixels
    # keep out's values; the fill is the full push-pull's, bit for bit, also in place and on the
    # classic-fallback path of the far-ground scene.
    img, depth, hole = _far_ground_scene() if depth_aware else _scene()
    d = depth if depth_aware else None
    gamma = 0.5 if depth_aware else 0.0
    full = pushpull(img, hole, d, gamma=gamma)
    write = hole & (np.arange(hole.shape[1])[None, :] % 3 != 0)  # two thirds of the hole pixels
    base = np.where(hole[..., None] if img.ndim == 3 else hole, np.float32(-7.0), img)
    expected = np.where(write[..., None] if img.ndim == 3 else write, full, base)
    got = pushpull(img, hole, d, gamma=gamma, write=write, out=base.copy())
    assert np.array_equal(got, expected)
    inplace = base.copy()
    assert pushpull(inplace, hole, d, gamma=gamma, write=write, out=inplace) is inplace
    assert np.array_equal(inplace, expected)
    copy = pushpull(base, hole, d, gamma=gamma, write=write)  # out: a copy of image
    assert np.array_equal(copy, expected) and copy is not base
    assert np.array_equal(pushpull(img, hole, d, gamma=gamma, write=np.zeros_like(hole)), img, equal_nan=True)
    with pytest.raises(BadValueError, match="write: only with holes_only"):
        _core.pushpull(img, hole, d, 0.04, gamma, write=write)
    with pytest.raises(ShapeError, match="write"):
        pushpull(img, hole, d, write=write[:, 1:])
    with pytest.raises(DtypeError, match="write"):
        pushpull(img, hole, d, write=[[True]])
    with pytest.raises(BadValueError, match="shares memory with write"):
        buf = base.copy()
        alias = buf.reshape(-1).view(np.uint8)[:hole.size].reshape(hole.shape)  # write's bytes inside out
        _core.pushpull(img, hole, d, 0.04, gamma, out=buf, holes_only=True, write=alias)


def test_out_bad_input():
    img, depth, hole = _scene()
    with pytest.raises(ShapeError, match="out"):
        _core.pushpull(img, hole, None, 0.0, 0.0, out=np.empty((64, 63), np.float32))
    with pytest.raises(DtypeError, match="out"):
        _core.pushpull(img, hole, None, 0.0, 0.0, out=np.empty((64, 64), np.float64))
    ro = np.empty_like(img)
    ro.flags.writeable = False
    with pytest.raises(BadValueError, match="out.*read-only"):
        _core.pushpull(img, hole, None, 0.0, 0.0, out=ro)
    with pytest.raises(BadValueError, match="out: shares memory"):
        _core.pushpull(img, hole, None, 0.0, 0.0, out=img)  # in place only with holes_only
    with pytest.raises(BadValueError, match="out: shares memory"):  # overlapping, not the same array
        buf = np.zeros(img.size + 3, np.float32)
        a = buf[:img.size].reshape(img.shape)
        a[...] = img
        _core.pushpull(a, hole, None, 0.0, 0.0, out=buf[3:].reshape(img.shape), holes_only=True)
    with pytest.raises(BadValueError, match="out: shares memory"):
        _core.pushpull(img, hole, depth, 0.04, 0.5, out=depth)


def test_uint8_mask_same_as_bool():
    rng = np.random.default_rng(6)
    img = rng.random((20, 30, 3), dtype=np.float32)
    hole = rng.random((20, 30)) < 0.3
    np.testing.assert_array_equal(pushpull(img, hole.astype(np.uint8) * 7), pushpull(img, hole))


# --- bad input ------------------------------------------------------------------------------
def test_bad_input():
    img = np.zeros((8, 8, 3), np.float32)
    hole = np.zeros((8, 8), bool)
    hole[2, 2] = True
    with pytest.raises(BadValueError, match="every pixel is a hole"):
        pushpull(img, np.ones((8, 8), bool))
    with pytest.raises(DtypeError, match="image"):
        pushpull(img.astype(np.float64), hole)
    with pytest.raises(DtypeError, match="image"):
        pushpull([[0.0]], hole)
    with pytest.raises(DtypeError, match="hole"):
        pushpull(img, hole.astype(np.int32))
    with pytest.raises(ShapeError, match="hole"):
        pushpull(img, np.zeros((8, 7), bool))
    with pytest.raises(ShapeError, match="image"):
        pushpull(np.zeros((8, 8, 3, 1), np.float32), hole)
    with pytest.raises(ShapeError, match="image"):
        pushpull(np.zeros((0, 8, 3), np.float32), np.zeros((0, 8), bool))
    with pytest.raises(ShapeError, match="C-contiguous"):
        pushpull(np.zeros((8, 16, 3), np.float32)[:, ::2], hole)
    with pytest.raises(ShapeError, match="depth"):
        pushpull(img, hole, np.ones((8, 9), np.float32))
    with pytest.raises(DtypeError, match="depth"):
        pushpull(img, hole, np.ones((8, 8), np.float64))
    with pytest.raises(BadValueError, match="gamma"):
        pushpull(img, hole, np.ones((8, 8), np.float32), gamma=-1)
    with pytest.raises(BadValueError, match="depth_threshold"):
        pushpull(img, hole, np.ones((8, 8), np.float32), depth_threshold=float("nan"))
    bad = img.copy()
    bad[0, 0, 1] = np.inf
    with pytest.raises(BadValueError, match="1 NaN or infinite"):
        pushpull(bad, hole)
    bad[2, 2] = np.nan  # inside the hole: fine
    bad[0, 0, 1] = 0
    assert np.all(np.isfinite(pushpull(bad, hole)))


def test_inpaint_switch():
    img, depth, hole = _scene()
    assert inpaint(img, hole, "none") is img
    np.testing.assert_array_equal(inpaint(img, hole, "pushpull"), pushpull(img, hole))
    np.testing.assert_array_equal(inpaint(img, hole, "pushpull", depth), pushpull(img, hole, depth))
    # metameric is built now (tests/inpaint/test_metameric.py covers it).
    with pytest.raises(BadValueError, match="inpaint method"):
        inpaint(img, hole, "telea")
    with pytest.raises(ShapeError):
        inpaint(img, hole[:, :3], "none")


# --- ibr-render --inpaint, end to end -------------------------------------------------------
@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return synth_scene_dir(tmp_path_factory, "--views", "6", "--size", "64x48", name="inpaint")


def test_cli_render_dibr_inpaint_pushpull(scene_dir, tmp_path, capsys):
    import json

    from ibrtools.imageio import read_image
    from ibrtools_cli import render

    base = ["--method", "dibr", "--holdout", "v002", "--inputs", "2", "-q"]
    assert render.main([str(scene_dir), *base, "--inpaint", "none", "-o", str(tmp_path / "none")]) == 0
    assert render.main([str(scene_dir), *base, "--inpaint", "pushpull", "-o", str(tmp_path / "pp")]) == 0
    rep0 = json.loads((tmp_path / "none" / "report.json").read_text())
    rep = json.loads((tmp_path / "pp" / "report.json").read_text())
    assert rep["inpaint"] == "pushpull" and rep0["inpaint"] == "none"
    f, f0 = rep["frames"][0], rep0["frames"][0]
    assert f["metrics"]["coverage"] < 1  # disocclusions: dibr leaves holes
    assert f["inpaint"] == "pushpull" and f["time_ms"]["inpaint"] >= 0 and "inpaint" not in f0["time_ms"]
    assert f["hole_mask"] == f0["hole_mask"]  # the hole mask is still written
    mask = read_image(tmp_path / "pp" / f["hole_mask"])[..., 0] > 0.5
    filled = read_image(tmp_path / "pp" / f["image"])
    black = read_image(tmp_path / "none" / f0["image"])
    # Outside the holes the frames are the same; inside, no-fill is black and push-pull is not.
    assert np.array_equal(filled[~mask], black[~mask])
    assert black[mask].max() == 0 and filled[mask].mean() > 0.02
    assert f["metrics"]["psnr_holes"] is not None
    # Scores over the covered pixels do not change (the fill only writes into holes).
    assert f["metrics"]["psnr_covered"] == f0["metrics"]["psnr_covered"]


def test_job_skips_inpaint_without_holes(scene_dir, tmp_path, monkeypatch):
    import json

    from ibrtools.formats import native
    from ibrtools.pipeline import job as render_job
    from ibrtools.pipeline import plan as planning
    from ibrtools import methods

    class NoHoleMethod:  # a method whose frame has a hole mask with no hole in it
        name = "nohole"

        def prepare(self, scene):
            return {}

        def render(self, camera):
            h, w = camera.height, camera.width
            return {"color": np.full((h, w, 3), 0.5, np.float32), "hole": np.zeros((h, w), bool)}, {}

    monkeypatch.setattr(methods, "resolve", lambda name, scene: name)
    monkeypatch.setattr(methods, "create", lambda name, params: NoHoleMethod())
    job = planning.plan(native.load(scene_dir), holdout=["v002"])
    rep = render_job.run(job, "nohole", tmp_path / "o", inpaint="pushpull")
    f = json.loads((tmp_path / "o" / "report.json").read_text())["frames"][0]
    assert f["inpaint"] == "skipped: no hole" and "inpaint" not in f["time_ms"] and "hole_mask" not in f
    assert rep["frames"][0]["inpaint"] == "skipped: no hole"
    from ibrtools.errors import BadValueError as Bad

    with pytest.raises(Bad, match="inpaint: expected"):
        render_job.run(job, "nohole", tmp_path / "b", inpaint="blur")
