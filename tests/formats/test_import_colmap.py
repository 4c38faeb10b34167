"""COLMAP importer on fixtures written here (binary and text), cross-checked against pycolmap."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from ibrtools.errors import BadValueError, FormatError, MissingFileError
from ibrtools.formats import colmap
from ibrtools.imageio import write_image

W, H = 16, 12
Q = np.array([np.cos(0.15), 0.0, np.sin(0.15), 0.0])  # 0.3 rad about y
T = np.array([0.1, -0.2, 0.3])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def write_bin(model, cams, imgs):
    model.mkdir(parents=True, exist_ok=True)
    ids = {v[0]: k for k, v in colmap.MODELS.items()}
    with open(model / "cameras.bin", "wb") as f:
        f.write(struct.pack("<Q", len(cams)))
        for cid, (name, w, h, params) in cams.items():
            f.write(struct.pack("<iiQQ", cid, ids[name], w, h) + struct.pack(f"<{len(params)}d", *params))
    with open(model / "images.bin", "wb") as f:
        f.write(struct.pack("<Q", len(imgs)))
        for iid, (q, t, cid, name) in imgs.items():
            f.write(struct.pack("<i7di", iid, *q, *t, cid) + name.encode() + b"\0")
            f.write(struct.pack("<Q", 2) + struct.pack("<ddq", 1.0, 2.0, -1) * 2)
    with open(model / "points3D.bin", "wb") as f:
        f.write(struct.pack("<Q", 0))


def _fmt(values):
    return " ".join(repr(float(v)) for v in values)


def write_txt(model, cams, imgs):
    model.mkdir(parents=True, exist_ok=True)
    (model / "cameras.txt").write_text("# Camera list\n" + "".join(
        f"{cid} {name} {w} {h} {_fmt(params)}\n" for cid, (name, w, h, params) in cams.items()))
    (model / "images.txt").write_text("# Image list\n" + "".join(
        f"{iid} {_fmt(q)} {_fmt(t)} {cid} {name}\n\n" for iid, (q, t, cid, name) in imgs.items()))
    (model / "points3D.txt").write_text("")


def make(tmp_path, kind="bin", model="PINHOLE", params=(20.0, 21.0, 8.0, 6.0), img_size=(W, H), cam_size=(W, H)):
    cams = {1: (model, cam_size[0], cam_size[1], list(params))}
    imgs = {5: (Q, T, 1, "a.png"), 7: (np.array([1.0, 0, 0, 0]), np.zeros(3), 1, "b.png")}
    (write_bin if kind == "bin" else write_txt)(tmp_path / "sparse" / "0", cams, imgs)
    (tmp_path / "images").mkdir(exist_ok=True)
    yy, xx = np.mgrid[0:img_size[1], 0:img_size[0]]
    for n in ("a", "b"):
        img = np.stack([xx / img_size[0], yy / img_size[1], np.full(xx.shape, 0.5)], -1).astype(np.float32)
        write_image(tmp_path / "images" / f"{n}.png", img)
    return tmp_path


@pytest.mark.parametrize("kind", ["bin", "txt"])
def test_cameras_exact(tmp_path, kind):
    make(tmp_path, kind)
    assert colmap.detect(tmp_path)
    scene = colmap.load(tmp_path, {})
    assert [v.name for v in scene.views] == ["a", "b"]
    c = scene.view("a").camera
    assert (c.fx, c.fy, c.cx, c.cy) == (20.0, 21.0, 8.0, 6.0)
    np.testing.assert_allclose(c.cam_from_world[:3, :3], rot_y(0.3), atol=1e-15)
    np.testing.assert_allclose(c.cam_from_world[:3, 3], T, atol=1e-15)
    assert scene.view("a").color.shape == (H, W, 3)


def test_matches_pycolmap(tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    make(tmp_path, "bin", "OPENCV", (20.0, 21.0, 8.0, 6.0, 0.01, -0.002, 0.001, 0.0005))
    rec = pycolmap.Reconstruction(str(tmp_path / "sparse" / "0"))
    ours_c = colmap.read_cameras(tmp_path / "sparse" / "0" / "cameras.bin")
    ours_i = colmap.read_images(tmp_path / "sparse" / "0" / "images.bin")
    for cid, c in rec.cameras.items():
        assert ours_c[cid]["model"] == c.model.name
        np.testing.assert_array_equal(ours_c[cid]["params"], c.params)
    for iid, im in rec.images.items():
        assert ours_i[iid]["name"] == im.name
        m = im.cam_from_world() if callable(im.cam_from_world) else im.cam_from_world
        np.testing.assert_allclose(colmap.quat_to_rotation(*ours_i[iid]["qvec"], where="x"), m.rotation.matrix(),
                                   atol=1e-12)
        # pycolmap's own projection of a distorted point equals our distortion model.
    cam = rec.cameras[1]
    pts = np.array([[0.1, -0.2], [0.3, 0.25]])
    ref = np.asarray(cam.img_from_cam(np.c_[pts, np.ones(len(pts))]))  # pycolmap >= 3.10: 3-D points
    xd, yd = colmap._distort("OPENCV", np.array(cam.params), pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(np.stack([xd * 20 + 8, yd * 21 + 6], -1), ref, atol=1e-9)


def test_scaled_images(tmp_path):
    make(tmp_path, img_size=(W // 2, H // 2), cam_size=(W, H))
    c = colmap.load(tmp_path, {}).view("a").camera
    assert (c.width, c.height, c.fx, c.fy, c.cx, c.cy) == (W // 2, H // 2, 10.0, 10.5, 4.0, 3.0)
    make(tmp_path, img_size=(W // 2, H), cam_size=(W, H))
    with pytest.raises(FormatError, match="aspect ratio"):
        colmap.load(tmp_path, {})


def test_undistortion_exact_mapping(tmp_path):
    # A radially distorted camera; the image is an analytic function of the distorted position,
    # so the undistorted image must equal the same function of the *undistorted* pixel's
    # distorted position. Tolerance: bilinear interpolation of a linear ramp is exact up to
    # float32 rounding (1e-6), except at the clamped border.
    make(tmp_path, "bin", "SIMPLE_RADIAL", (20.0, 8.0, 6.0, -0.05))
    v = colmap.load(tmp_path, {}).view("a")
    assert v.camera.fx == 20.0 and v.has_mask
    und = colmap._Undistorter(v.camera, "SIMPLE_RADIAL", np.array([20.0, 8.0, 6.0, -0.05]))
    sx, sy = und.map()
    inner = (sx > 1) & (sx < W - 1) & (sy > 1) & (sy < H - 1)
    np.testing.assert_allclose(v.color[..., 0][inner], srgb_ramp(sx[inner] - 0.5, W), atol=2e-3)


def srgb_ramp(x, n):
    # The fixture stores x / n sRGB-encoded in 8 bits: bilinear interpolation of the decoded values
    # of a ramp is not exactly linear, hence the 2e-3 tolerance above (8-bit step is 4e-3).
    from ibrtools.imageio import linear_to_srgb, srgb_to_linear

    lo = np.floor(x).astype(int)
    a = x - lo
    dec = lambda i: srgb_to_linear(np.round(linear_to_srgb(np.float32(i / n)) * 255) / 255)
    return dec(lo) * (1 - a) + dec(lo + 1) * a


def test_dense_depth(tmp_path):
    make(tmp_path)
    d = np.arange(W * H, dtype=np.float32).reshape(H, W) / 10
    d[0, 0] = -1.0  # invalid in COLMAP -> unknown
    (tmp_path / "stereo" / "depth_maps").mkdir(parents=True)
    with open(tmp_path / "stereo" / "depth_maps" / "a.png.geometric.bin", "wb") as f:
        f.write(f"{W}&{H}&1&".encode())
        # read_write_dense.py: reshape((W, H, C), order="F") -> column index fastest = row-major (H, W).
        f.write(d.tobytes())
    v = colmap.load(tmp_path, {}).view("a")
    assert v.depth[0, 0] == 0 and v.depth[2, 3] == pytest.approx(d[2, 3])
    assert not colmap.load(tmp_path, {}).view("b").has_depth
    (tmp_path / "stereo" / "depth_maps" / "a.png.geometric.bin").write_bytes(f"{W}&{H}&1&".encode() + b"\0" * 8)
    with pytest.raises(FormatError, match="a.png.geometric.bin.*bytes"):
        colmap.load(tmp_path, {}).view("a").depth


def test_bad_input(tmp_path):
    make(tmp_path, "txt")
    with pytest.raises(FormatError, match="no COLMAP model"):
        colmap.load(tmp_path / "images", {})
    (tmp_path / "images" / "a.png").unlink()
    with pytest.raises(MissingFileError, match="a.png"):
        colmap.load(tmp_path, {})
    make(tmp_path, "txt", params=(0.0, 21.0, 8.0, 6.0))
    with pytest.raises(BadValueError, match="focal"):
        colmap.load(tmp_path, {})
    make(tmp_path, "txt", model="OPENCV_FISHEYE", params=(20, 20, 8, 6, 0, 0, 0, 0))
    with pytest.raises(FormatError, match="OPENCV_FISHEYE"):
        colmap.load(tmp_path, {})
    make(tmp_path, "txt")
    m = tmp_path / "sparse" / "0" / "images.txt"
    m.write_text(m.read_text().replace(_fmt(Q), "2.0 0.0 0.0 0.0", 1))
    with pytest.raises(BadValueError, match="quaternion norm"):
        colmap.load(tmp_path, {})
    (tmp_path / "sparse" / "0" / "cameras.txt").write_text("1 PINHOLE 16 12 20.0\n")
    with pytest.raises(FormatError, match="cameras.txt.*expected 4 parameters"):
        colmap.load(tmp_path, {})
    make(tmp_path, "bin")
    b = tmp_path / "sparse" / "0" / "images.bin"
    b.write_bytes(b.read_bytes()[:30])
    with pytest.raises(FormatError, match="images.bin.*truncated"):
        colmap.load(tmp_path, {})
    with pytest.raises(BadValueError, match="unknown option"):
        colmap.load(tmp_path, {"image": "x"})


def test_round_trip_native(tmp_path):
    from ibrtools.formats import native

    (tmp_path / "in").mkdir()
    make(tmp_path / "in")
    scene = colmap.load(tmp_path / "in", {})
    native.save(scene, tmp_path / "out")
    back = native.load(tmp_path / "out", {})
    for a, b in zip(scene.views, back.views):
        assert a.camera.allclose(b.camera, 1e-9)
