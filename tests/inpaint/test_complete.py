"""Complete images (inpaint/complete.py, inpaint/background.py): the background at infinity is
rendered, never a hole and never foreground; disocclusions are filled from the background side;
overlap problems are said, not silent."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from ibrtools import api, synth
from ibrtools.camera import Camera, look_at
from ibrtools.inpaint import complete as C
from ibrtools.pipeline import job as J
from ibrtools.pipeline import plan as planning
from ibrtools.dibr import view_selection as vs

from conftest import need_data

SIZE = (64, 48)


@pytest.fixture(scope="module")
def sky_scene(tmp_path_factory):
    """synth:objects with every stage the mesh methods need: a scene with sky (depth +inf)."""
    from ibrtools.pipeline import stages as S
    from ibrtools.formats import native
    from ibrtools.methods import BUILT

    d = tmp_path_factory.mktemp("complete") / "scene"
    wanted = [m for m in ("tm", "ulr", "pvm", "hybrid") if m in BUILT]
    S.preprocess("synth:objects", d, synth={"preset": "objects", "size": list(SIZE), "views": 8, "seed": 0,
                                            "reconstructed": False, "holdout_targets": 1},
                 methods=wanted, stage_options={"mesh": {"source": "ground_truth", "resolution": 96}})
    return native.load(d)


def _far_from_surface(depth: np.ndarray, px: int = 2) -> np.ndarray:
    """Sky pixels (depth +inf) with no surface pixel within ``px`` (silhouettes may move by that)."""
    sky = np.isposinf(depth)
    out = sky.copy()
    h, w = sky.shape
    for dy in range(-px, px + 1):
        for dx in range(-px, px + 1):
            sh = np.ones_like(sky)
            sh[max(0, -dy):h - max(0, dy), max(0, -dx):w - max(0, dx)] = \
                sky[max(0, dy):h - max(0, -dy), max(0, dx):w - max(0, -dx)]
            out &= sh
    return out


@pytest.mark.parametrize("method", ["dibr", "warp", "tm", "ulr", "pvm", "hybrid"])
def test_background_stays_background_through_every_method(sky_scene, method):
    from ibrtools.methods import BUILT

    if method not in BUILT:
        pytest.skip(f"{method} not built")
    job = planning.plan(sky_scene, holdout=["v002"])
    truth = job.frames[0].truth
    sky = _far_from_surface(truth.depth)
    assert sky.mean() > 0.1  # the target sees sky
    r = api.render(job.scene, job.frames[0].camera, method=method)
    assert np.isfinite(r.color).all()
    # The sky is black (the scene's background colour): no foreground colour where an input sees
    # the sky, and the sky no input sees (a hole) filled with the background colour too.
    assert np.abs(r.color[sky]).max() == 0.0


def test_target_looking_only_at_the_sky_renders_the_sky(sky_scene):
    # The top rows of the input that sees the most sky, as a camera of their own (a crop).
    rows = [int(np.argmin(np.isposinf(v.depth).all(axis=1))) for v in sky_scene.views]
    v = sky_scene.views[int(np.argmax(rows))]
    n = max(rows) - 2
    assert n >= 4
    c = v.camera
    up = Camera.pinhole(c.width, n, c.fx, c.fy, c.cx, c.cy, c.cam_from_world)
    for method in ("dibr", "ulr"):
        r = api.render(sky_scene, up, method=method)
        assert np.isposinf(r.depth).all() and (r.color == 0).all(), method
        assert not r.hole.any(), method


def test_disocclusion_filled_from_the_background_side():
    """A hole between a near red box and a far blue wall, under a sky: filled with blue."""
    h, w = 40, 60
    color = np.zeros((h, w, 3), np.float32)
    depth = np.full((h, w), 5.0, np.float32)
    color[:] = (0.0, 0.0, 1.0)
    color[:, :20] = (1.0, 0.0, 0.0)
    depth[:, :20] = 1.0
    color[:8] = 0.0
    depth[:8] = np.inf  # sky
    hole = np.zeros((h, w), bool)
    hole[8:, 20:30] = True  # disocclusion right of the box
    out = {"color": color, "depth": depth, "hole": hole}
    done = C.complete(out, Camera.from_fov(w, h, 60.0), None, "auto")
    assert done.note == "auto" and done.filled
    filled = done.color[hole]
    # Blue: the background side (the push-pull's bilinear push still mixes ~half red into the
    # first column beside the box, docs/render.md "Limits"); a classic fill is half red.
    classic = C.complete(out, Camera.from_fov(w, h, 60.0), None, "pushpull")
    assert filled[:, 2].mean() > 0.85 and done.color[8:, 23:30, 2].min() > 0.85
    assert (done.color[:8] == 0).all()  # the sky is not a hole: untouched
    from ibrtools.inpaint.pushpull import pushpull

    plain = pushpull(color, hole | np.isposinf(depth))  # no depth: the foreground side too
    assert plain[hole][:, 2].mean() < filled[:, 2].mean() - 0.1
    assert np.array_equal(classic.color, done.color)  # auto is the depth-aware push-pull


def test_sky_hidden_behind_a_pole_top_is_filled_as_sky():
    """The sky no input sees past a near pole's top: a hole between the sky (left and above), the
    pole (right, near) and the ground at the horizon (below, far). The pole is the occluder: it
    does not vote, and the hole takes the sky's colour, not the ground's."""
    h, w = 40, 60
    color = np.zeros((h, w, 3), np.float32)
    depth = np.full((h, w), np.inf, np.float32)  # sky
    color[20:] = (0.0, 0.6, 0.0)
    depth[20:] = 15.0  # ground from the horizon down
    color[5:, 40:43] = (0.8, 0.8, 0.8)
    depth[5:, 40:43] = 4.0  # the pole, in front of sky and ground
    hole = np.zeros((h, w), bool)
    hole[10:20, 25:40] = True  # left of the pole, above the horizon
    depth[hole] = 0.0  # unknown, as the warp leaves a hole (not a mesh method's miss)
    sky_colour = np.array([0.1, 0.2, 0.9], np.float32)
    color[np.isposinf(depth)] = sky_colour
    bg = C.Background([], [], sky_colour)
    done = C.complete({"color": color, "depth": depth, "hole": hole}, Camera.from_fov(w, h, 60.0), bg, "auto")
    np.testing.assert_allclose(done.color[hole], np.tile(sky_colour, (hole.sum(), 1)))
    assert done.background[hole].all()
    # The pole is the right side's occluder: with every side voting for itself (no occluders),
    # the hole's rows right of the sky's reach would be split by a tie-free ground majority.
    from ibrtools import _core

    known = np.where(np.isfinite(depth) & ~hole, depth, 0).astype(np.float32)
    bgmask = np.isposinf(depth) & ~hole
    sides, _ = _core.hole_sides(hole, bgmask, known, C.OCCLUDER_RATIO)
    assert (((sides[hole] >> 2) & 3) == _core.SIDE_OCCLUDER).all()  # right: the pole
    assert C._background_holes(hole, sides)[hole].all()


def test_uniform_background_paints_the_edge_colours_inputs_carry():
    """An input's background pixels beside its silhouette carry the object's antialiased edge;
    warped rotation-only they would be a ghost outline. A scene with a background colour paints
    every background pixel in it; without one they stay as rendered."""
    h, w = 20, 30
    color = np.full((h, w, 3), 0.5, np.float32)
    depth = np.full((h, w), 2.0, np.float32)
    depth[:, 15:] = np.inf
    color[:, 15:] = 0.0
    color[5:15, 20] = (0.4, 0.3, 0.2)  # an edge colour drawn in the background
    out = {"color": color, "depth": depth, "hole": np.zeros((h, w), bool)}
    cam = Camera.from_fov(w, h, 60.0)
    black = np.zeros(3, np.float32)
    done = C.complete(out, cam, C.Background([], [], black), "auto")
    assert (done.color[:, 15:] == 0).all() and (done.color[:, :15] == 0.5).all()
    kept = C.complete(out, cam, C.Background([], [], None), "auto")
    np.testing.assert_array_equal(kept.color, color)
    white = C.complete(out, cam, C.Background([], [], black), "auto", C.parse_background("white"))
    assert (white.color[:, 15:] == 1).all()


def test_hole_inside_the_sky_takes_the_background_colour():
    h, w = 30, 30
    color = np.zeros((h, w, 3), np.float32)
    depth = np.full((h, w), np.inf, np.float32)
    color[20:] = 0.5
    depth[20:] = 3.0
    hole = np.zeros((h, w), bool)
    hole[5:12, 10:20] = True
    bg = C.Background([], [], np.array([0.2, 0.3, 0.4], np.float32))
    done = C.complete({"color": color, "depth": depth, "hole": hole}, Camera.from_fov(w, h, 60.0), bg, "auto")
    np.testing.assert_allclose(done.color[hole], np.tile([0.2, 0.3, 0.4], (hole.sum(), 1)))


def test_outlier_depths_do_not_change_view_selection():
    rng = np.random.default_rng(0)
    target = Camera.from_fov(*SIZE, 60.0, look_at((0, 1, 3), (0, 0, 0)))
    cams = [Camera.from_fov(*SIZE, 60.0, look_at((x, 1, 3), (0, 0, 0))) for x in (-2.0, -0.5, 0.7, 2.5)]
    depths = [rng.uniform(2.0, 3.0, (SIZE[1], SIZE[0])).astype(np.float32) for _ in cams]
    clean = vs.ViewSet([c for c in cams], [vs.depth_range(d) for d in depths],
                       vs.union([vs.depth_range(d) for d in depths]))
    noisy = [d.copy() for d in depths]
    n = max(1, noisy[1].size // 1000)  # 0.1 % of the pixels at 65.5 m (a sensor's invalid code)
    noisy[1].flat[rng.choice(noisy[1].size, n, replace=False)] = 65.5
    dirty = vs.ViewSet(cams, [vs.depth_range(d) for d in noisy], vs.union([vs.depth_range(d) for d in noisy]))
    assert dirty.ranges[1].far < 3.1
    assert dirty.select(target, 2).indices == clean.select(target, 2).indices


def test_target_overlapping_no_input_warns(sky_scene, tmp_path, capsys):
    from ibrtools_cli import render

    away = Camera.from_fov(*SIZE, 40.0, look_at((0.0, 1.0, 60.0), (0.0, 1.0, 120.0))).to_dict()
    poses = tmp_path / "p.json"
    poses.write_text(json.dumps([dict(away, name="away")]))
    assert render.main([str(sky_scene.root), "--method", "dibr", "--poses", str(poses), "-o", str(tmp_path / "o"),
                        ]) == 0
    err = capsys.readouterr().err
    assert "warning: frame away:" in err and "overlaps" in err
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert rep["frames"][0]["warnings"]


def test_inpaint_none_is_the_methods_output_with_black_holes(tmp_path):
    """On a scene without background (no depth +inf), --inpaint none writes exactly what the
    method rendered, holes black."""
    from ibrtools.imageio import read_image
    from ibrtools.dibr.method import DibrMethod

    s = synth.make_scene("objects", size=SIZE, views=4, holdout_targets=1)
    s = dataclasses.replace(s, views=[v.with_depth(np.where(np.isinf(v.depth), 0, v.depth).astype(np.float32))
                                      for v in s.views])
    assert C.Background.of(s.views) is None
    J.run(planning.plan(s, targets=["t000"]), "dibr", tmp_path / "o", inpaint="none", float_out=True)
    m = DibrMethod()
    m.prepare(s)
    out, _ = m.render(s.target("t000").camera)
    np.testing.assert_array_equal(read_image(tmp_path / "o" / "t000.exr"), C.clean_color(out))


def test_lego_background_gets_no_foreground_and_no_nan():
    d = need_data("nerf_lego")
    from ibrtools.formats import load
    from ibrtools.scene import Scene

    scene = load(d, "nerf", {"background": "black"})
    truth = scene.view("r_0")
    sub = Scene(views=[v for v in scene.views if v.name != "r_0"], shading=scene.shading, root=scene.root)
    r = api.render(sub, truth.camera, method="dibr", inputs=4)
    assert np.isfinite(r.color).all()
    sky = _far_from_surface(truth.depth, 3)
    assert (r.color[sky].max(-1) > 0.02).mean() < 0.001


def test_background_option_recolours_or_makes_it_transparent(sky_scene, tmp_path):
    from ibrtools.imageio import read_pixels
    from ibrtools_cli import render

    job = planning.plan(sky_scene, holdout=["v002"])
    cam = job.frames[0].camera
    sky = _far_from_surface(job.frames[0].truth.depth)
    white = api.render(job.scene, cam, method="dibr", background="white")
    assert (white.color[sky] == 1.0).all() and white.alpha is None
    clear = api.render(job.scene, cam, method="dibr", background="transparent")
    assert (clear.alpha[sky] == 0).all() and (clear.color[sky] == 0).all()
    plain = api.render(job.scene, cam, method="dibr")
    surface = np.isfinite(plain.depth) & (plain.depth > 0)
    assert (clear.alpha[surface] == 1).all()
    np.testing.assert_array_equal(white.color[surface], plain.color[surface])
    assert render.main([str(sky_scene.root), "--method", "dibr", "--holdout", "v002", "--background", "transparent",
                        "-o", str(tmp_path / "t"), "-q"]) == 0
    rgba, _ = read_pixels(tmp_path / "t" / "v002.png")
    assert rgba.shape[2] == 4 and (rgba[..., 3][sky] == 0).all()
    assert render.main([str(sky_scene.root), "--holdout", "v002", "--background", "pink", "-o",
                        str(tmp_path / "b"), "-q"]) == 2
    assert not (tmp_path / "b").exists() or not any((tmp_path / "b").iterdir())


@pytest.mark.parametrize("margin", [1, 2, 3, 5])
def test_clear_mask_is_no_surface_within_the_margin(margin):
    # An independent answer, pixel by pixel: clear where the (2 margin - 1)-wide square around the
    # pixel, cut by the image edge, holds no surface pixel.
    from ibrtools.inpaint.background import _clear

    rng = np.random.default_rng(margin)
    surface = rng.random((23, 31)) < 0.04
    surface[0, 30] = surface[22, 0] = True  # corners
    r = margin - 1
    want = np.array([[not surface[max(0, y - r):y + r + 1, max(0, x - r):x + r + 1].any() for x in range(31)]
                     for y in range(23)])
    np.testing.assert_array_equal(_clear(surface, margin), want)
    assert not _clear(np.ones((4, 5), bool), margin).any() and _clear(np.zeros((4, 5), bool), margin).all()
