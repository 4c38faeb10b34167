"""MPEG/RVS importer and raw YUV reader on tiny fixtures written here (hand-derived answers)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ibrtools.errors import BadValueError, FormatError, MissingFileError
from ibrtools.formats import mpeg, yuv
from ibrtools.imageio import srgb_to_linear

W, H = 8, 6


def write_yuv(path, planes, bits):
    dtype = np.uint8 if bits <= 8 else np.dtype("<u2")
    with open(path, "wb") as f:
        for frame in planes:
            for p in frame:
                f.write(np.asarray(p, dtype=dtype).tobytes())


def yuv_frame(y, cb, cr, w=W, h=H):
    return [np.full((h, w), y), np.full(((h + 1) // 2, (w + 1) // 2), cb), np.full(((h + 1) // 2, (w + 1) // 2), cr)]


def cam(name, pos=(0, 0, 0), rot=(0, 0, 0), **kw):
    c = {"Name": name, "Position": list(pos), "Rotation": list(rot), "Depthmap": 1, "Depth_range": [0.5, 1000.0],
         "Resolution": [W, H], "Projection": "Perspective", "Focal": [10.0, 10.0], "Principle_point": [4.0, 3.0],
         "BitDepthColor": 8, "BitDepthDepth": 16, "ColorSpace": "YUV420", "DepthColorSpace": "YUV420"}
    c.update(kw)
    return c


def write_cams(path, cams):
    path.write_text(json.dumps({"Version": "4.0", "cameras": cams}))
    return path


# --- poses: OMAF axes and Euler angles, checked through projection -------------------------------
def test_identity_pose_axes():
    m = mpeg.cam_from_world((0, 0, 0), (0, 0, 0))
    # OMAF forward (x) is OpenCV z, left (y) is -x, up (z) is -y.
    np.testing.assert_allclose(m[:3, :3] @ [1, 0, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(m[:3, :3] @ [0, 1, 0], [-1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(m[:3, :3] @ [0, 0, 1], [0, -1, 0], atol=1e-15)


@pytest.mark.parametrize("rot, point, uv", [
    # yaw 90: the camera looks along world +y (left); a point 5 m ahead is at the principal point.
    ((90, 0, 0), (1, 7, 3), (4.0, 3.0)),
    # pitch 90 (Ry): forward x turns to -z: the camera looks down.
    ((0, 90, 0), (1, 2, -2), (4.0, 3.0)),
    # roll 90 (Rx): the camera's left turns to world up: a point 1 m above, 5 ahead, is 2 px left.
    ((0, 0, 90), (6, 2, 4), (4.0 - 10.0 * 1 / 5, 3.0)),
    # no rotation: a point 1 m up and 1 m left of the axis, 5 ahead: u = cx - f y/x, v = cy - f z/x.
    ((0, 0, 0), (6, 3, 4), (2.0, 1.0)),
])
def test_euler_conventions_project(tmp_path, rot, point, uv):
    f = write_cams(tmp_path / "cams.json", [cam("v0", pos=(1, 2, 3), rot=rot)])
    scene = mpeg.load(f, {})
    c = scene.targets[0].camera  # no images beside the JSON: the camera is a target
    xy, z = c.project(np.array(point, float))
    np.testing.assert_allclose(xy, uv, atol=1e-12)
    np.testing.assert_allclose(z, 5.0, atol=1e-12)
    np.testing.assert_allclose(c.centre, (1, 2, 3), atol=1e-12)


def test_equirect_ranges(tmp_path):
    f = write_cams(tmp_path / "cams.json", [cam("erp", Projection="Equirectangular", Hor_range=[-90, 180],
                                                   Ver_range=[-45, 60], Resolution=[270, 105])])  # 1 px per degree
    c = mpeg.load(f, {}).targets[0].camera
    assert c.model == "equirect"
    np.testing.assert_allclose(np.degrees(c.lon_range), (-180, 90))
    np.testing.assert_allclose(np.degrees(c.lat_range), (-45, 60))
    # OMAF phi = 180 at the left edge; a point to the left (phi = +90) sits 90 deg from the left edge.
    xy, r = c.project(np.array([0.0, 2.0, 0.0]))
    np.testing.assert_allclose(xy, (90.0, 60.0), atol=1e-9)
    np.testing.assert_allclose(r, 2.0)
    # Straight up by 60 deg is the top edge.
    xy, _ = c.project(np.array([math.cos(math.radians(60)), 0, math.sin(math.radians(60))]))
    np.testing.assert_allclose(xy, (180.0, 0.0), atol=1e-9)


# --- depth decoding -----------------------------------------------------------------------------------
def test_decode_depth_values():
    v = np.array([0, 65535, 32767.5 * 0 + 32768, 13107])
    d = mpeg.decode_depth(v, 16, 0.5, 1000.0)
    assert np.isinf(d[0])  # far >= 1000 is infinity; v = 0 -> at infinity
    assert d[1] == pytest.approx(0.5)  # vmax -> near
    assert d[2] == pytest.approx(0.5 * 65535 / 32768, rel=1e-6)
    d = mpeg.decode_depth(np.array([0, 65535, 32768]), 16, 1.0, 4.0)
    assert d[0] == pytest.approx(4.0) and d[1] == pytest.approx(1.0)
    assert d[2] == pytest.approx(1 / (32768 / 65535 * 0.75 + 0.25), rel=1e-6)
    d = mpeg.decode_depth(np.array([0, 1023]), 10, 1.0, 4.0, invalid_zero=True)
    assert d[0] == 0 and d[1] == pytest.approx(1.0)
    with pytest.raises(BadValueError, match="exceeds"):
        mpeg.decode_depth(np.array([1024]), 10, 1.0, 4.0, where="x.yuv")


# --- YUV reading and colour ---------------------------------------------------------------------------
def test_yuv_grey_and_primaries_bt709_limited(tmp_path):
    f = tmp_path / "c.yuv"
    # Two frames: mid grey, then BT.709 limited-range red (Y 63, Cb 102, Cr 240).
    write_yuv(f, [yuv_frame(128, 128, 128), yuv_frame(63, 102, 240)], 8)
    grey = yuv.yuv_to_rgb(yuv.read_frame(f, W, H, 8, 0), 8)
    np.testing.assert_allclose(grey, srgb_to_linear(np.float32((128 - 16) / 219)), atol=1e-6)
    red = yuv.yuv_to_rgb(yuv.read_frame(f, W, H, 8, 1), 8)
    # 8-bit rounding of the codes leaves < 1 % of full scale on R'G'B' (0.005 in linear near 0).
    np.testing.assert_allclose(red[0, 0], [1.0, 0.0, 0.0], atol=0.01)


def test_yuv_10bit_little_endian_and_full_range(tmp_path):
    f = tmp_path / "c10.yuv"
    write_yuv(f, [yuv_frame(512, 512, 512)], 10)
    rgb = yuv.yuv_to_rgb(yuv.read_frame(f, W, H, 10, 0), 10, full_range=True)
    np.testing.assert_allclose(rgb, srgb_to_linear(np.float32(512 / 1023)), atol=1e-6)


def test_yuv_wrong_size_names_file_and_bytes(tmp_path):
    f = tmp_path / "bad.yuv"
    f.write_bytes(b"\0" * 100)
    with pytest.raises(FormatError) as e:
        yuv.read_frame(f, W, H, 8)
    msg = str(e.value)
    assert "bad.yuv" in msg and "100 bytes" in msg and str(yuv.frame_bytes(W, H, 8)) in msg


def test_yuv_frame_out_of_range_and_missing(tmp_path):
    f = tmp_path / "c.yuv"
    write_yuv(f, [yuv_frame(16, 128, 128)], 8)
    with pytest.raises(BadValueError, match="frame 1"):
        yuv.read_frame(f, W, H, 8, frame=1)
    with pytest.raises(MissingFileError, match="nope.yuv"):
        yuv.read_frame(tmp_path / "nope.yuv", W, H, 8)
    with pytest.raises(BadValueError):
        yuv.plane_shapes(W, H, "422")


# --- whole-scene import -------------------------------------------------------------------------------
def make_content(tmp_path, bits_depth=16):
    cams = [cam("v0", pos=(0, 0, 0), BitDepthDepth=bits_depth), cam("v1", pos=(0, -0.1, 0), BitDepthDepth=bits_depth),
            cam("virt", pos=(0, -0.05, 0))]
    write_cams(tmp_path / "cams.json", cams)
    vmax = (1 << bits_depth) - 1
    for n in ("v0", "v1"):
        write_yuv(tmp_path / f"{n}_texture_{W}x{H}_yuv420p.yuv", [yuv_frame(16, 128, 128), yuv_frame(235, 128, 128)], 8)
        # depth 1 m everywhere: 1/1 = v/vmax * (1/0.5 - 0) -> v = vmax / 2
        write_yuv(tmp_path / f"{n}_depth_{W}x{H}_yuv420p16le.yuv",
                  [yuv_frame(round(vmax / 2), 0, 0), yuv_frame(vmax, 0, 0)], bits_depth)
    return tmp_path / "cams.json"


def test_camera_file_with_yuv(tmp_path):
    f = make_content(tmp_path)
    assert mpeg.detect(f) and mpeg.detect(tmp_path)
    scene = mpeg.load(f, {})
    assert [v.name for v in scene.views] == ["v0", "v1"] and [t.name for t in scene.targets] == ["virt"]
    assert scene.units == "m"
    v0 = scene.view("v0")
    np.testing.assert_allclose(v0.color, 0.0, atol=1e-7)  # Y = 16: black in limited range
    # v = 32768: 1/d = 32768/65535 * (1/0.5 - 0) -> d = 65535 / 65536
    np.testing.assert_allclose(v0.depth, 65535 / 65536, rtol=1e-7)
    s1 = mpeg.load(f, {"frame": "1"})
    np.testing.assert_allclose(s1.view("v1").color, 1.0, atol=1e-6)  # Y = 235: white
    np.testing.assert_allclose(s1.view("v1").depth, 0.5, rtol=1e-6)  # vmax -> near
    assert not scene.targets[0].has_color


def test_rvs_config(tmp_path):
    make_content(tmp_path)
    (tmp_path / "gt.yuv").write_bytes(open(tmp_path / f"v0_texture_{W}x{H}_yuv420p.yuv", "rb").read())
    cfg = {"Version": "2.0", "InputCameraParameterFile": "cams.json", "VirtualCameraParameterFile": "cams.json",
           "InputCameraNames": ["v1", "v0"], "VirtualCameraNames": ["virt"],
           "ViewImageNames": [f"v1_texture_{W}x{H}_yuv420p.yuv", f"v0_texture_{W}x{H}_yuv420p.yuv"],
           "DepthMapNames": [f"v1_depth_{W}x{H}_yuv420p16le.yuv", f"v0_depth_{W}x{H}_yuv420p16le.yuv"],
           "OutputFiles": ["out.yuv"], "StartFrame": 1, "NumberOfFrames": 1}
    (tmp_path / "rvs.json").write_text(json.dumps(cfg))
    assert mpeg.detect(tmp_path / "rvs.json")
    scene = mpeg.load(tmp_path / "rvs.json", {"target_images": "gt.yuv"})
    assert [v.name for v in scene.views] == ["v1", "v0"]
    np.testing.assert_allclose(scene.view("v0").depth, 0.5, rtol=1e-6)  # StartFrame 1 is the default frame
    t = scene.target("virt")
    np.testing.assert_allclose(t.camera.centre, (0, -0.05, 0), atol=1e-15)
    np.testing.assert_allclose(t.color, 1.0, atol=1e-6)
    with pytest.raises(BadValueError, match="target_images"):
        mpeg.load(tmp_path / "rvs.json", {"target_images": "a.yuv,b.yuv"})
    # Bad input: a config naming a camera the camera file does not hold.
    cfg["InputCameraNames"] = ["v1", "nope"]
    (tmp_path / "rvs.json").write_text(json.dumps(cfg))
    with pytest.raises(FormatError, match="nope"):
        mpeg.load(tmp_path / "rvs.json", {})


def test_wrong_yuv_size_at_import(tmp_path):
    f = make_content(tmp_path)
    p = tmp_path / f"v1_texture_{W}x{H}_yuv420p.yuv"
    p.write_bytes(p.read_bytes()[:-3])
    with pytest.raises(FormatError, match=r"v1_texture.*141 bytes.*72 bytes each"):
        mpeg.load(f, {})


def test_bad_camera_files(tmp_path):
    f = tmp_path / "c.json"
    f.write_text("{ not json")
    with pytest.raises(FormatError, match="c.json.*malformed JSON"):
        mpeg.load(f, {})
    with pytest.raises(MissingFileError):
        mpeg.read_camera_file(tmp_path / "missing.json")
    c = cam("v0")
    del c["Focal"]
    write_cams(f, [c])
    with pytest.raises(FormatError, match=r"c.json cameras\[0\] \(v0\).*'Focal'"):
        mpeg.load(f, {})
    write_cams(f, [cam("v0", Focal=[0.0, 10.0])])
    with pytest.raises(BadValueError, match=r"c.json.*v0.*focal"):
        mpeg.load(f, {})
    write_cams(f, [cam("v0", Rotation=[0, "x", 0])])
    with pytest.raises(FormatError, match="Rotation"):
        mpeg.load(f, {})
    write_cams(f, [cam("v0", Projection="Fisheye")])
    with pytest.raises(FormatError, match="Fisheye"):
        mpeg.load(f, {})
    write_cams(f, [cam("v0"), cam("v0")])
    with pytest.raises(FormatError, match="twice"):
        mpeg.load(f, {})


def test_bad_depth_range_and_options(tmp_path):
    f = make_content(tmp_path)
    doc = json.loads(f.read_text())
    doc["cameras"][0]["Depth_range"] = [2.0, 1.0]
    f.write_text(json.dumps(doc))
    with pytest.raises(BadValueError, match="Depth_range"):
        mpeg.load(f, {})
    f = make_content(tmp_path)
    with pytest.raises(BadValueError, match="unknown option"):
        mpeg.load(f, {"frmae": 1})
    with pytest.raises(BadValueError, match="yuv_range"):
        mpeg.load(f, {"yuv_range": "tv"})
    with pytest.raises(BadValueError, match="frame 5"):
        mpeg.load(f, {"frame": 5}).view("v0").color


def test_round_trip_native(tmp_path):
    from ibrtools.formats import native

    (tmp_path / "in").mkdir()
    f = make_content(tmp_path / "in")
    scene = mpeg.load(f, {})
    native.save(scene, tmp_path / "out")
    back = native.load(tmp_path / "out", {})
    for a, b in zip(scene.views + scene.targets, back.views + back.targets):
        assert a.name == b.name and a.camera.allclose(b.camera, 1e-9)
