"""Speed paths of the forward warp (cpp/kernels/dibr/forward_warp.h): the AVX2 clones of the hot loops
against the SSE2 baseline, and the band-local accumulation of _core.DibrAccumulator against the
full-size per-view buffers of _core.forward_warp.

Tolerances: none. Both are the same IEEE operations in the same order (no FMA in the AVX2
clones; the band-local mode only changes where a band is drawn), so every comparison is
bit-for-bit (assert_array_equal).
"""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import BadValueError, Camera, _core, look_at

pytestmark = [pytest.mark.asan, pytest.mark.tsan]

needs_avx2 = pytest.mark.skipif(not _core.cpu_has_avx2(), reason="this CPU has no AVX2: only the baseline path runs")


@pytest.fixture
def restore_isa():
    yield
    _core.set_warp_isa("auto")


def rough_depth(h, w, seed, holes=True):
    """Random depth with jumps (stretched triangles across them), flat patches, unknown pixels."""
    rng = np.random.default_rng(seed)
    d = 2.0 + 3.0 * rng.random((h, w))
    d[rng.random((h, w)) < 0.15] *= 4.0  # isolated far pixels: long slivers in the target
    d[h // 3: h // 2, w // 4: w // 2] = 1.5  # a flat near block: its silhouette stretches
    if holes:
        d[rng.random((h, w)) < 0.05] = 0.0  # unknown depth: triangles dropped
    return d.astype(np.float32)


def cases():
    """(name, source camera, target camera, depth) covering small quads, stretched and
    degenerate triangles (a far zoomed-out target snaps many vertices together), pinhole and
    equirect sources and targets, sky at infinity."""
    src = Camera.from_fov(97, 71, 70, look_at([0, 0, 0], [0, 0, 1]))
    out = [
        ("near", src, Camera.from_fov(90, 80, 65, look_at([0.15, -0.05, 0.1], [0.1, 0, 4])), rough_depth(71, 97, 1)),
        ("wide baseline", src, Camera.from_fov(120, 64, 80, look_at([0.8, 0.3, -0.2], [0, 0, 4])),
         rough_depth(71, 97, 2)),
        ("zoomed out (degenerate)", src,
         Camera(model="pinhole", width=40, height=30, fx=8.0, fy=8.0, cx=20.0, cy=15.0,
                cam_from_world=look_at([0.05, 0, -0.5], [0, 0, 3])), rough_depth(71, 97, 3)),
        ("magnified (stretched)", src, Camera.from_fov(64, 64, 12, look_at([0.1, 0, 0], [0.3, 0.1, 4])),
         rough_depth(71, 97, 4, holes=False)),
    ]
    eq_src = Camera(model="equirect", width=96, height=48, cam_from_world=look_at([0, 0, 0], [0, 0, 1]))
    eq_dep = rough_depth(48, 96, 5)
    eq_dep[:6] = np.inf  # sky
    out.append(("equirect -> pinhole", eq_src, Camera.from_fov(80, 60, 70, look_at([0.1, 0, 0], [0, 0, 3])), eq_dep))
    eq_dst = Camera(model="equirect", width=100, height=50, cam_from_world=look_at([0.1, 0.05, 0], [0, 0, 1]))
    out.append(("pinhole -> equirect", src, eq_dst, rough_depth(71, 97, 6)))
    out.append(("equirect -> equirect", eq_src, eq_dst, eq_dep))
    # rectified pair: every target centre exactly on a horizontal mesh edge (inclusive-edge ties
    # between the two triangles sharing it, in the small-quad and general paths alike)
    rect_src = Camera(model="pinhole", width=97, height=71, fx=80.0, fy=80.0, cx=48.5, cy=35.5, cam_from_world=np.eye(4))
    moved = np.eye(4)
    moved[0, 3] = -0.05
    rect_dst = Camera(model="pinhole", width=97, height=71, fx=80.0, fy=80.0, cx=48.5, cy=35.5, cam_from_world=moved)
    out.append(("rectified (shared edges)", rect_src, rect_dst, rough_depth(71, 97, 7)))
    # magnified about 2-3x: small-path triangles that cover two to four centres (the lanes shade
    # a triangle's first centre, the others one by one), some sliver triangles of area 0 or
    # back-facing across the depth jumps
    out.append(("magnified 2-3x (multi-centre triangles)", src,
                Camera.from_fov(150, 120, 40, look_at([0.05, 0.02, 0.1], [0.1, 0.05, 4])), rough_depth(71, 97, 8)))
    return out


def noise(h, w, seed):
    return np.random.default_rng(seed).random((h, w, 3), dtype=np.float32)


def run_all(src, dst, dep, quality, depth_test="combined", discard_stretched=False, blend_exponent=5.0):
    """Every public entry point that goes through the hot loops, for one case."""
    col = noise(src.height, src.width, 9)
    opts = _core.WarpOptions()
    opts.quality = quality
    opts.side_threshold = 10.0
    opts.depth_test = depth_test
    opts.discard_stretched = discard_stretched
    opts.blend_exponent = blend_exponent
    res = list(_core.forward_warp(col, dep, src.to_core(), dst.to_core(), opts))
    acc = _core.DibrAccumulator(dst.to_core(), 0.1, True, 0.0)
    acc.add_view(col, dep, src.to_core(), opts)
    acc.add_view(col[::-1].copy(), dep[::-1].copy(), src.to_core(), opts)
    res += list(acc.result())
    plain = _core.DibrAccumulator(dst.to_core())  # no visibility rules: the AVX2 accumulation
    plain.add_view(col, dep, src.to_core(), opts)
    plain.add_view(col[:, ::-1].copy(), dep[:, ::-1].copy(), src.to_core(), opts)
    res += list(plain.result())
    # the resolve's sRGB decoding (blend space "srgb"; the colour only: the rest does not depend on it)
    res += [acc.result(srgb_to_linear=True)[0], plain.result(srgb_to_linear=True)[0]]
    res += list(_core.warp_with_holes(col, dep, src.to_core(), dst.to_core()))
    return res


@needs_avx2
@pytest.mark.parametrize("quality", ["side", "shape"])
def test_avx2_and_baseline_paths_are_bit_identical(quality, restore_isa):
    for name, src, dst, dep in cases():
        out = {}
        for isa in ("baseline", "avx2"):
            _core.set_warp_isa(isa)
            assert _core.warp_isa() == isa
            out[isa] = run_all(src, dst, dep, quality)
        covered = (out["baseline"][2] > 0).mean()
        assert covered > 0.005, name  # the case draws something
        for a, b in zip(out["baseline"], out["avx2"]):
            np.testing.assert_array_equal(a, b, err_msg=name)


@needs_avx2
@pytest.mark.parametrize("depth_test, discard, p", [("nearest", False, 5.0), ("combined", True, 3.0),
                                                    ("combined", False, 2.5)])
def test_avx2_and_baseline_identical_for_every_depth_test_and_discard(depth_test, discard, p, restore_isa):
    """The lane shading of the AVX2 raster step (score of either depth test, Eq. 1's discard of
    stretched triangles folded into the coverage masks) and the AVX2 band weights (p = 5 and 3 in
    lanes, other p scalar) against the scalar baseline."""
    for name, src, dst, dep in cases():
        out = {}
        for isa in ("baseline", "avx2"):
            _core.set_warp_isa(isa)
            out[isa] = run_all(src, dst, dep, "side", depth_test, discard, p)
        assert (out["baseline"][2] > 0).mean() > 0.005, name
        for a, b in zip(out["baseline"], out["avx2"]):
            np.testing.assert_array_equal(a, b, err_msg=name)


def warp_and_blend_both_isas(col, dep, src, dst) -> dict:
    """{isa: forward_warp's outputs + a one-view DibrAccumulator's result} for both ISAs."""
    out = {}
    for isa in ("baseline", "avx2"):
        _core.set_warp_isa(isa)
        acc = _core.DibrAccumulator(dst.to_core())
        acc.add_view(col, dep, src.to_core())
        out[isa] = list(_core.forward_warp(col, dep, src.to_core(), dst.to_core())) + list(acc.result())
    return out


@needs_avx2
def test_avx2_and_baseline_identical_on_random_meshes(restore_isa):
    """Random depth (pixel-wise noise over several octaves: slivers, degenerate and back-facing
    triangles, stretched ones across jumps) seen from random targets at 0.5x to 3x scale, with
    input widths that leave every length of the last 8-quad group."""
    rng = np.random.default_rng(21)
    for trial in range(8):
        h, w = int(rng.integers(9, 40)), int(rng.integers(9, 50))
        src = Camera.from_fov(w, h, float(rng.uniform(40, 90)), look_at([0, 0, 0], [0, 0, 1]))
        dep = (2.0 + rng.random((h, w)) * rng.choice([0.01, 0.3, 3.0])).astype(np.float32)
        dep[rng.random((h, w)) < 0.1] = 0.0
        eye = rng.normal(0, 0.2, 3)
        tw, th = int(w * rng.uniform(0.5, 3.0)) + 2, int(h * rng.uniform(0.5, 3.0)) + 2
        dst = Camera.from_fov(tw, th, float(rng.uniform(30, 90)), look_at(eye, [0, 0, 3]))
        out = warp_and_blend_both_isas(noise(h, w, trial), dep, src, dst)
        for a, b in zip(out["baseline"], out["avx2"]):
            np.testing.assert_array_equal(a, b, err_msg=f"trial {trial}")


@needs_avx2
@pytest.mark.parametrize("shift", [1 / 512, -1 / 512])
def test_avx2_vertex_snap_rounds_exact_ties_as_the_baseline(shift, restore_isa):
    """The AVX2 projection's 1/256 px snap (RoundHalfAway4) on exact ties. Same pose, fx = fy = 64,
    depth 2, the target's principal point moved by (k + 1/2) / 256 px: every projected coordinate
    is exact (powers of two), so x * 256 ends in exactly +0.5 (shift > 0: n + 0.5, n even: half to
    even would round down) or, with the target moved right, -0.5 for the vertices left of the
    image (half up would round toward zero); half away from zero is the rule of both paths. A tie
    rounded the other way moves the vertex by 1/256 px, which changes the edge functions, hence
    coverage and barycentrics."""
    h, w = 24, 40
    src = Camera(model="pinhole", width=w, height=h, fx=64.0, fy=64.0, cx=20.0, cy=12.0, cam_from_world=np.eye(4))
    off = 0.0 if shift > 0 else -10.0
    dst = Camera(model="pinhole", width=w, height=h, fx=64.0, fy=64.0, cx=20.0 + off + shift, cy=12.0 + off + shift,
                 cam_from_world=np.eye(4))
    dep = np.full((h, w), 2.0, np.float32)
    out = warp_and_blend_both_isas(noise(h, w, 15), dep, src, dst)
    assert (out["baseline"][2] > 0).mean() > 0.3  # the case draws something
    for a, b in zip(out["baseline"], out["avx2"]):
        np.testing.assert_array_equal(a, b)


@needs_avx2
def test_avx2_and_baseline_flow_warp_identical(restore_isa):
    rng = np.random.default_rng(11)
    h, w = 50, 70
    col, dep = noise(h, w, 1), rough_depth(h, w, 12)
    flow = rng.normal(0, 1.5, (h, w, 2)).astype(np.float32)
    flow[:, w // 2:, 0] += 6.0  # a shear: stretched quads along the cut
    out = {}
    for isa in ("baseline", "avx2"):
        _core.set_warp_isa(isa)
        out[isa] = _core.warp_flow(col, dep, flow)
    for a, b in zip(out["baseline"], out["avx2"]):
        np.testing.assert_array_equal(a, b)


def test_band_local_accumulation_equals_per_view_buffers():
    """DibrAccumulator draws each view band by band into per-thread buffers and never makes the
    full-size colour / depth / weight images; the sums must be those of the per-view images of
    forward_warp (Eq. 3 done here in float32 with the kernel's operation order: sums in view
    order, w * c then +=, colour = sum_wc * (1 / sum_w), depth = sum_w / sum(w / d))."""
    for name, src, dst, dep in cases():
        views = [(noise(src.height, src.width, 3), dep), (noise(src.height, src.width, 4), dep[::-1].copy())]
        opts = _core.WarpOptions()
        acc = _core.DibrAccumulator(dst.to_core())
        swc = np.zeros((dst.height, dst.width, 3), np.float32)
        sw = np.zeros((dst.height, dst.width), np.float32)
        swi = np.zeros_like(sw)
        for col, d in views:
            acc.add_view(col, d, src.to_core(), opts)
            c, dd, w = _core.forward_warp(col, d, src.to_core(), dst.to_core(), opts)
            m = w > 0
            swc[m] += w[m][:, None] * c[m]
            sw[m] += w[m]
            with np.errstate(divide="ignore"):
                swi[m] += w[m] / dd[m]
        color, depth, conf, hole = acc.result()
        np.testing.assert_array_equal(hole, ~(sw > 0), err_msg=name)
        m = sw > 0
        np.testing.assert_array_equal(color[m], swc[m] * (np.float32(1) / sw[m])[:, None], err_msg=name)
        with np.errstate(divide="ignore"):
            ref_d = np.where(swi[m] > 0, sw[m] / swi[m], np.inf).astype(np.float32)
        np.testing.assert_array_equal(depth[m], ref_d, err_msg=name)
        assert (color[~m] == 0).all() and (conf[~m] == 0).all() and (conf[m] > 0).all()


ISAS = ["baseline", pytest.param("avx2", marks=needs_avx2)]


@pytest.mark.parametrize("isa", ISAS)
def test_srgb_resolve_decodes_the_blend(isa, restore_isa):
    """result(srgb_to_linear=True) (blend space "srgb": the views' colours are sRGB encodings) is
    result() with its colour decoded by _core.srgb_to_linear, done inside the resolve. Tolerance
    1e-6 absolute: in [0, 1] the resolve reads the curve from a table of 4097 of its own values
    with linear interpolation (cpp/kernels/dibr/blend.cpp; measured 2.4e-7 here, the lerp's error
    bound is 2.5e-8 plus the curve's own polynomial wiggle between nodes); outside [0, 1] (HDR
    encodings above 1, negative colour) it is the curve itself, the same bits. Depth, confidence
    and hole are unchanged bit for bit, holes stay exactly 0, nothing is NaN. Both visibility
    settings, every warp case (widths that are not multiples of 8: the scalar tail of the rows;
    targets of 50-120 rows: several 16-row tasks), colour in [0, 1) and spread over [-0.5, 2.5)."""
    _core.set_warp_isa(isa)
    opts = _core.WarpOptions()
    opts.side_threshold = 10.0  # as --method dibr (the auto T makes the magnified case all stretched)
    for name, src, dst, dep in cases():
        for scale, offset in ((1.0, 0.0), (3.0, -0.5)):
            col = (noise(src.height, src.width, 9) * np.float32(scale) + np.float32(offset)).astype(np.float32)
            for rules in ((0.1, True, 0.0), (0.0, False, 0.0)):
                acc = _core.DibrAccumulator(dst.to_core(), *rules)
                acc.add_view(col, dep, src.to_core(), opts)
                acc.add_view(col[::-1].copy(), dep[::-1].copy(), src.to_core(), opts)
                lin = acc.result()
                enc = acc.result(srgb_to_linear=True)
                hole = lin[3]
                assert (~hole).mean() > 0.005, name
                want = _core.srgb_to_linear(lin[0])
                np.testing.assert_allclose(enc[0], want, rtol=0, atol=1e-6, err_msg=name)
                outside = ~((lin[0] >= 0) & (lin[0] <= 1))
                np.testing.assert_array_equal(enc[0][outside], want[outside], err_msg=name)
                for a, b in zip(lin[1:], enc[1:]):
                    np.testing.assert_array_equal(a, b, err_msg=name)
                assert (enc[0][hole] == 0).all() and not np.signbit(enc[0][hole]).any(), name
                assert np.isfinite(enc[0]).all(), name


@pytest.mark.parametrize("isa", ISAS)
def test_srgb_resolve_is_exact_on_the_table_nodes(isa, restore_isa):
    """Blended encodings k / 4096 (the float32 values in [0, 1] that are nodes of the resolve's
    table) decode to exactly _core.srgb_to_linear's value. An identity warp of a view whose colours
    run through every node from 0 to 1 gives most pixels their own colour back exactly (the rest
    differ by an ulp: colour * (1 / d) * d); every resolved node must decode exactly."""
    _core.set_warp_isa(isa)
    h, w = 40, 120
    cam = Camera.from_fov(w, h, 50, look_at([0, 0, 0], [0, 0, 1]))
    col = ((np.arange(h * w * 3) % 4097).astype(np.float32) / np.float32(4096)).reshape(h, w, 3)
    acc = _core.DibrAccumulator(cam.to_core())
    acc.add_view(col, np.full((h, w), 2.0, np.float32), cam.to_core())
    lin, _, _, hole = acc.result()
    enc = acc.result(srgb_to_linear=True)[0]
    node = ~hole[..., None] & (lin * np.float32(4096) == np.floor(lin * np.float32(4096))) & (lin <= 1)
    assert node.mean() > 0.8 and {0.0, 1.0} <= set(np.unique(lin[node]).tolist())
    np.testing.assert_array_equal(enc[node], _core.srgb_to_linear(lin)[node])


def test_rejected_view_leaves_the_sums_unchanged():
    src = Camera.from_fov(40, 30, 60, look_at([0, 0, 0], [0, 0, 1]))
    dst = Camera.from_fov(40, 30, 60, look_at([0.05, 0, 0], [0, 0, 3]))
    col = noise(30, 40, 5)
    dep = rough_depth(30, 40, 6)
    acc = _core.DibrAccumulator(dst.to_core())
    acc.add_view(col, dep, src.to_core())
    before = acc.result()
    bad = dep.copy()
    bad[3, 4] = np.nan
    with pytest.raises(BadValueError, match="NaN or negative"):
        acc.add_view(col, bad, src.to_core())
    with pytest.raises(BadValueError, match="no valid depth"):
        acc.add_view(col, np.zeros_like(dep), src.to_core())
    assert acc.num_views == 1
    for a, b in zip(before, acc.result()):
        np.testing.assert_array_equal(a, b)


def test_set_warp_isa_bad_input(restore_isa):
    with pytest.raises(BadValueError, match="isa"):
        _core.set_warp_isa("sse4")
    with pytest.raises(TypeError):
        _core.set_warp_isa(2)
    if not _core.cpu_has_avx2():
        with pytest.raises(BadValueError, match="no AVX2"):
            _core.set_warp_isa("avx2")
    _core.set_warp_isa("baseline")
    assert _core.warp_isa() == "baseline"
    _core.set_warp_isa("auto")
    assert _core.warp_isa() == ("avx2" if _core.cpu_has_avx2() else "baseline")


@pytest.fixture
def restore_threads():
    yield
    _core.set_num_threads(0)


def test_band_lists_and_band_order_change_no_result(restore_threads):
    """The band lists are built in parallel over chunks of 64 input block rows and pass 2 takes
    the bands by decreasing segment count (forward_warp.cpp, BuildBandLists): a tall input (5
    chunks) seen by a tilted target (bands of very different loads), on 1 and 2 threads and
    both ISAs, against the baseline on one thread, bit for bit."""
    h, w = 300, 41
    src = Camera.from_fov(w, h, 60, look_at([0, 0, 0], [0, 0, 1]))
    dst = Camera.from_fov(90, 170, 70, look_at([0.1, 0.3, 0.05], [0.2, -0.4, 4]))
    dep = rough_depth(h, w, 13)
    col = noise(h, w, 14)
    out = []
    isas = ("baseline", "avx2") if _core.cpu_has_avx2() else ("baseline",)
    try:
        for isa in isas:
            _core.set_warp_isa(isa)
            for n in (1, 2):
                _core.set_num_threads(n)
                acc = _core.DibrAccumulator(dst.to_core(), 0.1, True, 0.0)
                acc.add_view(col, dep, src.to_core())
                acc.add_view(col[::-1].copy(), dep[::-1].copy(), src.to_core())
                out.append(list(acc.result()) + list(_core.forward_warp(col, dep, src.to_core(), dst.to_core())))
    finally:
        _core.set_warp_isa("auto")
    assert (~out[0][3]).mean() > 0.2  # the case draws something
    for other in out[1:]:
        for a, b in zip(out[0], other):
            np.testing.assert_array_equal(a, b)
