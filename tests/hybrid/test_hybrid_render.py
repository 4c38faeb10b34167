"""Hybrid rendering: TM, per-pixel ULR, the hybrid selection and composite
(cpp/kernels/hybrid/ulr.h, cpp/kernels/hybrid/hybrid.h, python/ibrtools/hybrid/method.py)."""
from __future__ import annotations

import copy
import importlib.util
import math

import numpy as np
import pytest

from ibrtools import _core, look_at
from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, DtypeError, InputError, MissingFileError, ShapeError
from ibrtools.hybrid.pvm_render import PvmParams
from ibrtools.hybrid.method import SELECTION_COLORS

pytestmark = [pytest.mark.asan, pytest.mark.kernel]

HAVE_PVM = importlib.util.find_spec("ibrtools.hybrid.pvm_render") is not None
needs_pvm = pytest.mark.skipif(not HAVE_PVM, reason="ibrtools.hybrid.pvm_render (PVM rendering) not built yet")


# ---- the shared ULR header -------------------------------------------------------------------
def test_ulr_penalty_hand_checked():
    # 45 degrees between the rays, view sqrt(2) times farther: pi/4 + 0.5 * (sqrt(2) - 1).
    p = _core.ulr_penalty([0, 0, 0], [0, 0, 1], [1, 0, 1])
    assert p == pytest.approx(math.pi / 4 + 0.5 * (math.sqrt(2) - 1), abs=1e-6)
    # A closer view has no resolution penalty; the same direction has no angle.
    assert _core.ulr_penalty([0, 0, 0], [0, 0, 2], [0, 0, 1]) == pytest.approx(0.0, abs=1e-6)
    assert math.isinf(_core.ulr_penalty([0, 0, 0], [0, 0, 0], [0, 0, 1]))
    assert math.isinf(_core.ulr_penalty([0, 0, 0], [0, 0, 1], [0, 0, float("nan")]))


def test_fast_penalty_matches_the_header():
    """The per-pixel kernel's penalty (polynomial atan2, Abramowitz-Stegun 4.4.49, max error
    1e-5 rad) against UlrPenalty: within 2e-5 (the polynomial's error plus float rounding)."""
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(3000):
        p, a, b = rng.normal(size=(3, 3)) * rng.choice([0.01, 1.0, 100.0])
        worst = max(worst, abs(_core.ulr_penalty(p, a, b) - _core.ulr_penalty(p, a, b, fast=True)))
    assert worst < 2e-5
    assert math.isinf(_core.ulr_penalty([0, 0, 0], [0, 0, 0], [0, 0, 1], fast=True))
    # Opposite directions: pi.
    assert _core.ulr_penalty([0, 0, 0], [0, 0, 1], [0, 0, -1], fast=True) == pytest.approx(math.pi, abs=2e-5)


def test_ulr_select_k_best_weights_to_zero_at_kth():
    pen = np.array([0.3, np.inf, 0.1, 0.3, 0.2, 0.05], np.float32)
    idx, w = _core.ulr_select(pen, 4)
    assert idx == [5, 2, 4, 0]  # ties: lower index first (0 before 3)
    # thresh = the 4th smallest (0.3): w = 1 - p / 0.3, normalised; the 4th gets 0.
    raw = np.array([1 - 0.05 / 0.3, 1 - 0.1 / 0.3, 1 - 0.2 / 0.3, 0.0])
    np.testing.assert_allclose(w, raw / raw.sum(), atol=1e-6)
    # Fewer finite than k: every kept view keeps a positive weight.
    idx, w = _core.ulr_select(np.array([0.2, 0.4], np.float32), 4)
    assert idx == [0, 1] and min(w) > 0 and sum(w) == pytest.approx(1.0)
    # All zero penalties: uniform, never NaN; none finite: nothing.
    idx, w = _core.ulr_select(np.zeros(5, np.float32), 4)
    assert idx == [0, 1, 2, 3] and w == pytest.approx([0.25] * 4)
    assert _core.ulr_select(np.full(3, np.inf, np.float32), 4) == ([], [])


# ---- per-pixel ULR on a hand-made plane ------------------------------------------------------
def _plane_setup(size=(41, 31)):
    """A novel camera and two input views looking at the plane z = 5 from x = -0.5 / +0.5."""
    w, h = size
    novel = Camera.from_fov(w, h, 40, look_at([0, 0, 0], [0, 0, 5]))
    cams = [Camera.from_fov(w, h, 40, look_at([x, 0, 0], [x, 0, 5])) for x in (-0.5, 0.5)]
    gdepth = np.full((h, w), 5.0, np.float32)
    views = []
    for i, c in enumerate(cams):
        col = np.zeros((h, w, 3), np.float32)
        col[..., i] = 1.0  # view 0 red, view 1 green
        views.append((c.to_core(), col, np.full((h, w), 5.0, np.float32)))
    return novel, gdepth, views


def test_ulr_blends_visible_views_and_drops_occluded_ones():
    novel, gdepth, views = _plane_setup()
    color, count = _core.ulr_blend(novel.to_core(), gdepth, views)
    # Two views of equal penalty at the centre pixel (odd size: its centre is on the axis): with
    # fewer than k finite penalties both keep a positive weight, equal there.
    h, w = gdepth.shape
    c = color[h // 2, w // 2]
    assert count[h // 2, w // 2] == 2 and c[0] == pytest.approx(c[1], abs=0.05) and c.sum() == pytest.approx(1.0)
    assert not np.isnan(color).any()
    # View 1 (green) sees an occluder at z = 2 in front of the plane: it must not contribute.
    occluded = (views[1][0], views[1][1], np.full((h, w), 2.0, np.float32))
    color, count = _core.ulr_blend(novel.to_core(), gdepth, [views[0], occluded])
    hit = count > 0
    assert hit.mean() > 0.5
    np.testing.assert_allclose(color[hit], np.tile([1, 0, 0], (hit.sum(), 1)), atol=1e-6)
    # Within the relative tolerance (2 %), the view still counts; beyond it, not.
    near = (views[1][0], views[1][1], np.full((h, w), 5.0 * 1.015, np.float32))
    _, count = _core.ulr_blend(novel.to_core(), gdepth, [near], depth_tol=0.02)
    assert (count > 0).mean() > 0.5
    _, count = _core.ulr_blend(novel.to_core(), gdepth, [near], depth_tol=0.01)
    assert (count == 0).all()


def test_ulr_pixel_mask_and_no_surface():
    novel, gdepth, views = _plane_setup()
    gdepth[:, :5] = 0  # no surface there
    mask = np.zeros(gdepth.shape, bool)
    mask[10:20, 10:20] = True
    color, count = _core.ulr_blend(novel.to_core(), gdepth, views, pixel_mask=mask)
    assert (count[~mask] == 0).all() and (color[~mask] == 0).all() and (count[mask] > 0).all()
    color, count = _core.ulr_blend(novel.to_core(), gdepth, views)
    assert (count[:, :5] == 0).all() and (color[:, :5] == 0).all()


def test_ulr_back_facing_views_are_skipped():
    novel, gdepth, views = _plane_setup()
    h, w = gdepth.shape
    away = np.zeros((h, w, 3), np.float32)
    away[..., 2] = 1.0  # normal +z: facing away from every camera (they are at z = 0)
    _, count = _core.ulr_blend(novel.to_core(), gdepth, views, normal=away)
    assert (count == 0).all()
    toward = -away
    _, count = _core.ulr_blend(novel.to_core(), gdepth, views, normal=toward)
    assert (count > 0).mean() > 0.5


def test_interpolate_vertex_attribute_hand_checked():
    faces = np.array([[0, 1, 2]], np.int32)
    attrib = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
    prim = np.array([[0, -1]], np.int32)
    bary = np.array([[[0.25, 0.5], [0.3, 0.3]]], np.float32)
    out = _core.interpolate_vertex_attribute(prim, bary, faces, attrib)
    np.testing.assert_allclose(out[0, 0], [0.25, 0.25, 0.5], atol=1e-7)
    assert (out[0, 1] == 0).all()
    one = _core.interpolate_vertex_attribute(prim, bary, faces, np.array([0, 1, 2], np.float32))
    assert one.shape == (1, 2) and one[0, 0] == pytest.approx(0.25 * 1 + 0.5 * 2)
    # Barycentrics must be finite at hits (they are not read at misses).
    bad = bary.copy()
    bad[0, 1] = np.nan
    assert np.isfinite(_core.interpolate_vertex_attribute(prim, bad, faces, attrib)).all()
    bad[0, 0, 0] = np.inf
    with pytest.raises(BadValueError, match=r"bary: .*pixel \(0, 0\)"):
        _core.interpolate_vertex_attribute(prim, bad, faces, attrib)
    with pytest.raises(BadValueError, match="prim_id"):
        _core.interpolate_vertex_attribute(np.array([[1, -1]], np.int32), bary, faces, attrib)
    # Vertex indices: those of hit faces must lie in [0, N); faces no pixel hits are not read.
    faces2 = np.array([[0, 1, 2], [0, 1, 7]], np.int32)
    np.testing.assert_array_equal(_core.interpolate_vertex_attribute(prim, bary, faces2, attrib), out)
    with pytest.raises(BadValueError, match=r"faces: face 1 \(hit at pixel \(0, 1\)\) has vertex indices \(0, 1, 7\)"):
        _core.interpolate_vertex_attribute(np.array([[0, 1]], np.int32), bary, faces2, attrib)


# ---- selection, blur, composite ----------------------------------------------------------------
def test_selection_rules_of_fig7():
    g = np.array([[1.0, 1.0, 1.0, 1.0, 0.0, 1.0]], np.float32)
    inside = np.array([[False, True, True, True, True, True]])
    valid = np.array([[True, True, False, True, True, True]])
    pdepth = np.array([[0.5, 0.9, 0.0, 0.99, 0.5, 1.01]], np.float32)
    vd = np.array([[0, 0, 0.9, 0.9, 0, 0.1]], np.float32)
    lab = _core.hybrid_select(g, inside_grid=inside, pvm_valid=valid, pvm_depth=pdepth, vd=vd,
                              geo_threshold=0.03, tau_var=0.82)
    # outside -> ULR; 10 cm off -> PVM; no PVM + vd high -> ULR; 1 cm off + vd high -> ULR;
    # global misses, PVM has a surface -> PVM; 1 cm off, vd low -> TM.
    assert lab.tolist() == [[1, 2, 1, 1, 2, 0]]
    # tau_var below 0 (the method's default -1): the photometric test sends every pixel of agreeing
    # geometry to ULR, with or without a view-dependent texture (none = 0 everywhere).
    for v in (vd, None):
        lab = _core.hybrid_select(g, inside_grid=inside, pvm_valid=valid, pvm_depth=pdepth, vd=v,
                                  geo_threshold=0.03, tau_var=-1.0)
        assert lab.tolist() == [[1, 2, 1, 1, 2, 1]]
    lab = _core.hybrid_select(g, inside_grid=inside, pvm_valid=valid, pvm_depth=pdepth, geo_threshold=0.03,
                              tau_var=0.0)
    assert lab.tolist() == [[1, 2, 0, 0, 2, 0]]


def test_all_empty_candidates_fall_back_without_nan():
    """Every PVM candidate list empty: no pixel picks PVM, the composite is ULR/TM, no NaN."""
    rng = np.random.default_rng(0)
    h, w = 24, 32
    g = np.full((h, w), 2.0, np.float32)
    g[:, :4] = 0  # background
    valid = np.zeros((h, w), bool)
    pdepth = np.zeros((h, w), np.float32)
    vd = rng.random((h, w)).astype(np.float32)
    lab = _core.hybrid_select(g, inside_grid=np.ones((h, w), bool), pvm_valid=valid, pvm_depth=pdepth, vd=vd)
    assert not (lab == 2).any() and (lab[:, :4] == 3).all()
    wts = _core.blur_selection(lab, 4.0)
    assert not np.isnan(wts).any() and wts[..., 2].max() == 0
    tm = rng.random((h, w, 3)).astype(np.float32)
    ulr = np.full((h, w, 3), np.nan, np.float32)  # never read where count == 0
    count = np.zeros((h, w), np.uint8)
    pvm = np.full((h, w, 3), np.nan, np.float32)
    out = _core.hybrid_composite(wts, tm, ulr=ulr, ulr_count=count, pvm=pvm, pvm_valid=valid)
    assert not np.isnan(out).any()
    s = wts.sum(-1)
    np.testing.assert_allclose(out[s > 0], tm[s > 0], atol=1e-6)  # ULR without a view -> TM


def test_blur_selection_normalised_and_sigma_zero_is_one_hot():
    lab = np.zeros((10, 12), np.uint8)
    lab[:, 6:] = 2
    lab[0, 0] = 3
    hard = _core.blur_selection(lab, 0.0)
    assert (hard[1:, :6, 0] == 1).all() and (hard[:, 6:, 2] == 1).all() and (hard[0, 0] == 0).all()
    soft = _core.blur_selection(lab, 2.0)
    np.testing.assert_allclose(soft.sum(-1), 1.0, atol=1e-5)
    assert 0 < soft[5, 5, 2] < 0.5 < soft[5, 6, 2] < 1


@pytest.mark.parametrize("sigma", [1.5, 16.0])
def test_blur_selection_matches_a_float64_separable_reference(sigma):
    """The blur's SIMD passes (AVX2 eight columns at a time when the CPU has it, with the row tails
    scalar: a width of 45 exercises the 32-, 8- and 1-column loops; sigma 16 has a radius of 48 > H,
    W, so edge clamping covers the whole window) against scipy's correlate1d (mode 'nearest' =
    edge-clamped) of the one-hot planes in float64 with the same float32 taps. Tolerance 2e-6: float32
    sums of up to 97 x 97 terms against float64. The support (weight > 0, where ULR / PVM are
    computed) must be identical."""
    from scipy.ndimage import correlate1d

    rng = np.random.default_rng(3)
    lab = rng.integers(0, 4, size=(37, 45)).astype(np.uint8)
    lab[5:20, 10:30] = 0  # runs as well as noise
    r = math.ceil(3 * sigma)
    d = np.arange(-r, r + 1, dtype=np.float32)
    taps = np.exp(np.float32(-0.5) * d * d / np.float32(sigma * sigma)).astype(np.float64)
    planes = np.stack([(lab == c) for c in range(3)], -1).astype(np.float64)
    ref = correlate1d(correlate1d(planes, taps, axis=0, mode="nearest"), taps, axis=1, mode="nearest")
    s = ref.sum(-1, keepdims=True)
    ref = np.divide(ref, s, out=np.zeros_like(ref), where=s > 0)
    out = _core.blur_selection(lab, sigma)
    np.testing.assert_allclose(out, ref, atol=2e-6)
    np.testing.assert_array_equal(out > 0, ref > 0)


def test_outside_grid_is_ulr_only():
    h, w = 8, 8
    g = np.full((h, w), 3.0, np.float32)
    lab = _core.hybrid_select(g, inside_grid=np.zeros((h, w), bool), pvm_valid=np.ones((h, w), bool),
                              pvm_depth=np.ones((h, w), np.float32), vd=np.zeros((h, w), np.float32))
    assert (lab == 1).all()
    wts = _core.blur_selection(lab, 4.0)
    np.testing.assert_allclose(wts[..., 1], 1.0)


def test_ulr_blend_releases_the_gil():
    from gil import runs_python_during

    novel, gdepth, views = _plane_setup((641, 481))
    many = views * 8  # 16 views: long enough a run to sample
    assert runs_python_during(lambda: _core.ulr_blend(novel.to_core(), gdepth, many), min_span=0.0)


# ---- bad input ---------------------------------------------------------------------------------
def test_kernels_bad_input():
    novel, gdepth, views = _plane_setup()
    cam = novel.to_core()
    with pytest.raises(ShapeError):
        _core.ulr_blend(cam, gdepth[:, :-1], views)
    with pytest.raises(DtypeError):
        _core.ulr_blend(cam, gdepth.astype(np.float64), views)
    with pytest.raises(DtypeError):
        _core.ulr_blend(cam, gdepth, [views[0][1]])
    with pytest.raises(ShapeError):
        _core.ulr_blend(cam, gdepth, [(views[0][0], views[0][1][:-1], views[0][2])])
    with pytest.raises(BadValueError):
        _core.ulr_blend(cam, gdepth, views, k=0)
    with pytest.raises(BadValueError):
        _core.ulr_blend(cam, gdepth, views, depth_tol=float("nan"))
    with pytest.raises(ShapeError):
        _core.ulr_blend(cam, gdepth, views, pixel_mask=np.ones((3, 3), bool))
    faces = np.array([[0, 1, 5]], np.int32)
    with pytest.raises(BadValueError):
        _core.interpolate_vertex_attribute(np.zeros((1, 1), np.int32), np.zeros((1, 1, 2), np.float32), faces,
                                           np.zeros((3, 3), np.float32))
    with pytest.raises(BadValueError):
        _core.interpolate_vertex_attribute(np.full((1, 1), 4, np.int32), np.zeros((1, 1, 2), np.float32),
                                           faces[:, :] * 0, np.zeros((3, 3), np.float32))
    with pytest.raises(BadValueError):
        _core.hybrid_select(gdepth, pvm_valid=np.ones(gdepth.shape, bool))
    with pytest.raises(BadValueError):
        _core.hybrid_select(gdepth, geo_threshold=-1)
    with pytest.raises(BadValueError):
        _core.blur_selection(np.full((2, 2), 7, np.uint8), 1.0)
    with pytest.raises(BadValueError):
        _core.blur_selection(np.zeros((2, 2), np.uint8), -1.0)
    for mw in (-0.1, 0.5, float("nan")):
        with pytest.raises(BadValueError, match="min_weight"):
            _core.blur_selection(np.zeros((2, 2), np.uint8), 1.0, mw)
    with pytest.raises(ShapeError):
        _core.hybrid_composite(np.zeros((2, 2, 3), np.float32), np.zeros((2, 3, 3), np.float32))
    with pytest.raises(BadValueError):
        _core.hybrid_composite(np.zeros((2, 2, 3), np.float32), np.zeros((2, 2, 3), np.float32),
                               ulr=np.zeros((2, 2, 3), np.float32))


def test_hybrid_needs_and_frame_outputs_match_numpy():
    """The masks and outputs the hybrid frame computes in C++ against their NumPy definitions,
    on random weights (with exact zeros), labels and depths, sizes past the row grain."""
    rng = np.random.default_rng(5)
    h, w = 37, 61
    weights = rng.random((h, w, 3)).astype(np.float32)
    weights[rng.random((h, w, 3)) < 0.4] = 0.0
    weights[:5] = 0.0
    valid = rng.random((h, w)) < 0.6
    label = rng.integers(0, 4, (h, w)).astype(np.uint8)
    gdepth = rng.random((h, w)).astype(np.float32)
    pdepth = rng.random((h, w)).astype(np.float32)
    need_ulr, need_pvm, n_ulr, n_pvm = _core.hybrid_needs(weights, valid)
    ref_ulr = (weights[..., 1] > 0) | ((weights[..., 2] > 0) & ~valid)
    ref_pvm = (weights[..., 2] > 0) & valid
    np.testing.assert_array_equal(need_ulr, ref_ulr)
    np.testing.assert_array_equal(need_pvm, ref_pvm)
    assert (n_ulr, n_pvm) == (int(ref_ulr.sum()), int(ref_pvm.sum()))
    fo = _core.hybrid_frame_outputs(label, weights, gdepth, pdepth)
    np.testing.assert_array_equal(fo["hole"], label == 3)
    np.testing.assert_array_equal(fo["depth"], np.where(label == 2, pdepth, gdepth))
    np.testing.assert_array_equal(fo["selection"], np.where((label == 3)[..., None], 0, weights @ SELECTION_COLORS))
    assert fo["label_counts"] == tuple(int((label == i).sum()) for i in range(4))
    with pytest.raises(BadValueError, match="label"):
        _core.hybrid_frame_outputs(np.full((h, w), 4, np.uint8), weights, gdepth, pdepth)
    with pytest.raises(ShapeError, match="pvm_depth"):
        _core.hybrid_frame_outputs(label, weights, gdepth, pdepth[:, :-1])
    with pytest.raises(ShapeError, match="pvm_valid"):
        _core.hybrid_needs(weights, valid[:-1])


def test_method_params_and_missing_stages(tmp_path):
    from ibrtools import methods
    from ibrtools.scene import Scene

    with pytest.raises(BadValueError, match="no parameter"):
        methods.create("ulr", {"magic": 1})
    with pytest.raises(BadValueError, match="k"):
        methods.create("ulr", {"k": 0})
    with pytest.raises(BadValueError, match="depth_tol"):
        methods.create("ulr", {"depth_tol": -1})
    for method in ("ulr", "hybrid"):
        with pytest.raises(BadValueError, match="resample: expected 'cubic' or 'bilinear', got 'lanczos'"):
            methods.create(method, {"resample": "lanczos"})
    assert methods.create("hybrid", {"resample": "bilinear"}).params.resample == "bilinear"
    # The hybrid's PVM parameters go through the PVM renderer's checks.
    for bad, name in (({"free_space_tol": 1.5}, "free_space_tol"), ({"free_space": "sometimes"}, "free_space"),
                      ({"free_space_point_tol": -0.01}, "free_space_point_tol"), ({"tau_empty": -1}, "tau_empty"),
                      ({"sigma": 0}, "sigma"), ({"tau_depth": -1}, "tau_depth"), ({"min_weight": 0.4}, "min_weight"),
                      ({"max_angle": 0}, "max_angle"), ({"max_angle": 200}, "max_angle"), ({"merge_rel": -0.1}, "merge_rel")):
        with pytest.raises(BadValueError, match=name):
            methods.create("hybrid", bad)
    assert methods.create("hybrid", {"free_space": "false"}).params.free_space is False
    hp = methods.create("hybrid").params  # the hybrid's PVM defaults are the PVM renderer's
    assert hp.max_angle == PvmParams.max_angle and hp.merge_rel == PvmParams.merge_rel
    assert methods.create("hybrid", {"max_angle": "40", "merge_rel": 0.04}).params.max_angle == 40.0
    m = methods.create("tm")
    with pytest.raises(InputError, match="ibr-preprocess"):
        m.prepare(Scene(views=[], targets=[]))
    # A scene directory without the stage: the error names the command.
    from ibrtools import synth
    from ibrtools.formats import native

    sc = synth.make_scene("objects", size=(32, 24), views=2, holdout_targets=1)
    native.save(sc, tmp_path / "s")
    with pytest.raises(MissingFileError, match="ibr-preprocess .* --methods tm"):
        methods.create("tm").prepare(native.load(tmp_path / "s"))


# ---- end to end on a preprocessed scene whose global mesh is exact -------------------------
@pytest.fixture(scope="module")
def exact_scene(tmp_path_factory):
    from ibrtools.pipeline import stages as S
    from ibrtools import cache
    d = tmp_path_factory.mktemp("hybrid") / "scene"
    methods_ = ["tm", "ulr"] + (["hybrid"] if HAVE_PVM else [])
    S.preprocess("synth:objects", d, synth={"preset": "objects", "size": [96, 72], "views": 6, "seed": 0,
                                            "reconstructed": False, "holdout_targets": 2},
                 methods=methods_, stage_options={"mesh": {"source": "ground_truth", "resolution": 128}})
    from ibrtools.formats import native

    return native.load(d)


def _diffuse_seen(scene, camera, views_cams):
    """Pixels on diffuse objects (ks = 0) of the ground truth that some input view sees."""
    from ibrtools.raycast.reference import ReferenceRenderer, Light

    gt = scene.meshes["ground_truth"]
    lights = [Light(kind=d["kind"], vector=tuple(d["vector"]), color=tuple(d["color"]),
                    shadows=bool(d.get("shadows", True))) for d in scene.lights]
    r = ReferenceRenderer(gt).render(camera, outputs=("color", "object_id"), lights=lights,
                                     ambient=scene.shading.get("ambient", 0.15))
    oid = r["object_id"]
    diffuse = (oid >= 0) & (gt.materials[np.clip(oid, 0, None), 0] == 0)
    return r["color"], diffuse


def test_exact_mesh_tm_ulr_match_reference_on_diffuse(exact_scene):
    from ibrtools import methods

    tm, ulr = methods.create("tm"), methods.create("ulr")
    tm.prepare(exact_scene)
    ulr.prepare(exact_scene)
    assert tm._gm.atlas is not None  # TM reads the texture atlas (a small mesh: within the cap)
    for t in exact_scene.targets:
        ref, diffuse = _diffuse_seen(exact_scene, t.camera, None)
        o_tm, times = tm.render(t.camera)
        o_ulr, _ = ulr.render(t.camera)
        assert set(times) == {"gbuffer", "tm_shade"}
        gb = ulr._gm.gbuffer(t.camera)
        _, count = _core.ulr_blend(t.camera.to_core(), gb["depth"], ulr._views, normal=gb["normal"])
        sel = diffuse & (count > 0)  # parts of the ground no input sees have no colour to match
        assert sel.mean() > 0.4
        # Tolerances (linear RGB, mean over channels): measured 0.017 (TM) and 0.011 (ULR) mean,
        # 0.007 / 0.003 median at 96x72. The residual is resampling, not geometry: ULR reads
        # the 96x72 inputs bilinearly across checkerboard edges, TM interpolates per-vertex
        # colour (vertex spacing = extent / 128) across them. Bounds ~2x the measured values.
        for name, out, mean_tol, med_tol in (("tm", o_tm, 0.035, 0.015), ("ulr", o_ulr, 0.025, 0.008)):
            e = np.abs(out["color"] - ref).mean(-1)[sel]
            assert e.mean() < mean_tol and np.median(e) < med_tol, (name, e.mean(), np.median(e))
        assert np.abs(o_tm["color"] - o_ulr["color"]).mean(-1)[sel].mean() < 0.025
        assert not np.isnan(o_ulr["color"]).any()


def test_ulr_method_tm_fallback_equals_the_frame_wide_choice(exact_scene):
    """UlrMethod reads TM only at the hits no view sees and writes it into the ULR image in place:
    the image is np.where(seen, ULR, TM of the whole frame), bit for bit. One input view only, so
    that many hits are unseen."""
    from ibrtools import methods

    ulr = methods.create("ulr")
    ulr.prepare(exact_scene)
    ulr._views = ulr._views[:1]
    cam = exact_scene.targets[0].camera
    out, _ = ulr.render(cam)
    gb = ulr._gm.gbuffer(cam)
    c, n = _core.ulr_blend(cam.to_core(), gb["depth"], ulr._views, normal=gb["normal"])
    seen = n > 0
    assert (gb["hit"] & ~seen).sum() > 20 and seen.sum() > 20
    np.testing.assert_array_equal(out["color"], np.where(seen[..., None], c, ulr._gm.tm_color(gb)))
    np.testing.assert_array_equal(out["hole"], ~gb["hit"])


@needs_pvm
def test_exact_mesh_hybrid_matches_reference_on_diffuse(exact_scene):
    from ibrtools import methods

    hy = methods.create("hybrid")
    hy.prepare(exact_scene)
    for t in exact_scene.targets:
        ref, diffuse = _diffuse_seen(exact_scene, t.camera, None)
        out, times = hy.render(t.camera)
        assert out["selection"].shape == out["color"].shape and not np.isnan(out["color"]).any()
        e = np.abs(out["color"] - ref).mean(-1)[diffuse & ~out["hole"]]
        assert np.median(e) < 0.015, np.median(e)


@needs_pvm
@pytest.mark.parametrize("tau_var", [-1.0, 0.0])
def test_hybrid_tm_shaded_where_read_equals_the_full_frame_shade(exact_scene, monkeypatch, tau_var):
    # TM is shaded only at the pixels the composite reads (a TM weight, or ULR's fallback where no
    # view sees the point) when they are few; the frame is the one a full-frame shade gives, bit for bit.
    from ibrtools.hybrid import method as H
    from ibrtools import methods

    t = exact_scene.targets[0]
    frames = {}
    for share in (0.0, 1.0):  # 0: always the full frame; 1: always the subset
        monkeypatch.setattr(H, "TM_SUBSET_MAX", share)
        hy = methods.create("hybrid", {"tau_var": tau_var})
        hy.prepare(exact_scene)
        frames[share], _ = hy.render(t.camera)
    for k in ("color", "selection", "hole", "depth"):
        np.testing.assert_array_equal(frames[0.0][k], frames[1.0][k])
    assert 0 < hy.frame_report()["tm_pixels"] < t.camera.width * t.camera.height or tau_var == 0.0


def test_geo_threshold_default_by_units_and_voxel(exact_scene):
    # 3 cm in a length unit; one voxel of the global mesh where the units are not a length; 3 cm
    # read as metres when there is no usable voxel either. The method takes the mesh stage's voxel.
    from ibrtools import methods
    from ibrtools.hybrid.method import GEO_THRESHOLD_VOXELS, geo_threshold_for

    assert geo_threshold_for("m") == pytest.approx(0.03) and geo_threshold_for("m", 0.5) == pytest.approx(0.03)
    assert geo_threshold_for("cm") == pytest.approx(3.0) and geo_threshold_for(" MM ") == pytest.approx(30.0)
    assert geo_threshold_for("unknown", 0.006) == pytest.approx(0.006 * GEO_THRESHOLD_VOXELS)
    assert geo_threshold_for("disparity", 0.25) == pytest.approx(0.25 * GEO_THRESHOLD_VOXELS)
    for bad in (None, 0.0, -1.0, float("nan"), float("inf")):
        assert geo_threshold_for("unknown", bad) == pytest.approx(0.03)
    if not HAVE_PVM:
        return
    hy = methods.create("hybrid")
    hy.prepare(exact_scene)
    hy.render(exact_scene.targets[0].camera)
    assert exact_scene.units == "m" and hy.frame_report()["geo_threshold"] == pytest.approx(0.03)
    unitless = copy.copy(exact_scene)
    unitless.units = "unknown"
    hy.prepare(unitless)
    hy.render(exact_scene.targets[0].camera)
    voxel = exact_scene.stages.get("mesh", {}).get("details", {}).get("voxel")
    assert voxel and hy.frame_report()["geo_threshold"] == pytest.approx(voxel * GEO_THRESHOLD_VOXELS)


@needs_pvm
def test_target_outside_grid_renders_with_ulr_only(exact_scene):
    """PVMs built from the near half of each view's depth only: the grid then covers the objects,
    not the far ground; a target looking at the far ground from outside the grid is all ULR."""
    from ibrtools.hybrid.pvm import build_tiles
    from ibrtools.hybrid.pvm_render import PvmRenderer
    from ibrtools import methods

    cams = {v.name: v.camera for v in exact_scene.views}
    near = {}
    for v in exact_scene.views:
        d = v.depth.copy()
        d[d > 6.0] = 0  # the objects stand within ~5 units of the cameras' look-at point
        near[v.name] = d
    tiles = build_tiles(cams, near)
    lo, hi = tiles.origin, tiles.origin + tiles.cell * tiles.coarse * tiles.sub
    hy = methods.create("hybrid")
    hy.prepare(exact_scene)
    hy._pvm = PvmRenderer(exact_scene, tiles=tiles)
    eye = np.array([hi[0] + 2.0, 3.0, hi[2] + 2.0])
    assert (eye > hi).any()  # the camera is outside the grid's box
    cam = Camera.from_fov(48, 36, 50, look_at(eye, [11.0, 0.0, 11.0]))
    out, _ = hy.render(cam)
    lab = out["label"]
    assert not np.isnan(out["color"]).any()
    assert (lab == 1).mean() > 0.3 and set(np.unique(lab).tolist()) <= {1, 3}
    np.testing.assert_allclose(out["selection"][lab == 1], np.tile([0, 0, 1], ((lab == 1).sum(), 1)), atol=1e-6)


@needs_pvm
def test_thin_object_missing_from_the_global_mesh_picks_pvm(tmp_path):
    """synth reconstructed=True removes the thin object (a pole) from the global mesh; the input
    depth maps (so the PVMs) have it. Its pixels must pick PVM in the selection: measured 64 %
    and 78 % of them at the two targets (the rest are its 1-2 px wide silhouette, where the
    mask blur and the PVM spatial filter mix with the background); bound 50 %."""
    from ibrtools.pipeline import stages as S
    from ibrtools import cache
    from ibrtools import synth
    from ibrtools.formats import native
    from ibrtools import methods
    from ibrtools.raycast.reference import ReferenceRenderer

    spec = {"preset": "objects", "size": [128, 96], "views": 8, "seed": 0, "reconstructed": True,
            "holdout_targets": 2}
    S.preprocess("synth:objects", tmp_path / "s", synth=spec, methods=["hybrid"],
                 stage_options={"mesh": {"resolution": 128}})
    scene = native.load(tmp_path / "s")
    _, built = synth.build_mesh("objects", size=(128, 96), views=8, seed=0, holdout_targets=2, path_frames=48,
                                extra_meshes=[])
    hy = methods.create("hybrid")
    hy.prepare(scene)
    rr = ReferenceRenderer(scene.meshes["ground_truth"])
    picked, total = 0, 0
    for t in scene.targets:
        thin = rr.render(t.camera, outputs=("object_id",))["object_id"] == built.thin_object
        out, _ = hy.render(t.camera)
        picked += int((out["label"][thin] == 2).sum())
        total += int(thin.sum())
        assert not np.isnan(out["color"]).any()
    assert total > 20 and picked / total > 0.5, (picked, total)


def test_render_job_writes_frames(exact_scene, tmp_path):
    from ibrtools.pipeline import job as J
    from ibrtools.pipeline import plan as planning
    job = planning.plan(exact_scene, holdout=["v001"])
    rep = J.run(job, "ulr", tmp_path / "out")
    f = rep["frames"][0]
    assert f["name"] == "v001" and (tmp_path / "out" / "v001.png").is_file()
    assert f["metrics"]["psnr"] > 25 and "ulr_fraction" in f
    assert rep["inputs"] == 5


@needs_pvm
def test_render_job_hybrid_writes_the_selection_mask(exact_scene, tmp_path):
    from ibrtools.imageio import read_image
    from ibrtools.pipeline import job as J
    from ibrtools.pipeline import plan as planning
    rep = J.run(planning.plan(exact_scene), "hybrid", tmp_path / "out", params={"sigma_blur": 0})
    f = rep["frames"][0]
    assert f["method_mask"] == f"{f['name']}.method.png" and set(f["selection"]) == {"tm", "ulr", "pvm", "none"}
    mask = read_image(tmp_path / "out" / f["method_mask"])
    assert mask.shape[2] == 3
    # sigma_blur 0: every pixel is pure red (PVM), green (TM), blue (ULR) or black (nothing).
    hard = np.round(mask, 3)
    assert set(map(tuple, hard.reshape(-1, 3).tolist())) <= {(1, 0, 0), (0, 1, 0), (0, 0, 1), (0, 0, 0)}
    assert "masking" in f["time_ms"] and "ulr_blend" in f["time_ms"]


# ---- pvm_floor: the composite's PVM weight floor and the mix stage that fits it -------------
def test_pvm_floor_matches_numpy_and_keeps_the_weights_normalised():
    rng = np.random.default_rng(5)
    lab = rng.integers(0, 4, size=(29, 41)).astype(np.uint8)
    lab[:, :8] = 3  # columns 0-1 lie beyond the blur's reach (radius 6): no weight there
    base = _core.blur_selection(lab, 2.0, 0.05)
    np.testing.assert_array_equal(_core.blur_selection(lab, 2.0, 0.05, pvm_floor=0.0), base)
    some = base.sum(-1) > 0
    assert not some[:, :2].any() and some[:, 2:].all()
    for f in (0.25, 1.0):
        out = _core.blur_selection(lab, 2.0, 0.05, pvm_floor=f)
        ref = base.astype(np.float64)
        live = some & (base[..., 2] < f)
        s = (1.0 - f) / (1.0 - ref[..., 2][live])
        ref[live, 0] *= s
        ref[live, 1] *= s
        ref[live, 2] = f
        np.testing.assert_allclose(out, ref, atol=1e-6)
        assert (out[~some] == 0).all()
        np.testing.assert_allclose(out.sum(-1)[some], 1.0, atol=1e-5)
        assert (out[..., 2][some] >= np.float32(f) - 1e-7).all() and live.sum() > 100
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(BadValueError, match="pvm_floor"):
            _core.blur_selection(lab, 2.0, pvm_floor=bad)


def test_pvm_floor_parameter_checks(tmp_path):
    from ibrtools.formats import native
    from ibrtools import methods
    from ibrtools import synth

    assert methods.create("hybrid").params.pvm_floor == "auto"
    assert methods.create("hybrid", {"pvm_floor": "0.3"}).params.pvm_floor == 0.3
    for bad in (1.5, -0.2, "sometimes"):
        with pytest.raises(BadValueError, match="pvm_floor"):
            methods.create("hybrid", {"pvm_floor": bad})
    # "auto" in a scene without the mix stage: the error names the command.
    sc = synth.make_scene("objects", size=(32, 24), views=2, holdout_targets=1)
    native.save(sc, tmp_path / "s")
    with pytest.raises(MissingFileError, match="stage 'mix'.*ibr-preprocess .* --methods hybrid"):
        methods.create("hybrid")._resolve_floor(native.load(tmp_path / "s"))
    assert methods.create("hybrid", {"pvm_floor": 0.2})._resolve_floor(native.load(tmp_path / "s")) == (0.2, "parameter")


@needs_pvm
def test_several_floors_in_one_frame_equal_separate_renders(exact_scene):
    # The mix stage scores every floor from one frame: the colours the largest floor needs serve the
    # smaller ones, bit for bit the frames a render at each floor gives.
    from ibrtools import methods

    t = exact_scene.targets[0]
    hy = methods.create("hybrid", {"pvm_floor": 0.0})
    hy.prepare(exact_scene)
    floors = (0.2, 0.0, 0.5)
    out, _, colors = hy._render(t.camera, floors)
    np.testing.assert_array_equal(out["color"], colors[0])
    for f, c in zip(floors, colors):
        m = methods.create("hybrid", {"pvm_floor": f})
        m.prepare(exact_scene)
        o, _ = m.render(t.camera)
        np.testing.assert_array_equal(c, o["color"])
        assert m.frame_report()["pvm_floor"] == f
    assert not np.array_equal(colors[1], colors[2])  # the floor mixes PVM in somewhere
    with pytest.raises(BadValueError, match="floors"):
        hy._render(t.camera, (0.0, 1.0))


@needs_pvm
def test_mix_stage_fit_is_what_holding_each_view_out_gives(exact_scene):
    # The stage's table against renders made the way --holdout makes them, one floor at a time;
    # its floor is the one of the best mean (tol_db 0; the smallest when tied); "auto" reads it.
    from ibrtools.pipeline import stages as S
    from ibrtools import cache
    from ibrtools.imageio import linear_to_srgb
    from ibrtools.metrics import psnr
    from ibrtools.pipeline import mix
    from ibrtools.pipeline import job as J
    from ibrtools.pipeline import plan as planning
    from ibrtools import methods

    d = cache.load_npz(cache.stage_output(exact_scene.root, "mix"))
    names = [v.name for v in exact_scene.views]
    assert list(d["views"]) == names and d["psnr"].shape == (len(names), len(mix.MIX_FLOORS))
    mean = d["psnr"].mean(0)
    assert float(d["pvm_floor"]) == mix.MIX_FLOORS[int(np.argmax(mean))]
    for i, j in ((0, 0), (3, 4)):
        job = planning.plan(exact_scene, holdout=[names[i]])
        m = methods.create("hybrid", {"pvm_floor": mix.MIX_FLOORS[j]})
        m.prepare(job.scene)
        o, _ = m.render(job.frames[0].camera)
        c = np.where(o["hole"][..., None], 0.0, o["color"]).astype(np.float32)
        assert psnr(linear_to_srgb(c), linear_to_srgb(job.frames[0].truth.color), 1.0) == pytest.approx(d["psnr"][i, j], abs=1e-9)
    hy = methods.create("hybrid")
    hy.prepare(exact_scene)
    hy.render(exact_scene.targets[0].camera)
    assert hy.frame_report()["pvm_floor"] == float(d["pvm_floor"]) and hy.frame_report()["pvm_floor_source"] == "mix stage"


@needs_pvm
def test_without_views_renders_what_preparing_the_held_out_scene_gives(exact_scene):
    # The mix stage's shortcut: one prepare on the whole scene, a copy per held-out view sharing
    # what was loaded. Every output equals a prepare of --holdout's scene, bit for bit.
    from ibrtools.hybrid import method as H
    from ibrtools.pipeline import job as J
    from ibrtools.pipeline import plan as planning
    base = H.HybridMethod({"pvm_floor": 0.3})
    base.prepare(exact_scene)
    for name in (exact_scene.views[0].name, exact_scene.views[-1].name):
        job = planning.plan(exact_scene, holdout=[name])
        fresh = H.HybridMethod({"pvm_floor": 0.3})
        fresh.prepare(job.scene)
        a, _ = base._without_views(job.scene).render(job.frames[0].camera)
        b, _ = fresh.render(job.frames[0].camera)
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
        assert not np.array_equal(a["color"], base.render(job.frames[0].camera)[0]["color"])  # the view is out
    smaller = planning.plan(exact_scene, holdout=[exact_scene.views[0].name]).scene
    part = H.HybridMethod({"pvm_floor": 0.3})
    part.prepare(smaller)
    with pytest.raises(BadValueError, match="subset"):
        part._without_views(exact_scene)
