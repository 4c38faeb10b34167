"""YUV 4:2:0 output (formats/yuv.py rgb_to_yuv / write_frame, ``ibr-render --yuv``): the inverse of
the MPEG importer's reader, as RVS writes its outputs."""
from __future__ import annotations

import json

import numpy as np
import pytest

from ibrtools.errors import BadValueError
from ibrtools.formats import yuv
from ibrtools.imageio import linear_to_srgb, read_image, srgb_to_linear
from conftest import synth_scene_dir


def test_codes_of_black_white_and_grey():
    img = np.zeros((2, 4, 3), np.float32)
    img[:, 2:] = 1.0
    y, cb, cr = yuv.rgb_to_yuv(img, 10)
    assert y.dtype == np.dtype("<u2") and y.shape == (2, 4) and cb.shape == (1, 2)
    np.testing.assert_array_equal(y, [[64, 64, 940, 940]] * 2)  # limited range: 16..235 x 4
    np.testing.assert_array_equal(cb, [[512, 512]])
    np.testing.assert_array_equal(cr, [[512, 512]])
    y8, cb8, _ = yuv.rgb_to_yuv(img, 8, full_range=True)
    assert y8.dtype == np.uint8 and y8.max() == 255 and y8.min() == 0 and cb8.max() == 128
    # Pure red, BT.709: Cr at its top code 960 (128 + 112 = 240 in 8 bits), Y = 16 + 219 * 0.2126.
    red = np.zeros((2, 2, 3), np.float32)
    red[..., 0] = 1
    y, cb, cr = yuv.rgb_to_yuv(red, 8)
    assert int(y[0, 0]) == round(16 + 219 * 0.2126) and int(cr[0, 0]) == 240


@pytest.mark.parametrize("bits,full", [(8, False), (10, False), (10, True)])
def test_roundtrip_through_the_importers_reader(bits, full):
    rng = np.random.default_rng(1)
    # Smooth colour (chroma subsampling loses little) with odd sizes (the last row/column repeated).
    yy, xx = np.mgrid[0:33, 0:47] / 40.0
    enc = np.stack([0.5 + 0.4 * np.sin(xx * 3), 0.5 + 0.4 * np.cos(yy * 2), 0.3 + 0.3 * xx * yy], -1)
    enc = np.clip(enc + rng.normal(0, 0.002, enc.shape), 0, 1).astype(np.float32)
    planes = yuv.rgb_to_yuv(srgb_to_linear(enc), bits, full_range=full)
    assert [p.shape for p in planes] == yuv.plane_shapes(47, 33)
    back = linear_to_srgb(yuv.yuv_to_rgb(planes, bits, full_range=full))
    err = np.abs(back - enc)
    assert err.max() < (0.03 if bits == 8 else 0.02) and err.mean() < (0.004 if bits == 8 else 0.002)


def test_nan_and_out_of_range_are_clipped():
    img = np.array([[[np.nan, -1.0, 5.0]] * 2] * 2, np.float32)
    y, cb, cr = yuv.rgb_to_yuv(img, 10)
    assert 64 <= int(y.min()) and int(y.max()) <= 940 and 64 <= int(cb.min()) and int(cr.max()) <= 960


def test_bad_arguments():
    with pytest.raises(BadValueError, match="bit depth"):
        yuv.rgb_to_yuv(np.zeros((2, 2, 3), np.float32), 7)
    with pytest.raises(BadValueError, match="matrix"):
        yuv.rgb_to_yuv(np.zeros((2, 2, 3), np.float32), 8, matrix="bt2020")
    with pytest.raises(BadValueError, match=r"\(H, W, 3\)"):
        yuv.rgb_to_yuv(np.zeros((2, 2), np.float32), 8)


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory):
    d = synth_scene_dir(tmp_path_factory, "--views", "4", "--size", "64x48", name="yuvscene")
    return d


def test_render_writes_every_frame_into_one_yuv_file(small_scene, tmp_path):
    from ibrtools_cli import render

    out, video = tmp_path / "o", tmp_path / "out.yuv"
    assert render.main([str(small_scene), "--method", "dibr", "-o", str(out), "--yuv", str(video), "-q"]) == 0
    rep = json.loads((out / "report.json").read_text())
    n = len(rep["frames"])
    assert n >= 2 and rep["yuv"] == {"path": str(video), "frames": n, "width": 64, "height": 48, "chroma": "420",
                                     "bits": 10, "matrix": "bt709", "range": "limited"}
    assert yuv.frame_count(video, 64, 48, 10) == n
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left
    for k, f in enumerate(rep["frames"]):
        # Frame k's planes are those of the frame's own image: the same codes as converting its
        # PNG, up to the PNG's 8-bit rounding (half a PNG step = 1.7 codes of 10-bit luma).
        got = yuv.read_frame(video, 64, 48, 10, k)
        want = yuv.rgb_to_yuv(read_image(out / f["image"]), 10)
        for g, w in zip(got, want):
            assert np.abs(g.astype(int) - w.astype(int)).max() <= 2
    assert render.main([str(small_scene), "--method", "dibr", "-o", str(tmp_path / "o8"), "--yuv",
                        str(tmp_path / "o8.yuv"), "--yuv-bits", "8", "-q"]) == 0
    assert yuv.frame_count(tmp_path / "o8.yuv", 64, 48, 8) == n


def test_render_refuses_bad_yuv_options(small_scene, tmp_path, capsys):
    from ibrtools_cli import render

    base = [str(small_scene), "--method", "dibr", "-o", str(tmp_path / "o"), "-q"]
    assert render.main(base + ["--yuv-bits", "10"]) == 2
    assert "--yuv-bits: only with --yuv" in capsys.readouterr().err
    assert render.main(base + ["--yuv", str(tmp_path / "v.yuv"), "--yuv-bits", "7"]) == 2
    assert "--yuv-bits: expected a bit depth of 8..16, got 7" in capsys.readouterr().err
    assert render.main(base + ["--yuv", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err
    assert render.main(base + ["--yuv", str(tmp_path / "nope" / "v.yuv")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not (tmp_path / "o").exists() and not (tmp_path / "v.yuv").exists()
