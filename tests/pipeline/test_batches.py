"""Light-field camera grids and the MP4 of a frame sequence (ibrtools.pipeline.batches,
ibr-render --lightfield / --baseline / --center / --mp4 / --fps)."""
from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, InputError
from ibrtools.pipeline import batches as B
from ibrtools.scene import Scene, View
from ibrtools_cli import render
from conftest import synth_scene_dir

# Poses are composed in float64 from one rotation: the only error is the rounding of a few
# additions of numbers of order 1 (1e-12 is ~1e4 ulp of margin).
TOL = 1e-12


def _cam(eye=(1.0, 2.0, 3.0), target=(0.0, 0.0, 0.0), w=64, h=48) -> Camera:
    return Camera.from_fov(w, h, 60.0, look_at(eye, target))


def test_parse_grid_and_baseline():
    assert B.parse_grid("9x8") == (9, 8) and B.parse_grid("1X1") == (1, 1) and B.parse_grid("3×2") == (3, 2)
    for bad in ("0x3", "3x0", "3", "ax2", "-1x2", "3x2x1", ""):
        with pytest.raises(BadValueError, match="lightfield: "):
            B.parse_grid(bad)
    with pytest.raises(BadValueError, match="100000"):
        B.parse_grid("1000x1000")
    assert B.check_baseline(0.25) == 0.25
    for bad in (-1, 0, float("nan"), float("inf")):
        with pytest.raises(BadValueError, match="baseline: "):
            B.check_baseline(bad)
    with pytest.raises(InputError, match="baseline: "):
        B.check_baseline("wide")


def test_odd_grid_centre_spacing_orientation():
    c = _cam()
    n, m, b = 5, 3, 0.125
    poses = B.grid_poses(c.cam_from_world, n, m, b)
    assert poses.shape == (n * m, 4, 4)
    cams = [c.with_pose(p) for p in poses]
    # The middle camera of an odd grid is the centre camera itself.
    mid = (m // 2) * n + n // 2
    np.testing.assert_allclose(poses[mid], c.cam_from_world, atol=TOL, rtol=0)
    r = c.cam_from_world[:3, :3]
    centres = np.array([k.centre for k in cams]).reshape(m, n, 3)
    # Same rotation everywhere: parallel optical axes (row 2 of R is the viewing direction).
    for p in poses:
        np.testing.assert_array_equal(p[:3, :3], r)
    # Columns step by b along the camera's x (image right), rows by b along its y (image down).
    np.testing.assert_allclose(centres[:, 1:] - centres[:, :-1], np.broadcast_to(b * r[0], (m, n - 1, 3)),
                               atol=TOL, rtol=0)
    np.testing.assert_allclose(centres[1:] - centres[:-1], np.broadcast_to(b * r[1], (m - 1, n, 3)),
                               atol=TOL, rtol=0)
    # Top-left camera: half the grid to the left and up.
    np.testing.assert_allclose(centres[0, 0], c.centre - 2 * b * r[0] - 1 * b * r[1], atol=TOL, rtol=0)
    # Every camera lies on the centre camera's plane (no offset along its viewing direction).
    np.testing.assert_allclose((centres - c.centre) @ r[2], 0.0, atol=TOL)


def test_even_grid_is_symmetric_about_the_centre():
    c = _cam()
    cams = [c.with_pose(p) for p in B.grid_poses(c.cam_from_world, 4, 2, 0.5)]
    centres = np.array([k.centre for k in cams])
    np.testing.assert_allclose(centres.mean(axis=0), c.centre, atol=TOL, rtol=0)
    r = c.cam_from_world[:3, :3]
    # Offsets in the camera frame: x in {-0.75, -0.25, 0.25, 0.75}, y in {-0.25, 0.25}, row-major.
    off = (centres - c.centre) @ r.T
    np.testing.assert_allclose(off[:4, 0], [-0.75, -0.25, 0.25, 0.75], atol=TOL)
    np.testing.assert_allclose(off[:4, 1], -0.25, atol=TOL)
    np.testing.assert_allclose(off[4:, 1], 0.25, atol=TOL)


def _scene(targets=True) -> Scene:
    views = [View.create(f"v{i}", _cam(eye=(i, 1.0, 3.0))) for i in range(3)]
    tg = [View.create("t0", _cam(eye=(0.5, 0.5, 2.0)))] if targets else []
    return Scene(views=views, targets=tg)


def test_centre_choice_and_names():
    s = _scene()
    assert B.centre_camera(s)[0] == "t0"                  # default: the first target
    assert B.centre_camera(s, "v2")[0] == "v2"            # a named input view
    assert B.centre_camera(s, "t0")[0] == "t0"
    assert B.centre_camera(_scene(targets=False))[0] == "v0"  # no target: the first view
    with pytest.raises(BadValueError, match="centre .nope.: no target"):
        B.centre_camera(s, "nope")
    with pytest.raises(BadValueError, match="neither targets nor input views"):
        B.centre_camera(Scene())
    name, cams = B.lightfield_cameras(s, 3, 2, 0.1, "v1")
    assert name == "v1" and [c[0] for c in cams] == [f"lf_{k:04d}" for k in range(6)]
    assert [(c[1], c[2]) for c in cams] == [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (1, 2)]
    assert all(c[3].width == 64 and c[3].fx == s.views[1].camera.fx for c in cams)
    _, big = B.lightfield_cameras(s, 101, 100, 0.1)
    assert big[0][0] == "lf_00000" and big[-1][0] == "lf_10099"


# --- MP4 -------------------------------------------------------------------------------------------
def _decode(path):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    gen = imageio_ffmpeg.read_frames(str(path))
    meta = gen.__next__()
    frames = [np.frombuffer(f, np.uint8).reshape(meta["size"][1], meta["size"][0], 3) for f in gen]
    return meta, frames


def test_write_mp4_frame_count_size_and_order(tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    from ibrtools.imageio import write_image

    paths = []
    for k, level in enumerate((0.0, 0.2, 1.0)):   # dark, mid, white: order visible after encoding
        img = np.full((24, 33, 3), level, np.float32)  # odd width: padded to 34
        paths.append(write_image(tmp_path / f"f{k}.png", img))
    out = B.write_mp4(paths, tmp_path / "v.mp4", fps=10)
    meta, frames = _decode(out)
    assert len(frames) == 3 and meta["size"] == (34, 24)
    means = [f.mean() for f in frames]
    # H.264 is lossy: flat frames come back within a few levels (tolerance 8 of 255).
    assert means[0] < 8 and abs(means[1] - 124) < 8 and means[2] > 247, means
    assert not list(tmp_path.glob(".v.*"))  # no temporary file left (written atomically)
    # Mixed sizes: refused, and the old file is untouched.
    write_image(tmp_path / "small.png", np.zeros((10, 10, 3), np.float32))
    with pytest.raises(BadValueError, match="one size"):
        B.write_mp4([paths[0], tmp_path / "small.png"], out)
    assert len(_decode(out)[1]) == 3
    for bad, msg in (({"fps": 0}, "fps: "), ({"fps": float("nan")}, "fps: ")):
        with pytest.raises(BadValueError, match=msg):
            B.write_mp4(paths, tmp_path / "w.mp4", **bad)
    with pytest.raises(BadValueError, match=r"\.mp4"):
        B.write_mp4(paths, tmp_path / "w.avi")
    with pytest.raises(BadValueError, match="no frame"):
        B.write_mp4([], tmp_path / "w.mp4")


def test_missing_imageio_ffmpeg_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import now raises ImportError
    with pytest.raises(B.MissingVideoError, match=r"ibrtools\[video\]"):
        B.require_video()


# --- the command --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return synth_scene_dir(tmp_path_factory, "--views", "4", "--size", "64x48", name="lf")


def test_render_lightfield_with_mp4(scene_dir, tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    out = tmp_path / "lf"
    assert render.main([str(scene_dir), "--method", "reference", "--lightfield", "3x2", "--baseline", "0.05",
                        "--center", "v001", "--mp4", str(out / "lf.mp4"), "--fps", "12", "-o", str(out), "-q"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert [(f["name"], f["row"], f["col"]) for f in rep["frames"]] == [
        ("lf_0000", 0, 0), ("lf_0001", 0, 1), ("lf_0002", 0, 2), ("lf_0003", 1, 0), ("lf_0004", 1, 1),
        ("lf_0005", 1, 2)]
    meta, frames = _decode(out / "lf.mp4")
    assert len(frames) == 6 and meta["size"] == (64, 48) and meta["fps"] == 12
    # The video holds the frames in order: each decoded frame is closest to its own PNG.
    from ibrtools.imageio import linear_to_srgb, read_image
    pngs = [linear_to_srgb(read_image(out / f"lf_{k:04d}.png")) * 255 for k in range(6)]
    for k, f in enumerate(frames):
        err = [np.abs(f.astype(np.float32) - p).mean() for p in pngs]
        assert int(np.argmin(err)) == k or err[k] == min(err), (k, err)


@pytest.mark.parametrize("argv, msg", [
    (["--lightfield", "0x3", "--baseline", "1"], "at least 1x1"),
    (["--lightfield", "3by3", "--baseline", "1"], "expected NxM"),
    (["--lightfield", "3x3", "--baseline", "-1"], "--baseline"),
    (["--lightfield", "3x3"], "--baseline B"),
    (["--baseline", "0.1"], "--baseline: only with --lightfield"),
    (["--center", "v001"], "--center: only with --lightfield"),
    (["--lightfield", "3x3", "--baseline", "0.1", "--center", "unknown"], "--center unknown: no target"),
    (["--lightfield", "2x2", "--baseline", "0.1", "--mp4", "{tmp}/x.avi"], ".mp4"),
    (["--lightfield", "2x2", "--baseline", "0.1", "--mp4", "{tmp}"], "is a directory"),
    (["--lightfield", "2x2", "--baseline", "0.1", "--mp4", "{tmp}/file.txt/x.mp4"], "not a directory"),
    (["--lightfield", "2x2", "--baseline", "0.1", "--mp4", "{tmp}/x.mp4", "--fps", "0"], "--fps"),
    (["--lightfield", "2x2", "--baseline", "0.1", "--fps", "30"], "--fps: only with --mp4"),
    (["--poses", "{tmp}/mixed.json", "--mp4", "{tmp}/x.mp4"], "different sizes"),
])
def test_render_batch_bad_input(scene_dir, tmp_path, capsys, argv, msg):
    pytest.importorskip("imageio_ffmpeg")
    (tmp_path / "file.txt").write_text("x")
    c = _cam()
    (tmp_path / "mixed.json").write_text(json.dumps([dict(c.to_dict(), name="a"),
                                                     dict(c.scaled(32, 24).to_dict(), name="b")]))
    args = [str(scene_dir), *[a.format(tmp=tmp_path) for a in argv], "-o", str(tmp_path / "out")]
    assert render.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "out").exists()  # refused before anything was rendered


def test_render_mp4_without_imageio_ffmpeg(scene_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    assert render.main([str(scene_dir), "--lightfield", "2x1", "--baseline", "0.1", "--mp4",
                        str(tmp_path / "v.mp4"), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "ibrtools[video]" in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists() and not (tmp_path / "v.mp4").exists()
