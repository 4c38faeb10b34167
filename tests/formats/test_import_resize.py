"""Downscaling on import (formats/resize.py; ibr-preprocess --downscale / --max-size), for every
importer: hand-checked area averages and depth blocks, the pixel-centre convention, lazy loading,
and bad input."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError
from ibrtools.formats import load, resize

from test_import_nerf import make_set
from test_import_rgbd import make as make_icl


def test_area_average_by_hand():
    img = np.arange(12, dtype=np.float32).reshape(2, 6)
    # integer factor 2 along x, 2 along y: block means
    np.testing.assert_allclose(resize.area_resize(img, 3, 1), [[3.5, 5.5, 7.5]])
    # 3 -> 2 pixels: each output covers 1.5 source pixels: (a0 + a1/2) / 1.5, (a1/2 + a2) / 1.5
    row = np.array([[3.0, 6.0, 9.0]], np.float32)
    np.testing.assert_allclose(resize.area_resize(row, 2, 1), [[(3 + 3) / 1.5, (3 + 9) / 1.5]], rtol=1e-6)
    # any factor keeps the mean (the integral) of the image exactly
    rng = np.random.default_rng(1)
    big = rng.random((37, 53, 3)).astype(np.float32)
    for w, h in ((20, 14), (53, 37), (7, 29), (1, 1)):
        out = resize.area_resize(big, w, h)
        assert out.shape == (h, w, 3) and out.dtype == np.float32
        np.testing.assert_allclose(out.mean((0, 1)), big.mean((0, 1)), rtol=1e-5)


def test_depth_keeps_the_nearest_known_surface():
    inf = np.inf
    d = np.array([[2.0, 5.0, inf, inf, 0.0, 0.0],
                  [5.0, 5.0, inf, 3.0, 0.0, 4.0]], np.float32)
    # 2x2 blocks: foreground 2 over background 5; background at infinity with a 3 in it; unknown
    # pixels left out (4); an all-background block stays at infinity, an all-unknown one unknown
    np.testing.assert_array_equal(resize.min_depth_resize(d, 3, 1), [[2.0, 3.0, 4.0]])
    np.testing.assert_array_equal(resize.min_depth_resize(np.full((2, 2), inf, np.float32), 1, 1), [[inf]])
    np.testing.assert_array_equal(resize.min_depth_resize(np.zeros((2, 2), np.float32), 1, 1), [[0.0]])
    # 3 -> 2: each output pixel sees the source pixels it overlaps (the middle one by both)
    np.testing.assert_array_equal(resize.min_depth_resize(np.array([[4.0, 1.0, 6.0]], np.float32), 2, 1),
                                  [[1.0, 1.0]])
    np.testing.assert_array_equal(resize.min_depth_resize(np.array([[4.0, 7.0, 6.0]], np.float32), 2, 1),
                                  [[4.0, 6.0]])


def test_sizes_and_the_pixel_centre_convention():
    assert resize.scaled_size(800, 800, 2) == (400, 400)
    assert resize.scaled_size(1920, 1080, max_size=960) == (960, 540)
    assert resize.scaled_size(1080, 1920, max_size=960) == (540, 960)
    assert resize.scaled_size(640, 480, max_size=960) == (640, 480)  # never upscaled
    assert resize.scaled_size(641, 481, 2) == (320, 240)
    # A world point seen at source pixel position (x, y) is at (x, y) * (w'/w, h'/h) in the scaled
    # camera: output pixel i covers source [i/s, (i+1)/s), centres map to centres.
    cam = Camera.pinhole(800, 600, 700.0, 710.0, 401.3, 299.1)
    small = cam.scaled(*resize.scaled_size(800, 600, 2))
    p = np.array([0.3, -0.2, 2.0])
    np.testing.assert_allclose(small.project(p)[0], cam.project(p)[0] / 2, rtol=1e-12)
    np.testing.assert_allclose(small.pixel_grid()[0][0, :2], [0.5, 1.5])
    np.testing.assert_allclose((small.pixel_grid()[0][0, :2]) * 2, [1.0, 3.0])  # source pixel edges


def test_every_importer_downscaled_lazily(tmp_path):
    # nerf (RGBA, mask, 8-bit depth with the background at infinity) and ICL (16-bit depth): the
    # cameras scaled, images resized when first read, headers still checked, a summary line.
    (tmp_path / "nerf").mkdir()
    make_set(tmp_path / "nerf")
    full = load(tmp_path / "nerf")
    half = load(tmp_path / "nerf", downscale=2)
    a, b = full.views[0], half.views[0]
    assert (b.camera.width, b.camera.height) == (4, 3) and b.camera.fx == pytest.approx(a.camera.fx / 2)
    assert b._color._loader is not None  # not read yet
    np.testing.assert_allclose(b.color, resize.area_resize(a.color, 4, 3), rtol=1e-6)
    np.testing.assert_array_equal(b.depth, resize.min_depth_resize(a.depth, 4, 3))
    assert b.depth[0, 0] < np.inf  # the block of the background pixel (0, 0) has object depth too
    np.testing.assert_array_equal(b.mask, resize.mask_resize(a.mask, 4, 3))
    assert half.source["adapted"] == ["images downscaled (by 2): 1 views 8x6 -> 4x3 (colour: area "
                                      "average; depth: nearest known depth of each block)"]
    assert "adapted" not in full.source
    (tmp_path / "icl").mkdir()
    icl = load(make_icl(tmp_path / "icl"), "rgbd", {"fx": 4, "fy": -5, "cx": 3.5, "cy": 2.5}, max_size=4)
    c = icl.views[1].camera
    assert (c.width, c.height) == (4, 3) and (c.cx, c.cy) == (2.0, 1.5)  # (3.5 + 0.5) / 2: centres kept
    np.testing.assert_allclose(icl.views[1].depth, 2.0)
    assert load(tmp_path / "nerf", max_size=8).source.get("adapted") is None  # already within 8 px


def test_downscaled_scene_round_trips_native(tmp_path):
    from ibrtools.formats import native

    (tmp_path / "in").mkdir()
    make_set(tmp_path / "in")
    scene = load(tmp_path / "in", downscale=2)
    native.save(scene, tmp_path / "out")
    back = native.load(tmp_path / "out")
    assert back.views[0].camera.allclose(scene.views[0].camera, 1e-9)
    assert back.views[0].color.shape == (3, 4, 3)
    assert back.source["adapted"] == scene.source["adapted"]


@pytest.mark.parametrize("kw, msg", [
    ({"downscale": 0.5}, "downscale: expected a number >= 1"),
    ({"downscale": "two"}, "downscale: expected a number >= 1"),
    ({"downscale": float("nan")}, "downscale"),
    ({"max_size": 0}, "max_size: expected a whole number of pixels >= 1"),
    ({"max_size": 1.5}, "max_size"),
    ({"max_size": "big"}, "max_size"),
])
def test_bad_factors(tmp_path, kw, msg):
    make_set(tmp_path)
    with pytest.raises(BadValueError, match=msg):
        load(tmp_path, **kw)


@pytest.mark.parametrize("argv, msg", [
    (["--downscale", "0.5"], "--downscale: expected a number >= 1"),
    (["--max-size", "0"], "--max-size: expected a whole number"),
    (["--downscale", "inf"], "--downscale"),
])
def test_cli_bad_factors_exit_2_and_write_nothing(tmp_path, capsys, argv, msg):
    from ibrtools_cli import preprocess

    (tmp_path / "in").mkdir()
    make_set(tmp_path / "in")
    assert preprocess.main([str(tmp_path / "in"), "-o", str(tmp_path / "s"), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and len(err.splitlines()) == 1
    assert not (tmp_path / "s").exists()
    with pytest.raises(SystemExit) as e:  # not a number: argparse's usage error, exit 2
        preprocess.main([str(tmp_path / "in"), "-o", str(tmp_path / "s"), "--max-size", "1.5"])
    assert e.value.code == 2
    assert not (tmp_path / "s").exists()


def test_cli_prints_the_import_summary(tmp_path, capsys):
    from ibrtools_cli import preprocess

    (tmp_path / "in").mkdir()
    make_set(tmp_path / "in")
    assert preprocess.main([str(tmp_path / "in"), "-o", str(tmp_path / "s"), "--downscale", "2"]) == 0
    err = capsys.readouterr().err
    assert "ibr-preprocess: import: images downscaled (by 2): 1 views 8x6 -> 4x3" in err
    with pytest.raises(BadValueError, match="downscale: for data sets only"):
        from ibrtools.pipeline.stages import preprocess as run

        run("synth:objects", tmp_path / "syn", synth={"preset": "objects"}, downscale=2, stages=[])


def test_area_resample_matches_the_overlap_weighted_mean():
    # An independent answer: each output pixel's mean over the source pixels, each weighted by the
    # length of its overlap with the footprint, one pixel at a time; edges with a scale, an
    # offset and a footprint that leaves the image (clipped; wholly outside: the edge pixel).
    from ibrtools.formats.resize import area_resample

    rng = np.random.default_rng(3)
    img = rng.random((13, 17, 3))

    def ref_axis(n_src, e):
        w = np.zeros((len(e) - 1, n_src))
        for k in range(len(e) - 1):
            a, b = np.clip(e[k], 0, n_src), np.clip(e[k + 1], 0, n_src)
            if b - a <= 1e-12:
                w[k, min(int(np.floor(a)), n_src - 1)] = 1
                continue
            for i in range(n_src):
                w[k, i] = max(0.0, min(b, i + 1) - max(a, i))
            w[k] /= w[k].sum()
        return w

    xe = (np.arange(8) - 3.2) * 2.37 + 8.9  # 7 output columns, the last ones past the right edge
    ye = np.arange(6) * 2.6 - 1.5  # 5 rows, the first starting above the image
    xe = np.append(xe, [xe[-1] + 3, xe[-1] + 6])  # wholly outside
    want = np.einsum("yi,ijc,xj->yxc", ref_axis(13, ye), img, ref_axis(17, xe))
    got = area_resample(img.astype(np.float32), xe, ye)
    assert got.shape == (5, 9, 3) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=1e-6)
    # the columns wholly past the right edge are the last source column, averaged over the rows
    np.testing.assert_allclose(got[:, -2:], np.repeat((ref_axis(13, ye) @ img[:, -1])[:, None], 2, 1), atol=1e-6)
