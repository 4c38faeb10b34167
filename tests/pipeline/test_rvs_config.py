"""Multi-frame MPEG/RVS input and an RVS config rendered in one command (``ibr-render CONFIG.json``):
a small sample in the real layout (camera JSON, YUV 4:2:0 texture and 16-bit inverse-depth files
with several frames, an RVS synthesis config), written here."""
from __future__ import annotations

import json

import numpy as np
import pytest

from ibrtools.errors import BadValueError, FormatError
from ibrtools.formats import load_frames, mpeg, parse_frames, yuv
from ibrtools_cli import preprocess as preprocess_cli
from ibrtools_cli import render as render_cli

W, H, FRAMES = 48, 32, 3


def _cam(name, pos, bits=8):
    return {"Name": name, "Position": list(pos), "Rotation": [0, 0, 0], "Depth_range": [0.5, 1000.0],
            "Resolution": [W, H], "Projection": "Perspective", "Focal": [40.0, 40.0], "Principle_point": [24.0, 16.0],
            "BitDepthColor": bits, "BitDepthDepth": 16, "ColorSpace": "YUV420", "DepthColorSpace": "YUV420"}


def _texture(frame: int) -> list[np.ndarray]:
    """Frame ``frame`` of the input texture: smooth luma that changes with the frame, grey chroma."""
    yy, xx = np.mgrid[0:H, 0:W]
    y = 60 + 2 * xx + yy + 20 * frame
    c = np.full(((H + 1) // 2, (W + 1) // 2), 128)
    return [y.astype(np.uint8), c.astype(np.uint8), c.astype(np.uint8)]


def _write(path, frames, dtype):
    with open(path, "wb") as f:
        for planes in frames:
            for p in planes:
                f.write(np.asarray(p, dtype=dtype).tobytes())


def make_sequence(tmp_path, frames=FRAMES, **extra):
    """One input camera v0 and two virtual cameras: "same" at v0's pose, "near" 1 cm beside it."""
    cams = [_cam("v0", (0, 0, 0)), _cam("same", (0, 0, 0), bits=10), _cam("near", (0, 0.01, 0))]
    (tmp_path / "cams.json").write_text(json.dumps({"Version": "4.0", "cameras": cams}))
    _write(tmp_path / f"v0_texture_{W}x{H}_yuv420p.yuv", [_texture(i) for i in range(frames)], np.uint8)
    d = np.full((H, W), 32767)  # 1/d = 32767/65535 * 2 -> d ~ 1 m: a plane in front of the camera
    c = np.zeros(((H + 1) // 2, (W + 1) // 2))
    _write(tmp_path / f"v0_depth_{W}x{H}_yuv420p16le.yuv", [[d, c, c]] * frames, np.dtype("<u2"))
    cfg = {"Version": "2.0", "InputCameraParameterFile": "cams.json", "VirtualCameraParameterFile": "cams.json",
           "InputCameraNames": ["v0"], "VirtualCameraNames": ["same", "near"],
           "ViewImageNames": [f"v0_texture_{W}x{H}_yuv420p.yuv"],
           "DepthMapNames": [f"v0_depth_{W}x{H}_yuv420p16le.yuv"],
           "OutputFiles": ["same_out.yuv", "near_out.yuv"], "StartFrame": 0, "NumberOfFrames": frames, **extra}
    (tmp_path / "rvs.json").write_text(json.dumps(cfg))
    return tmp_path / "rvs.json"


def test_parse_frames():
    assert parse_frames("1:3") == (1, 3) and parse_frames("2:") == (2, None) and parse_frames(":4") == (0, 4)
    assert parse_frames("all") == (0, None) and parse_frames("default") is None
    for bad in ("3", "3:3", "4:2", "-1:2", "a:b", ""):
        with pytest.raises(BadValueError, match=r"frames .*: expected A:B"):
            parse_frames(bad)


def test_frame_range_and_load_frames(tmp_path):
    cfg = make_sequence(tmp_path)
    held, default = mpeg.frame_range(cfg, {})
    assert held == FRAMES and default == range(0, FRAMES)
    video, scenes = load_frames(cfg, frames="1:3")
    assert list(scenes) == ["f001", "f002"] and [t.name for t in video.targets] == ["same", "near"]
    assert video.source["frames"] == [1, 3]
    for name, i in (("f001", 1), ("f002", 2)):
        np.testing.assert_array_equal(scenes[name].view("v0").color, mpeg.load(cfg, {"frame": i}).view("v0").color)
    assert set(load_frames(cfg)[1]) == {"f000", "f001", "f002"}  # default: StartFrame, NumberOfFrames
    with pytest.raises(BadValueError, match=r"frames .2:5.: .*has 3 frame"):
        load_frames(cfg, frames="2:5")
    with pytest.raises(BadValueError, match="frames: not with the importer's option frame="):
        load_frames(cfg, options={"frame": 1}, frames="all")
    with pytest.raises(BadValueError, match="frame 3 asked for"):  # one frame beyond the files
        mpeg.load(cfg, {"frame": 3})


def test_load_frames_refuses_formats_without_frames(tmp_path):
    (tmp_path / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": []}))
    with pytest.raises(BadValueError, match="one frame per view"):
        load_frames(tmp_path / "transforms.json", "nerf", frames="all")


def test_preprocess_frames_makes_a_video_scene(tmp_path):
    cfg = make_sequence(tmp_path)
    out = tmp_path / "scene"
    assert preprocess_cli.main([str(cfg), "-o", str(out), "--frames", "0:2", "--quiet"]) == 0
    doc = json.loads((out / "scene.json").read_text())
    assert doc["version"] == 2 and doc["frames"] == ["f000", "f001"]
    assert (out / "frames" / "f001" / "scene.json").is_file()
    # bad values: one line, exit 2, nothing written
    for argv in (["--frames", "5:9"], ["--frames", "x"], ["--frames", "0:2", "--holdout", "v0"]):
        bad = tmp_path / "bad"
        assert preprocess_cli.main([str(cfg), "-o", str(bad), *argv, "--quiet"]) == 2
        assert not bad.exists()
    assert preprocess_cli.main(["synth:objects", "-o", str(tmp_path / "s"), "--frames", "0:2", "--quiet"]) == 2


def _y_planes(path, bits, n):
    return [yuv.read_frame(path, W, H, bits, i)[0].astype(np.int64) for i in range(n)]


def test_render_rvs_config_one_command(tmp_path, capsys):
    cfg = make_sequence(tmp_path)
    out = tmp_path / "out"
    assert render_cli.main([str(cfg), "-o", str(out), "--inpaint", "none"]) == 0
    err = capsys.readouterr().err
    assert "RVS config" in err
    report = json.loads((out / "report.json").read_text())
    assert {f["name"] for f in report["frames"]} == {f"f00{i}_{c}" for i in range(FRAMES) for c in ("same", "near")}
    files = {y["camera"]: y for y in report["yuv"]}
    assert files["same"]["bits"] == 10 and files["near"]["bits"] == 8 and files["same"]["frames"] == FRAMES
    # "same" sits at the input camera: each output frame is that frame of the input, up to the
    # YUV round trip (8 -> 10 bits: x4) and the plane's edge pixels.
    src = _y_planes(tmp_path / f"v0_texture_{W}x{H}_yuv420p.yuv", 8, FRAMES)
    got = _y_planes(out / "same_out.yuv", 10, FRAMES)
    for s, g in zip(src, got):
        inner = np.s_[2:-2, 2:-2]
        assert np.abs(g[inner] - 4 * s[inner]).max() <= 8
    assert np.abs(got[2][2:-2, 2:-2] - got[0][2:-2, 2:-2]).mean() > 100  # the frames differ: 20 codes x 4
    assert (out / "near_out.yuv").stat().st_size == FRAMES * yuv.frame_bytes(W, H, 8, "420")
    # a second run: the scene is up to date, the outputs are the same bytes
    first = (out / "same_out.yuv").read_bytes()
    assert render_cli.main([str(cfg), "-o", str(out), "--inpaint", "none", "--quiet"]) == 0
    assert (out / "same_out.yuv").read_bytes() == first


def test_render_rvs_config_bad_input(tmp_path, capsys):
    cfg = make_sequence(tmp_path, VirtualPoseTraceName="trace.csv")
    out = tmp_path / "out"
    assert render_cli.main([str(cfg), "-o", str(out)]) == 2
    assert "VirtualPoseTraceName" in capsys.readouterr().err and not (out / "scene").exists()
    cfg = make_sequence(tmp_path)
    assert render_cli.main([str(cfg), "-o", str(out), "--yuv", str(tmp_path / "x.yuv")]) == 2
    assert "OutputFiles" in capsys.readouterr().err
    doc = json.loads(cfg.read_text())
    doc["OutputFiles"] = ["a.yuv"]
    cfg.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="OutputFiles"):
        mpeg.config_outputs(cfg)
    doc["OutputFiles"] = ["a.yuv", "b.yuv"]
    for bad in (1e400, -1, 1.5, "3"):  # 1e400: JSON's overflow to infinity
        cfg.write_text(json.dumps(doc).replace('"NumberOfFrames": 3', f'"NumberOfFrames": {json.dumps(bad) if bad != 1e400 else "1e400"}'))
        with pytest.raises(FormatError, match="NumberOfFrames"):
            mpeg.config_outputs(cfg)


def test_yuv_file_per_camera_pattern(tmp_path):
    cfg = make_sequence(tmp_path, frames=1)
    scene = tmp_path / "scene"
    assert preprocess_cli.main([str(cfg), "-o", str(scene), "--quiet"]) == 0
    out = tmp_path / "out"
    assert render_cli.main([str(scene), "-o", str(out), "--yuv", str(out / "v_{camera}.yuv"), "--yuv-bits", "8",
                            "--quiet"]) == 2  # its folder does not exist yet
    out.mkdir()
    assert render_cli.main([str(scene), "-o", str(out), "--yuv", str(out / "v_{camera}.yuv"), "--yuv-bits", "8",
                            "--quiet"]) == 0
    for c in ("same", "near"):
        assert (out / f"v_{c}.yuv").stat().st_size == yuv.frame_bytes(W, H, 8, "420")
