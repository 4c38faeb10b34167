"""Middlebury importer on a fixture written here: geometry by hand, disparity decoding, errors."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools.errors import BadValueError, FormatError, MissingFileError, ShapeError
from ibrtools.formats import middlebury
from ibrtools.imageio import write_image

from test_import_nerf import write_png

W, H = 10, 4


def make(tmp_path, layout="2003"):
    names = ("im2", "im6", "disp2", "disp6") if layout == "2003" else ("view1", "view5", "disp1", "disp5")
    for n in names[:2]:
        write_image(tmp_path / f"{n}.png", np.full((H, W, 3), 0.5, np.float32))
    disp = np.full((H, W), 8, np.uint8)  # disparity 2 (2003: value / 4) or 8/3 (2005)
    disp[0, 0] = 0
    for n in names[2:]:
        write_png(tmp_path / f"{n}.png", disp)
    return tmp_path


def test_geometry_and_depth(tmp_path):
    make(tmp_path)
    assert middlebury.detect(tmp_path)
    scene = middlebury.load(tmp_path, {})
    left, right = scene.view("left"), scene.view("right")
    assert scene.units == "disparity"
    assert left.camera.fx == W and left.camera.cx == W / 2
    np.testing.assert_allclose(right.camera.centre, (1, 0, 0))
    assert left.depth[0, 0] == 0  # disparity 0 = unknown
    np.testing.assert_allclose(left.depth[1, 1], W * 1 / 2)  # z = f B / d
    # Exactness: a left pixel with disparity d lands at x - d in the right view.
    p = left.camera.unproject(left.depth)[2, 7]
    xy, _ = right.camera.project(p)
    np.testing.assert_allclose(xy, (7.5 - 2, 2.5), atol=1e-9)
    s = middlebury.load(tmp_path, {"focal": "100", "baseline": 0.2, "disp_scale": 8})
    assert s.units == "m"
    np.testing.assert_allclose(s.view("left").depth[1, 1], 100 * 0.2 / 1)


def test_2005_layout(tmp_path):
    make(tmp_path, "2005")
    v = middlebury.load(tmp_path, {}).view("left")
    np.testing.assert_allclose(v.depth[1, 1], W / (8 / 3), rtol=1e-6)


def test_bad_input(tmp_path):
    with pytest.raises(FormatError, match="no Middlebury pair"):
        middlebury.load(tmp_path, {})
    with pytest.raises(MissingFileError):
        middlebury.load(tmp_path / "nope", {})
    make(tmp_path)
    with pytest.raises(BadValueError, match="focal"):
        middlebury.load(tmp_path, {"focal": 0})
    with pytest.raises(BadValueError, match="baseline"):
        middlebury.load(tmp_path, {"baseline": "-1"})
    write_png(tmp_path / "disp6.png", np.zeros((H + 1, W), np.uint8))
    with pytest.raises(ShapeError, match="disp6.png"):
        middlebury.load(tmp_path, {})


def test_round_trip_native(tmp_path):
    from ibrtools.formats import native

    (tmp_path / "in").mkdir()
    scene = middlebury.load(make(tmp_path / "in"), {})
    native.save(scene, tmp_path / "out")
    back = native.load(tmp_path / "out", {})
    for a, b in zip(scene.views, back.views):
        assert a.camera.allclose(b.camera, 1e-9)
