"""Video scenes (docs/FORMAT.md "Frames"): a scene of frames x views, made by
``ibr-preprocess synth:objects --frames N``, rendered frame by frame by ``ibr-render`` (names
<frame>_<camera>, metrics against each frame's own ground truth), on Dask too (split by
frame x camera, the same files); still scenes load unchanged."""
from __future__ import annotations

import filecmp
import json
from pathlib import Path

import numpy as np
import pytest

from ibrtools import synth
from ibrtools.errors import BadValueError, FormatError, MissingFileError
from ibrtools.formats import native
from ibrtools.pipeline import job as J
from ibrtools.pipeline import plan as planning
@pytest.fixture(scope="module")
def video_dir(tmp_path_factory):
    from ibrtools_cli import preprocess

    d = tmp_path_factory.mktemp("video") / "scene"
    assert preprocess.main(["synth:objects", "-o", str(d), "--frames", "3", "--views", "3", "--size", "64x48",
                            "-q"]) == 0
    return d


def test_video_scene_layout_and_motion(video_dir):
    doc = json.loads((video_dir / "scene.json").read_text())
    assert doc["version"] == 2 and doc["frames"] == ["f000", "f001", "f002"] and doc["views"] == []
    assert doc["stages"]["import"]["frames"] == 3
    s = native.load(video_dir)
    assert s.frames == ["f000", "f001", "f002"] and [t.name for t in s.targets] == ["t000", "t001", "t002"]
    frames = [s.frame(f) for f in s.frames]
    assert all(len(f.views) == 3 and f.frames == [] for f in frames)
    # The objects move by the same offset every frame (constant velocity), the ground stays;
    # the cameras are the same at every frame.
    m = [f.meshes["ground_truth"] for f in frames]
    ground = np.zeros(len(m[0].vertices), bool)
    ground[m[0].faces[m[0].object_ids == 0].ravel()] = True
    np.testing.assert_array_equal(m[1].vertices[ground], m[0].vertices[ground])
    d1, d2 = m[1].vertices - m[0].vertices, m[2].vertices - m[1].vertices
    assert np.abs(d1[~ground]).max() > 0.01  # moved
    # atol: the positions went through the OBJ file (6 significant digits: ~1e-5 at coordinates ~10)
    np.testing.assert_allclose(d1, d2, atol=3e-5)
    np.testing.assert_array_equal(frames[0].views[0].camera.cam_from_world, frames[2].views[0].camera.cam_from_world)
    assert np.abs(frames[0].views[0].color - frames[2].views[0].color).max() > 0.05  # the images differ


def test_render_iterates_frames(video_dir, tmp_path):
    from ibrtools_cli import render

    out = tmp_path / "o"
    assert render.main([str(video_dir), "--method", "reference", "--target", "t000", "t001", "-o", str(out),
                        "-q"]) == 0
    rep = json.loads((out / "report.json").read_text())
    names = [f["name"] for f in rep["frames"]]
    assert names == ["f000_t000", "f000_t001", "f001_t000", "f001_t001", "f002_t000", "f002_t001"]
    assert [f["frame"] for f in rep["frames"]] == ["f000", "f000", "f001", "f001", "f002", "f002"]
    assert all((out / f"{n}.png").is_file() for n in names)
    # Each frame is scored against its own ground truth: the reference renderer made the
    # targets, so it matches them to 8-bit quantisation (> 40 dB); scoring f001's render against
    # f000's truth would not (the objects moved).
    assert all(f["metrics"]["psnr"] is None or f["metrics"]["psnr"] > 40 for f in rep["frames"])
    s = native.load(video_dir)
    from ibrtools.imageio import read_image
    from ibrtools.metrics import psnr

    r1 = read_image(out / "f001_t000.png")
    assert psnr(r1, s.frame("f000").target("t000").color, 1.0) < 35


def test_plan_of_a_video_and_its_spec(video_dir):
    job = planning.plan(native.load(video_dir), path="orbit")
    assert len(job.frames) == 3 * 48 and job.frames[48].name == "f001_orbit_0000"
    assert job.frames[48].scene_frame == "f001" and set(job.scenes) == {"f000", "f001", "f002"}
    assert job.scene is job.scenes["f000"] and job.spec["path"] == "orbit"
    held = planning.plan(native.load(video_dir), holdout=["v001"])
    assert [f.name for f in held.frames] == ["f000_v001", "f001_v001", "f002_v001"]
    assert all(len(sc.views) == 2 for sc in held.scenes.values())  # held out of every frame


def test_distributed_video_matches_local(video_dir, tmp_path):
    pytest.importorskip("distributed", reason="dask.distributed is not installed")
    kw = {"holdout": ["v002"], "targets": ["t001"]}
    J.run(planning.plan(native.load(video_dir), **kw), "dibr", tmp_path / "local", depth_out=True)
    rep = J.run(planning.plan(native.load(video_dir), **kw), "dibr", tmp_path / "dist", depth_out=True, workers=2)
    assert rep["distributed"]["tasks"] == 6  # frame x camera
    files = sorted(p.name for p in (tmp_path / "local").iterdir())
    assert files == sorted(p.name for p in (tmp_path / "dist").iterdir())
    assert [f for f in files if f != "report.json"
            and not filecmp.cmp(tmp_path / "local" / f, tmp_path / "dist" / f, shallow=False)] == []


def test_still_scenes_load_unchanged(tmp_path):
    scene = synth.make_scene("objects", size=(32, 24), views=2, holdout_targets=1, path_frames=2)
    d = native.save(scene, tmp_path / "still")
    assert json.loads((d / "scene.json").read_text())["version"] == 1
    s = native.load(d)
    assert s.frames == [] and len(s.views) == 2
    with pytest.raises(BadValueError, match="a still scene"):
        s.frame("f000")


def test_bad_video_scenes(video_dir, tmp_path, capsys):
    import shutil

    from ibrtools_cli import preprocess

    bad = tmp_path / "bad"
    shutil.copytree(video_dir, bad)
    doc = json.loads((bad / "scene.json").read_text())
    for change, err, msg in (
            ({"version": 1}, FormatError, "cannot hold 'frames'"),
            ({"frames": []}, FormatError, "non-empty list"),
            ({"frames": ["f000", "f000"]}, FormatError, "distinct"),
            ({"frames": ["f000", "f009"]}, MissingFileError, "frame 'f009'"),
            ({"frames": ["../f000"]}, MissingFileError, "frame '../f000'")):
        (bad / "scene.json").write_text(json.dumps({**doc, **change}))
        with pytest.raises(err, match=msg):
            native.load(bad)
    no_frames = {k: v for k, v in doc.items() if k != "frames"}
    (bad / "scene.json").write_text(json.dumps(no_frames))
    with pytest.raises(FormatError, match="needs a 'frames' list"):
        native.load(bad)
    with pytest.raises(BadValueError, match="not in the scene"):
        native.load(video_dir).frame("f007")
    video, frames = synth.make_video("objects", frames=1, size=(32, 24), views=2, holdout_targets=0, path_frames=2)
    with pytest.raises(BadValueError, match="no frames"):
        native.save_video(video, {}, tmp_path / "v0")
    with pytest.raises(BadValueError, match="plain file names"):
        native.save_video(video, {"a/b": frames["f000"]}, tmp_path / "v1")
    with pytest.raises(BadValueError, match="frames"):
        synth.make_video("objects", frames=0)
    assert preprocess.main(["synth:objects", "-o", str(tmp_path / "v2"), "--frames", "0"]) == 2
    assert "--frames: expected an integer >= 1" in capsys.readouterr().err


def test_streamed_video_writes_the_frames_of_frame_by_frame_rendering(video_dir, tmp_path):
    """The video loop decodes scene frame k + 1 while k renders and releases k's images after
    it: the same files as rendering each scene frame as a still scene on its own."""
    video = J.run(planning.plan(native.load(video_dir), targets=["t000", "t002"]), "dibr", tmp_path / "video",
                  depth_out=True)
    seq = video["sequence"]
    assert seq["frames"] == 6 and seq["fps"] > 0 and seq["wall_ms"] > 0 and seq["decode_wait_ms"] >= 0
    assert {"warp", "total"} <= set(seq["stage_ms_mean"])
    for fr in ("f000", "f001", "f002"):
        still = J.run(planning.plan(native.load(video_dir / "frames" / fr), targets=["t000", "t002"]), "dibr",
                      tmp_path / fr, depth_out=True)
        assert "sequence" not in still
        for f in sorted(p.name for p in (tmp_path / fr).iterdir() if p.name != "report.json"):
            assert filecmp.cmp(tmp_path / fr / f, tmp_path / "video" / f"{fr}_{f}", shallow=False), f


def test_stream_prefetches_and_releases(video_dir):
    job = planning.plan(native.load(video_dir), targets=["t000"])
    views = {fr: job.scenes[fr].views[0] for fr in job.scenes}
    with J.VideoStream(job) as stream:
        assert stream.order == ["f000", "f001", "f002"]
        stream.entered("f000")  # decodes f001 in the background
        scene = stream.enter("f001")
        assert scene is job.scenes["f001"] and views["f001"]._color._value is not None
        first = views["f000"].color
        assert views["f000"]._color._value is not None
        stream.leave("f000")
        assert views["f000"]._color._value is None
        np.testing.assert_array_equal(views["f000"].color, first)  # read again on use
        stream.leave("f001")
        assert views["f001"]._color._value is None
    # A still job streams nothing.
    still = planning.plan(native.load(video_dir / "frames" / "f000"), targets=["t000"])
    with J.VideoStream(still) as stream:
        assert stream.order == []
        stream.entered(None)


def test_render_reports_the_sustained_rate(video_dir, tmp_path, capsys):
    from ibrtools_cli import render

    assert render.main([str(video_dir), "--method", "dibr", "--target", "t000", "-o", str(tmp_path / "o"),
                        "--report"]) == 0
    out = capsys.readouterr().out
    assert "sequence: 3 frames in" in out and "fps sustained" in out and "warp" in out
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert rep["sequence"]["frames"] == 3
