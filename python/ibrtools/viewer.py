"""``ibr-view``: a scene in the browser, every frame rendered by the engine (docs/viewer.md).

:class:`Viewer` is a local HTTP server (the standard library's ``ThreadingHTTPServer``) that
serves one page (:mod:`ibrtools.viewer_page`) and the frames it asks for; nothing else, no file
from disk. Every request must carry the server's random token (``?t=``): without it the answer
is 403, any other path is 404. Endpoints:

  ``GET /``            the page
  ``GET /scene.json``  the input cameras, targets, paths (stored and generated: ibrtools.paths),
                       methods, the world's up vector and the start camera (scene.json camera dicts, docs/FORMAT.md)
  ``GET /frame``       one frame: ``pose`` (a camera dict as JSON), ``method``, ``w``, ``h`` (the
                       pose's camera scaled to w x h), ``overlay`` (none | holes | method),
                       ``fmt`` (jpeg | png), ``client`` and ``seq``: a client's request that a
                       newer one of the same client has overtaken before it started rendering
                       is answered 204 (not rendered: the pose is no longer needed). Headers
                       ``X-Render-Ms`` (the render, as ``ibrtools.render`` times it) and ``X-Seq``.
  ``POST /path``       body {"name", "poses": [camera dicts]}: written atomically as
                       ``<save_dir>/<name>.json``, a poses file ``ibr-render --poses`` reads.

Frames are rendered one at a time (the scene's prepared methods are shared and serialised by
:func:`ibrtools.render`); they are the same images ``ibrtools.render`` gives for the pose.
"""
from __future__ import annotations

import json
import secrets
import tempfile
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlparse

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, InputError, NotBuiltError
from ibrtools.paths import all_paths
from ibrtools.scene import Scene
from ibrtools import methods
from ibrtools.api import render
from ibrtools.cache import with_stage_depth
from ibrtools.imageio import atomic_path, write_image
from ibrtools.outputs import file_stem
from ibrtools.viewer_page import PAGE

FORMATS = {"jpeg": ("image/jpeg", ".jpg"), "png": ("image/png", ".png")}
OVERLAYS = ("none", "holes", "method")
# Largest frame a request may ask for (pixels a side): a pose from the page is scaled to the
# browser window; anything larger is a mistake or an attack on the server's memory.
MAX_SIDE = 4096
# Largest request body (POST /path): a path of 10 000 poses is ~4 MB.
MAX_BODY = 8 << 20


def scene_info(scene: Scene, methods: list[str]) -> dict:
    """What the page needs to know about ``scene`` (GET /scene.json)."""
    cams = [v.camera for v in scene.views] or [t.camera for t in scene.targets]
    if not cams:
        raise InputError("ibr-view: the scene has no input views and no targets: nothing to look at")
    up = _world_up(scene, cams)
    return {"views": [{"name": v.name, "camera": v.camera.to_dict()} for v in scene.views],
            "targets": [{"name": t.name, "camera": t.camera.to_dict()} for t in scene.targets],
            "paths": {k: [c.to_dict() for c in p] for k, p in all_paths(scene).items()},
            "methods": methods, "up": [float(x) for x in up], "start": cams[0].to_dict(),
            "centre": [float(x) for x in _centre(cams)]}


def _world_up(scene: Scene, cams: list[Camera]) -> np.ndarray:
    """The scene's up direction: ``source.world_up`` when the scene gives one, else the mean of
    the cameras' up axes (-y in OpenCV axes)."""
    up = (scene.source or {}).get("world_up")
    if up is not None and len(up) == 3:
        v = np.asarray(up, np.float64)
    else:
        v = -np.mean([c.world_from_cam[:3, 1] for c in cams], axis=0)
    n = np.linalg.norm(v)
    return v / n if n > 0 else np.array([0.0, 1.0, 0.0])


def _centre(cams: list[Camera]) -> np.ndarray:
    """The point the cameras look at most nearly (least squares over their optical axes), or
    their mean position when the axes are (nearly) parallel."""
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for c in cams:
        d = c.world_from_cam[:3, 2]
        p = np.eye(3) - np.outer(d, d)
        a += p
        b += p @ c.centre
    mean = np.mean([c.centre for c in cams], axis=0)
    if len(cams) < 2 or np.linalg.cond(a) > 1e6:
        return mean + cams[0].world_from_cam[:3, 2]
    return np.linalg.solve(a, b)


def encode(image: np.ndarray, fmt: str) -> bytes:
    """An image (H, W, 3) linear float as JPEG or PNG bytes (8-bit sRGB), by the engine's writer."""
    with tempfile.TemporaryDirectory(prefix="ibr-view-") as d:
        p = Path(d) / f"frame{FORMATS[fmt][1]}"
        write_image(p, image)
        return p.read_bytes()


def overlay_image(result, overlay: str) -> np.ndarray:
    """The frame with its holes tinted red (``holes``) or the hybrid's method choice (``method``,
    when the method gives one; else the frame)."""
    color = result.color
    if overlay == "holes" and result.hole is not None:
        tint = np.array([1.0, 0.0, 0.0], np.float32)
        return np.where(result.hole[..., None], 0.5 * color + 0.5 * tint, color).astype(np.float32)
    if overlay == "method" and result.selection is not None:
        return result.selection
    return color


class Viewer:
    """The server of one scene: ``Viewer(scene, method, host, port).serve_forever()``;
    ``url`` is the page's address with the token. ``port`` 0 picks a free port."""

    def __init__(self, scene: Scene, method: str = "auto", host: str = "127.0.0.1", port: int = 0,
                 save_dir: str | Path = ".", token: str | None = None):
        self.scene = scene
        self.method = methods.resolve(method, scene)
        self.methods = [m for m in methods.BUILT if m != "depthwarp" and _usable(m, scene)]
        if self.method not in self.methods:
            self.methods.insert(0, self.method)
        self.info = {**scene_info(scene, self.methods), "method": self.method}
        self.save_dir = Path(save_dir)
        self.token = token or secrets.token_urlsafe(16)
        self._latest: dict[str, int] = {}
        self._latest_lock = threading.Lock()
        self.httpd = ThreadingHTTPServer((host, int(port)), _handler(self))
        self.httpd.daemon_threads = True

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host}:{port}/?t={self.token}"

    def serve_forever(self) -> None:
        self.httpd.serve_forever(poll_interval=0.2)

    def shutdown(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()

    # --- requests -----------------------------------------------------------------------------
    def note_request(self, client: str, seq: int) -> None:
        with self._latest_lock:
            self._latest[client] = max(seq, self._latest.get(client, -1))

    def overtaken(self, client: str, seq: int) -> bool:
        with self._latest_lock:
            return self._latest.get(client, -1) > seq

    def frame(self, query: dict) -> tuple[bytes, str, dict]:
        """(bytes, content type, headers) of GET /frame, or raises BadValueError."""
        pose = _one(query, "pose")
        try:
            cam = Camera.from_dict(json.loads(pose), "pose")
        except json.JSONDecodeError as e:
            raise BadValueError(f"pose: not JSON ({e.msg})") from None
        w, h = _int(query, "w", cam.width), _int(query, "h", cam.height)
        if not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE):
            raise BadValueError(f"w, h: expected 1..{MAX_SIDE} pixels, got {w} x {h}")
        method = query.get("method", [self.method])[0]
        if method not in self.methods:
            raise BadValueError(f"method: expected one of {', '.join(self.methods)}, got {method!r}")
        overlay = query.get("overlay", ["none"])[0]
        if overlay not in OVERLAYS:
            raise BadValueError(f"overlay: expected one of {', '.join(OVERLAYS)}, got {overlay!r}")
        fmt = query.get("fmt", ["jpeg"])[0]
        if fmt not in FORMATS:
            raise BadValueError(f"fmt: expected one of {', '.join(FORMATS)}, got {fmt!r}")
        result = render(self.scene, cam.scaled(w, h) if (w, h) != (cam.width, cam.height) else cam, method)
        t0 = time.perf_counter()
        data = encode(overlay_image(result, overlay), fmt)
        return data, FORMATS[fmt][0], {"X-Render-Ms": f"{result.times_ms['total']:.1f}",
                                       "X-Encode-Ms": f"{(time.perf_counter() - t0) * 1e3:.1f}",
                                       "X-Method": result.method}

    def save_path(self, body: bytes) -> dict:
        """POST /path: the poses written as a file ``ibr-render --poses`` reads."""
        try:
            doc = json.loads(body)
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise BadValueError("path: the body is not JSON") from None
        if not isinstance(doc, dict) or not isinstance(doc.get("poses"), list) or not doc["poses"]:
            raise BadValueError('path: expected {"name": ..., "poses": [camera, ...]} with at least one pose')
        poses = []
        for i, d in enumerate(doc["poses"]):
            cam = Camera.from_dict(d, f"path poses[{i}]")
            poses.append({**cam.to_dict(), "name": str(d.get("name") or f"frame_{i:04d}")})
        name = file_stem(str(doc.get("name") or "path"))
        self.save_dir.mkdir(parents=True, exist_ok=True)
        target = self.save_dir / f"{name}.json"
        with atomic_path(target) as tmp:
            tmp.write_text(json.dumps(poses, indent=1))
        return {"file": str(target), "poses": len(poses)}


def _usable(method: str, scene: Scene) -> bool:
    """Whether ``method`` can render ``scene`` as it is (what the page offers)."""
    if method == "reference":
        return "ground_truth" in scene.meshes
    if method in ("dibr", "warp"):
        return bool(scene.views) and all(v.has_depth for v in with_stage_depth(scene).views)
    return (scene.stages or {}).get("mesh") is not None or "reconstructed" in scene.meshes


def _one(query: dict, key: str) -> str:
    v = query.get(key)
    if not v:
        raise BadValueError(f"{key}: missing")
    return v[0]


def _int(query: dict, key: str, default: int) -> int:
    v = query.get(key)
    if not v:
        return int(default)
    try:
        return int(v[0])
    except ValueError:
        raise BadValueError(f"{key}: expected an integer, got {v[0]!r}") from None


def _handler(viewer: Viewer):
    class Handler(BaseHTTPRequestHandler):
        server_version = "ibr-view"

        def log_message(self, fmt, *args):  # quiet: the CLI prints what matters
            pass

        def _send(self, status: int, body: bytes, ctype: str = "text/plain; charset=utf-8",
                  headers: dict | None = None) -> None:
            self.send_response(status)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            for k, v in (headers or {}).items():
                self.send_header(k, v)
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(body)

        def _route(self):
            u = urlparse(self.path)
            q = parse_qs(u.query)
            if not secrets.compare_digest(q.get("t", [""])[0], viewer.token):
                self._send(HTTPStatus.FORBIDDEN, b"forbidden: this page needs the token ibr-view printed\n")
                return None, None
            return u.path, q

        def do_GET(self):  # noqa: N802 - the http.server interface
            path, q = self._route()
            if path is None:
                return
            try:
                if path == "/":
                    self._send(HTTPStatus.OK, PAGE.encode(), "text/html; charset=utf-8")
                elif path == "/scene.json":
                    self._send(HTTPStatus.OK, json.dumps(viewer.info).encode(), "application/json")
                elif path == "/frame":
                    client, seq = q.get("client", [""])[0], _int(q, "seq", 0)
                    viewer.note_request(client, seq)
                    with _RENDER:
                        if client and viewer.overtaken(client, seq):
                            self._send(HTTPStatus.NO_CONTENT, b"", headers={"X-Seq": str(seq)})
                            return
                        data, ctype, headers = viewer.frame(q)
                    self._send(HTTPStatus.OK, data, ctype, {**headers, "X-Seq": str(seq)})
                else:
                    self._send(HTTPStatus.NOT_FOUND, b"not found\n")
            except (InputError, NotBuiltError) as e:
                self._send(HTTPStatus.BAD_REQUEST, f"{e}\n".encode())
            except Exception as e:  # noqa: BLE001 - one line to the page, the server goes on
                self._send(HTTPStatus.INTERNAL_SERVER_ERROR, f"internal error: {type(e).__name__}: {e}\n".encode())

        def do_POST(self):  # noqa: N802
            path, _ = self._route()
            if path is None:
                return
            if path != "/path":
                self._send(HTTPStatus.NOT_FOUND, b"not found\n")
                return
            n = int(self.headers.get("Content-Length") or 0)
            if not 0 < n <= MAX_BODY:
                self._send(HTTPStatus.BAD_REQUEST, f"path: expected a JSON body of at most {MAX_BODY} bytes\n".encode())
                return
            try:
                out = viewer.save_path(self.rfile.read(n))
                self._send(HTTPStatus.OK, json.dumps(out).encode(), "application/json")
            except InputError as e:
                self._send(HTTPStatus.BAD_REQUEST, f"{e}\n".encode())

    return Handler


# One frame renders at a time (the engine uses every core for it); a client's queued request
# that its own newer request overtook is dropped when its turn comes.
_RENDER = threading.Lock()
