"""Hostile and careless input files: a decompression bomb, truncated, garbage,
wrong-size and NaN images, overflowing scales and poses, a COLMAP camera of width 0 and scene.json
names that are not strings. Each is refused with a typed error whose one line names the file and
what was expected; the commands exit 2 and write nothing. Memory is bounded: an image's size is
checked from its header before any pixel is decoded."""
from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from ibrtools import Camera, Scene, View, look_at
from ibrtools.errors import BadValueError, FormatError, ShapeError
from ibrtools.formats import load, native
from ibrtools.imageio import MAX_PIXELS, read_depth, read_header, read_image, read_mask, read_pixels, write_image
from ibrtools_cli import preprocess, render

BIN = Path(sys.executable).parent
W, H = 160, 120


def _cmd(name: str) -> list[str]:
    exe = BIN / name
    if exe.is_file():
        return [str(exe)]
    module = {"ibr-render": "ibrtools_cli.render", "ibr-preprocess": "ibrtools_cli.preprocess"}[name]
    return [sys.executable, "-c", f"import sys; from {module} import main; sys.exit(main())"]


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_of_zeros(path: Path, width: int, height: int, *, rows: int | None = None) -> Path:
    """An 8-bit grey PNG of zeros written row by row (no image-sized array): 12000 x 12000 is
    144 MB of pixels in a file of about 140 KB. ``rows``: stop after that many rows (a header
    promising more pixels than the file holds; only the header check may read it)."""
    comp = zlib.compressobj(9)
    row = b"\0" * (width + 1)  # filter byte 0, then the row
    parts = []
    for _ in range(height if rows is None else rows):
        parts.append(comp.compress(row))
    parts.append(comp.flush())
    with open(path, "wb") as fh:
        fh.write(b"\x89PNG\r\n\x1a\n")
        fh.write(_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)))
        fh.write(_chunk(b"IDAT", b"".join(parts)))
        fh.write(_chunk(b"IEND", b""))
    return path


def make_scene(root: Path, color_format: str = "png", rng=None) -> Path:
    """Three 160 x 120 views with colour and depth, and one target: the smallest scene that
    ``ibr-render --method dibr`` renders."""
    rng = rng or np.random.default_rng(5)
    views = []
    for i in range(3):
        cam = Camera.pinhole(W, H, 150.0, 150.0, 80.0, 60.0, look_at([0.3 * (i - 1), 0.0, -3.0], [0, 0, 0]))
        views.append(View.create(f"v{i:03d}", cam, color=rng.uniform(0, 1, (H, W, 3)).astype(np.float32),
                                 depth=rng.uniform(2.5, 3.5, (H, W)).astype(np.float32)))
    target = View.create("t0", Camera.pinhole(W, H, 150.0, 150.0, 80.0, 60.0, look_at([0.1, 0.0, -3.0], [0, 0, 0])))
    native.save(Scene(views=views, targets=[target]), root, color_format=color_format)
    return root


def _render(scene: Path, out: Path, capsys) -> tuple[int, str]:
    code = render.main([str(scene), "--method", "dibr", "-o", str(out), "-q"])
    return code, capsys.readouterr().err.strip()


def _one_line(err: str, *needles: str) -> None:
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, (n, err)


# --- 1. decompression bomb ----------------------------------------------------------------------
def test_bomb_in_a_native_scene_is_refused_from_its_header(tmp_path):
    """12000 x 12000 zeros in a view whose camera says 160 x 120: before, decoded whole (4.3 GB
    peak, 11 s) and then refused per frame (exit 1). Now refused from its header: exit 2, one
    line, in about a second, the memory of a normal start."""
    scene = make_scene(tmp_path / "s")
    bomb = png_of_zeros(scene / "images" / "v001.png", 12000, 12000)
    assert bomb.stat().st_size < 1 << 20
    t0 = time.monotonic()
    # The peak is measured by a small launcher: a process started straight from this (large)
    # test worker would inherit the worker's high-water mark, kept by Linux across exec.
    launcher = ("import os, subprocess, sys; p = subprocess.Popen(sys.argv[2:]); _, st, u = os.wait4(p.pid, 0); "
                "open(sys.argv[1], 'w').write(str(u.ru_maxrss)); sys.exit(os.waitstatus_to_exitcode(st))")
    peak_file = tmp_path / "peak.txt"
    proc = subprocess.run([sys.executable, "-c", launcher, str(peak_file)] + _cmd("ibr-render")
                          + [str(scene), "--method", "dibr", "-o", str(tmp_path / "out")],
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    err = proc.stderr
    assert proc.returncode == 2, err
    assert err.count("\n") == 1
    assert err.startswith("ibr-render: error: ") and "v001.png: image is 12000x12000, the camera says 160x120" in err
    peak_kb = int(peak_file.read_text())
    assert peak_kb < 1 << 20, f"peak {peak_kb} KB"  # KB on Linux: under 1 GB (decoding: 4.3 GB)
    assert time.monotonic() - t0 < 60
    assert not (tmp_path / "out" / "report.json").exists()


def test_expected_size_is_checked_before_decoding(tmp_path):
    # the header promises 12000 x 12000, the file holds 10 rows: only a header check can pass it by
    f = png_of_zeros(tmp_path / "b.png", 12000, 12000, rows=10)
    for fn in (lambda: read_pixels(f, (W, H)), lambda: read_image(f, size=(W, H)), lambda: read_mask(f, size=(W, H)),
               lambda: read_depth(f, size=(W, H), scale=1.0), lambda: read_header(f, (W, H))):
        with pytest.raises(ShapeError, match=r"b.png: image is 12000x12000, the camera says 160x120$"):
            fn()


def test_ceiling_without_an_expected_size(tmp_path, monkeypatch):
    side = int(MAX_PIXELS ** 0.5) + 1  # 16385 x 16385: one row is enough, the header is refused
    f = png_of_zeros(tmp_path / "huge.png", side, side, rows=1)
    with pytest.raises(ShapeError, match=rf"huge.png: image is {side}x{side} \(268 Mpixels\), more than the 268"):
        read_image(f)
    # under the ceiling but beyond the memory available (IBR_MEMORY_LIMIT stands for it)
    g = png_of_zeros(tmp_path / "big.png", 8000, 8000, rows=1)
    monkeypatch.setenv("IBR_MEMORY_LIMIT", "100M")
    with pytest.raises(BadValueError, match=r"big.png: image is 8000x8000 with 1 channels: decoding needs 0.8 GiB"):
        read_image(g)


# --- 2. colour (and masks) checked up front -------------------------------------------------------
def _truncate(f: Path) -> None:
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])


def _garbage(f: Path) -> None:
    f.write_bytes(os.urandom(3000))


def _wrong_size(f: Path) -> None:
    write_image(f, np.zeros((H // 2, W, 3), np.float32))


@pytest.mark.parametrize("damage, err, msg", [
    (_truncate, FormatError, r"v001.png: truncated PNG \(no IEND chunk at the end of its \d+ bytes\)"),
    (_garbage, FormatError, r"v001.png: not a readable image \("),
    (_wrong_size, ShapeError, r"v001.png: image is 160x60, the camera says 160x120"),
])
def test_bad_colour_stops_render_before_any_frame(tmp_path, capsys, damage, err, msg):
    scene = make_scene(tmp_path / "s")
    damage(scene / "images" / "v001.png")
    with pytest.raises(err, match=msg):
        load(scene)
    code, text = _render(scene, tmp_path / "out", capsys)
    assert code == 2
    _one_line(text, "ibr-render: error: ", "v001.png")
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_bad_mask_is_checked_up_front(tmp_path):
    scene = make_scene(tmp_path / "s")
    doc = json.loads((scene / "scene.json").read_text())
    write_image(scene / "images" / "v000.mask.png", np.ones((H, W + 1), np.float32))
    doc["views"][0]["mask"] = "images/v000.mask.png"
    (scene / "scene.json").write_text(json.dumps(doc))
    with pytest.raises(ShapeError, match=r"v000.mask.png: image is 161x120, the camera says 160x120"):
        load(scene)


def _nan_exr_scene(tmp_path: Path) -> Path:
    import OpenImageIO as oiio

    scene = make_scene(tmp_path / "s", color_format="exr")
    f = scene / "images" / "v001.exr"
    img = read_image(f)
    img[10, 20, 1] = np.nan  # write_image writes NaN as 0: OpenImageIO directly
    out = oiio.ImageOutput.create(str(f))
    assert out.open(str(f), oiio.ImageSpec(W, H, 3, "float")) and out.write_image(img)
    out.close()
    return scene


def test_nan_colour_is_a_typed_error_at_first_load_every_time(tmp_path):
    """A NaN needs the pixels: found when the colour is first loaded (decoding every view up front
    costs 51 ms per 1080p PNG, 90-125 ms per EXR, against 0.1-0.2 ms for a header). The failed
    check is not cached: a second use fails the same way (before, it got the unchecked array)."""
    s = load(_nan_exr_scene(tmp_path))
    for _ in range(2):
        with pytest.raises(BadValueError, match=r"v001.exr: colour contains NaN or infinity \(1 values\)"):
            _ = s.views[1].color


def test_nan_colour_stops_render(tmp_path, capsys):
    code, text = _render(_nan_exr_scene(tmp_path), tmp_path / "out", capsys)
    assert code == 2
    _one_line(text, "v001.exr: colour contains NaN")


# --- 3. decoding errors are one line, nothing on stderr from libpng -------------------------------
def test_decoding_errors_are_one_line_and_libpng_is_quiet(tmp_path, capfd):
    good = write_image(tmp_path / "g.png", np.random.default_rng(1).uniform(0, 1, (64, 64, 3)).astype(np.float32))
    data = good.read_bytes()
    cut_header = tmp_path / "h.png"
    cut_header.write_bytes(data[:60])   # within the header chunks: fails at open
    cut_pixels = tmp_path / "p.png"
    cut_pixels.write_bytes(data[: len(data) // 2])  # within IDAT: fails at decode
    for f, msg in ((cut_header, "not a readable image"), (cut_pixels, "could not decode")):
        with pytest.raises(FormatError) as e:
            read_image(f)
        text = str(e.value)
        assert f.name in text and msg in text and "\n" not in text and len(text) < 400, text
    out, err = capfd.readouterr()
    assert "libpng" not in err and err == "", err
    assert read_image(good).shape == (64, 64, 3)  # and a good file afterwards: fd 2 was restored
    print("still here", file=sys.stderr)
    assert capfd.readouterr().err == "still here\n"


def test_cli_stderr_is_one_line_for_a_file_cut_in_its_header(tmp_path):
    scene = make_scene(tmp_path / "s")
    f = scene / "images" / "v002.png"
    f.write_bytes(f.read_bytes()[:70])
    r = subprocess.run(_cmd("ibr-render") + [str(scene), "--method", "dibr", "-o", str(tmp_path / "out")],
                       capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "libpng error" not in r.stderr and "v002.png: not a readable image" in r.stderr


# --- 4. numbers that overflow --------------------------------------------------------------------
def test_depth_scale_that_overflows_float32(tmp_path, capsys):
    from conftest import need_data

    icl = need_data("icl_nuim_livingroom")
    argv = [str(icl), "-o", str(tmp_path / "x"), "--format", "rgbd", "--opt", "fx=481.2", "--opt", "fy=-480.0",
            "--opt", "cx=319.5", "--opt", "cy=239.5", "--opt", "depth_scale=1e308", "-q"]
    assert preprocess.main(argv) == 2
    _one_line(capsys.readouterr().err, "option depth_scale: 1e+308 times 65535", "overflows float32")
    assert not (tmp_path / "x").exists()


def test_read_depth_refuses_an_overflowing_scale(tmp_path):
    import warnings

    from ibrtools.imageio import write_depth

    f = write_depth(tmp_path / "d.exr", np.full((4, 5), 1e9, np.float32))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning either
        with pytest.raises(BadValueError, match=r"d.exr: depth scale 1e\+30 times the stored value 1e\+09 overflows"):
            read_depth(f, scale=1e30)
        with pytest.raises(BadValueError, match=r"d.exr: depth scale 1e\+308 is not a positive float32"):
            read_depth(f, scale=1e308)
        assert read_depth(f, scale=2.0).max() == 2e9



def test_nerf_depth_scale_that_overflows_float32(tmp_path, capsys):
    from conftest import need_data

    lego = need_data("nerf_lego")
    assert preprocess.main([str(lego), "-o", str(tmp_path / "y"), "--opt", "depth_scale=1e308", "-q"]) == 2
    _one_line(capsys.readouterr().err, "option depth_scale: 1e+308 overflows float32")


@pytest.mark.parametrize("key, value, msg", [
    ("Position", [1e308, 0, 0], r"'Position' \[1e\+308, 0.0, 0.0\] is beyond \+-1e\+12"),
    ("Focal", [1e308, 10.0], r"fx: focal length 1e\+308 is outside"),
    ("Resolution", [1e308, 6], r"camera width: expected an integer <= 65536"),
    ("Depth_range", [1e-320, 10.0], r"Depth_range near 9.99989e-321 is below 1e-09"),
])
def test_mpeg_camera_values_out_of_range(key, value, msg):
    import warnings

    from ibrtools.formats.mpeg import MpegCamera

    c = {"Name": "v0", "Position": [0, 0, 0], "Rotation": [0, 0, 0], "Depthmap": 1, "Depth_range": [0.5, 1000.0],
         "Resolution": [8, 6], "Projection": "Perspective", "Focal": [10.0, 10.0], "Principle_point": [4.0, 3.0]}
    c[key] = value
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(BadValueError, match=r"cams.json cameras\[0\] \(v0\): " + msg):
            MpegCamera(c, "cams.json cameras[0]").check_depth_range()

@pytest.mark.parametrize("edit, msg", [
    (lambda c: c["cam_from_world"][0].__setitem__(3, 1e308), "cam_from_world: translation 1e+308 is beyond +-1e+12"),
    (lambda c: c.update(fx=1e308), "fx: focal length 1e+308 is outside 0.001 to 1e+09 pixels"),
    (lambda c: c.update(cx=-1e300), "cx: principal point -1e+300 is beyond +-1e+09 pixels"),
    (lambda c: c.update(width=100000), "camera width: expected an integer <= 65536, got 100000"),
    (lambda c: c["cam_from_world"][0].__setitem__(0, 1e200), "not a rigid pose (rotation entry 1e+200)"),
])
def test_huge_camera_values_one_line_no_warning(tmp_path, capsys, edit, msg):
    scene = make_scene(tmp_path / "s")
    doc = json.loads((scene / "scene.json").read_text())
    cam = json.loads(json.dumps(doc["views"][0]["camera"]))
    edit(cam)
    # in a pose file (--poses) and in scene.json
    (tmp_path / "poses.json").write_text(json.dumps([cam]))
    assert render.main([str(scene), "--poses", str(tmp_path / "poses.json"), "-o", str(tmp_path / "o1"), "-q"]) == 2
    _one_line(capsys.readouterr().err, "poses.json[0]", msg)
    doc["views"][0]["camera"] = cam
    (scene / "scene.json").write_text(json.dumps(doc))
    assert render.main([str(scene), "-o", str(tmp_path / "o2"), "-q"]) == 2
    _one_line(capsys.readouterr().err, "scene.json: views[0].camera", msg)
    assert "RuntimeWarning" not in capsys.readouterr().err


# --- 5. importers' camera errors name their file ---------------------------------------------------
def test_colmap_camera_of_width_zero_names_cameras_txt(tmp_path, capsys):
    d = tmp_path / "colmap"
    (d / "sparse" / "0").mkdir(parents=True)
    (d / "images").mkdir()
    write_image(d / "images" / "a.png", np.zeros((H, W, 3), np.float32))
    (d / "sparse" / "0" / "cameras.txt").write_text(f"1 PINHOLE 0 {H} 150 150 80 60\n")
    (d / "sparse" / "0" / "images.txt").write_text("1 1 0 0 0 0 0 3 1 a.png\n\n")
    with pytest.raises(BadValueError, match=r"cameras.txt: camera 1: camera width: expected an integer >= 1, got 0"):
        load(d)
    assert preprocess.main([str(d), "-o", str(tmp_path / "s"), "-q"]) == 2
    _one_line(capsys.readouterr().err, "cameras.txt: camera 1: camera width")


# --- 6. scene.json names ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", [None, 3, ["v"], {"a": 1}, "", True])
def test_scene_json_names_must_be_strings(tmp_path, capsys, name):
    scene = make_scene(tmp_path / "s")
    doc = json.loads((scene / "scene.json").read_text())
    doc["targets"][0]["name"] = name
    (scene / "scene.json").write_text(json.dumps(doc))
    with pytest.raises(FormatError, match=r"scene.json: targets\[0\].name: expected a non-empty string, got "):
        load(scene)
    assert render.main([str(scene), "-o", str(tmp_path / "o"), "-q"]) == 2
    _one_line(capsys.readouterr().err, "targets[0].name")


def test_scene_json_names_with_slashes_stay_legal(tmp_path):
    scene = make_scene(tmp_path / "s")
    doc = json.loads((scene / "scene.json").read_text())
    doc["targets"][0]["name"] = "../a/b"
    (scene / "scene.json").write_text(json.dumps(doc))
    assert load(scene).targets[0].name == "../a/b"

