"""The rasterised G-buffer of TM / ULR / hybrid (_core.raster_gbuffer, cpp/kernels/hybrid/gbuffer_raster.h)
against the Embree ray caster, and the 8-bit sRGB atlas read (cpp/kernels/hybrid/atlas8.h) against the
float32 one."""
import numpy as np
import pytest

from ibrtools import _core
from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, ShapeError
from ibrtools.hybrid import atlas as A
from ibrtools.hybrid.globalmesh import densify
from ibrtools.raycast.reference import ReferenceRenderer
from ibrtools.synth import make_scene


@pytest.fixture(scope="module")
def scene_mesh():
    scene = make_scene("objects", size=(96, 72), views=2, seed=1, reconstructed=True, holdout_targets=1)
    return scene, scene.meshes["reconstructed"]


def _compare(mesh, cam):
    ref = ReferenceRenderer(mesh).render(cam, outputs=("depth", "normal", "prim_id", "bary"), lights=[], ambient=0.0)
    r = _core.raster_gbuffer(cam.to_core(), np.ascontiguousarray(mesh.vertices, np.float32), mesh.faces)
    return ref, r


def test_raster_matches_the_ray_caster(scene_mesh):
    scene, mesh = scene_mesh
    cams = [v.camera for v in scene.views] + [t.camera for t in scene.targets]
    # Also a camera close to the ground looking along it: faces cross the camera plane (clipping).
    cams.append(Camera.pinhole(80, 60, 50.0, 50.0, 40.0, 30.0, look_at((0.0, -0.3, 0.0), (5.0, 0.0, 5.0), up=(0.0, -1.0, 0.0))))
    for cam in cams:
        ref, r = _compare(mesh, cam)
        hit = ref["prim_id"] >= 0
        # Faces may differ only where a pixel centre lies on an edge (within rounding): a few
        # pixels in a thousand at most; coverage (hit or not) the same up to such silhouette ties.
        assert (ref["prim_id"] != r["prim_id"]).mean() < 0.003
        assert ((r["prim_id"] >= 0) != hit).mean() < 0.002
        same = hit & (ref["prim_id"] == r["prim_id"])
        assert same.sum() > 0.3 * hit.size
        # Same face: depth and barycentrics agree to Embree's float rounding (its watertight
        # intersection works in float32: |du| up to ~1e-3 on faces spanning the view).
        assert np.max(np.abs(ref["depth"][same] - r["depth"][same]) / ref["depth"][same]) < 1e-4
        assert np.max(np.abs(ref["bary"][same] - r["bary"][same])) < 2e-3
        assert np.max(np.abs(ref["normal"][same] - r["normal"][same])) < 1e-3
        # No hit: depth 0, prim -1, bary and normal 0.
        miss = r["prim_id"] < 0
        assert np.all(r["depth"][miss] == 0) and np.all(r["bary"][miss] == 0) and np.all(r["normal"][miss] == 0)
        assert np.all(r["depth"][~miss] > 0)


def test_raster_nearest_face_wins_and_faces_behind_the_camera_are_cut():
    cam = Camera.pinhole(32, 32, 32.0, 32.0, 16.0, 16.0, np.eye(4))
    # Two parallel quads at z = 2 and z = 1 (the nearer, smaller one in front) and one behind
    # the camera (z = -1), which must not appear.
    def quad(z, s):
        return np.array([[-s, -s, z], [s, -s, z], [s, s, z], [-s, s, z]], np.float32)
    v = np.concatenate([quad(2.0, 2.0), quad(1.0, 0.25), quad(-1.0, 3.0)])
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [8, 9, 10], [8, 10, 11]], np.int32)
    r = _core.raster_gbuffer(cam.to_core(), v, f, normal=False)
    assert "normal" not in r
    assert np.all(r["prim_id"] >= 0) and np.all(r["prim_id"] < 4)
    centre = r["prim_id"][12:20, 12:20]
    assert np.all((centre == 2) | (centre == 3))
    assert np.allclose(r["depth"][14:18, 14:18], 1.0, rtol=1e-6)
    assert np.allclose(r["depth"][0, 0], 2.0, rtol=1e-6)


def test_raster_independent_of_thread_count(scene_mesh):
    scene, mesh = scene_mesh
    cam = scene.targets[0].camera
    v = np.ascontiguousarray(mesh.vertices, np.float32)
    n = _core.get_num_threads()
    try:
        _core.set_num_threads(1)
        one = _core.raster_gbuffer(cam.to_core(), v, mesh.faces)
        _core.set_num_threads(2)
        two = _core.raster_gbuffer(cam.to_core(), v, mesh.faces)
    finally:
        _core.set_num_threads(n)
    for k in one:
        assert np.array_equal(one[k], two[k]), k


@pytest.mark.skipif(not _core.cpu_has_avx2(), reason="this CPU has no AVX2: only the baseline path runs")
def test_raster_avx2_and_baseline_give_the_same_bits(scene_mesh):
    # The band and attribute loops run compiled for AVX2 (no FMA) or for the SSE2 baseline by the
    # engine's switch (set_warp_isa): the same IEEE operations, the same G-buffer bit for bit.
    scene, mesh = scene_mesh
    v = np.ascontiguousarray(mesh.vertices, np.float32)
    try:
        for cam in [x.camera for x in scene.views] + [t.camera.scaled(131, 97) for t in scene.targets]:
            out = {}
            for isa in ("baseline", "avx2"):
                _core.set_warp_isa(isa)
                out[isa] = _core.raster_gbuffer(cam.to_core(), v, mesh.faces)
            assert (out["avx2"]["prim_id"] >= 0).any()
            for k in out["avx2"]:
                np.testing.assert_array_equal(out["baseline"][k], out["avx2"][k], err_msg=k)
    finally:
        _core.set_warp_isa("auto")


def test_raster_bad_input():
    cam = Camera.pinhole(8, 8, 8.0, 8.0, 4.0, 4.0, np.eye(4))
    v = np.zeros((3, 3), np.float32)
    f = np.array([[0, 1, 2]], np.int32)
    eq = Camera.equirect(16, 8, cam_from_world=np.eye(4))
    with pytest.raises(BadValueError, match="pinhole"):
        _core.raster_gbuffer(eq.to_core(), v, f)
    with pytest.raises(BadValueError, match="out of range"):
        _core.raster_gbuffer(cam.to_core(), v, np.array([[0, 1, 3]], np.int32))
    with pytest.raises(BadValueError, match="finite"):
        _core.raster_gbuffer(cam.to_core(), np.full((3, 3), np.nan, np.float32), f)
    with pytest.raises(ShapeError):
        _core.raster_gbuffer(cam.to_core(), np.zeros((3, 2), np.float32), f)
    with pytest.raises(ShapeError):
        _core.raster_gbuffer(cam.to_core(), v, np.zeros((1, 4), np.int32))
    # No faces: everything a miss.
    r = _core.raster_gbuffer(cam.to_core(), v, np.zeros((0, 3), np.int32))
    assert np.all(r["prim_id"] == -1) and np.all(r["depth"] == 0)


def test_srgb8_atlas_reads_as_the_float_atlas_within_quantisation():
    rng = np.random.default_rng(0)
    mesh = densify(Mesh_wall(), 0.5)
    lay = A.layout(mesh, texel=0.05)
    atlas = rng.random(lay.face_of_texel.shape + (3,), dtype=np.float32)
    a8 = A.to_srgb8(atlas)
    assert a8.dtype == np.uint8 and a8.shape == atlas.shape[:2] + (4,) and np.all(a8[..., 3] == 255)
    cam = Camera.pinhole(64, 64, 64.0, 64.0, 32.0, 32.0,
                         look_at((0.0, 0.0, 0.0), (0.0, 0.0, 2.0), up=(0.0, -1.0, 0.0)))
    gb = ReferenceRenderer(mesh).render(cam, outputs=("prim_id", "bary"), lights=[], ambient=0.0)
    f = _core.sample_atlas(gb["prim_id"], gb["bary"], lay.uv, atlas)
    g = _core.sample_atlas(gb["prim_id"], gb["bary"], lay.uv, a8)
    # 8-bit sRGB: half a code step is at most 0.5/255 in sRGB; in linear light that is at most
    # ~0.0045 absolute (the steepest part, near 1) and 0.5/255/12.92 in the linear toe.
    assert np.max(np.abs(f - g)) < 0.005
    assert np.all(g[gb["prim_id"] < 0] == 0)
    with pytest.raises(ShapeError):
        _core.sample_atlas(gb["prim_id"], gb["bary"], lay.uv, a8[..., :3].copy())
    with pytest.raises(ShapeError):
        A.to_srgb8(atlas[..., :2])


def Mesh_wall():
    from ibrtools.mesh import Mesh

    v = np.array([[-1, -1, 2], [1, -1, 2], [1, 1, 2], [-1, 1, 2]], np.float32)
    return Mesh(v, np.array([[0, 2, 1], [0, 3, 2]], np.int32))


def test_gbuffer_rasterises_small_meshes_and_ray_casts_dense_ones(scene_mesh, monkeypatch):
    # _GlobalMesh.gbuffer takes the rasteriser for a mesh of few faces per pixel, Embree otherwise
    # (RASTER_MAX_FACES, RASTER_MAX_FACES_PER_PIXEL): each path's output as such, and the same surface.
    from ibrtools.hybrid import method as H

    scene, mesh = scene_mesh
    gm = H._GlobalMesh.__new__(H._GlobalMesh)
    gm.mesh, gm.faces, gm._vertices32 = mesh, np.ascontiguousarray(mesh.faces, np.int32), None
    gm.renderer = ReferenceRenderer(mesh)
    f = len(gm.faces)
    big = scene.views[0].camera
    small = big.scaled(24, 18)  # more faces than RASTER_MAX_FACES_PER_PIXEL per pixel
    names = ("depth", "normal", "prim_id", "bary")
    for cam, raster in ((small, False), (big.scaled(1600, 1200), True)):
        assert (f <= H.RASTER_MAX_FACES_PER_PIXEL * cam.width * cam.height) == raster
        got = gm.gbuffer(cam)
        want = (_core.raster_gbuffer(cam.to_core(), np.ascontiguousarray(mesh.vertices, np.float32), mesh.faces)
                if raster else gm.renderer.render(cam, outputs=names, lights=[], ambient=0.0))
        assert all(np.array_equal(got[k], want[k]) for k in names)
        assert np.array_equal(got["hit"], want["prim_id"] >= 0)
    monkeypatch.setattr(H, "RASTER_MAX_FACES", f - 1)  # a mesh over the face limit: ray cast at any size
    cam = big.scaled(1600, 1200)
    got = gm.gbuffer(cam)
    assert np.array_equal(got["prim_id"], gm.renderer.render(cam, outputs=("prim_id",), lights=[], ambient=0.0)["prim_id"])


def test_srgb8_atlas_decodes_each_code_as_an_8bit_image_file():
    """An 8-bit atlas texel decodes to _core.srgb_to_linear(code / 255) bit for bit: the atlas read and
    the image reader (ibrtools.imageio) share the engine's one sRGB decoder (cpp/ibr/colour.h)."""
    codes = np.arange(256, dtype=np.uint8).reshape(16, 16)
    a8 = np.empty((16, 16, 4), np.uint8)
    a8[..., :3] = codes[..., None]
    a8[..., 3] = 255
    # One face whose uv maps barycentrics (x / 16, y / 16) exactly onto texel (x, y)'s centre.
    uv = np.array([[[0.5, 0.5], [16.5, 0.5], [0.5, 16.5]]], np.float32)
    yy, xx = np.mgrid[0:16, 0:16]
    bary = np.ascontiguousarray(np.stack([xx / 16.0, yy / 16.0], axis=-1), np.float32)
    prim = np.zeros((16, 16), np.int32)
    got = _core.sample_atlas(prim, bary, uv, a8)
    want = _core.srgb_to_linear(codes.astype(np.float32) / 255.0)
    np.testing.assert_array_equal(got, np.repeat(want[..., None], 3, axis=2))


def test_raster_faces_far_outside_the_image_are_clipped_to_the_guard_band():
    """The rasteriser core (cpp/ibr/raster.h) snaps vertices to 1/256 px within a guard band of
    2^20 px; a face reaching further (here a vertex projecting ~1e8 px away, next to the camera
    plane) is clipped to the band in screen space, 1/z interpolated linearly (exact on a plane). Its
    coverage is the exact triangle's (numpy, float64 edge functions), apart from centres within
    1/256 px of an edge, and its depth the plane's."""
    cam = Camera.pinhole(64, 48, 40.0, 40.0, 32.0, 24.0, np.eye(4))
    v = np.array([[-1.0, -1.0, 2.0], [3.0e3, 0.5, 1.0e-3], [0.5, 2.0, 4.0]], np.float32)
    f = np.array([[0, 1, 2]], np.int32)
    r = _core.raster_gbuffer(cam.to_core(), v, f, normal=False)
    p = v.astype(np.float64)
    sx, sy = 40.0 * p[:, 0] / p[:, 2] + 32.0, 40.0 * p[:, 1] / p[:, 2] + 24.0
    assert np.abs(sx).max() > 1e7  # beyond the guard band
    x, y = np.meshgrid(np.arange(64) + 0.5, np.arange(48) + 0.5)
    # Inside test in camera space (exact for a projected triangle): the ray through the centre
    # meets the face inside it (barycentrics of the ray's hit >= 0).
    d = np.stack([(x - 32.0) / 40.0, (y - 24.0) / 40.0, np.ones_like(x)], -1)
    e1, e2 = p[1] - p[0], p[2] - p[0]
    pv = np.cross(d, e2)
    det = pv @ e1
    s = -p[0]
    u = np.einsum("...k,k->...", pv, s) / det
    q = np.cross(s, e1)
    w = (d @ q) / det
    inside = (u >= 0) & (w >= 0) & (u + w <= 1)
    margin = np.minimum(np.minimum(np.abs(u), np.abs(w)), np.abs(1 - u - w))
    sure = margin > 1e-3
    assert inside.sum() > 100
    np.testing.assert_array_equal((r["prim_id"] == 0)[sure], inside[sure])
    t = (e2 @ q) / det  # z-depth of the hit (the ray has z = 1)
    hit = (r["prim_id"] == 0) & sure
    np.testing.assert_allclose(r["depth"][hit], t[hit], rtol=1e-5)
