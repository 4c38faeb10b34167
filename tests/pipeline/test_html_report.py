"""The self-contained HTML reports (ibrtools.pipeline.report_html; ibr-render --report-html, ibr-bench's
report.html), checked as files and in a headless browser (Debian's chromium-headless-shell)."""
from __future__ import annotations

import json
import os
import re
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

from ibrtools.pipeline import report_html as R
from ibrtools.errors import BadValueError, ShapeError
from ibrtools_cli import bench, render
from conftest import synth_scene_dir

CHROMIUM = next((p for p in ("/usr/bin/chromium-headless-shell", shutil.which("chromium-headless-shell") or "",
                             shutil.which("chromium") or "") if p and Path(p).exists()), None)
SRC = re.compile(r'<img[^>]*\ssrc="([^"]*)"')


def _decode_png(data: bytes) -> np.ndarray:
    """Decode PNG bytes with Pillow (an implementation independent of the OpenImageIO encoder)."""
    import io

    from PIL import Image

    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    a = np.asarray(Image.open(io.BytesIO(data)))
    return a if a.ndim == 3 else a[..., None]


def _images(page: str) -> list[tuple[int, int]]:
    """(width, height) of every image of the page, each checked to be an embedded PNG."""
    import base64

    srcs = SRC.findall(page)
    assert all(s.startswith("data:image/png;base64,") for s in srcs), [s[:40] for s in srcs]
    sizes = []
    for s in srcs:
        data = base64.b64decode(s.split(",", 1)[1])
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
        sizes.append(struct.unpack(">II", data[16:24]))
    return sizes


def test_png_encoder_round_trip_and_bad_input(rng):
    rgb = rng.integers(0, 256, (7, 5, 3), dtype=np.uint8)
    grey = rng.integers(0, 256, (3, 9), dtype=np.uint8)
    np.testing.assert_array_equal(_decode_png(R.encode_png(rgb)), rgb)
    np.testing.assert_array_equal(_decode_png(R.encode_png(grey))[..., 0], grey)
    with pytest.raises(BadValueError, match="uint8"):
        R.encode_png(rgb.astype(np.float32))
    with pytest.raises(ShapeError):
        R.encode_png(np.zeros((2, 2, 4), np.uint8))
    with pytest.raises(ShapeError):
        R.encode_png(np.zeros((0, 2, 3), np.uint8))


def test_shrink_colormap_and_frame_choice():
    a = np.arange(4 * 6, dtype=np.float32).reshape(4, 6)
    s = R.shrink(a, 3)  # factor 2: 2x2 box means
    np.testing.assert_array_equal(s, a.reshape(2, 2, 3, 2).mean(axis=(1, 3)))
    assert R.shrink(a, 6) is not None and R.shrink(a, 6).shape == (4, 6)
    assert R.shrink(np.zeros((5, 700, 3)), 640).shape == (2, 350, 3)
    cm = R.colormap(np.array([0.0, 0.5, 1.0, 2.0, np.nan]), 1.0)
    assert cm[0].tolist() == [0, 0, 4] and cm[2].tolist() == [252, 253, 191] and cm[3].tolist() == cm[2].tolist()
    assert cm[4].tolist() == [0, 0, 4]  # NaN shows as no error
    assert R.pick_frames(5, 10) == [0, 1, 2, 3, 4]
    p = R.pick_frames(100, 5)
    assert p[0] == 0 and p[-1] == 99 and len(p) == 5


def test_frame_panel_error_map_and_masks(rng):
    truth = rng.random((20, 30, 3), dtype=np.float32)
    rendered = truth.copy()
    rendered[5:10, 5:10] = 0.0
    sel = np.zeros((20, 30, 3), np.float32)
    sel[..., 0] = 1.0
    hole = np.zeros((20, 30), bool)
    hole[0, 0] = True
    p = R.frame_panel("f", rendered, truth, selection=sel, hole=hole, stage_ms={"a": 1.0}, max_width=15)
    assert p.rendered.shape == (10, 15, 3) and p.truth.shape == (10, 15, 3) and p.error.shape == (10, 15, 3)
    assert p.mask_label.startswith("selection") and p.hole is not None
    # The error map is dark where the images agree and bright where they differ.
    assert p.error[3:4, 3:4].sum() > p.error[8:, 10:].sum()
    q = R.frame_panel("g", rendered, None, hole=hole)
    assert q.truth is None and q.error is None and q.mask_label == "holes (white)"
    with pytest.raises(ShapeError):
        R.error_map(rendered, truth[:10])


def test_check_output_and_unwritable_page(tmp_path):
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(BadValueError, match="is a directory"):
        R.check_output(tmp_path)
    with pytest.raises(BadValueError, match="not a directory"):
        R.check_output(tmp_path / "file.txt" / "r.html")
    assert R.check_output(tmp_path / "new" / "r.html") == tmp_path / "new" / "r.html"
    with pytest.raises(BadValueError, match="cannot write"):
        R.write_page(tmp_path / "file.txt" / "r.html", "<html></html>")


def test_unwritable_directory_is_refused(tmp_path, monkeypatch, capsys, scene_dir):
    # Tests may run as root, for whom permission bits do not stop a write: os.access decides.
    import os

    monkeypatch.setattr(os, "access", lambda p, mode: False)
    with pytest.raises(BadValueError, match="cannot write into"):
        R.check_output(tmp_path / "r.html")
    assert render.main([str(scene_dir), "--holdout", "v001", "--report-html", str(tmp_path / "r.html"),
                        "-o", str(tmp_path / "out")]) == 2
    assert "cannot write into" in capsys.readouterr().err and not (tmp_path / "out").exists()


# --- the commands ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return synth_scene_dir(tmp_path_factory, "--views", "4", "--size", "64x48", name="html")


@pytest.fixture(scope="module")
def render_page(scene_dir, tmp_path_factory):
    """A dibr run with holes (mask images) and ground truth (held-out views), and an escaped
    frame name from a pose file."""
    from ibrtools.formats import native

    tmp = tmp_path_factory.mktemp("htmlrun")
    scene = native.load(scene_dir)
    poses = tmp / "poses.json"
    poses.write_text(json.dumps([dict(scene.views[0].camera.to_dict(), name="a<b>&\"c'")]))
    out = tmp / "out"
    assert render.main([str(scene_dir), "--method", "dibr", "--holdout", "v001", "v002", "--poses", str(poses),
                        "--report-html", "-o", str(out), "-q"]) == 0
    return out / "report.html"


def test_render_report_contents(render_page):
    page = render_page.read_text()
    assert "http://" not in page and "https://" not in page and "<link" not in page  # self-contained
    assert "a&lt;b&gt;&amp;&quot;c&#x27;" in page and "a<b>" not in page  # names escaped
    imgs = _images(page)
    # 3 frames: rendered (+ truth + error map for the two held-out ones) + hole masks, + colour bars.
    assert page.count('alt="v001 rendered"') == 1 and page.count('alt="v001 ground truth"') == 1
    assert page.count("error: FLIP") + page.count("error: |error|") == 2
    assert "holes (white)" in page and "Summary" in page and "median ms per frame" in page
    assert all(w <= 640 for w, _ in imgs) and len(imgs) >= 3 + 2 + 2
    assert not list(render_page.parent.glob(".report.*"))  # written atomically, nothing left over


def test_render_report_caps_frames_and_shrinks(scene_dir, tmp_path):
    out = tmp_path / "o"
    assert render.main([str(scene_dir), "--method", "reference", "--holdout", "v001", "v002", "v003",
                        "-o", str(out), "-q"]) == 0
    rep = json.loads((out / "report.json").read_text())
    page_path = R.render_report(rep, out, tmp_path / "r.html", max_frames=2, max_width=20)
    page = page_path.read_text()
    assert "Showing 2 of 3 frames" in page and "v001" in page and "v003" in page and "v002" not in page
    widths = [w for w, _ in _images(page)]
    assert max(w for w in widths if w != 256) <= 20  # the colour bar strip (256) aside


def test_render_report_names_failed_frames(scene_dir, tmp_path):
    out = tmp_path / "o"
    assert render.main([str(scene_dir), "--method", "reference", "--holdout", "v001", "-o", str(out), "-q"]) == 0
    rep = json.loads((out / "report.json").read_text())
    rep["failed"] = [{"name": "p<1>", "error": "BadValueError: x & y"}]  # as a distributed run reports them
    page = R.render_report(rep, out, tmp_path / "r.html").read_text()
    assert "<li>p&lt;1&gt;: BadValueError: x &amp; y</li>" in page and "failed frames" in page


def test_render_report_html_bad_path(scene_dir, tmp_path, capsys):
    (tmp_path / "file.txt").write_text("x")
    for target, msg in ((tmp_path / "file.txt" / "r.html", "not a directory"), (tmp_path, "is a directory")):
        assert render.main([str(scene_dir), "--holdout", "v001", "--report-html", str(target),
                            "-o", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err
        assert msg in err and err.count("\n") == 1
        assert not (tmp_path / "out").exists()  # refused before rendering


@pytest.fixture(scope="module")
def bench_page(tmp_path_factory):
    from ibrtools.pipeline import stages as S

    d = tmp_path_factory.mktemp("htmlbench")
    S.preprocess("synth:objects", d / "scene", synth={"preset": "objects", "size": [48, 36], "views": 4, "seed": 0,
                                                      "reconstructed": False, "holdout_targets": 1},
                 methods=["tm", "ulr"], stage_options={"mesh": {"source": "ground_truth", "resolution": 64}})
    out = d / "sweep"
    assert bench.main([str(d / "scene"), "--method", "ulr", "--sweep", "k=2:3", "--holdout", "v001", "v002",
                       "-o", str(out), "-q", "--report-frames", "1"]) == 0
    return out / "report.html"


def test_bench_report_contents(bench_page):
    page = bench_page.read_text()
    assert "Run time against error" in page and "Configurations" in page and "Frames of configuration" in page
    imgs = _images(page)
    assert page.count('alt="run time against error"') == 1
    assert page.count("rendered</figcaption>") == 1  # --report-frames 1
    # The configurations table (header + 2 rows) and one frame table (header + values).
    assert page.count("<tr>") == 3 + 2 and len(imgs) >= 4


def test_bench_report_frames_bad_input(tmp_path, capsys):
    assert bench.main([str(tmp_path), "--report-frames", "-1", "-o", str(tmp_path / "o")]) == 2
    assert "--report-frames" in capsys.readouterr().err


# --- in a browser -----------------------------------------------------------------------------------
def _chromium(page: Path) -> tuple[str, str]:
    """Load ``page`` in headless Chromium; return (DOM after the load event, log on stderr). Not
    with the sanitizer runtime tools/sanitize.sh preloads into Python (``make check-asan``): the
    browser is not ours, and under it it hung past the timeout."""
    env = {k: v for k, v in os.environ.items() if k != "LD_PRELOAD"}
    r = subprocess.run([CHROMIUM, "--headless", "--disable-gpu", "--no-sandbox", "--dump-dom",
                        "--virtual-time-budget=5000", "--enable-logging=stderr", "--v=0",
                        page.resolve().as_uri()], capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout, r.stderr


@pytest.mark.skipif(CHROMIUM is None, reason="no headless Chromium (Debian: apt install chromium-headless-shell)")
@pytest.mark.parametrize("which", ["render_page", "bench_page"])
def test_report_renders_in_a_browser_with_every_image(which, request):
    page = request.getfixturevalue(which)
    n = len(SRC.findall(page.read_text()))
    dom, log = _chromium(page)
    m = re.search(r'data-images-ok="(\d+)/(\d+)"', dom)
    assert m, "the page's load script did not run"
    assert (int(m.group(1)), int(m.group(2))) == (n, n), m.group(0)
    console = [line for line in log.splitlines() if ":CONSOLE" in line or "Uncaught" in line]
    assert not console, console
