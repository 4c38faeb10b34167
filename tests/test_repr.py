"""repr of the scene model: a short summary that never prints an array or loads an image."""
from __future__ import annotations

import numpy as np

from ibrtools.camera import Camera, look_at
from ibrtools.mesh import Mesh
from ibrtools.scene import Scene, View


def _view(name: str, w: int = 640, h: int = 480, depth: bool = True) -> View:
    cam = Camera.from_fov(w, h, 60.0, look_at((0, 0, -3), (0, 0, 0), (0, -1, 0)))
    return View.create(name, cam, color=np.full((h, w, 3), 0.25, np.float32),
                       depth=np.full((h, w), 3.0, np.float32) if depth else None)


def test_view_repr_names_size_and_images():
    assert repr(_view("v000")) == "View('v000', pinhole 640x480, color+depth)"
    loaded: list[int] = []
    lazy = View.create("lazy", _view("x").camera, color=lambda: loaded.append(1) or np.zeros((480, 640, 3), np.float32))
    assert repr(lazy) == "View('lazy', pinhole 640x480, color)" and not loaded  # nothing loaded
    assert "no images" in repr(View.create("bare", _view("x").camera))


def test_scene_repr_is_a_short_summary():
    mesh = Mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), np.array([[0, 1, 2]], np.int32))
    views = [_view(f"v{i:03d}", depth=i % 2 == 0) for i in range(200)] + [_view("small", 320, 240)]
    s = Scene(views=views, targets=[_view("t0")], meshes={"ground_truth": mesh},
              paths={"orbit": [v.camera for v in views[:48]]}, stages={"import": {}, "depth": {}}, units="m")
    r = repr(s)
    for part in ("201 views", "200 at 640x480", "1 at 320x240", "101 with depth", "1 targets (1 with ground truth)",
                 "ground_truth (1 faces)", "orbit (48)", "stages: import, depth", "units 'm'"):
        assert part in r, (part, r)
    assert len(r) < 400 and len(r.splitlines()) <= 5 and "array" not in r and "[[" not in r
    assert repr(Scene()) == "Scene(0 views, 0 targets, units 'unknown')"
