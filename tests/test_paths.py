"""Generated camera paths (ibrtools.paths: interpolate, spiral, orbit), pose files in the
nerfstudio and transforms conventions (ibrtools.formats.poses), ``ibr-render --path`` on a scene
without stored paths, and their bad input."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, FormatError, InputError
from ibrtools.formats import native
from ibrtools.formats.nerf import GL_TO_CV
from ibrtools.paths import (DEFAULT_FRAMES, GENERATED, camera_path, depth_range, interpolate, orbit, path_names,
                            quat_from_matrix, spiral, spline)
from ibrtools.pipeline.plan import plan, read_poses
from ibrtools.scene import Scene, View
from ibrtools_cli import preprocess, render

W, H = 96, 72
LOOK = np.array([0.5, -0.2, 1.0])  # the point the test rig looks at


def _rig(k: int = 6, seed: int = 0) -> list[Camera]:
    """``k`` cameras on an uneven arc (radius and height vary) looking at LOOK, in order."""
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(k):
        a = 0.35 * i + 0.1 * rng.standard_normal()
        eye = LOOK + np.array([3.0 * math.sin(a), -0.8 + 0.3 * rng.standard_normal(), -3.0 * math.cos(a)])
        cams.append(Camera.from_fov(W, H, 60.0, look_at(eye, LOOK, (0.0, -1.0, 0.0))))
    return cams


def _scene(cams: list[Camera], depth: float | None = None) -> Scene:
    views = []
    for i, c in enumerate(cams):
        d = None if depth is None else np.full((c.height, c.width), depth, np.float32)
        views.append(View.create(f"v{i:03d}", c, color=np.zeros((c.height, c.width, 3), np.float32), depth=d))
    return Scene(views=views)


def _angle(r1: np.ndarray, r2: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(r1.T @ r2) - 1) / 2, -1, 1)))


# --- interpolate ------------------------------------------------------------------------------
def test_interpolate_passes_exactly_through_every_input():
    cams = _rig(6)
    at = spline(cams)
    for i, c in enumerate(cams):
        np.testing.assert_allclose(at(i), c.cam_from_world, atol=1e-12)
    m = 5  # frames per segment: frames - 1 a multiple of the 5 segments, every input is a frame
    frames = interpolate(cams, m * (len(cams) - 1) + 1)
    assert len(frames) == 26
    for i, c in enumerate(cams):
        f = frames[m * i]
        np.testing.assert_allclose(f.centre, c.centre, atol=1e-12)
        assert _angle(f.cam_from_world[:3, :3], c.cam_from_world[:3, :3]) < 1e-9
        assert (f.width, f.height, f.fx, f.cx) == (W, H, cams[0].fx, cams[0].cx)  # the first view's intrinsics


def test_interpolate_is_smooth():
    """C1 in centre and rotation: the second differences of a fine sampling are O(h^2) everywhere,
    the knots included (a polyline or plain slerp between the inputs has O(h) kinks there)."""
    cams = _rig(6)
    m = 40
    frames = interpolate(cams, m * (len(cams) - 1) + 1)
    p = np.array([f.centre for f in frames])
    chord = max(float(np.linalg.norm(a.centre - b.centre)) for a, b in zip(cams, cams[1:]))
    d2 = np.linalg.norm(p[2:] - 2 * p[1:-1] + p[:-2], axis=1)
    # |p''| of a Catmull-Rom segment is at most ~6 chords (its cubic coefficients), times h^2 = 1/m^2
    assert d2.max() < 6 * chord / m ** 2
    q = [quat_from_matrix(f.world_from_cam[:3, :3]) for f in frames]
    for i in range(1, len(q)):
        if np.dot(q[i], q[i - 1]) < 0:
            q[i] = -q[i]
    q = np.array(q)
    turn = max(_angle(a.cam_from_world[:3, :3], b.cam_from_world[:3, :3]) for a, b in zip(cams, cams[1:]))
    assert np.linalg.norm(q[2:] - 2 * q[1:-1] + q[:-2], axis=1).max() < 6 * turn / m ** 2
    # linear (a kink at each knot) would fail the same bound
    lin = np.concatenate([np.linspace(a.centre, b.centre, m + 1)[:-1] for a, b in zip(cams, cams[1:])])
    assert np.linalg.norm(lin[2:] - 2 * lin[1:-1] + lin[:-2], axis=1).max() > 6 * chord / m ** 2


def test_interpolate_degenerate_inputs():
    c = _rig(1)[0]
    with pytest.raises(BadValueError, match="needs at least 2 input views"):
        interpolate([c], 10)
    with pytest.raises(BadValueError, match="path_frames: expected an integer >= 2"):
        interpolate(_rig(3), 1)
    same = interpolate([c, c, c], 9)  # coincident cameras: the same pose, no NaN
    for f in same:
        np.testing.assert_allclose(f.cam_from_world, c.cam_from_world, atol=1e-12)


# --- spiral and orbit -------------------------------------------------------------------------
def _looks_at(cams: list[Camera], point: np.ndarray) -> None:
    for c in cams:
        xy, z = c.project(point[None])
        assert z[0] > 0
        np.testing.assert_allclose(xy[0], [c.cx, c.cy], atol=1e-6)


def test_spiral_looks_at_its_focus_at_the_llff_distance():
    cams = _rig(6)
    scene = _scene(cams, depth=3.0)
    near, far = depth_range(scene, cams)
    assert near == pytest.approx(3.0, rel=1e-5) and far == pytest.approx(3.0, rel=1e-5)
    path, focus = spiral(scene, 30)
    assert len(path) == 30 and all(np.all(np.isfinite(c.cam_from_world)) for c in path)
    _looks_at(path, focus)
    mean = np.mean([c.centre for c in cams], 0)
    expect = 1.0 / (0.25 / (0.9 * 3.0) + 0.75 / (5 * 3.0))  # LLFF's focus distance
    assert float(np.linalg.norm(focus - mean)) == pytest.approx(expect, rel=1e-9)
    spread = np.linalg.norm(np.array([c.centre for c in path]) - mean, axis=1)
    assert spread.min() > 0 and spread.max() < 2 * np.linalg.norm(np.array([c.centre for c in cams]) - mean, axis=1).max()


def test_spiral_without_depth_focuses_where_the_axes_meet():
    """Photographs only (no depth, no mesh): the focus is the point of the mean optical axis
    nearest LOOK, where every input looks."""
    cams = _rig(6)
    scene = _scene(cams)
    assert depth_range(scene, cams) is None
    path, focus = spiral(scene, 12)
    _looks_at(path, focus)
    mean = np.mean([c.centre for c in cams], 0)
    fwd = (focus - mean) / np.linalg.norm(focus - mean)
    assert np.linalg.norm(focus - mean) == pytest.approx(float((LOOK - mean) @ fwd), rel=1e-9)
    assert np.linalg.norm(np.cross(LOOK - mean, fwd)) < 0.2 * np.linalg.norm(LOOK - mean)


def test_spiral_of_one_view_without_depth_is_finite():
    """No spread to take a radius from: a circle of a tenth of the focus distance (two turns: 8
    frames are 4 places)."""
    scene = _scene(_rig(1))
    path, focus = spiral(scene, 8)
    c0 = scene.views[0].camera.centre
    assert np.all(np.isfinite(focus)) and len({tuple(np.round(c.centre, 9)) for c in path}) == 4
    np.testing.assert_allclose([np.linalg.norm(c.centre - c0) for c in path], 0.1 * np.linalg.norm(focus - c0))
    _looks_at(path, focus)


def test_orbit_looks_at_the_point_the_cameras_look_at():
    cams = _rig(6)
    path, centre = orbit(_scene(cams), 24)
    np.testing.assert_allclose(centre, LOOK, atol=1e-9)  # every input's axis passes through LOOK
    _looks_at(path, centre)
    up = -np.mean([c.cam_from_world[1, :3] for c in cams], 0)
    up /= np.linalg.norm(up)
    rel = np.array([c.centre for c in path]) - centre
    flat = rel - np.outer(rel @ up, up)
    r_in = np.linalg.norm((lambda x: x - np.outer(x @ up, up))(np.array([c.centre for c in cams]) - centre), axis=1)
    np.testing.assert_allclose(np.linalg.norm(flat, axis=1), r_in.mean(), rtol=1e-9)
    np.testing.assert_allclose(rel @ up, np.mean((np.array([c.centre for c in cams]) - centre) @ up), atol=1e-9)


def test_orbit_of_parallel_cameras_uses_the_bounds_centre():
    cams = [Camera.from_fov(W, H, 60.0, look_at((x, 0, 0), (x, 0, 1), (0, -1, 0))) for x in (0.0, 1.0, 2.0)]
    scene = _scene(cams, depth=4.0)
    path, centre = orbit(scene, 8)
    b = scene.bounds()
    np.testing.assert_allclose(centre, 0.5 * (b[0] + b[1]))
    _looks_at(path, centre)


def test_stored_path_wins_and_names_are_listed():
    cams = _rig(4)
    stored = [cams[0], cams[1]]
    scene = Scene(views=_scene(cams).views, paths={"orbit": stored})
    assert camera_path(scene, "orbit") == stored
    assert path_names(scene) == ["orbit", "interpolate", "spiral"]
    assert len(camera_path(scene, "spiral")) == DEFAULT_FRAMES
    with pytest.raises(BadValueError, match="stored in the scene"):
        camera_path(scene, "orbit", 10)
    job = plan(scene, path="interpolate", path_frames=7)
    assert [f.name for f in job.frames] == [f"interpolate_{i:04d}" for i in range(7)]
    assert job.spec["path_frames"] == 7
    with pytest.raises(BadValueError) as e:
        plan(scene, path="nope")
    assert "stored: orbit" in str(e.value) and all(g in str(e.value) for g in GENERATED)
    with pytest.raises(BadValueError, match="path_frames: only with a path"):
        plan(scene, path_frames=5)


# --- pose files ---------------------------------------------------------------------------------
def _gl_c2w(c: Camera) -> np.ndarray:
    return c.world_from_cam @ GL_TO_CV


def test_nerfstudio_camera_path_gives_the_cameras_of_our_pose_file(tmp_path):
    f = 70.0
    cams = [Camera.pinhole(W, H, f, f, W / 2, H / 2, c.cam_from_world) for c in _rig(4)]
    ours = tmp_path / "ours.json"
    ours.write_text(json.dumps([c.to_dict() for c in cams]))
    fov = math.degrees(2 * math.atan(H / 2 / f))
    ns = {"camera_type": "perspective", "render_height": H, "render_width": W, "seconds": 1.0,
          "camera_path": [{"camera_to_world": _gl_c2w(c).reshape(-1).tolist() if i % 2 else _gl_c2w(c).tolist(),
                           "fov": fov, "aspect": W / H} for i, c in enumerate(cams)]}
    (tmp_path / "camera_path.json").write_text(json.dumps(ns))
    a, b = read_poses(ours), read_poses(tmp_path / "camera_path.json")
    assert [x.name for x in b] == [f"pose_{i:03d}" for i in range(4)]
    for x, y in zip(a, b):
        assert x.camera.allclose(y.camera, 1e-9), (x.camera, y.camera)
    del ns["render_width"]  # the width from the aspect
    (tmp_path / "camera_path.json").write_text(json.dumps(ns))
    assert all(y.camera.width == W for y in read_poses(tmp_path / "camera_path.json"))


def test_transforms_pose_file_reads_as_the_nerf_importer(tmp_path):
    cams = _rig(3)
    doc = {"fl_x": cams[0].fx, "fl_y": cams[0].fy, "cx": cams[0].cx, "cy": cams[0].cy, "w": W, "h": H,
           "frames": [{"file_path": f"images/f{i}", "transform_matrix": _gl_c2w(c).tolist()}
                      for i, c in enumerate(cams)]}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    got = read_poses(tmp_path / "transforms.json")
    assert [g.name for g in got] == ["f0", "f1", "f2"]
    for g, c in zip(got, cams):
        assert g.camera.allclose(c, 1e-9)
    # camera_angle_x instead of fl_x
    doc2 = {"camera_angle_x": math.radians(60.0), "w": W, "h": H, "frames": doc["frames"]}
    (tmp_path / "t2.json").write_text(json.dumps(doc2))
    assert read_poses(tmp_path / "t2.json")[1].camera.allclose(cams[1], 1e-9)
    del doc2["w"]
    (tmp_path / "t2.json").write_text(json.dumps(doc2))
    with pytest.raises(FormatError, match="missing 'w'/'h'"):
        read_poses(tmp_path / "t2.json")


# --- the command ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """A synthetic scene with its stored paths removed: what an imported capture looks like."""
    d = tmp_path_factory.mktemp("paths") / "scene"
    assert preprocess.main(["synth:objects", "-o", str(d), "--views", "6", "--size", f"{W}x{H}", "-q"]) == 0
    doc = json.loads((d / "scene.json").read_text())
    doc["paths"] = {}
    (d / "scene.json").write_text(json.dumps(doc))
    return d


def test_render_interpolate_on_a_scene_without_paths(capture, tmp_path):
    out = tmp_path / "r"
    assert render.main([str(capture), "--method", "dibr", "--path", "interpolate", "--path-frames", "6",
                        "-o", str(out), "-q"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert [f["name"] for f in rep["frames"]] == [f"interpolate_{i:04d}" for i in range(6)]
    assert all((out / f["image"]).is_file() for f in rep["frames"])
    scene = native.load(capture)
    assert scene.paths == {}
    # the first and the last frame are the first and the last input view
    job = plan(scene, path="interpolate", path_frames=6)
    assert job.frames[0].camera.allclose(scene.views[0].camera, 1e-9)
    assert job.frames[-1].camera.allclose(scene.views[-1].camera, 1e-9)


def _bad(tmp_path, name: str, text: str):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("argv, msg", [
    (["--path", "nope"], "--path nope: not a path of the scene (stored: none; generated: interpolate, spiral, orbit)"),
    (["--path", "spiral", "--path-frames", "1"], "--path-frames: expected an integer >= 2, got 1"),
    (["--path-frames", "5", "--holdout", "v001"], "--path-frames: only with a path"),
    (["--poses", "{tmp}/ns.json"], "ns.json: 'render_height': expected an integer in [1, 65536]"),
    (["--poses", "{tmp}/ns2.json"], "ns2.json: camera_path[0].camera_to_world: expected a 4x4 matrix"),
    (["--poses", "{tmp}/ns3.json"], "ns3.json: camera_path[0]: 'fov'"),
    (["--poses", "{tmp}/other.json"], "other.json: expected a non-empty JSON list of cameras"),
])
def test_render_bad_path_input(capture, tmp_path, capsys, argv, msg):
    eye = np.eye(4).tolist()
    _bad(tmp_path, "ns.json", json.dumps({"camera_path": [{"camera_to_world": eye, "fov": 50}]}))
    _bad(tmp_path, "ns2.json", json.dumps({"render_height": 10, "render_width": 10,
                                           "camera_path": [{"camera_to_world": [1, 2, 3], "fov": 50}]}))
    _bad(tmp_path, "ns3.json", json.dumps({"render_height": 10, "render_width": 10,
                                           "camera_path": [{"camera_to_world": eye, "fov": 0}]}))
    _bad(tmp_path, "other.json", json.dumps({"something": 1}))
    out = tmp_path / "out"
    args = [str(capture)] + [a.format(tmp=tmp_path) for a in argv] + ["-o", str(out)]
    assert render.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert not out.exists() or not any(out.iterdir())


def test_interpolate_of_a_one_view_scene_is_a_one_line_error(tmp_path, capsys):
    c = _rig(1)[0]
    scene = Scene(views=[View.create("only", c, color=np.full((H, W, 3), 0.5, np.float32),
                                     depth=np.full((H, W), 2.0, np.float32))])
    native.save(scene, tmp_path / "one")
    out = tmp_path / "out"
    assert render.main([str(tmp_path / "one"), "--method", "dibr", "--path", "interpolate", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "--path interpolate: needs at least 2 input views, the scene has 1" in err and len(err.splitlines()) == 1
    assert not out.exists() or not any(out.iterdir())


# --- fuzzing the pose-file readers ----------------------------------------------------------------
_VALUES = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**400, 10**400), st.none(),
                    st.booleans(), st.text(max_size=5), st.lists(st.floats(), max_size=17),
                    st.just([[1, 0, 0, 0]] * 4), st.just({"x": 1}))


@settings(max_examples=60, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_pose_files_with_any_values_are_input_errors(tmp_path_factory, data):
    """A nerfstudio camera path or a transforms file with any value in any field: cameras or an
    InputError (one line, exit 2), never another exception."""
    eye = _gl_c2w(_rig(1)[0]).tolist()
    ns = {"render_height": H, "render_width": W, "camera_path": [{"camera_to_world": eye, "fov": 50.0, "aspect": 1.3}]}
    tf = {"fl_x": 50.0, "w": W, "h": H, "frames": [{"transform_matrix": eye}]}
    doc = data.draw(st.sampled_from([ns, tf]))
    inner = doc["camera_path" if "camera_path" in doc else "frames"][0]
    target = data.draw(st.sampled_from([doc, inner]))
    key = data.draw(st.sampled_from(sorted(target) + ["cx", "camera_angle_x", "camera_type", "file_path"]))
    target[key] = data.draw(_VALUES)
    f = tmp_path_factory.mktemp("fuzz") / "poses.json"
    f.write_text(json.dumps(doc))
    try:
        for fr in read_poses(f):
            assert np.all(np.isfinite(fr.camera.cam_from_world))
    except InputError as e:
        assert "\n" not in str(e) and str(e).startswith("poses: ") and e.argument == ("poses",)
