"""LLFF importer (poses_bounds.npy + images) on captures written here in LLFF's own layout: poses
converted from OpenCV cameras exactly as LLFF's imgs2poses does, images_N folders, bad input."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, FormatError, MissingFileError
from ibrtools.formats import detect, llff, load
from ibrtools.imageio import write_image

W, H, F = 32, 24, 30.0


def llff_row(world_from_cam_cv: np.ndarray, h: float, w: float, f: float, near: float, far: float) -> np.ndarray:
    """One row of poses_bounds.npy as LLFF's pose_utils.py writes it: COLMAP's camera-to-world
    columns (x right, y down, z forward) reordered to (y, x, -z) = "down, right, back", hwf appended."""
    c2w = world_from_cam_cv[:3, :4]
    hwf = np.array([[h], [w], [f]])
    pose = np.concatenate([c2w[:, 1:2], c2w[:, 0:1], -c2w[:, 2:3], c2w[:, 3:4], hwf], 1)
    return np.concatenate([pose.ravel(), [near, far]])


def cameras():
    eyes = [(0.0, 0.0, -3.0), (0.4, 0.1, -3.0), (-0.3, -0.2, -2.8)]
    return [Camera.pinhole(W, H, F, F, W / 2, H / 2, look_at(e, (0, 0, 0), up=(0, -1, 0))) for e in eyes]


def make_capture(root, factor=None):
    """root/poses_bounds.npy, root/images/IMG_40NN.JPG (and root/images_<factor>/ when given)."""
    (root / "images").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    rows = []
    for i, cam in enumerate(cameras()):
        img = rng.random((H, W, 3)).astype(np.float32)
        write_image(root / "images" / f"IMG_40{i:02d}.JPG", img)
        if factor:
            (root / f"images_{factor}").mkdir(exist_ok=True)
            write_image(root / f"images_{factor}" / f"IMG_40{i:02d}.png", img[::factor, ::factor])
        rows.append(llff_row(cam.world_from_cam, H, W, F, 1.5 + i, 4.5 + i))
    np.save(root / "poses_bounds.npy", np.array(rows))
    return root


def test_cameras_in_the_captures_own_frame(tmp_path):
    make_capture(tmp_path)
    assert detect(tmp_path) == "llff"
    scene = load(tmp_path)
    assert [v.name for v in scene.views] == ["IMG_4000", "IMG_4001", "IMG_4002"]
    for v, cam in zip(scene.views, cameras()):
        # the OpenCV camera the poses were made from, not recentred or rescaled
        assert v.camera.allclose(cam, 1e-9)
        p = np.array([0.2, -0.1, 0.3])
        np.testing.assert_allclose(v.camera.project(p)[0], cam.project(p)[0], atol=1e-9)
    assert scene.source["depth_bounds"] == {"IMG_4000": [1.5, 4.5], "IMG_4001": [2.5, 5.5], "IMG_4002": [3.5, 6.5]}
    # the same data in the native format renders the same: identical cameras and images
    from ibrtools.formats import native

    native.save(scene, tmp_path / "native")
    back = native.load(tmp_path / "native")
    for a, b in zip(scene.views, back.views):
        assert a.camera.allclose(b.camera, 1e-9)
    assert back.source["depth_bounds"] == scene.source["depth_bounds"]


def test_downscaled_image_folder_scales_the_focal(tmp_path):
    make_capture(tmp_path, factor=4)
    scene = load(tmp_path, "llff", {"images": "images_4"})
    c = scene.views[0].camera
    assert (c.width, c.height, c.fx, c.fy, c.cx, c.cy) == (8, 6, F / 4, F / 4, 4.0, 3.0)
    assert c.allclose(cameras()[0].scaled(8, 6), 1e-9)


def test_mvs_searches_the_bounds(tmp_path):
    from ibrtools.mvs import MvsOptions
    from ibrtools.mvs.stereo import MvsRun

    scene = load(make_capture(tmp_path))
    run = MvsRun(scene.views, MvsOptions(), bounds=scene.source["depth_bounds"])
    assert run.ranges == {"IMG_4000": (1.5, 4.5), "IMG_4001": (2.5, 5.5), "IMG_4002": (3.5, 6.5)}
    given = MvsRun(scene.views, MvsOptions(depth_range="1,9"), bounds=scene.source["depth_bounds"])
    assert set(given.ranges.values()) == {(1.0, 9.0)}  # an explicit range wins


def test_bad_input(tmp_path):
    make_capture(tmp_path)
    f = tmp_path / "poses_bounds.npy"
    good = np.load(f)
    with pytest.raises(BadValueError, match="unknown option"):
        llff.load(tmp_path, {"factor": 4})
    with pytest.raises(MissingFileError, match="images_8.*option images="):
        llff.load(tmp_path, {"images": "images_8"})
    np.save(f, good[:2])
    with pytest.raises(FormatError, match="2 poses for 3 images"):
        llff.load(tmp_path, {})
    np.save(f, good[:, :15])
    with pytest.raises(FormatError, match=r"expected a numeric \(N, 17\) array"):
        llff.load(tmp_path, {})
    bad = good.copy()
    bad[1, 15:] = (5.0, 2.0)
    np.save(f, bad)
    with pytest.raises(BadValueError, match="row 1.*0 < near < far"):
        llff.load(tmp_path, {})
    bad = good.copy()
    bad[0, :3] *= 2  # a scaled rotation
    np.save(f, bad)
    with pytest.raises(BadValueError, match="row 0.*rigid"):
        llff.load(tmp_path, {})
    bad = good.copy()
    bad[:, 9] = 10.0  # hwf width 10 for 32x24 images: another aspect ratio
    np.save(f, bad)
    with pytest.raises(FormatError, match="different aspect ratio"):
        llff.load(tmp_path, {})
    bad = good.copy()
    bad[2, 16] = np.nan
    np.save(f, bad)
    with pytest.raises(BadValueError, match="NaN"):
        llff.load(tmp_path, {})
    f.write_bytes(b"not numpy")
    with pytest.raises(FormatError, match="poses_bounds.npy: not a numpy array"):
        llff.load(tmp_path, {})
    np.save(f, np.array([{"a": 1}], dtype=object))
    with pytest.raises(FormatError, match="poses_bounds.npy"):
        llff.load(tmp_path, {})
