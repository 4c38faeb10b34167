"""ibr-view (ibrtools/viewer.py): the server in this process on a free port, the page in
headless Chromium (as the HTML report's test)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import threading
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from ibrtools import api
from ibrtools.camera import Camera

CHROMIUM = next((p for p in ("/usr/bin/chromium-headless-shell", shutil.which("chromium-headless-shell") or "",
                             shutil.which("chromium") or "") if p and Path(p).exists()), None)
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="no headless Chromium (Debian: apt install "
                                                             "chromium-headless-shell)")
SIZE = (96, 72)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from ibrtools import synth
    from ibrtools.formats import native

    d = tmp_path_factory.mktemp("view") / "scene"
    native.save(synth.make_scene("objects", size=SIZE, views=6, holdout_targets=1), d)
    return native.load(d)


@pytest.fixture
def server(scene, tmp_path):
    from ibrtools.viewer import Viewer

    v = Viewer(scene, "dibr", port=0, save_dir=tmp_path / "paths")
    t = threading.Thread(target=v.serve_forever, daemon=True)
    t.start()
    yield v
    v.shutdown()
    t.join(10)


def _get(url: str) -> tuple[int, bytes, dict]:
    try:
        with urllib.request.urlopen(url, timeout=60) as r:
            return r.status, r.read(), dict(r.headers)
    except urllib.error.HTTPError as e:
        return e.code, e.read(), dict(e.headers)


def _frame_url(v, cam: Camera, **kw) -> str:
    q = {"t": v.token, "pose": json.dumps(cam.to_dict()), "fmt": "png", **{k: str(x) for k, x in kw.items()}}
    return v.url.split("?")[0] + "frame?" + urllib.parse.urlencode(q)


def _decode(data: bytes, tmp_path: Path) -> np.ndarray:
    from ibrtools.imageio import read_pixels

    p = tmp_path / "f.png"
    p.write_bytes(data)
    return read_pixels(p)[0][..., :3].astype(np.int32)


def _png_of(color: np.ndarray, tmp_path: Path) -> np.ndarray:
    from ibrtools.viewer import encode

    return _decode(encode(color, "png"), tmp_path)


def _chromium(url: str, *extra: str) -> str:
    env = {k: v for k, v in os.environ.items() if k != "LD_PRELOAD"}
    r = subprocess.run([CHROMIUM, "--headless", "--disable-gpu", "--no-sandbox", "--virtual-time-budget=20000",
                        *extra, url], capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout


def test_token_and_paths_are_checked(server):
    base = server.url.split("?")[0]
    assert _get(base)[0] == 403 and _get(base + "scene.json")[0] == 403
    assert _get(base + "scene.json?t=wrong")[0] == 403
    assert _get(server.url)[0] == 200
    for p in ("../../etc/passwd", "scene.json/../../x", "images/v000.png", "%2e%2e/scene.json"):
        assert _get(base + p + "?t=" + server.token)[0] == 404, p
    status, body, _ = _get(base + "frame?t=" + server.token + "&pose=%7B")
    assert status == 400 and b"pose" in body
    cam = server.scene.views[0].camera
    assert _get(_frame_url(server, cam, w=100000))[0] == 400
    assert _get(_frame_url(server, cam, method="nerf"))[0] == 400


def test_frame_is_the_render_of_the_pose_and_clients_do_not_mix(server, scene, tmp_path):
    cams = [scene.views[0].camera, scene.views[3].camera]
    got: dict = {}

    def ask(i):
        got[i] = _get(_frame_url(server, cams[i], client=f"c{i}", seq=1))

    threads = [threading.Thread(target=ask, args=(i,)) for i in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    for i, cam in enumerate(cams):
        status, data, headers = got[i]
        assert status == 200 and float(headers["X-Render-Ms"]) > 0
        want = _png_of(api.render(scene, cam, method="dibr").color, tmp_path)
        np.testing.assert_array_equal(_decode(data, tmp_path), want)
    # A client's request overtaken by its own newer one before it rendered: not rendered.
    server.note_request("c9", 5)
    assert _get(_frame_url(server, cams[0], client="c9", seq=3))[0] == 204


def test_saved_path_renders_the_same_frames_with_ibr_render(server, scene, tmp_path):
    from ibrtools.imageio import read_image
    from ibrtools_cli import render

    poses = [dict(scene.views[i].camera.to_dict(), name=f"frame_{i:04d}") for i in (1, 2)]
    req = urllib.request.Request(server.url.split("?")[0] + "path?t=" + server.token, method="POST",
                                 data=json.dumps({"name": "walk/../x", "poses": poses}).encode())
    with urllib.request.urlopen(req, timeout=60) as r:
        out = json.loads(r.read())
    f = Path(out["file"])
    assert f.parent == tmp_path / "paths" and f.name == "walk_.._x.json" and out["poses"] == 2
    assert render.main([str(scene.root), "--method", "dibr", "--poses", str(f), "--float", "-o", str(tmp_path / "o"),
                        "-q"]) == 0
    for p in poses:
        np.testing.assert_array_equal(read_image(tmp_path / "o" / f"{p['name']}.exr"),
                                      api.render(scene, Camera.from_dict(p), method="dibr").color)
    bad = urllib.request.Request(server.url.split("?")[0] + "path?t=" + server.token, method="POST", data=b"[1]")
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(bad, timeout=60)
    assert e.value.code == 400


@needs_chromium
def test_page_shows_the_frame_ibr_render_gives(server, scene, tmp_path):
    shot = tmp_path / "shot.png"
    w, h = scene.views[0].camera.width, scene.views[0].camera.height
    _chromium(server.url, f"--window-size={w + 300},{max(h, 300)}", f"--screenshot={shot}")
    from ibrtools.imageio import read_pixels

    px = read_pixels(shot)[0][:h, :w, :3].astype(np.int32)
    want = _png_of(api.render(scene, scene.views[0].camera, method="dibr").color, tmp_path)
    assert px.std() > 5  # not empty
    assert np.abs(px - want).max() <= 1


@needs_chromium
def test_drag_changes_the_pose_and_the_image(server, scene, tmp_path):
    import re

    dom = _chromium(server.url + "&selftest=drag", "--dump-dom")
    m = re.search(r'<body[^>]*data-frames="(\d+)"[^>]*>', dom)
    assert m, dom[:500]
    body = m.group(0)
    poses = json.loads(re.search(r'data-poses="([^"]*)"', body).group(1).replace("&quot;", '"'))
    sizes = json.loads(re.search(r'data-sizes="([^"]*)"', body).group(1).replace("&quot;", '"'))
    assert len(poses) >= 2 and poses[-1] != poses[0]
    assert sizes[-1] == [SIZE[0], SIZE[1]]  # refined to full size when the camera stopped
    assert any(s[0] < SIZE[0] for s in sizes)  # ... after frames at reduced size while it moved
    start = scene.views[0].camera
    a = api.render(scene, start, method="dibr").color
    b = api.render(scene, start.with_pose(np.array(poses[-1])), method="dibr").color
    assert np.abs(a - b).mean() > 0.01


def test_cli_bad_scene_and_port(tmp_path, capsys):
    from ibrtools_cli import view

    assert view.main([str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "nope" in err
    assert view.main([str(tmp_path), "--port", "70000"]) == 2


def test_ctrl_c_stops_cleanly(scene):
    import signal
    import sys

    p = subprocess.Popen([sys.executable, "-m", "ibrtools_cli.view", str(scene.root), "--port", "0"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = p.stdout.readline()
        assert "open http://127.0.0.1:" in line and "?t=" in line
        url = line.split("open ", 1)[1].strip()
        assert _get(url)[0] == 200
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=30)
    finally:
        p.kill()
    assert p.returncode == 0 and "stopped" in err
