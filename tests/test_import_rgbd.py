"""RGB-D importer (ICL-NUIM / TUM layouts) on fixtures written here."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools.errors import BadValueError, FormatError, MissingFileError, ShapeError
from ibrtools.formats import rgbd
from ibrtools.imageio import write_image

from test_import_nerf import write_png

W, H = 8, 6


def make(tmp_path, n=2, poses=None):
    (tmp_path / "color").mkdir(exist_ok=True)
    (tmp_path / "depth").mkdir(exist_ok=True)
    for k in range(1, n + 1):
        write_image(tmp_path / "color" / f"{k}.png", np.full((H, W, 3), 0.25, np.float32))
        write_png(tmp_path / "depth" / f"{k}.png", np.full((H, W), 10000, np.uint16))  # 2 m
    poses = poses or ["0 0 0 0 0 0 1", "1 2 3 0 0 0.7071067811865476 0.7071067811865476"][:n]
    (tmp_path / "pose.txt").write_text("\n".join(poses) + "\n")
    return tmp_path


def test_negative_focal_mirrors_world(tmp_path):
    make(tmp_path)
    assert rgbd.detect(tmp_path)
    opts = {"fx": 4.0, "fy": -5.0, "cx": 3.5, "cy": 2.5}
    scene = rgbd.load(tmp_path, opts)
    assert scene.units == "m" and scene.source["world_mirror"] == [1.0, -1.0, 1.0]
    for view, (t, rot) in zip(scene.views, [(np.zeros(3), np.eye(3)),
                                             (np.array([1.0, 2, 3]), np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]]))]):
        c = view.camera
        assert (c.fx, c.fy, c.cx, c.cy) == (4.0, 5.0, 4.0, 3.0)  # +0.5: our pixel centres
        np.testing.assert_allclose(view.depth, 2.0)
        # The data set's own unprojection of integer pixel (u, v) at depth z, mirrored by y -> -y,
        # equals our unprojection of that pixel's centre.
        u, v, z = 6, 1, 2.0
        p_ds = np.array([(u - 3.5) * z / 4.0, (v - 2.5) * z / -5.0, z])
        world = rot @ p_ds + t
        world_mirrored = world * [1, -1, 1]
        xy, depth = c.project(world_mirrored)
        np.testing.assert_allclose(xy, (u + 0.5, v + 0.5), atol=1e-12)
        assert depth == pytest.approx(z)
        assert np.linalg.det(c.cam_from_world[:3, :3]) == pytest.approx(1.0)


def test_positive_focals_keep_world(tmp_path):
    make(tmp_path)
    c = rgbd.load(tmp_path, {"fx": 4, "fy": 5, "cx": 3.5, "cy": 2.5, "depth_scale": "1/1000"}).views[1]
    assert c.camera.centre.tolist() == pytest.approx([1, 2, 3])
    np.testing.assert_allclose(c.depth, 10.0)


def test_tum_layout(tmp_path):
    (tmp_path / "rgb").mkdir()
    (tmp_path / "depth").mkdir()
    write_image(tmp_path / "rgb" / "1.0.png", np.zeros((H, W, 3), np.float32))
    write_png(tmp_path / "depth" / "1.01.png", np.full((H, W), 5000, np.uint16))
    (tmp_path / "rgb.txt").write_text("# rgb\n1.0 rgb/1.0.png\n5.0 rgb/1.0.png\n")
    (tmp_path / "depth.txt").write_text("1.01 depth/1.01.png\n")
    (tmp_path / "groundtruth.txt").write_text("# t tx ty tz qx qy qz qw\n0.995 1 2 3 0 0 0 1\n")
    assert rgbd.detect(tmp_path)
    scene = rgbd.load(tmp_path, {})
    assert len(scene.views) == 1  # the second colour frame has no depth within 0.02 s
    assert scene.views[0].camera.fx == 525.0  # TUM default intrinsics
    np.testing.assert_allclose(scene.views[0].camera.centre, (1, 2, 3))
    with pytest.raises(FormatError, match="no colour frame"):
        rgbd.load(tmp_path, {"max_dt": 0.001})


def test_bad_input(tmp_path):
    make(tmp_path)
    with pytest.raises(BadValueError, match="fy"):
        rgbd.load(tmp_path, {"fy": 0})
    with pytest.raises(BadValueError, match="depth_scale"):
        rgbd.load(tmp_path, {"depth_scale": -1})
    (tmp_path / "pose.txt").write_text("0 0 0 0 0 0 1\n")
    with pytest.raises(FormatError, match="pose.txt: 1 poses for 2 images"):
        rgbd.load(tmp_path, {})
    (tmp_path / "pose.txt").write_text("0 0 0 0 0 0 1\n0 0 0 0 0 0 2\n")
    with pytest.raises(BadValueError, match="pose.txt line 2.*quaternion"):
        rgbd.load(tmp_path, {})
    (tmp_path / "pose.txt").write_text("0 0 0 0 0 0 1\n0 0 x 0 0 0 1\n")
    with pytest.raises(FormatError, match="pose.txt line 2"):
        rgbd.load(tmp_path, {})
    make(tmp_path)
    write_png(tmp_path / "depth" / "2.png", np.full((H + 2, W), 1, np.uint16))
    with pytest.raises(ShapeError, match="2.png"):
        rgbd.load(tmp_path, {})
    (tmp_path / "depth" / "2.png").unlink()
    with pytest.raises(MissingFileError, match="2.png"):
        rgbd.load(tmp_path, {})


def test_round_trip_native(tmp_path):
    from ibrtools.formats import native

    (tmp_path / "in").mkdir()
    scene = rgbd.load(make(tmp_path / "in"), {"fx": 4, "fy": -5, "cx": 3.5, "cy": 2.5})
    native.save(scene, tmp_path / "out")
    back = native.load(tmp_path / "out", {})
    for a, b in zip(scene.views, back.views):
        assert a.camera.allclose(b.camera, 1e-9)
