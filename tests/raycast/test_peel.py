"""Deep depth buffers by depth peeling (ReferenceRenderer.peel; cpp/kernels/raycast/raycast.h
"Deep depth buffers"; Lee, Kim, Eisemann 2018 sec. 3.4, Eq. 1)."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import _core
from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.mesh import Mesh
from ibrtools.raycast.reference import DeepDepth, ReferenceRenderer
from ibrtools.synth import boxes, ground_grid, merge

pytestmark = [pytest.mark.asan, pytest.mark.kernel]


def _quad(z: float, half: float, oid: int):
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    return v, f, np.full(2, oid, np.int32)


def _planes(zs=(5.0, 8.0), half=(2.0, 20.0)) -> Mesh:
    vs, fs, ids = [], [], []
    for k, (z, h) in enumerate(zip(zs, half)):
        v, f, i = _quad(z, h, k)
        fs.append(f + 4 * k)
        vs.append(v)
        ids.append(i)
    return Mesh(np.concatenate(vs), np.concatenate(fs), object_ids=np.concatenate(ids))


def _cam(w=48, h=36, eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, 10.0)) -> Camera:
    return Camera.from_fov(w, h, 60.0, look_at(eye, target, (0.0, -1.0, 0.0)))


def _box_scene(seed: int = 0) -> Mesh:
    """A ground plane with 40 random boxes (object ids 1..40): depth complexity 2-6."""
    rng = np.random.default_rng(seed)
    n = 40
    c = np.stack([rng.uniform(-3, 3, n), np.zeros(n), rng.uniform(-3, 3, n)], -1)
    s = rng.uniform(0.3, 1.0, (n, 3))
    c[:, 1] = s[:, 1] / 2
    parts = [ground_grid(12.0, cells=4, object_id=0), boxes(c, s, rng.uniform(0, 3, n), 0, 1 + np.arange(n))]
    return merge(parts, [], None)


def _ring_cam(angle_deg: float, w=64, h=48, radius=8.0) -> Camera:
    a = np.radians(angle_deg)
    return Camera.from_fov(w, h, 60.0, look_at((radius * np.sin(a), 3.0, -radius * np.cos(a)), (0, 0.3, 0)))


def test_two_parallel_planes_give_both_planes():
    r = ReferenceRenderer(_planes())
    cam = _cam()
    d = r.peel(cam, 3)
    assert isinstance(d, DeepDepth) and d.depth.shape == (3, 36, 48) and d.object_id.shape == (3, 36, 48)
    # The near quad (half-width 2 at z 5) covers the centre pixels; the far one (20 at z 8) all.
    # z along a pinhole ray is exact to float rounding of t (rel. 1e-6).
    centre = (slice(14, 22), slice(20, 28))
    np.testing.assert_allclose(d.depth[0][centre], 5.0, rtol=1e-6)
    np.testing.assert_allclose(d.depth[1][centre], 8.0, rtol=1e-6)
    assert (d.object_id[0][centre] == 0).all() and (d.object_id[1][centre] == 1).all()
    assert (d.depth[2] == 0).all() and (d.object_id[2] == -1).all()
    # Off the near quad, layer 0 is the far plane and layer 1 is empty.
    assert d.depth[0, 0, 0] == pytest.approx(8.0, rel=1e-6) and d.depth[1, 0, 0] == 0
    np.testing.assert_allclose(d.fill, [1.0, (d.object_id[0] == 0).mean(), 0.0])


def test_layer_one_equals_the_depth_render():
    mesh = _box_scene()
    r = ReferenceRenderer(mesh)
    cam = _ring_cam(30)
    ref = r.render(cam, outputs=("depth", "object_id"), lights=[])
    d = r.peel(cam, 1)
    # The same rays and the same 16-ray packets: bit-identical.
    np.testing.assert_array_equal(d.depth[0], ref["depth"])
    np.testing.assert_array_equal(d.object_id[0], ref["object_id"])


def test_layers_strictly_increase_and_empty_layers_come_last():
    r = ReferenceRenderer(_box_scene())
    d = r.peel(_ring_cam(70), 6)
    full = d.depth > 0
    assert (full[1:] <= full[:-1]).all()        # a non-empty layer only follows a non-empty one
    both = full[1:] & full[:-1]
    assert (d.depth[1:][both] > d.depth[:-1][both]).all()
    assert ((d.object_id >= 0) == full).all()
    assert full[2].any()                         # the scene has depth complexity > 2


def test_ground_only_last_layer():
    mesh = _box_scene()
    r = ReferenceRenderer(mesh)
    cam = _ring_cam(10)
    d = r.peel(cam, 3, ground_object=0)
    assert d.ground_layer and d.depth.shape[0] == 3 and set(d.times_ms) == {"peel", "ground"}
    ground = ReferenceRenderer(Mesh(mesh.vertices, mesh.faces[mesh.object_ids == 0]))
    ref = ground.render(cam, outputs=("depth",), lights=[])["depth"]
    np.testing.assert_array_equal(d.depth[2], ref)
    assert set(np.unique(d.object_id[2])) <= {-1, 0}
    # The first two layers are the plain peel.
    np.testing.assert_array_equal(d.depth[:2], r.peel(cam, 2).depth)


def _found(deep: np.ndarray, src: Camera, novel: Camera, novel_depth: np.ndarray) -> np.ndarray:
    """For every pixel of a novel camera that sees a surface, whether some layer of the source's
    deep buffer holds that surface at the source pixel its point projects to (relative depth
    difference <= 2 %: neighbouring surface samples of one pixel quad on surfaces up to ~80
    degrees oblique; a wrong surface is >= 10 cm = 1 % away at these 8-11 m). Points outside
    the source image count as found (peeling cannot see them at all)."""
    pts = novel.unproject(novel_depth)[novel_depth > 0]
    xy, z = src.project(pts)
    x, y = xy[:, 0], xy[:, 1]
    with np.errstate(invalid="ignore"):
        inside = (x >= 0) & (x < src.width) & (y >= 0) & (y < src.height) & (z > 0)
    x, y = np.nan_to_num(x), np.nan_to_num(y)
    xi = np.clip(x.astype(int), 0, src.width - 1)
    yi = np.clip(y.astype(int), 0, src.height - 1)
    cand = deep[:, yi, xi]
    ok = (np.abs(cand - z[None]) <= 0.02 * z[None]).any(axis=0)
    return ok | ~inside


def test_umbra_culling_keeps_every_surface_the_novel_cameras_see_and_peels_faster():
    mesh = _box_scene(3)
    r = ReferenceRenderer(mesh)
    src = _ring_cam(0, w=160, h=120)
    novel = [_ring_cam(a, w=160, h=120) for a in (4.0, -4.0, 8.0)]
    L = 8
    plain = r.peel(src, L)
    umbra = r.peel(src, L, umbra=novel)
    assert umbra.umbra and not plain.umbra
    # Peels faster: later layers hold fewer fragments (fragments no novel camera sees are skipped).
    assert umbra.fill[1:].sum() < plain.fill[1:].sum()
    assert (umbra.fill[1:] <= plain.fill[1:] + 1e-12).all()
    for cam in novel:
        nd = r.render(cam, outputs=("depth",), lights=[])["depth"]
        f_plain = _found(plain.depth, src, cam, nd)
        f_umbra = _found(umbra.depth, src, cam, nd)
        # Umbra culling never loses a surface that plain peeling found. Tolerance: the umbra
        # (Eq. 1) treats a pixel's surface as an opaque square filling the pixel; at a
        # silhouette it does not, so a novel pixel seen past a silhouette pixel may lose its
        # sample. Measured: 2 of ~12000 novel pixels at 160x120 (all at silhouettes), 0 at
        # 256x192, ~1 % at 64x48 (pixel quads are large): bound 0.1 %.
        lost = (f_plain & ~f_umbra).mean()
        assert lost <= 0.001, lost


def test_umbra_with_the_source_itself_keeps_only_the_first_layer():
    r = ReferenceRenderer(_box_scene())
    src = _ring_cam(20)
    d = r.peel(src, 3, umbra=[src])          # the source sees nothing behind its first layer
    assert d.fill[0] > 0 and d.fill[1] == 0 and d.fill[2] == 0


def test_thread_count_independence():
    r = ReferenceRenderer(_box_scene())
    cam = _ring_cam(45, w=131, h=77)      # sizes just past tile and packet boundaries
    novel = [_ring_cam(50, w=131, h=77)]
    old = _core.get_num_threads()
    try:
        _core.set_num_threads(1)
        a = r.peel(cam, 4, umbra=novel, umbra_radius=0.2)
        _core.set_num_threads(2)
        b = r.peel(cam, 4, umbra=novel, umbra_radius=0.2)
    finally:
        _core.set_num_threads(old)
    np.testing.assert_array_equal(a.depth, b.depth)
    np.testing.assert_array_equal(a.object_id, b.object_id)


def test_peel_bad_input():
    mesh = _box_scene()
    r = ReferenceRenderer(mesh)
    cam = _ring_cam(0, w=16, h=12)
    with pytest.raises(BadValueError, match="layers"):
        r.peel(cam, 0)
    with pytest.raises(DtypeError, match="camera"):
        r.peel("cam", 2)
    with pytest.raises(ShapeError, match="umbra"):
        r.peel(cam, 2, umbra=np.zeros((2, 2)))
    with pytest.raises(BadValueError, match="umbra"):
        r.peel(cam, 2, umbra=np.full((1, 3), np.nan))
    with pytest.raises(BadValueError, match="umbra_radius"):
        r.peel(cam, 2, umbra=[cam], umbra_radius=-1.0)
    with pytest.raises(BadValueError, match="ground_object"):
        r.peel(cam, 2, ground_object=999)
    with pytest.raises(BadValueError, match="layers"):
        r.peel(cam, 1, ground_object=0)
    with pytest.raises(BadValueError, match="pinhole"):
        r.peel(Camera.equirect(16, 8), 2, umbra=[cam])
    # Plain peeling works for equirect cameras (depth = ray distance).
    assert r.peel(Camera.equirect(16, 8, cam_from_world=look_at((0, 2, -8), (0, 0, 0))), 2).depth.shape == (2, 8, 16)


def test_gil_released_during_peel():
    """Structural (tests/gil.py): while a peel runs in another thread, this thread runs Python."""
    import math
    import sys
    import time
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from gil import runs_python_during

    r = ReferenceRenderer(_box_scene())
    old = _core.get_num_threads()
    try:
        _core.set_num_threads(1)  # leave a core for this thread
        t = time.perf_counter()
        r.peel(_ring_cam(30, w=160, h=120), 8)
        # Size the image so that one call lasts ~80 ms (>> the 5 ms switch interval).
        scale = min(8.0, max(1.0, math.sqrt(0.08 / max(time.perf_counter() - t, 1e-4))))
        cam = _ring_cam(30, w=int(160 * scale), h=int(120 * scale))
        assert runs_python_during(lambda: r.peel(cam, 8)), "no Python ran during the peels (or each lasted < 20 ms)"
    finally:
        _core.set_num_threads(old)
