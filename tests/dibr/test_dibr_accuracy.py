"""DIBR accuracy work: the ``blend_space`` option of
``--method dibr`` and the conventions of the real data that the accuracy figures rest on
(docs/dibr_accuracy.md; benchmarks/bench_dibr_accuracy.py)."""
from __future__ import annotations


import numpy as np
import pytest

from conftest import need_data, shared_data
from ibrtools import _core
from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError
from ibrtools.imageio import srgb_to_linear
from ibrtools.dibr.method import DibrMethod, DibrParams, srgb_encode
from ibrtools.scene import Scene, View

DATA = shared_data()
needs_kernel = pytest.mark.skipif(not hasattr(_core, "DibrAccumulator"),
                                  reason="_core.DibrAccumulator (the DIBR kernel) is not built")


def _render(views, camera, **params):
    m = DibrMethod({"inputs": [v.name for v in views], **params})
    m.prepare(Scene(views=views))
    out, _ = m.render(camera)
    return out


# --- blend_space ---------------------------------------------------------------------------
def test_blend_space_default_and_bad_values():
    assert DibrParams.from_dict(None).blend_space == "srgb"  # chosen on validation views (docs/dibr_accuracy.md "Blend space")
    assert DibrParams.from_dict({"blend_space": "linear"}).blend_space == "linear"
    assert DibrParams.from_dict({"blend_space": "srgb"}).blend_space == "srgb"
    for bad in ("sRGB", "gamma", "", 1, None):
        with pytest.raises(BadValueError, match="blend_space"):
            DibrMethod({"blend_space": bad})


def test_srgb_encode_decode_round_trip():
    # The IEC 61966-2-1 curve: 0 -> 0, 1 -> 1, 0.5 -> 0.7354 (tabulated value), the linear toe
    # below 0.0031308; values above 1 stay on the curve (HDR inputs are not clipped) and
    # negative light is 0. float32 round trip within 2e-6 relative (the powers in float32).
    v = np.array([0.0, 0.001, 0.0031308, 0.18, 0.5, 1.0, 4.0], np.float32)
    e = srgb_encode(v)
    assert e[0] == 0 and e[5] == pytest.approx(1.0, abs=1e-6) and e[4] == pytest.approx(0.7354, abs=1e-4)
    assert e[1] == pytest.approx(0.01292, rel=1e-5) and e[6] > 1.0
    np.testing.assert_allclose(srgb_to_linear(e), v, rtol=2e-6, atol=1e-9)
    # negative light is 0; NaN stays NaN (views reject NaN colour; add_view would too)
    neg_nan = srgb_encode(np.array([-1.0, np.nan], np.float32))
    assert neg_nan[0] == 0 and np.isnan(neg_nan[1])
    assert e.dtype == np.float32 and srgb_to_linear(e).dtype == np.float32
    # any shape (the C++ curve works on rows): an image, a scalar, an empty array
    img = np.random.default_rng(1).uniform(-0.1, 2.0, (5, 7, 3)).astype(np.float32)
    want = np.where(img <= 0.0031308, 12.92 * np.maximum(img, 0), 1.055 * np.maximum(img, 0.0) ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(srgb_encode(img), want, rtol=1e-6, atol=1e-7)
    assert srgb_encode(np.float32(0.5)).shape == () and srgb_encode(np.zeros((0, 3), np.float32)).shape == (0, 3)


@pytest.mark.asan
@needs_kernel
def test_blend_space_srgb_render_is_the_decoded_srgb_blend():
    # The renderer's srgb frame (inputs encoded by srgb_encode, decoded inside the kernel's
    # resolve) against the same blend done without the fused decode: encoded views into a
    # DibrAccumulator, result() in the encoded space, then srgb_to_linear. 1e-6: the resolve reads the
    # curve from a table (tests/dibr/test_forward_warp_isa.py::test_srgb_resolve_decodes_the_blend).
    rng = np.random.default_rng(5)
    views = []
    for i in range(3):
        cam = Camera.from_fov(37, 29, 60, look_at((0.3 * i - 0.3, 0.1 * i, -2), (0, 0, 0)))
        depth = (2.0 + 0.3 * rng.random((29, 37))).astype(np.float32)
        views.append(View.create(f"v{i}", cam, color=rng.uniform(0, 1.5, (29, 37, 3)).astype(np.float32), depth=depth))
    target = Camera.from_fov(37, 29, 60, look_at((0.05, 0.05, -2), (0, 0, 0)))
    m = DibrMethod({"inputs": [v.name for v in views], "blend_space": "srgb"})
    m.prepare(Scene(views=views))
    out, _ = m.render(target)
    p = m.params
    acc = _core.DibrAccumulator(target.to_core(), p.stretched_quality, p.stretched_holes, p.depth_tolerance)
    for name in m.frame_report()["selected"]:
        v = next(x for x in views if x.name == name)
        acc.add_view(srgb_encode(v.color), v.depth, v.camera.to_core(), m.warp_options())
    enc, depth, _, hole = acc.result()
    assert (~hole).mean() > 0.5
    np.testing.assert_allclose(out["color"], srgb_to_linear(enc), rtol=0, atol=1e-6)
    np.testing.assert_array_equal(out["depth"], depth)
    np.testing.assert_array_equal(out["hole"], hole)
    assert (out["color"][hole] == 0).all()


@needs_kernel
def test_blend_space_srgb_identity_warp_reproduces_the_input():
    # One view warped into its own camera: every pixel centre is a vertex, so the result is the
    # input through encode -> kernel -> decode (float32: > 60 dB away from the last row/column,
    # where the implicit mesh ends at the last pixel centre).
    rng = np.random.default_rng(3)
    cam = Camera.from_fov(40, 30, 60, look_at((0, 0, -2), (0, 0, 0)))
    color = rng.uniform(0.0, 1.0, (30, 40, 3)).astype(np.float32)
    view = View.create("v", cam, color=color, depth=np.full((30, 40), 2.0, np.float32))
    out = _render([view], cam, blend_space="srgb")
    inner = (slice(1, -1), slice(1, -1))
    err = np.abs(out["color"][inner] - color[inner]).max()
    assert not out["hole"][inner].any() and err < 1e-3  # 1e-3 linear = PSNR > 60 dB


@needs_kernel
def test_blend_space_decides_what_is_averaged():
    # Two views with the same camera and depth (equal triangle quality and depth, so equal
    # weights) and constant colours a and b: the blend is (a + b) / 2 in linear, and
    # decode((encode a + encode b) / 2) in srgb, to float32 precision.
    cam = Camera.from_fov(24, 18, 60, look_at((0, 0, -2), (0, 0, 0)))
    depth = np.full((18, 24), 2.0, np.float32)
    a, b = np.float32(0.05), np.float32(0.8)
    views = [View.create(n, cam, color=np.full((18, 24, 3), c, np.float32), depth=depth) for n, c in (("a", a), ("b", b))]
    inner = (slice(2, -2), slice(2, -2))
    lin = _render(views, cam, blend_space="linear")["color"][inner]
    srgb = _render(views, cam, blend_space="srgb")["color"][inner]
    want_srgb = srgb_to_linear((srgb_encode(np.array([a])) + srgb_encode(np.array([b]))) / 2)[0]
    np.testing.assert_allclose(lin, (a + b) / 2, rtol=1e-5)
    np.testing.assert_allclose(srgb, want_srgb, rtol=1e-5)
    assert want_srgb < (a + b) / 2 - 0.1  # the two spaces really differ here (0.309 vs 0.425)


# --- conventions of the real data ----------------------------------------------------------
@pytest.fixture(scope="module")
def bench(dibr_accuracy_bench):
    return dibr_accuracy_bench


_need = need_data


def test_visible_in_inputs_uses_the_ground_truth_geometry(bench):
    # A wall at z = 5 with a box in front (z = 2) seen by a target; an input beside it sees the wall
    # only (its depth is the wall's everywhere): the wall pixels are visible, the box's are not (the
    # input's depth 5 is not within 5 % of the box point's 2 + shift), pixels that land outside the
    # input's image are not, unknown target depth is not; the target seen by itself is visible.
    w = h = 48
    cam_t = Camera.pinhole(w, h, 40.0, 40.0, w / 2, h / 2)
    cam_i = Camera.pinhole(w, h, 40.0, 40.0, w / 2, h / 2, cam_from_world=look_at((1.0, 0, 0), (1.0, 0, 5.0)))
    d_t = np.full((h, w), 5.0, np.float32)
    d_t[20:28, 20:28] = 2.0
    d_t[0, 0] = 0.0
    col = np.zeros((h, w, 3), np.float32)
    scene = Scene(views=[View.create("t", cam_t, color=col, depth=d_t),
                         View.create("i", cam_i, color=col, depth=np.full((h, w), 5.0, np.float32))])
    vis = bench.visible_in_inputs(scene, "t", ["i"])
    assert not vis[20:28, 20:28].any()                      # the box: the input sees the wall there
    assert not vis[0, 0]                                     # unknown depth
    uv, _ = cam_i.project(cam_t.unproject(np.where(d_t > 0, d_t, 1.0)))
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < w)
    wall = (d_t == 5.0)
    assert vis[wall & inside].all() and not vis[~inside].any()
    assert bench.visible_in_inputs(scene, "t", ["t"]).sum() == (d_t > 0).sum()


def test_icl_depth_is_z_not_ray_distance():
    # ICL-NUIM depth PNGs are often said to hold the distance along the ray. Frame 1 faces the
    # back wall: with the importer's z reading, 3-D points of a wall patch fit a plane to
    # ~2 mm (the data's noise, measured 1.84 mm); read as ray distance they bend by ~9 cm RMS.
    _need("icl_nuim_livingroom")
    from ibrtools.formats import load

    v = load(DATA / "icl_nuim_livingroom").view("1")
    x, y = v.camera.pixel_grid()
    rays = v.camera.rays_in_cam(x, y)[80:136, 160:620].reshape(-1, 3)
    d = v.depth[80:136, 160:620].reshape(-1, 1).astype(np.float64)

    def plane_rms(p):
        c = p - p.mean(0)
        return np.linalg.svd(c, full_matrices=False)[1][-1] / np.sqrt(len(c))

    assert plane_rms(rays * d) < 0.004
    assert plane_rms(rays / np.linalg.norm(rays, axis=1, keepdims=True) * d) > 0.05


@needs_kernel
@pytest.mark.parametrize("name", ["Teddy", "Cones"])
def test_middlebury_warp_has_no_subpixel_offset(bench, name):
    # The right view from the left: shifting our result horizontally by -0.25 ... +0.25 px
    # (cubic resampling) never beats the unshifted result by more than 0.15 dB (measured: the
    # best shift is -0.125 px on Teddy, +0.11 dB, i.e. an offset under 0.1 px; 0 on Cones), so
    # there is no half-pixel convention error. A 0.25 px shift costs 0.2-0.9 dB.
    _need(f"middlebury/{name}")
    pytest.importorskip("scipy")
    from scipy.ndimage import shift
    from ibrtools.formats import load
    from ibrtools.imageio import linear_to_srgb

    scene = load(DATA / "middlebury" / name, "middlebury")
    truth = scene.view("right")
    color, hole, _, _ = bench._render(bench._sub(scene, ["left"]), ["left"], truth.camera)
    m = bench.visible_in_both_right(scene) & ~hole
    m[:, :2] = m[:, -2:] = False
    g, t = linear_to_srgb(color), linear_to_srgb(truth.color)

    def psnr(dx):
        s = np.stack([shift(g[..., k], (0, dx), order=3, mode="nearest") for k in range(3)], -1)
        return 10 * np.log10(1 / ((s - t) ** 2).mean(-1)[m].mean())

    p0 = psnr(0.0)
    others = {dx: psnr(dx) for dx in (-0.25, -0.125, 0.125, 0.25)}
    assert max(others.values()) < p0 + 0.15, others
    assert max(others[-0.25], others[0.25]) < p0, others


@needs_kernel
def test_blend_space_srgb_caches_only_the_selected_views():
    # The encoded colours are cached per input view, for the views of the current selection
    # only: memory stays at k encoded copies whatever the number of inputs or frames.
    views = []
    for i in range(3):
        cam = Camera.from_fov(24, 18, 60, look_at((0.6 * i, 0, -2), (0.6 * i, 0, 0)))
        views.append(View.create(f"v{i}", cam, color=np.full((18, 24, 3), 0.2 * (i + 1), np.float32),
                                 depth=np.full((18, 24), 2.0, np.float32)))
    m = DibrMethod({"inputs": 1, "blend_space": "srgb"})
    m.prepare(Scene(views=views))
    for i in (0, 2, 1):
        out, _ = m.render(views[i].camera)
        assert m.frame_report()["selected"] == [f"v{i}"]
        assert list(m._encoded) == [i]
        np.testing.assert_allclose(out["color"][4:-4, 4:-4], 0.2 * (i + 1), rtol=1e-5)


# --- depth de-quantisation of the nerf importer (option depth_dequantize) -----------------------
def test_dequantize_codes_turns_terraces_into_ramps():
    # A plane stored as rounded 8-bit codes (slopes of 0.1 and 0.3 code per pixel: terraces 10
    # and 3 px wide) has an RMS error of 1/sqrt(12) = 0.29 code. Three rounds bring it under
    # 0.15 (measured 0.139 and 0.035); the interior is scored (the border rows see fewer
    # neighbours). Every value stays inside the rounding bin of its stored code.
    from ibrtools.formats.nerf import dequantize_codes

    y, x = np.mgrid[0:40, 0:60]
    inner = (slice(3, -3), slice(3, -3))
    for slope in (0.1, 0.3):
        truth = 100 + slope * x + 0.5 * slope * y
        v = np.rint(truth).astype(np.uint8)
        d = dequantize_codes(v, 255.0, 3)
        assert d.dtype == np.float32 and d.shape == v.shape
        rms = lambda a: float(np.sqrt(((a - truth)[inner] ** 2).mean()))  # noqa: E731
        assert rms(v) > 0.28 and rms(d) < 0.15
        assert np.all(np.abs(d - v) <= 0.5)


def test_dequantize_codes_keeps_edges_unknowns_and_flat_regions():
    # A step of 5 codes between two flat regions is a depth edge: nothing is smoothed across it,
    # so both sides stay exactly flat; codes 0 and vmax (unknown depth) are left as they are and
    # never pull their neighbours; 0 rounds return the codes unchanged.
    from ibrtools.formats.nerf import dequantize_codes

    v = np.full((12, 16), 100, np.uint16)
    v[:, 8:] = 105
    v[0, 0], v[5, 5], v[11, 15] = 0, 65535, 0
    d = dequantize_codes(v, 65535.0, 20)
    np.testing.assert_array_equal(d, v.astype(np.float32))
    ramp = np.rint(np.linspace(1, 9, 48)).reshape(6, 8)
    np.testing.assert_array_equal(dequantize_codes(ramp.astype(np.uint8), 255.0, 0), ramp.astype(np.float32))


def test_dequantize_bad_input(tmp_path):
    from ibrtools.errors import DtypeError, ShapeError
    from ibrtools.formats import nerf

    v = np.full((4, 5), 9, np.uint8)
    for bad in (-1, 1.5, True, "3", None):
        with pytest.raises(BadValueError, match="depth_dequantize"):
            nerf.dequantize_codes(v, 255.0, bad)
    with pytest.raises(ShapeError, match=r"\(H, W\)"):
        nerf.dequantize_codes(np.zeros((4, 5, 1), np.uint8), 255.0, 1)
    # the importer option is checked before any file is read
    with pytest.raises(BadValueError, match="depth_dequantize"):
        nerf.load(tmp_path, {"depth_dequantize": "-2"})
    with pytest.raises(DtypeError, match="depth_dequantize"):
        nerf.load(tmp_path, {"depth_dequantize": "many"})


def test_lego_dequantized_depth_stays_in_the_stored_bins():
    # Real data: every de-quantised lego depth lies within half a code step of the depth the
    # stored code encodes (the step is 8/255 along the ray; z = ray * cos, so the bound is taken
    # on the ray distance), background stays unknown (0), and the notes say what was done.
    _need("nerf_lego")
    from ibrtools.formats import load
    from ibrtools.imageio import read_pixels

    plain = load(DATA / "nerf_lego", "nerf", {"split": "test", "depth_dequantize": 0}).view("r_0")
    scene = load(DATA / "nerf_lego", "nerf", {"split": "test", "depth_dequantize": 3})
    deq = scene.view("r_0")
    assert "de-quantised (3 rounds)" in scene.source["notes"]
    codes, _ = read_pixels(DATA / "nerf_lego" / "test" / "r_0_depth_0001.png")
    x, y = plain.camera.pixel_grid()
    r = plain.camera.rays_in_cam(x, y)
    to_ray = np.linalg.norm(r, axis=-1) / r[..., 2]
    known = codes[..., 0] > 0
    for v in (deq, plain):  # code 0: the background at infinity
        assert np.array_equal(np.isfinite(v.depth) & (v.depth > 0), known) and np.isposinf(v.depth[~known]).all()
    diff = np.abs(deq.depth - plain.depth) * to_ray
    assert diff[known].max() <= 0.5 * 8 / 255 * (1 + 1e-4) and diff[known].mean() > 1e-3
    # the lego depth PNGs are 8-bit: the default (auto) de-quantises them with AUTO_DEQUANTIZE's 5 rounds
    auto = load(DATA / "nerf_lego", "nerf", {"split": "test"})
    np.testing.assert_array_equal(auto.view("r_0").depth,
                                  load(DATA / "nerf_lego", "nerf", {"split": "test", "depth_dequantize": 5}).view("r_0").depth)
    assert "auto (8-bit: 5 rounds" in auto.source["notes"]


@needs_kernel
def test_lego_dequantized_depth_improves_the_weak_view(bench):
    # docs/dibr_accuracy.md, "lego": held-out r_100 (nearest inputs 1.25 units away, where the
    # 8-bit depth steps misregister most) measured 20.83 dB on object pixels (RVS protocol) with
    # the stored codes and 22.75 dB with depth_dequantize=5. The floor asks for +1 dB.
    _need("nerf_lego")
    plain = bench.lego(DATA, heldout=("r_100",), options={"depth_dequantize": 0})["object"]["filled"]
    deq = bench.lego(DATA, heldout=("r_100",), options={"depth_dequantize": 5})["object"]["filled"]
    assert deq > plain + 1.0, (plain, deq)


# --- per-view weights: WarpOptions.view_weight (kernel) and distance_exponent (DibrMethod) -------
def _plane_cam(x: float = 0.0) -> Camera:
    return Camera.from_fov(24, 18, 60, look_at((x, 0, -2), (x, 0, 0)))


@needs_kernel
def test_view_weight_default_and_bad_values():
    o = _core.WarpOptions()
    assert o.view_weight == 1.0
    o.view_weight = 0.25
    assert o.view_weight == 0.25
    for bad in (0.0, -1.0, 1.5, 1e-7, float("nan"), float("inf")):
        with pytest.raises(BadValueError, match="view_weight"):
            o.view_weight = bad
    assert o.view_weight == 0.25


@pytest.mark.asan
@needs_kernel
def test_view_weight_scales_the_fragment_weights(isa):
    # forward_warp's weight output is (q / d)^p times the factor (a power of two: exact), colour
    # and depth are unchanged, uncovered pixels stay 0.
    rng = np.random.default_rng(5)
    color = rng.uniform(0, 1, (18, 24, 3)).astype(np.float32)
    depth = (2.0 + 0.3 * rng.uniform(0, 1, (18, 24))).astype(np.float32)
    src, dst = _plane_cam().to_core(), _plane_cam(0.1).to_core()
    o1, o4 = _core.WarpOptions(), _core.WarpOptions()
    o4.view_weight = 0.25
    c1, d1, w1 = _core.forward_warp(color, depth, src, dst, o1)
    c4, d4, w4 = _core.forward_warp(color, depth, src, dst, o4)
    np.testing.assert_array_equal(c1, c4)
    np.testing.assert_array_equal(d1, d4)
    assert (w1 > 0).sum() > 0.5 * w1.size
    np.testing.assert_array_equal(w4, 0.25 * w1)


@pytest.mark.asan
@needs_kernel
def test_view_weight_weights_the_blend(isa):
    # Two views with the same camera and depth and constant colours a, b (equal (q / d)^p): with
    # factors 1 and 1/4 the blend is (a + b / 4) / (5 / 4); confidence (the sum of q) and the
    # hole mask do not depend on the factors.
    cam = _plane_cam().to_core()
    depth = np.full((18, 24), 2.0, np.float32)
    a, b = 0.1, 0.9
    out = {}
    for f in (1.0, 0.25):
        acc = _core.DibrAccumulator(cam, 0.1, True, 0.0)
        o = _core.WarpOptions()
        acc.add_view(np.full((18, 24, 3), a, np.float32), depth, cam, o)
        o.view_weight = f
        acc.add_view(np.full((18, 24, 3), b, np.float32), depth, cam, o)
        out[f] = acc.result()
    inner = (slice(2, -2), slice(2, -2))
    np.testing.assert_allclose(out[1.0][0][inner], (a + b) / 2, rtol=1e-6)
    np.testing.assert_allclose(out[0.25][0][inner], (a + b / 4) / 1.25, rtol=1e-6)
    np.testing.assert_array_equal(out[1.0][2], out[0.25][2])
    np.testing.assert_array_equal(out[1.0][3], out[0.25][3])


def test_distance_exponent_default_and_bad_values():
    assert DibrParams.from_dict(None).distance_exponent == 0.0
    assert DibrParams.from_dict({"distance_exponent": "2"}).distance_exponent == 2.0
    for bad in (-1, "far", True, float("nan"), 17):
        with pytest.raises(BadValueError, match="distance_exponent"):
            DibrMethod({"distance_exponent": bad})


def test_distance_exponent_view_factors():
    # (b_min / b_i)^beta by the camera centres' distances to the target (1, 2, 4 here); 0 = all 1;
    # an input at the target's own centre gets 1 and the others the floor 1e-6.
    target = Camera.from_fov(24, 18, 60, look_at((0, 0, -2), (0, 0, 0)))
    views = [View.create(f"v{i}", Camera.from_fov(24, 18, 60, look_at((x, 0, -2), (x, 0, 0))),
                         color=np.zeros((18, 24, 3), np.float32), depth=np.full((18, 24), 2.0, np.float32))
             for i, x in enumerate((2.0, 1.0, 4.0, 0.0))]
    m = DibrMethod({"distance_exponent": 1})
    m.prepare(Scene(views=views))
    np.testing.assert_allclose(m.view_factors(target, [0, 1, 2]), [0.5, 1.0, 0.25])
    m.params = m.params.replace(distance_exponent=2.0)
    np.testing.assert_allclose(m.view_factors(target, [0, 1, 2]), [0.25, 1.0, 0.0625])
    assert m.view_factors(target, [3, 1]) == [1.0, 1e-6]
    m.params = m.params.replace(distance_exponent=0.0)
    assert m.view_factors(target, [0, 1, 2]) == [1.0, 1.0, 1.0]


@needs_kernel
def test_distance_exponent_favours_the_nearer_view():
    # Two inputs 0.01 and 0.03 units from the target, both fronto-parallel views of the same plane,
    # constant colours a (near) and b (far), blended in linear light: beta = 1 blends
    # (a + b / 3) / (4 / 3) where both cover the pixel; beta = 0 (RVS) weights them by (q / d)^p
    # alone (equal here: same depth).
    target = Camera.from_fov(24, 18, 40, look_at((0, 0, -4), (0, 0, 0)))
    depth = np.full((18, 24), 4.0, np.float32)
    a, b = 0.1, 0.9
    views = [View.create("near", Camera.from_fov(24, 18, 40, look_at((0.01, 0, -4), (0.01, 0, 0))),
                         color=np.full((18, 24, 3), a, np.float32), depth=depth),
             View.create("far", Camera.from_fov(24, 18, 40, look_at((0.03, 0, -4), (0.03, 0, 0))),
                         color=np.full((18, 24, 3), b, np.float32), depth=depth)]
    inner = (slice(3, -3), slice(3, -3))
    for beta, want in ((0, (a + b) / 2), (1, (a + b / 3) / (4 / 3))):
        m = DibrMethod({"inputs": ["near", "far"], "distance_exponent": beta, "blend_space": "linear"})
        m.prepare(Scene(views=views))
        out, _ = m.render(target)
        assert m.frame_report().get("view_factors") == (None if beta == 0 else [1.0, pytest.approx(1 / 3, rel=1e-5)])
        assert not out["hole"][inner].any()
        np.testing.assert_allclose(out["color"][inner], want, rtol=1e-4)


@needs_kernel
def test_lego_distance_weights_favour_the_near_duplicate_input(bench):
    # docs/dibr_accuracy.md, "lego": held-out r_50 has r_150 0.09 units away among its four
    # inputs (the others 1.1-1.2 units). Measured on object pixels (RVS protocol): 28.82 dB with
    # RVS's equal view weights, 31.84 dB with distance_exponent = 4 (the value the validation views
    # chose). The floor asks for +2 dB.
    _need("nerf_lego")
    plain = bench.lego(DATA, heldout=("r_50",))["object"]["filled"]
    near = bench.lego(DATA, {"distance_exponent": 4}, heldout=("r_50",))["object"]["filled"]
    assert near > plain + 2.0, (plain, near)
