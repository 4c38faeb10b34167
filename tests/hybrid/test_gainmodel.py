"""Which part of the views' gains is exposure (ibrtools.hybrid.gainmodel): the leave-one-out
smoothness ratio against a plain-loop reference, a smooth function of the viewing direction
(shading) against independent jitter (exposure), the three modes, bad input."""
import math

import numpy as np
import pytest

from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, ShapeError
from ibrtools.hybrid.gainmodel import HALF_MIN_SAMPLES, exposure_gains, gain_halves, gain_smoothness, global_shrink


def ring(n=24, elevation=0.5):
    """n cameras on a circle around the origin, looking at it."""
    cams = {}
    for i in range(n):
        a = 2 * math.pi * i / n
        eye = (4 * math.cos(a), elevation, 4 * math.sin(a))
        cams[f"v{i}"] = Camera.pinhole(32, 24, 30.0, 30.0, 16, 12, look_at(eye, (0.0, 0.0, 0.0)))
    return cams


def reference_ratio(gains, cams, sigma):
    """The leave-one-out ratio with plain loops (independent of the vectorised version)."""
    names = list(gains)
    lg = {n: [math.log(x) for x in gains[n]] for n in names}
    mu = [sum(lg[n][c] for n in names) / len(names) for c in range(3)]
    num = den = 0.0
    for a in names:
        fa = np.asarray(cams[a].world_from_cam)[:3, 2]
        ws, acc = 0.0, [0.0, 0.0, 0.0]
        for b in names:
            if b == a:
                continue
            fb = np.asarray(cams[b].world_from_cam)[:3, 2]
            cosang = float(fa @ fb) / float(np.linalg.norm(fa) * np.linalg.norm(fb))
            ang = math.degrees(math.acos(max(-1.0, min(1.0, cosang))))
            if ang <= 3 * sigma:
                w = math.exp(-0.5 * (ang / sigma) ** 2)
                ws += w
                acc = [acc[c] + w * lg[b][c] for c in range(3)]
        pred = [acc[c] / ws for c in range(3)] if ws > 0 else mu
        num += sum((lg[a][c] - pred[c]) ** 2 for c in range(3))
        den += sum((lg[a][c] - mu[c]) ** 2 for c in range(3))
    return math.sqrt(num / den)


def shading_gains(cams):
    """A gain that is a smooth function of the azimuth (like lego's shading)."""
    out = {}
    for i, n in enumerate(cams):
        a = 2 * math.pi * i / len(cams)
        out[n] = np.exp(0.15 * np.array([math.cos(a), math.cos(a + 0.2), math.cos(a + 0.4)]))
    return out


def jitter_gains(cams, seed=0):
    rng = np.random.default_rng(seed)
    return {n: np.exp(rng.normal(0, 0.1, 3)) for n in cams}


@pytest.mark.parametrize("kind", ["shading", "jitter"])
def test_ratio_matches_reference(kind):
    cams = ring()
    g = shading_gains(cams) if kind == "shading" else jitter_gains(cams)
    ratio, pred = gain_smoothness(g, cams, 20.0)
    # float64 both ways, different summation order: agreement to rounding.
    assert ratio == pytest.approx(reference_ratio(g, cams, 20.0), rel=1e-9)
    assert set(pred) == set(cams)


def test_shading_kept_jitter_removed():
    cams = ring()
    sh = shading_gains(cams)
    out, rec = exposure_gains(sh, cams)
    assert rec["model"] == "shading" and rec["ratio"] < 0.5
    # The smooth part stays in the images: what is divided out is far smaller than the gains.
    spread_in = np.ptp(np.log(list(sh.values())), axis=0).max()
    spread_out = np.ptp(np.log(list(out.values())), axis=0).max()
    assert spread_out < 0.2 * spread_in
    jit = jitter_gains(cams)
    out, rec = exposure_gains(jit, cams)
    assert rec["model"] == "exposure" and rec["ratio"] > 0.9
    for n in jit:  # exposure jitter: the gains unchanged (the previous model, bit for bit)
        assert np.array_equal(out[n], jit[n])


def test_shading_plus_jitter_keeps_the_jitter():
    cams = ring(48)
    sh = shading_gains(cams)
    rng = np.random.default_rng(3)
    jit = {n: np.exp(rng.normal(0, 0.02, 3)) for n in cams}
    both = {n: sh[n] * jit[n] for n in cams}
    out, rec = exposure_gains(both, cams)
    assert rec["model"] == "shading"
    lo = np.array([np.log(out[n]) for n in cams])
    lj = np.array([np.log(jit[n]) for n in cams])
    lj -= lj.mean(0)
    # What is divided out follows the jitter (correlation), not the shading.
    assert np.corrcoef(lo.ravel(), lj.ravel())[0, 1] > 0.7


def test_modes():
    cams = ring(8)
    g = shading_gains(cams)
    out, rec = exposure_gains(g, cams, mode="none")
    assert rec["model"] == "none" and all(np.array_equal(v, np.ones(3)) for v in out.values())
    out, rec = exposure_gains(g, cams, mode="exposure")
    assert rec["model"] == "exposure" and all(np.array_equal(out[n], g[n]) for n in g)
    out, rec = exposure_gains(g, cams, max_ratio=0.0)  # never shading
    assert rec["model"] == "exposure"
    two = {n: g[n] for n in list(g)[:2]}
    out, rec = exposure_gains(two, cams)  # too few views to tell: unchanged
    assert rec["model"] == "exposure" and all(np.array_equal(out[n], g[n]) for n in two)


def test_bad_input():
    cams = ring(6)
    g = shading_gains(cams)
    with pytest.raises(BadValueError, match="gain model"):
        exposure_gains(g, cams, mode="median")
    with pytest.raises(BadValueError, match="max_ratio"):
        exposure_gains(g, cams, max_ratio=-1.0)
    with pytest.raises(BadValueError, match="sigma_deg"):
        gain_smoothness(g, cams, 0.0)
    with pytest.raises(BadValueError, match="no camera"):
        gain_smoothness({**g, "other": np.ones(3)}, cams)
    with pytest.raises(BadValueError, match="at least 3"):
        gain_smoothness({n: g[n] for n in list(g)[:2]}, cams)
    with pytest.raises(ShapeError, match="gains"):
        gain_smoothness({n: np.ones(2) for n in g}, cams)
    with pytest.raises(BadValueError, match="positive"):
        gain_smoothness({**g, "v0": np.array([1.0, 0.0, 1.0])}, cams)
    eq = {n: Camera.equirect(32, 16, cam_from_world=np.eye(4)) for n in g}
    with pytest.raises(BadValueError, match="optical axis"):
        gain_smoothness(g, eq)
    out, rec = exposure_gains(g, eq)  # the stage's call: an equirect scene keeps its gains
    assert rec["model"] == "exposure" and all(np.array_equal(out[n], g[n]) for n in g)


def test_global_shrink_hand_checked():
    # r = +-0.1 about the views' mean (mean square 0.01); half differences d = +-0.1 in every
    # view, channel and split: s2 = 0.01 / 4 = 0.0025, f = 1 - 0.0025 / 0.01 = 0.75.
    c = np.log(np.array([1.1, 0.9, 1.0]))
    gains = {"a": np.exp(c + 0.1), "b": np.exp(c - 0.1)}
    half = {n: np.exp(np.log(g)[None] + np.array([[0.05], [-0.05], [0.05], [-0.05]])) for n, g in gains.items()}
    out, f = global_shrink(gains, half)
    assert f == pytest.approx(0.75)
    np.testing.assert_allclose(np.log(out["a"]), c + 0.075, atol=1e-12)
    np.testing.assert_allclose(np.log(out["b"]), c - 0.075, atol=1e-12)


def test_global_gains_kept_local_ones_shrunk_away():
    cams = ring(12)
    jit = jitter_gains(cams)
    # An exposure scales the whole image: every half measures the same gain -> kept (bit for bit
    # up to exp(log)).
    same = {n: np.repeat(np.asarray(g)[None], 4, 0) for n, g in jit.items()}
    out, rec = exposure_gains(jit, cams, half_gains=same)
    assert rec["model"] == "exposure" and rec["shrink"] == 1.0
    for n in jit:
        np.testing.assert_allclose(out[n], jit[n], rtol=1e-12)
    # Halves that disagree by more than the views do: the "gains" are not global -> nothing divided.
    rng = np.random.default_rng(1)
    noisy = {n: np.asarray(g)[None] * np.exp(rng.normal(0, 0.5, (4, 3))) for n, g in jit.items()}
    out, rec = exposure_gains(jit, cams, half_gains=noisy)
    assert rec["shrink"] == 0.0
    lo = np.log(np.array(list(out.values())))
    np.testing.assert_allclose(lo - lo.mean(0), 0.0, atol=1e-12)
    # Without half gains: no shrink step.
    assert exposure_gains(jit, cams)[1]["shrink"] is None


def test_global_shrink_bad_input():
    g = {"a": np.ones(3), "b": np.full(3, 1.2)}
    with pytest.raises(BadValueError, match="half_gains"):
        global_shrink(g, {"a": np.ones((4, 3))})
    with pytest.raises(ShapeError, match="half_gains"):
        global_shrink(g, {"a": np.ones((2, 3)), "b": np.ones((2, 3))})
    with pytest.raises(BadValueError, match="half_gains"):
        global_shrink(g, {"a": np.ones((4, 3)), "b": np.zeros((4, 3))})
    # Identical gains (nothing to shrink): f = 0 and the common level, never NaN.
    out, f = global_shrink({"a": np.ones(3), "b": np.ones(3)}, {"a": np.ones((4, 3)), "b": np.ones((4, 3))})
    assert f == 0.0 and all(np.array_equal(v, np.ones(3)) for v in out.values())


def test_gain_halves_split_and_sparse_half():
    # 40 samples on a 10 x 8 image: ratio 2 left of x = 5, 3 right of it; top / bottom mixed.
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.uniform(0, 5, 20), rng.uniform(5, 10, 20)])
    y = rng.uniform(0, 8, 40)
    ratio = np.where((x < 5)[:, None], 2.0, 3.0) * np.ones((1, 3))
    h = gain_halves(ratio, x, y, 10, 8, np.full(3, 2.5))
    np.testing.assert_array_equal(h[0], 2.0)
    np.testing.assert_array_equal(h[1], 3.0)
    for k, part in ((2, y < 4), (3, y >= 4)):
        np.testing.assert_array_equal(h[k], np.median(ratio[part], axis=0))
    # A half with fewer than HALF_MIN_SAMPLES samples takes the whole image's gain: no evidence.
    few = np.concatenate([np.full(HALF_MIN_SAMPLES - 1, 1.0), np.full(30, 9.0)])
    h = gain_halves(np.ones((len(few), 3)), few, np.full(len(few), 4.0), 10, 8, np.full(3, 1.7))
    np.testing.assert_array_equal(h[0], 1.7)
    np.testing.assert_array_equal(h[1], 1.0)
