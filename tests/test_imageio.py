"""Image and depth I/O through OpenImageIO: sRGB on integer formats, linear floats, atomic writes."""
import numpy as np
import pytest

from ibrtools import BadValueError, DtypeError, FormatError, MissingFileError, ShapeError
from ibrtools.checks import check_depth
from ibrtools.imageio import (linear_to_srgb, read_depth, read_image, read_mask,
                              srgb_to_linear, write_depth, write_image)


def test_srgb_transfer_matches_the_standard():
    # IEC 61966-2-1: 0.5 linear -> 0.735357 encoded; 0.214041 encoded -> 0.037649 linear (by hand).
    assert abs(float(linear_to_srgb(np.float32(0.5))) - 0.735357) < 1e-5
    assert abs(float(srgb_to_linear(np.float32(0.214041))) - 0.037649) < 1e-5
    v = np.linspace(0, 1, 1001, dtype=np.float32)
    assert np.abs(srgb_to_linear(linear_to_srgb(v)) - v).max() < 2e-6


@pytest.mark.parametrize("ext, bits, tol", [
    # 8-bit sRGB: one code step is at most ~1/255 in encoded value; in linear it is < 1.3e-2.
    ("png", 8, 1.3e-2), ("png", 16, 1e-4), ("exr", 8, 0.0), ("pfm", 8, 0.0), ("jpg", 8, 0.12)])
def test_colour_round_trip(tmp_path, rng, ext, bits, tol):
    img = rng.uniform(0, 1, (9, 13, 3)).astype(np.float32)
    if ext == "jpg":
        img = np.full((16, 16, 3), 0.3, np.float32)  # JPEG is lossy: a flat patch is exact-ish
    f = write_image(tmp_path / f"a.{ext}", img, bits=bits)
    back = read_image(f)
    assert back.dtype == np.float32 and back.shape == img.shape and back.flags.c_contiguous
    assert np.abs(back - img).max() <= tol + 1e-7


def test_png_8bit_encoding_is_srgb(tmp_path):
    import OpenImageIO as oiio
    write_image(tmp_path / "g.png", np.full((2, 2, 3), 0.5, np.float32))
    raw = oiio.ImageInput.open(str(tmp_path / "g.png")).read_image("uint8")
    assert int(raw[0, 0, 0]) == round(0.735357 * 255)


def test_alpha_and_mask(tmp_path):
    img = np.zeros((4, 4, 4), np.float32)
    img[..., 3] = 0.0
    img[:2, :, 3] = 1.0
    write_image(tmp_path / "a.png", img)
    rgba = read_image(tmp_path / "a.png", alpha=True)
    assert rgba.shape == (4, 4, 4) and np.all(rgba[:2, :, 3] == 1) and np.all(rgba[2:, :, 3] == 0)
    m = read_mask(tmp_path / "a.png")
    assert m.dtype == bool


def test_depth_float_and_16bit(tmp_path):
    d = np.linspace(0.5, 20, 12, dtype=np.float32).reshape(3, 4)
    write_depth(tmp_path / "d.exr", d)
    assert np.array_equal(read_depth(tmp_path / "d.exr"), d)
    import OpenImageIO as oiio
    raw = np.array([[0, 5000], [10000, 65535]], np.uint16)
    out = oiio.ImageOutput.create(str(tmp_path / "d.png"))
    out.open(str(tmp_path / "d.png"), oiio.ImageSpec(2, 2, 1, "uint16"))
    out.write_image(raw[:, :, None])
    out.close()
    got = read_depth(tmp_path / "d.png", scale=1 / 5000)
    assert np.allclose(got, raw / 5000.0, rtol=1e-6)
    with pytest.raises(BadValueError, match="needs a positive scale"):
        read_depth(tmp_path / "d.png")


def test_pfm_rows_are_bottom_to_top(tmp_path):
    """A PFM written by hand to the spec (bottom row first) reads with its top row first."""
    img = np.arange(6, dtype=np.float32).reshape(2, 3)
    with open(tmp_path / "m.pfm", "wb") as f:
        f.write(b"Pf\n3 2\n-1.0\n" + img[::-1].tobytes())
    assert np.array_equal(read_depth(tmp_path / "m.pfm"), img)


def test_depth_never_through_8_bits(tmp_path):
    write_image(tmp_path / "d8.png", np.zeros((2, 2, 1), np.float32))
    with pytest.raises(DtypeError, match="8-bit"):
        read_depth(tmp_path / "d8.png")
    with pytest.raises(FormatError, match="exr or .pfm"):
        write_depth(tmp_path / "d.png", np.ones((2, 2), np.float32))


def test_check_depth_rejects_bad_values():
    ok = np.ones((2, 3), np.float32)
    assert check_depth(ok, "d") is ok
    for bad, msg in [(np.full((2, 3), np.nan, np.float32), "NaN"), (-ok, "negative"),
                     (np.zeros((2, 3), np.float32), "no valid depth")]:
        with pytest.raises(BadValueError, match=msg):
            check_depth(bad, "d")
    with pytest.raises(DtypeError):
        check_depth(ok.astype(np.float64), "d")
    with pytest.raises(ShapeError, match=r"\(H, W\) = \(3, 2\)"):
        check_depth(ok, "d", (3, 2))
    inf = ok.copy()
    inf[0, 0] = np.inf  # a point at infinity (sky) is allowed
    check_depth(inf, "d")


def test_bad_files(tmp_path):
    with pytest.raises(MissingFileError, match="nope.png"):
        read_image(tmp_path / "nope.png")
    (tmp_path / "junk.png").write_bytes(b"not a png at all")
    with pytest.raises(FormatError, match="junk.png"):
        read_image(tmp_path / "junk.png")
    good = tmp_path / "t.png"
    write_image(good, np.zeros((64, 64, 3), np.float32))
    (tmp_path / "trunc.png").write_bytes(good.read_bytes()[:60])
    with pytest.raises(FormatError, match="trunc.png"):
        read_image(tmp_path / "trunc.png")
    with pytest.raises(FormatError, match="unknown image extension"):
        write_image(tmp_path / "x.xyz", np.zeros((2, 2, 3), np.float32))
    with pytest.raises(ShapeError):
        write_image(tmp_path / "x.png", np.zeros((2, 2, 7), np.float32))
    with pytest.raises(DtypeError):
        write_image(tmp_path / "x.png", np.zeros((2, 2, 3), np.uint8))


def test_write_is_atomic(tmp_path, monkeypatch):
    """A write that fails leaves neither a partial file nor a temporary one."""
    import ibrtools.imageio as io

    f = tmp_path / "keep.png"
    write_image(f, np.zeros((4, 4, 3), np.float32))
    before = f.read_bytes()

    class Boom(Exception):
        pass

    real = io.srgb8
    monkeypatch.setattr(io, "srgb8", lambda v: (_ for _ in ()).throw(Boom()))
    with pytest.raises(Boom):
        write_image(f, np.ones((4, 4, 3), np.float32))
    monkeypatch.setattr(io, "srgb8", real)
    assert f.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.png"]


def test_png_level_changes_the_bytes_not_the_pixels(tmp_path):
    rng = np.random.default_rng(0)
    img = np.repeat(np.linspace(0, 1, 64, dtype=np.float32)[None, :, None], 48, 0) * np.ones(3, np.float32)
    img[::7] = rng.random((7, 64, 3)).astype(np.float32)
    sizes = {}
    for level in (None, 0, 1, 9):
        p = write_image(tmp_path / f"l{level}.png", img, png_level=level)
        sizes[level] = p.stat().st_size
        np.testing.assert_array_equal(read_image(p), read_image(tmp_path / "lNone.png"))
    assert sizes[0] > sizes[1] >= sizes[9] and sizes[None] >= sizes[9]
    for bad in (10, -1, 1.5, True):
        with pytest.raises(BadValueError, match="png_level must be an integer 0-9"):
            write_image(tmp_path / "bad.png", img, png_level=bad)
    # One row filter: other bytes, the same pixels.
    plain = (tmp_path / "l1.png").read_bytes()
    for name in ("none", "sub", "up", "avg", "paeth"):
        p = write_image(tmp_path / f"f{name}.png", img, png_level=1, png_filter=name)
        np.testing.assert_array_equal(read_image(p), read_image(tmp_path / "lNone.png"))
    assert (tmp_path / "fnone.png").read_bytes() != plain or (tmp_path / "fsub.png").read_bytes() != plain
    with pytest.raises(BadValueError, match="png_filter must be one of none, sub"):
        write_image(tmp_path / "bad.png", img, png_filter="best")
    assert not (tmp_path / "bad.png").exists()
