"""NeRF importer on tiny fixtures written here: cameras by hand, compositing, depth decoding, errors."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ibrtools.errors import BadValueError, FormatError, MissingFileError, ShapeError
from ibrtools.formats import nerf
from ibrtools.imageio import _oiio, srgb_to_linear

W, H = 8, 6


def write_png(path, arr):
    oiio = _oiio()
    arr = np.ascontiguousarray(arr)
    if arr.ndim == 2:
        arr = arr[..., None]
    out = oiio.ImageOutput.create(str(path))
    spec = oiio.ImageSpec(arr.shape[1], arr.shape[0], arr.shape[2], str(arr.dtype))
    spec.attribute("oiio:UnassociatedAlpha", 1)  # store our values as they are (straight alpha)
    out.open(str(path), spec)
    out.write_image(arr)
    out.close()


def make_set(tmp_path, frames=None, **meta):
    (tmp_path / "test").mkdir(exist_ok=True)
    rgba = np.zeros((H, W, 4), np.uint8)
    rgba[..., 0] = 200
    rgba[:, : W // 2, 3] = 255  # left half opaque, right half transparent
    rgba[:, W // 2:, 3] = 64
    write_png(tmp_path / "test" / "r_0.png", rgba)
    depth = np.zeros((H, W, 4), np.uint8)
    depth[..., 0] = 100
    depth[0, 0, 0] = 0
    write_png(tmp_path / "test" / "r_0_depth_0001.png", depth)
    c2w = np.eye(4)
    c2w[:3, 3] = (1.0, 2.0, 3.0)
    doc = {"camera_angle_x": 2 * math.atan(0.5 * W / 10.0),
           "frames": frames if frames is not None else [{"file_path": "./test/r_0", "transform_matrix": c2w.tolist()}]}
    doc.update(meta)
    (tmp_path / "transforms_test.json").write_text(json.dumps(doc))
    return tmp_path


def test_camera_from_blender_pose(tmp_path):
    make_set(tmp_path)
    assert nerf.detect(tmp_path) and nerf.detect(tmp_path / "transforms_test.json")
    scene = nerf.load(tmp_path, {})
    (v,) = scene.views
    c = v.camera
    assert v.name == "r_0" and (c.width, c.height) == (W, H)
    assert c.fx == pytest.approx(10.0) and c.fy == pytest.approx(10.0) and (c.cx, c.cy) == (W / 2, H / 2)
    np.testing.assert_allclose(c.centre, (1, 2, 3), atol=1e-12)
    # Identity Blender rotation: the camera looks along world -z with y up -> OpenCV R = diag(1, -1, -1).
    np.testing.assert_allclose(c.cam_from_world[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    xy, z = c.project(np.array([1.0, 3.0, 1.0]))  # 2 ahead, 1 up -> above the centre
    np.testing.assert_allclose(xy, (W / 2, H / 2 - 10 * 1 / 2))
    assert z == pytest.approx(2.0)


def test_composite_mask_and_depth(tmp_path):
    make_set(tmp_path)
    v = nerf.load(tmp_path, {}).views[0]
    a = 64 / 255
    np.testing.assert_allclose(v.color[0, 0], srgb_to_linear(np.float32([200 / 255, 0, 0])), atol=1e-6)
    np.testing.assert_allclose(v.color[0, -1, 0], srgb_to_linear(np.float32(200 / 255 * a)), atol=1e-6)
    vw = nerf.load(tmp_path, {"background": "white"}).views[0]
    np.testing.assert_allclose(vw.color[0, -1, 1], srgb_to_linear(np.float32(1 - a)), atol=1e-6)
    assert v.mask[:, : W // 2].all() and not v.mask[:, W // 2:].any()
    ray = 8 * (1 - 100 / 255)
    z = v.camera.depth_ray_to_z(np.full((H, W), ray))
    assert v.depth[0, 0] == np.inf  # v = 0: the background at infinity
    np.testing.assert_allclose(v.depth[1:], z[1:], rtol=1e-6)
    v4 = nerf.load(tmp_path, {"depth_scale": "4"}).views[0]
    np.testing.assert_allclose(v4.depth[1, 1], 4 * (1 - 100 / 255) / np.linalg.norm(
        v.camera.rays_in_cam(1.5, 1.5)), rtol=1e-6)
    assert not nerf.load(tmp_path, {"depth": "none"}).views[0].has_depth


def test_instant_ngp_intrinsics_and_splits(tmp_path):
    make_set(tmp_path, fl_x=12.0, fl_y=11.0, cx=3.5, cy=2.5, w=W, h=H)
    (tmp_path / "transforms_train.json").write_text((tmp_path / "transforms_test.json").read_text())
    scene = nerf.load(tmp_path, {})
    assert sorted(v.name for v in scene.views) == ["test/r_0", "train/r_0"]  # stems collide
    c = scene.views[0].camera
    assert (c.fx, c.fy, c.cx, c.cy) == (12.0, 11.0, 3.5, 2.5)
    assert [v.name for v in nerf.load(tmp_path, {"split": "train"}).views] == ["r_0"]


def test_bad_input(tmp_path):
    make_set(tmp_path)
    f = tmp_path / "transforms_test.json"
    with pytest.raises(MissingFileError, match="transforms_val"):
        nerf.load(tmp_path, {"split": "val"})
    with pytest.raises(BadValueError, match="unknown option"):
        nerf.load(tmp_path, {"bg": "white"})
    with pytest.raises(BadValueError, match="background"):
        nerf.load(tmp_path, {"background": "grey"})
    doc = json.loads(f.read_text())
    f.write_text("{")
    with pytest.raises(FormatError, match="transforms_test.json.*malformed"):
        nerf.load(tmp_path, {})
    bad = dict(doc, camera_angle_x=0.0)
    f.write_text(json.dumps(bad))
    with pytest.raises(BadValueError, match="camera_angle_x"):
        nerf.load(tmp_path, {})
    bad = dict(doc, fl_x=-3.0)
    f.write_text(json.dumps(bad))
    with pytest.raises(BadValueError, match="focal"):
        nerf.load(tmp_path, {})
    bad = {k: v for k, v in doc.items() if k != "camera_angle_x"}
    f.write_text(json.dumps(bad))
    with pytest.raises(FormatError, match="camera_angle_x"):
        nerf.load(tmp_path, {})
    m = np.eye(4)
    m[:3, :3] *= 2.0  # a scale, not a rotation
    f.write_text(json.dumps(dict(doc, frames=[{"file_path": "./test/r_0", "transform_matrix": m.tolist()}])))
    with pytest.raises(BadValueError, match=r"transforms_test.json frames\[0\].*rigid"):
        nerf.load(tmp_path, {})
    f.write_text(json.dumps(dict(doc, frames=[{"file_path": "./test/r_9", "transform_matrix": np.eye(4).tolist()}])))
    with pytest.raises(MissingFileError, match="r_9"):
        nerf.load(tmp_path, {})
    f.write_text(json.dumps(dict(doc, w=W + 1, h=H)))
    with pytest.raises(ShapeError, match="r_0.png"):
        nerf.load(tmp_path, {})
    f.write_text(json.dumps(doc))
    write_png(tmp_path / "test" / "r_0_depth_0001.png", np.zeros((H + 1, W, 4), np.uint8))
    with pytest.raises(ShapeError, match="r_0_depth_0001.png"):
        nerf.load(tmp_path, {})


def test_round_trip_native(tmp_path):
    from ibrtools.formats import native

    (tmp_path / "in").mkdir()
    make_set(tmp_path / "in")
    scene = nerf.load(tmp_path / "in", {})
    native.save(scene, tmp_path / "out")
    back = native.load(tmp_path / "out", {})
    assert back.views[0].camera.allclose(scene.views[0].camera, 1e-9)


# --- depth_dequantize=auto|N (module doc: coarse 8-bit codes are de-quantised, fine 16-bit are not) ---
def _ramp_depth(tmp_path, dtype):
    """The fixture with a depth PNG of ``dtype`` holding a ramp of 0.3 code per pixel along x
    (terraces ~3 px wide): de-quantisation changes it, the stored codes do not."""
    tmp_path.mkdir(exist_ok=True)
    make_set(tmp_path)
    codes = np.rint(100 + 0.3 * np.arange(W)).astype(dtype)
    depth = np.zeros((H, W, 4), dtype)
    depth[..., 0] = codes
    depth[..., 3] = np.iinfo(dtype).max
    write_png(tmp_path / "test" / "r_0_depth_0001.png", depth)
    full = float(np.iinfo(dtype).max)
    cam = nerf.load(tmp_path, {"depth": "none"}).views[0].camera
    stored = cam.depth_ray_to_z(nerf.decode_depth(depth[..., 0], full, 8.0)).astype(np.float32)
    return stored, full, depth[..., 0]


def test_dequantize_auto_picks_rounds_by_bit_depth(tmp_path):
    # 8-bit: auto = the explicit 5 rounds (and not the stored codes); 16-bit: auto = the codes
    # as stored (0 rounds), though the same ramp would be smoothed by an explicit N.
    assert nerf.AUTO_DEQUANTIZE == {"uint8": 5, "uint16": 0}
    assert nerf.dequantize_rounds(None, "uint8") == 5 and nerf.dequantize_rounds(None, "uint16") == 0
    assert nerf.dequantize_rounds(2, "uint8") == 2 and nerf.dequantize_rounds(0, "uint8") == 0
    assert nerf.dequantize_rounds(7, "uint16") == 7
    stored, _, _ = _ramp_depth(tmp_path / "a", np.uint8)
    auto = nerf.load(tmp_path / "a", {})
    assert "auto (8-bit: 5 rounds, 16-bit: 0)" in auto.source["notes"]
    five = nerf.load(tmp_path / "a", {"depth_dequantize": 5}).views[0].depth
    np.testing.assert_array_equal(auto.views[0].depth, five)
    assert np.abs(auto.views[0].depth - stored).max() > 1e-4
    stored16, _, _ = _ramp_depth(tmp_path / "b", np.uint16)
    np.testing.assert_array_equal(nerf.load(tmp_path / "b", {"depth_dequantize": "auto"}).views[0].depth, stored16)
    assert np.abs(nerf.load(tmp_path / "b", {"depth_dequantize": 5}).views[0].depth - stored16).max() > 0


def test_dequantize_explicit_overrides_auto(tmp_path):
    # depth_dequantize=0 keeps the stored 8-bit codes exactly; N = 2 (a string, as the CLI's
    # --opt passes it) equals dequantize_codes with 2 rounds; the notes name the explicit N.
    stored, full, codes = _ramp_depth(tmp_path, np.uint8)
    off = nerf.load(tmp_path, {"depth_dequantize": 0})
    np.testing.assert_array_equal(off.views[0].depth, stored)
    assert "de-quantised" not in off.source["notes"]
    two = nerf.load(tmp_path, {"depth_dequantize": "2"})
    assert "de-quantised (2 rounds)" in two.source["notes"]
    cam = two.views[0].camera
    want = cam.depth_ray_to_z(nerf.decode_depth(nerf.dequantize_codes(codes, full, 2), full, 8.0)).astype(np.float32)
    np.testing.assert_array_equal(two.views[0].depth, want)


def test_dequantized_views_keep_the_stored_depth_for_fusion(tmp_path):
    # Where the codes are de-quantised (8-bit auto, any explicit N > 0) the view also keeps the
    # depth as stored, fusion_depth reads it, and a native save / load keeps it; where nothing
    # was filtered (16-bit auto, N = 0) there is no second copy and fusion_depth is the depth.
    from ibrtools.formats import native

    stored, _, _ = _ramp_depth(tmp_path / "a", np.uint8)
    v = nerf.load(tmp_path / "a", {}).views[0]
    assert v.has_depth_stored
    np.testing.assert_array_equal(v.depth_stored, stored)
    assert v.fusion_depth is v.depth_stored and np.abs(v.depth - stored).max() > 1e-4
    off = nerf.load(tmp_path / "a", {"depth_dequantize": 0}).views[0]
    assert not off.has_depth_stored and off.depth_stored is None and off.fusion_depth is off.depth
    stored16, _, _ = _ramp_depth(tmp_path / "b", np.uint16)
    assert not nerf.load(tmp_path / "b", {}).views[0].has_depth_stored
    two = nerf.load(tmp_path / "b", {"depth_dequantize": 2}).views[0]
    np.testing.assert_array_equal(two.depth_stored, stored16)
    scene = nerf.load(tmp_path / "a", {})
    native.save(scene, tmp_path / "out")
    back = native.load(tmp_path / "out").views[0]
    assert (tmp_path / "out" / "images" / "r_0.depth_stored.exr").is_file()
    np.testing.assert_array_equal(back.depth_stored, stored)
    np.testing.assert_array_equal(back.depth, scene.views[0].depth)


def test_dequantize_option_bad_values(tmp_path):
    from ibrtools.errors import DtypeError

    make_set(tmp_path)
    for bad in ("Auto-5", "many", True, None, 1.5, "-"):
        with pytest.raises(DtypeError, match="depth_dequantize: expected auto or an integer"):
            nerf.load(tmp_path, {"depth_dequantize": bad})
    for bad in (-1, "-3"):
        with pytest.raises(BadValueError, match="depth_dequantize.*>= 0"):
            nerf.load(tmp_path, {"depth_dequantize": bad})
    with pytest.raises(DtypeError, match="depth_dequantize=auto: no rule for float32"):
        nerf.dequantize_rounds(None, "float32")


# --- instant-ngp / nerfstudio captures: missing images, per-frame intrinsics, lens distortion ---
def _texture(u, v):
    """A smooth linear-light pattern of continuous pixel coordinates (the scene every camera sees)."""
    return np.stack([0.5 + 0.3 * np.sin(u / 3.1) * np.cos(v / 4.3), 0.4 + 0.2 * np.cos(u / 5.0),
                     0.3 + 0.2 * np.sin(v / 2.7)], -1).astype(np.float32)


def _distorted_capture(tmp_path, meta, frames_meta, w=48, h=36, f=40.0):
    """A capture in instant-ngp's layout (``images/NNNN.png``, one transforms.json): each frame's
    16-bit PNG is what a lens of the frame's distortion sees of ``_texture`` as the undistorted
    pinhole (fx = fy = f, principal point at the centre) would see it. Returns the pinhole image."""
    from ibrtools.formats._undistort import _distort

    (tmp_path / "images").mkdir(parents=True, exist_ok=True)
    cx, cy = w / 2, h / 2
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    pinhole = _texture(u, v)
    frames = []
    for i, fm in enumerate(frames_meta):
        m = {**meta, **fm}
        model, params = fm.pop("_model")
        xd, yd = (u - cx) / f, (v - cy) / f
        x, y = xd.copy(), yd.copy()
        for _ in range(100):  # the undistorted point of each distorted pixel centre (fixed point)
            dx, dy = _distort(model, params, x, y)
            x, y = x + (xd - dx), y + (yd - dy)
        img = _texture(x * f + cx, y * f + cy)
        write_image(tmp_path / "images" / f"{i + 1:04d}.png", img, bits=16)
        c2w = np.eye(4)
        c2w[0, 3] = 0.1 * i
        frames.append({"file_path": f"./images/{i + 1:04d}.png", "transform_matrix": c2w.tolist(),
                       **{k: v for k, v in fm.items()}})
    doc = {"fl_x": f, "fl_y": f, "cx": cx, "cy": cy, "w": w, "h": h, "aabb_scale": 4, **meta, "frames": frames}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    return pinhole


def _psnr(a, b, mask):
    return 10 * np.log10(1.0 / np.mean((a[mask] - b[mask]) ** 2))


from ibrtools.imageio import write_image  # noqa: E402


@pytest.mark.parametrize("meta, fm, model, params", [
    # instant-ngp's colmap2nerf: k1 k2 p1 p2 at top level, no camera_model
    ({"k1": -0.12, "k2": 0.02, "p1": 0.002, "p2": -0.001}, {}, "OPENCV", [-0.12, 0.02, 0.002, -0.001]),
    # nerfstudio OPENCV with k3 (OpenCV's 5-coefficient model)
    ({"camera_model": "OPENCV", "k1": -0.1, "k2": 0.01, "k3": 0.005, "p1": 0.0, "p2": 0.001}, {},
     "FULL_OPENCV", [-0.1, 0.01, 0.0, 0.001, 0.005, 0, 0, 0]),
    # nerfstudio OPENCV_FISHEYE (k1..k4)
    ({"camera_model": "OPENCV_FISHEYE", "k1": 0.05, "k2": -0.01, "k3": 0.002, "k4": -0.0005}, {},
     "OPENCV_FISHEYE", [0.05, -0.01, 0.002, -0.0005]),
])
def test_distortion_removed_on_import(tmp_path, meta, fm, model, params):
    # The undistorted view is the pinhole image to within the bilinear resampling (> 40 dB on the
    # pixels whose source is inside the distorted image); the same file read as a pinhole (the
    # coefficients ignored, as before) is far off. The summary says what was removed.
    f = 40.0
    p = np.array([f, f, 24.0, 18.0, *params], float)
    pinhole = _distorted_capture(tmp_path, meta, [{"_model": (model, p)}], f=f)
    scene = nerf.load(tmp_path, {})
    (v,) = scene.views
    assert (v.camera.fx, v.camera.cx) == (f, 24.0)
    mask = v.mask
    assert mask.mean() > 0.8
    assert _psnr(v.color, pinhole, mask) > 40
    assert scene.source["adapted"] == [f"distortion removed: 1 views ({model}), undistorted to a pinhole "
                                       "with the same fx, fy, cx, cy"]
    plain = json.loads((tmp_path / "transforms.json").read_text())
    for k in ("k1", "k2", "k3", "k4", "p1", "p2", "camera_model"):
        plain.pop(k, None)
    (tmp_path / "transforms.json").write_text(json.dumps(plain))
    ignored = nerf.load(tmp_path, {})
    assert "adapted" not in ignored.source
    assert _psnr(ignored.views[0].color, pinhole, mask) < _psnr(v.color, pinhole, mask) - 10


def test_missing_images_skipped_with_one_counted_warning(tmp_path):
    # instant-ngp's fox lists 67 frames and ships 50: the frames without an image are skipped and
    # counted in one warning; with no image at all it is an error naming the first.
    (tmp_path / "images").mkdir()
    frames = []
    for i in range(6):
        if i % 3 != 2:
            write_image(tmp_path / "images" / f"{i:04d}.jpg", np.full((H, W, 3), 0.2, np.float32))
        c2w = np.eye(4)
        c2w[2, 3] = float(i)
        frames.append({"file_path": f"images/{i:04d}.jpg", "transform_matrix": c2w.tolist()})
    doc = {"camera_angle_x": 1.0, "frames": frames}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    scene = nerf.load(tmp_path, {})
    assert [v.name for v in scene.views] == ["0000", "0001", "0003", "0004"]
    (warning,) = scene.source["warnings"]
    assert warning.startswith("2 of 6 frames skipped: image not found") and "0002.jpg" in warning
    assert "2 frames skipped (image not found)" in scene.source["adapted"]
    for p in (tmp_path / "images").iterdir():
        p.unlink()
    with pytest.raises(MissingFileError, match=r"0000.jpg: image not found.*none of the 6 frames"):
        nerf.load(tmp_path, {})


def test_per_frame_intrinsics_and_distortion(tmp_path):
    # Per-frame fl_x/cx/w/h and coefficients override the file's; a frame without its own uses the file's.
    f = 40.0
    base = np.array([f, f, 24.0, 18.0], float)
    pinhole = _distorted_capture(
        tmp_path, {"k1": -0.1},
        [{"_model": ("OPENCV", np.r_[base, -0.1, 0, 0, 0])},
         {"k1": 0.08, "p1": 0.001, "_model": ("OPENCV", np.r_[base, 0.08, 0, 0.001, 0])}], f=f)
    doc = json.loads((tmp_path / "transforms.json").read_text())
    doc["frames"].append(dict(doc["frames"][0], file_path="./images/0001.png", fl_x=44.0, cx=23.0))
    doc["frames"][2]["transform_matrix"][1][3] = 1.0
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    # the third frame re-uses image 0001 under another name: per-frame intrinsics
    (tmp_path / "images" / "0003.png").write_bytes((tmp_path / "images" / "0001.png").read_bytes())
    doc["frames"][2]["file_path"] = "./images/0003.png"
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    scene = nerf.load(tmp_path, {})
    a, b, c = scene.views
    assert (c.camera.fx, c.camera.fy, c.camera.cx, c.camera.cy) == (44.0, f, 23.0, 18.0)
    for v in (a, b):
        assert _psnr(v.color, pinhole, v.mask) > 40
    assert scene.source["adapted"] == ["distortion removed: 3 views (OPENCV), undistorted to a pinhole "
                                       "with the same fx, fy, cx, cy"]


def test_distortion_bad_input(tmp_path):
    make_set(tmp_path)
    f = tmp_path / "transforms_test.json"
    doc = json.loads(f.read_text())
    for bad, err, match in [
        ({"camera_model": "EQUIRECTANGULAR"}, FormatError, "camera_model 'EQUIRECTANGULAR' is not supported"),
        ({"camera_model": "OPENCV_FISHEYE", "p1": 0.1}, FormatError, "no tangential"),
        ({"camera_model": "PINHOLE", "k1": 0.1}, FormatError, "PINHOLE with distortion"),
        ({"k4": 0.1}, FormatError, "k4.*fisheye"),
        ({"k1": "x"}, FormatError, "'k1' is not a number"),
        ({"k1": float("inf")}, BadValueError, "'k1' is not finite"),
    ]:
        f.write_text(json.dumps(dict(doc, **bad)))
        with pytest.raises(err, match=match):
            nerf.load(tmp_path, {})


def test_nerfstudio_depth_file_path(tmp_path):
    # nerfstudio's depth_file_path: 16-bit z-depth in millimetres (depth_unit 0.001), 0 unknown.
    (tmp_path / "images").mkdir()
    (tmp_path / "depths").mkdir()
    write_image(tmp_path / "images" / "frame_00001.png", np.full((H, W, 3), 0.3, np.float32))
    mm = np.full((H, W), 1500, np.uint16)
    mm[0, 0] = 0
    write_png(tmp_path / "depths" / "frame_00001.png", mm)
    doc = {"camera_model": "OPENCV", "fl_x": 10.0, "fl_y": 10.0, "cx": 4.0, "cy": 3.0, "w": W, "h": H,
           "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
           "frames": [{"file_path": "images/frame_00001.png", "depth_file_path": "depths/frame_00001.png",
                       "transform_matrix": np.eye(4).tolist()}]}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    scene = nerf.load(tmp_path, {})
    d = scene.views[0].depth
    assert d[0, 0] == 0 and d[1, 1] == pytest.approx(1.5)
    assert "depth_file_path: z-depth = 16-bit value * 0.001" in scene.source["notes"]
    assert nerf.load(tmp_path, {"depth_unit": "1/5000"}).views[0].depth[1, 1] == pytest.approx(0.3)
    assert not nerf.load(tmp_path, {"depth": "none"}).views[0].has_depth
    with pytest.raises(BadValueError, match="option depth_unit: expected a positive number"):
        nerf.load(tmp_path, {"depth_unit": "0"})
    write_png(tmp_path / "depths" / "frame_00001.png", np.full((H, W), 7, np.uint8))
    from ibrtools.errors import DtypeError

    with pytest.raises(DtypeError, match="frame_00001.png: 8-bit image cannot hold metric depth"):
        nerf.load(tmp_path, {})
    (tmp_path / "depths" / "frame_00001.png").unlink()
    with pytest.raises(MissingFileError, match=r"frame_00001.png: depth image of .*depth_file_path"):
        nerf.load(tmp_path, {})
