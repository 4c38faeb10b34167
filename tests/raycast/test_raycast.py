"""Reference ray casting (cpp/kernels/raycast/raycast.h, ibrtools.raycast.reference).

Tolerances:
* REL_DEPTH = 1e-5: rays and vertices are float32 (7 significant digits) and Embree
  intersects in float32; for the non-grazing rays used here the error of t is a few ulps
  (~1e-6 relative). 1e-5 leaves a margin without hiding a wrong convention (a wrong pixel
  centre or z-vs-distance mix-up is >= 1e-3 here).
* Shading is computed in float32 with a handful of operations per light: 1e-5 relative too.
* Against embreex (Embree 4, a different build and traversal): primitive ids and hit masks
  may differ where a ray passes within float rounding of a shared edge; we allow 0.5 % of the
  pixels, far above the handful expected and far below what any systematic difference (pixel
  centre, ray direction) would give (tens of percent).
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
from gil import runs_python_during

from ibrtools import BadValueError, Camera, DtypeError, Mesh, ShapeError, _core, look_at
from ibrtools.raycast.reference import Light, ReferenceRenderer, default_lights

pytestmark = [pytest.mark.asan, pytest.mark.kernel]

REL_DEPTH = 1e-5
REL_SHADE = 1e-5


# --- meshes -----------------------------------------------------------------------------------
def quad(center, half, axis_u, axis_v):
    c, u, v = (np.asarray(a, np.float64) for a in (center, axis_u, axis_v))
    verts = np.array([c - half * u - half * v, c + half * u - half * v, c + half * u + half * v,
                      c - half * u + half * v], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    return verts, faces


def uv_sphere(n_lat=24, n_lon=48, radius=1.0, center=(0.0, 0.0, 0.0)):
    th = np.linspace(0, np.pi, n_lat + 1)
    ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    T, P = np.meshgrid(th[1:-1], ph, indexing="ij")
    v = np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], -1).reshape(-1, 3)
    v = np.vstack([v, [[0, 1, 0], [0, -1, 0]]]) * radius + np.asarray(center)
    j = np.arange(n_lon)[None, :]
    jn = (j + 1) % n_lon
    i = np.arange(n_lat - 2)[:, None] * n_lon
    faces = [np.stack([(i + j).ravel(), (i + n_lon + jn).ravel(), (i + jn).ravel()], 1),
             np.stack([(i + j).ravel(), (i + n_lon + j).ravel(), (i + n_lon + jn).ravel()], 1)]
    top, bot, last = len(v) - 2, len(v) - 1, (n_lat - 2) * n_lon
    faces.append(np.stack([np.full(n_lon, top), j.ravel(), jn.ravel()], 1))
    faces.append(np.stack([np.full(n_lon, bot), (last + jn).ravel(), (last + j).ravel()], 1))
    return v.astype(np.float32), np.vstack(faces).astype(np.int32)


def world_rays(cam: Camera):
    """Unit world directions (H, W, 3) and the camera's per-pixel ray vectors in camera axes."""
    x, y = cam.pixel_grid()
    d_cam = cam.rays_in_cam(x, y)
    d_world = d_cam @ cam.world_from_cam[:3, :3].T
    return d_world, d_cam


def analytic_depth_from_hits(cam, mesh_v, mesh_f, prim):
    """float64 intersection of each pixel's ray with the plane of the face it hit; returned in
    the scene's depth convention (z for pinhole, distance for equirect)."""
    d_world, d_cam = world_rays(cam)
    o = cam.centre
    tri = mesh_v.astype(np.float64)[mesh_f[np.maximum(prim, 0)]]
    n = np.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :])
    t = np.einsum("...i,...i", n, tri[..., 0, :] - o) / np.einsum("...i,...i", n, d_world)
    return t  # d_world has z_cam = 1 for pinhole (t = z), unit length for equirect (t = distance)


@pytest.fixture
def restore_threads():
    yield
    _core.set_num_threads(0)


# --- geometry --------------------------------------------------------------------------------
@pytest.mark.parametrize("size", [(64, 48), (37, 23)])  # 37x23: not a multiple of any packet
def test_plane_depth_pinhole_analytic(size):
    n = np.array([0.2, -0.3, -1.0]) / np.linalg.norm([0.2, -0.3, -1.0])
    u = np.cross(n, [0, 1, 0]); u /= np.linalg.norm(u)
    v, f = quad(center=[0.3, -0.2, 6.0], half=50.0, axis_u=u, axis_v=np.cross(n, u))
    r = ReferenceRenderer(Mesh(v, f))
    cam = Camera.from_fov(*size, 70, look_at([0.5, 0.2, -1.0], [0.0, 0.0, 5.0]))
    out = r.render(cam, outputs=("depth", "distance", "hit"))
    # Plane n.p = n.c; ray o + t d: t = n.(c - o) / n.d, with d = R^T (x', y', 1) (z = 1).
    d_world, d_cam = world_rays(cam)
    t = (n @ (np.array([0.3, -0.2, 6.0]) - cam.centre)) / (d_world @ n)
    assert out["hit"].all()
    np.testing.assert_allclose(out["depth"], t, rtol=REL_DEPTH)
    np.testing.assert_allclose(out["distance"], t * np.linalg.norm(d_world, axis=-1), rtol=REL_DEPTH)
    # the depth convention: z of the hit point in the camera
    p = cam.unproject(out["depth"])
    z_cam = (p @ cam.cam_from_world[:3, :3].T + cam.cam_from_world[:3, 3])[..., 2]
    np.testing.assert_allclose(z_cam, out["depth"], rtol=REL_DEPTH)


def test_plane_depth_equirect_analytic():
    # Floor at y = +1 (OpenCV world with identity pose: +y is down); a huge quad.
    v, f = quad(center=[0, 1.0, 0], half=1000.0, axis_u=[1, 0, 0], axis_v=[0, 0, 1])
    r = ReferenceRenderer(Mesh(v, f))
    cam = Camera.equirect(72, 36)
    out = r.render(cam, outputs=("depth", "distance", "hit"))
    d_world, _ = world_rays(cam)
    down = d_world[..., 1] > math.sin(math.radians(10))  # lat < -10 deg: well inside the quad
    t = 1.0 / d_world[..., 1]
    assert out["hit"][down].all()
    assert not out["hit"][d_world[..., 1] < 0].any()
    np.testing.assert_allclose(out["depth"][down], t[down], rtol=REL_DEPTH)
    np.testing.assert_array_equal(out["depth"], out["distance"])  # equirect depth = distance
    assert np.all(out["depth"][~out["hit"]] == 0)


@pytest.mark.parametrize("model", ["pinhole", "equirect"])
def test_sphere_depth(model):
    radius, center = 2.0, np.array([0.1, -0.2, 5.0])
    v, f = uv_sphere(48, 96, radius, center)
    r = ReferenceRenderer(Mesh(v, f))
    if model == "pinhole":
        cam = Camera.from_fov(80, 60, 60, look_at([0, 0, 0], center))
    else:  # inside the sphere: every ray hits its inner wall
        cam = Camera.equirect(64, 32, cam_from_world=look_at(center + [0.3, 0.1, 0.0], center + [0, 0, 1]))
    out = r.render(cam, outputs=("depth", "prim_id", "hit", "distance"))
    hit = out["hit"]
    assert hit.any() and (model == "pinhole" or hit.all())
    # 1) the depth is the exact (float64) intersection with the face Embree reports
    t = analytic_depth_from_hits(cam, v, f, out["prim_id"])
    np.testing.assert_allclose(out["depth"][hit], t[hit], rtol=REL_DEPTH)
    # 2) that face is the sphere: hit points lie between the inscribed polygon's sag and radius
    p = cam.unproject(out["depth"])[hit]
    rr = np.linalg.norm(p - center, axis=-1)
    sag = radius * (1 - math.cos(math.pi / 48))  # chord sag of the coarser (latitude) spacing
    assert rr.max() <= radius * (1 + 1e-5) and rr.min() >= radius - 2 * sag
    if model == "pinhole":  # the silhouette: pixels whose ray misses the analytic sphere miss
        d_world, _ = world_rays(cam)
        dn = d_world / np.linalg.norm(d_world, axis=-1, keepdims=True)
        oc = center - cam.centre
        miss_dist = np.linalg.norm(oc - (dn @ oc)[..., None] * dn, axis=-1)
        assert not hit[miss_dist > radius * 1.001].any()
        assert hit[miss_dist < radius - 2 * sag].all()


def test_normals_face_camera_and_match_faces():
    v, f = uv_sphere(16, 32, 1.0, (0, 0, 4))
    r = ReferenceRenderer(Mesh(v, f))
    cam = Camera.from_fov(48, 40, 50)
    out = r.render(cam, outputs=("normal", "prim_id", "hit"))
    hit = out["hit"]
    nrm = out["normal"]
    np.testing.assert_allclose(np.linalg.norm(nrm[hit], axis=-1), 1.0, atol=1e-6)
    assert np.all(nrm[~hit] == 0)
    d_world, _ = world_rays(cam)
    assert np.all(np.einsum("...i,...i", nrm, d_world)[hit] < 0)  # facing the camera
    tri = v[f[out["prim_id"][hit]]].astype(np.float64)
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.linalg.norm(fn, axis=-1, keepdims=True)
    np.testing.assert_allclose(np.abs(np.einsum("...i,...i", fn, nrm[hit])), 1.0, atol=1e-5)
    # outward-wound sphere seen from outside: facing normal = outward face normal
    np.testing.assert_allclose(nrm[hit], -fn if np.mean(fn[:, 2]) > 0 else fn, atol=1e-5)


def test_plane_normal_flips_towards_camera():
    v, f = quad([0, 0, 3], 5.0, [1, 0, 0], [0, 1, 0])  # face normal +z (away from the camera)
    r = ReferenceRenderer(Mesh(v, f))
    out = r.render(Camera.from_fov(8, 8, 40), outputs=("normal",))
    np.testing.assert_allclose(out["normal"].reshape(-1, 3), np.tile([0, 0, -1.0], (64, 1)), atol=1e-7)


def test_object_ids_and_visible_objects():
    va, fa = quad([-1.0, 0, 4], 0.8, [1, 0, 0], [0, 1, 0])
    vb, fb = quad([1.0, 0, 4], 0.8, [1, 0, 0], [0, 1, 0])
    vc, fc = quad([1.0, 0, 6], 0.3, [1, 0, 0], [0, 1, 0])  # hidden behind b
    vd, fd = quad([30.0, 0, 4], 0.3, [1, 0, 0], [0, 1, 0])  # outside the frustum
    v = np.vstack([va, vb, vc, vd])
    f = np.vstack([fa, fb + 4, fc + 8, fd + 12]).astype(np.int32)
    ids = np.repeat(np.array([3, 7, 5, 9], np.int32), 2)
    r = ReferenceRenderer(Mesh(v, f, object_ids=ids))
    cam = Camera.from_fov(64, 32, 60)
    out = r.render(cam, outputs=("object_id", "prim_id", "hit"))
    oid, prim, hit = out["object_id"], out["prim_id"], out["hit"]
    assert set(np.unique(oid)) == {-1, 3, 7}
    np.testing.assert_array_equal(oid[hit], ids[prim[hit]])
    assert np.all(prim[~hit] == -1) and np.all(oid[~hit] == -1)
    assert np.all(oid[:, :20][hit[:, :20]] == 3) and np.all(oid[:, 44:][hit[:, 44:]] == 7)
    vis = r.visible_objects(cam)
    assert vis.dtype == np.int32
    np.testing.assert_array_equal(vis, [3, 7])
    np.testing.assert_array_equal(vis, np.unique(oid[hit]))


def test_barycentrics_reconstruct_hit_point():
    v, f = uv_sphere(12, 24, 1.5, (0.2, 0.1, 5))
    r = ReferenceRenderer(Mesh(v, f))
    cam = Camera.from_fov(40, 30, 45, look_at([0.5, 0.3, 0], [0.2, 0.1, 5]))
    out = r.render(cam, outputs=("bary", "prim_id", "distance", "hit"))
    hit = out["hit"]
    b = out["bary"][hit].astype(np.float64)
    assert np.all(b >= -1e-6) and np.all(b.sum(-1) <= 1 + 1e-6)
    tri = v[f[out["prim_id"][hit]]].astype(np.float64)
    p_bary = (1 - b[:, :1] - b[:, 1:]) * tri[:, 0] + b[:, :1] * tri[:, 1] + b[:, 1:] * tri[:, 2]
    d_world, _ = world_rays(cam)
    dn = d_world[hit] / np.linalg.norm(d_world[hit], axis=-1, keepdims=True)
    p_ray = cam.centre + out["distance"][hit][:, None] * dn
    # float32 barycentrics of a unit-scale triangle: ~1e-7 * scene size, with margin
    np.testing.assert_allclose(p_bary, p_ray, atol=1e-5 * 5)
    assert np.all(out["bary"][~hit] == 0)


# --- shading ------------------------------------------------------------------------------------
def test_lambert_plane_matches_n_dot_l():
    v, f = quad([0, 0, 5], 20.0, [1, 0, 0], [0, 1, 0])
    r = ReferenceRenderer(Mesh(v, f))
    cam = Camera.from_fov(16, 12, 40)
    to_light = np.array([0.3, -0.5, -1.0])  # towards the light: in front of the plane (-z)
    color = (0.9, 0.6, 0.3)
    out = r.render(cam, outputs=("color",), lights=[Light("directional", to_light, color)],
                   ambient=0.1)
    cos = (to_light / np.linalg.norm(to_light)) @ np.array([0, 0, -1.0])
    expected = 0.8 * (0.1 + np.array(color) * cos)  # grey albedo 0.8, no 1/pi (raycast.h)
    np.testing.assert_allclose(out["color"], np.broadcast_to(expected, out["color"].shape), rtol=REL_SHADE)


def test_point_light_inverse_square_and_vertex_colors():
    v, f = quad([0, 0, 5], 20.0, [1, 0, 0], [0, 1, 0])
    vc = np.tile([[0.2, 0.4, 0.6]], (4, 1)).astype(np.float32)
    r = ReferenceRenderer(Mesh(v, f, vertex_colors=vc))
    cam = Camera.from_fov(9, 9, 40)
    light_pos = np.array([0.0, 0.0, 3.0])  # 2 units in front of the plane, on the axis
    out = r.render(cam, outputs=("color", "depth"), lights=[Light("point", light_pos, (8.0, 8.0, 8.0))],
                   ambient=0.0)
    p = cam.unproject(out["depth"])
    to = light_pos - p
    d2 = np.einsum("...i,...i", to, to)
    cos = to[..., 2] * -1 / np.sqrt(d2) * -1  # N = (0, 0, -1): N.L = -to_z / d
    cos = -to[..., 2] / np.sqrt(d2)
    expected = vc[0] * (8.0 * cos / d2)[..., None]
    np.testing.assert_allclose(out["color"], expected, rtol=1e-4)  # float32 d^2 and sqrt: 1e-4


def test_texture_orientation_and_bilinear():
    # A 2x2 texture on a quad whose uv (0, 0) is its bottom-left corner (OBJ convention):
    # texel row 0 (top of the image) must appear at the top of the quad.
    v, f = quad([0, 0, 4], 1.0, [1, 0, 0], [0, -1, 0])  # world -y is up on screen (y down)
    uvs = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    tex = np.array([[[1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 0]]], np.float32)
    r = ReferenceRenderer(Mesh(v, f, uvs=uvs, textures=[tex]))
    cam = Camera.from_fov(40, 40, 40)
    out = r.render(cam, outputs=("color", "depth", "hit"), lights=[], ambient=1.0)
    c, hit = out["color"], out["hit"]
    # numpy reference: uv of each hit point (quad corner 0 = world (-1, +1) = uv (0, 0)), then
    # bilinear with repeat wrap at texel row (1 - v) * H - 0.5, column u * W - 0.5
    p = cam.unproject(out["depth"])[hit]
    u, vv = (p[:, 0] + 1) / 2, (1 - p[:, 1]) / 2
    fx, fy = u * 2 - 0.5, (1 - vv) * 2 - 0.5
    x0, y0 = np.floor(fx).astype(int), np.floor(fy).astype(int)
    ax, ay = (fx - x0)[:, None], (fy - y0)[:, None]
    t = lambda yy, xx: tex[yy % 2, xx % 2]  # noqa: E731
    ref = (1 - ay) * ((1 - ax) * t(y0, x0) + ax * t(y0, x0 + 1)) + ay * ((1 - ax) * t(y0 + 1, x0) + ax * t(y0 + 1, x0 + 1))
    np.testing.assert_allclose(c[hit], ref, atol=1e-4)  # float32 uv interpolation
    # orientation, without the reference: the top-left of the quad on screen is texel (0, 0) red
    rows, cols = np.nonzero(hit)
    q_r, q_c = (rows.max() - rows.min()) // 4, (cols.max() - cols.min()) // 4  # texel centres
    corner = c[rows.min() + q_r, cols.min() + q_c]
    assert corner[0] > 0.8 and corner[1] < 0.2 and corner[2] < 0.2
    corner = c[rows.max() - q_r, cols.min() + q_c]  # bottom-left: texel (1, 0) blue
    assert corner[2] > 0.8 and corner[0] < 0.2


def test_specular_highlight_only_with_material():
    v, f = quad([0, 0, 5], 20.0, [1, 0, 0], [0, 1, 0])
    cam = Camera.from_fov(31, 31, 40)
    lights = [Light("directional", (0, 0, -1), (1, 1, 1))]
    diffuse = ReferenceRenderer(Mesh(v, f)).render(cam, outputs=("color",), lights=lights, ambient=0.0)["color"]
    glossy = ReferenceRenderer(Mesh(v, f, materials=np.array([[0.5, 50.0]], np.float32))).render(
        cam, outputs=("color",), lights=lights, ambient=0.0)["color"]
    np.testing.assert_allclose(diffuse, 0.8, rtol=REL_SHADE)
    # centre pixel: N = H exactly (view and light both along -z): +0.5
    np.testing.assert_allclose(glossy[15, 15], 0.8 + 0.5, rtol=1e-4)
    assert np.all(glossy >= diffuse - 1e-6) and glossy[0, 0, 0] < glossy[15, 15, 0]


def test_shadowed_point_is_dark():
    floor_v, floor_f = quad([0, 0, 5], 10.0, [1, 0, 0], [0, 1, 0])
    occ_v, occ_f = quad([0, 0, 3], 0.5, [1, 0, 0], [0, 1, 0])  # between the camera and the floor
    v = np.vstack([floor_v, occ_v])
    f = np.vstack([floor_f, occ_f + 4]).astype(np.int32)
    r = ReferenceRenderer(Mesh(v, f, object_ids=np.array([0, 0, 1, 1], np.int32)))
    # Camera looks at the floor from the side, light straight down the z axis from the front.
    cam = Camera.from_fov(64, 64, 60, look_at([4, 0, 0.5], [0, 0, 5]))
    light = Light("directional", (0, 0, -1), (1, 1, 1), shadows=True)
    out = r.render(cam, outputs=("color", "object_id", "depth"), lights=[light], ambient=0.2)
    p = cam.unproject(out["depth"])
    floor = out["object_id"] == 0
    under = floor & (np.abs(p[..., 0]) < 0.45) & (np.abs(p[..., 1]) < 0.45)
    lit = floor & ((np.abs(p[..., 0]) > 0.55) | (np.abs(p[..., 1]) > 0.55))
    assert under.sum() > 10 and lit.sum() > 10
    np.testing.assert_allclose(out["color"][under], 0.8 * 0.2, rtol=REL_SHADE)  # ambient only
    np.testing.assert_allclose(out["color"][lit], 0.8 * 1.2, rtol=REL_SHADE)
    no_shadow = r.render(cam, outputs=("color",), lights=[Light("directional", (0, 0, -1), (1, 1, 1), False)],
                         ambient=0.2)["color"]
    np.testing.assert_allclose(no_shadow[under], 0.8 * 1.2, rtol=REL_SHADE)


def test_background_and_default_lights():
    v, f = quad([0, 0, 5], 0.5, [1, 0, 0], [0, 1, 0])
    mesh = Mesh(v, f)
    r = ReferenceRenderer(mesh)
    out = r.render(Camera.from_fov(32, 32, 60), outputs=("color", "hit", "depth"), background=(0.1, 0.2, 0.3))
    np.testing.assert_array_equal(out["color"][~out["hit"]], np.broadcast_to([0.1, 0.2, 0.3], out["color"][~out["hit"]].shape).astype(np.float32))
    assert np.all(out["depth"][~out["hit"]] == 0)
    assert np.all(out["color"][out["hit"]] > 0.8 * 0.15)  # lit by the default lights
    lights = default_lights(mesh.bounds())
    assert [l.kind for l in lights] == ["point", "directional"] and lights[0].shadows
    # the key light's irradiance at the scene centre is 0.8 (its documented intensity)
    c = mesh.bounds().mean(0)
    d2 = float(np.sum((np.array(lights[0].vector) - c) ** 2))
    assert lights[0].color[0] / d2 == pytest.approx(0.8)


# --- against an independent implementation -----------------------------------------------------
def test_against_embreex():
    pytest.importorskip("embreex")
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    rng = np.random.default_rng(7)
    v, f = uv_sphere(40, 80, 1.0)
    v = (v * (1 + 0.05 * rng.standard_normal((len(v), 1)))).astype(np.float32)  # bumpy
    cam = Camera.from_fov(96, 72, 50, look_at([0.4, -0.6, -3.0], [0, 0, 0]))
    ours = ReferenceRenderer(Mesh(v, f)).render(cam, outputs=("depth", "prim_id", "hit"))
    d_world, _ = world_rays(cam)
    dirs = np.ascontiguousarray(d_world.reshape(-1, 3).astype(np.float32))
    origins = np.ascontiguousarray(np.broadcast_to(cam.centre, dirs.shape).astype(np.float32))
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, v, f)
    res = scene.run(origins, dirs, output=1)
    prim = res["primID"].reshape(cam.height, cam.width).astype(np.int64)
    their_hit = res["geomID"].reshape(cam.height, cam.width) != -1
    prim[~their_hit] = -1
    n = prim.size
    assert (their_hit != ours["hit"]).sum() <= 0.005 * n
    assert (prim != ours["prim_id"]).sum() <= 0.005 * n
    both = their_hit & ours["hit"]
    assert both.sum() > 0.3 * n
    t = res["tfar"].reshape(cam.height, cam.width)  # along our (z = 1) directions: z-depth
    np.testing.assert_allclose(ours["depth"][both], t[both], rtol=REL_DEPTH)


# --- engine properties ------------------------------------------------------------------------
def _busy_scene():
    v, f = uv_sphere(30, 60, 1.0, (0, 0, 0))
    fv, ff = quad([0, 1.0, 0], 4.0, [1, 0, 0], [0, 0, 1])
    verts = np.vstack([v, fv])
    faces = np.vstack([f, ff + len(v)]).astype(np.int32)
    ids = np.r_[np.zeros(len(f), np.int32), np.ones(2, np.int32)]
    mesh = Mesh(verts, faces, vertex_colors=np.random.default_rng(3).random((len(verts), 3)),
                object_ids=ids, materials=np.array([[0.4, 30.0], [0.0, 0.0]], np.float32))
    cam = Camera.from_fov(67, 45, 60, look_at([1.5, -1.2, -3.0], [0, 0.3, 0]))
    return mesh, cam


ALL = ("color", "depth", "distance", "normal", "object_id", "prim_id", "bary", "hit")


def test_thread_count_determinism(restore_threads):
    mesh, cam = _busy_scene()
    r = ReferenceRenderer(mesh)
    _core.set_num_threads(1)
    one = r.render(cam, outputs=ALL)
    _core.set_num_threads(2)
    two = r.render(cam, outputs=ALL)
    for k in ALL:
        np.testing.assert_array_equal(one[k], two[k], err_msg=k)
    assert one["hit"].dtype == bool and one["object_id"].dtype == np.int32


def test_packet_paths_agree_with_scalar_path():
    mesh, cam = _busy_scene()
    r = ReferenceRenderer(mesh)
    ref = r.render(cam, outputs=ALL, packet=1)
    for packet in (8, 16):
        out = r.render(cam, outputs=ALL, packet=packet)
        np.testing.assert_array_equal(out["hit"], ref["hit"])
        same = out["prim_id"] == ref["prim_id"]
        assert same.mean() >= 0.995  # edge pixels only (see the module docstring)
        np.testing.assert_allclose(out["depth"], ref["depth"], rtol=REL_DEPTH)
        np.testing.assert_allclose(out["color"][same], ref["color"][same], rtol=1e-4, atol=1e-6)


def test_outputs_are_fresh_contiguous_arrays():
    mesh, cam = _busy_scene()
    out = ReferenceRenderer(mesh).render(cam, outputs=ALL)
    assert set(out) == set(ALL)
    shapes = {"color": (45, 67, 3), "normal": (45, 67, 3), "bary": (45, 67, 2)}
    for k, a in out.items():
        assert a.flags.c_contiguous and a.flags.writeable and a.flags.owndata, k
        assert a.shape == shapes.get(k, (45, 67))
        assert np.all(np.isfinite(a)) if a.dtype.kind == "f" else True


def test_gil_released_during_render(restore_threads):
    """Structural: while a render runs in another thread, this thread executes Python code.
    A kernel holding the GIL would leave no time stamp of ours strictly inside the middle
    half of the render's interval (the interval is many switch intervals long)."""
    mesh, _ = _busy_scene()
    r = ReferenceRenderer(mesh)
    pose = look_at([1.5, -1.2, -3.0], [0, 0.3, 0])
    lights = default_lights(mesh.bounds()) * 4
    _core.set_num_threads(1)  # leave a core for this thread
    # Size the image so that one call lasts ~80 ms here (>> the 5 ms switch interval).
    t = time.perf_counter()
    r.render(Camera.from_fov(160, 120, 60, pose), outputs=("color",), lights=lights, packet=1)
    scale = min(8.0, max(1.0, math.sqrt(0.08 / max(time.perf_counter() - t, 1e-4))))
    cam = Camera.from_fov(int(160 * scale), int(120 * scale), 60, pose)
    assert runs_python_during(lambda: r.render(cam, outputs=("color",), lights=lights, packet=1)), \
        "no Python ran during the render (or it lasted < 20 ms)"
    # (Negative control: tests/gil.py.)


# --- bad input ---------------------------------------------------------------------------------
def _tri():
    return (np.array([[0, 0, 5], [1, 0, 5], [0, 1, 5]], np.float32), np.array([[0, 1, 2]], np.int32))


def test_bad_scene_input():
    v, f = _tri()
    with pytest.raises(DtypeError, match="vertices: expected float32"):
        _core.RayScene(v.astype(np.float64), f)
    with pytest.raises(ShapeError, match="vertices"):
        _core.RayScene(v[:, :2].copy(), f)
    with pytest.raises(DtypeError, match="faces"):
        _core.RayScene(v, f.astype(np.int64))
    with pytest.raises(ShapeError, match="faces"):
        _core.RayScene(v, f.reshape(1, 3, 1))
    with pytest.raises(BadValueError, match="outside"):
        _core.RayScene(v, np.array([[0, 1, 3]], np.int32))
    with pytest.raises(BadValueError, match="no triangles"):
        _core.RayScene(v, np.zeros((0, 3), np.int32))
    bad = v.copy()
    bad[1, 2] = np.nan
    with pytest.raises(BadValueError, match="NaN"):
        _core.RayScene(bad, f)
    with pytest.raises(ShapeError, match="object_ids"):
        _core.RayScene(v, f, np.zeros(2, np.int32))
    with pytest.raises(BadValueError, match="texture_ids"):
        _core.RayScene(v, f, uvs=np.zeros((1, 3, 2), np.float32), texture_ids=np.array([2], np.int32),
                       textures=[np.zeros((2, 2, 3), np.float32)])
    with pytest.raises(BadValueError, match="quality"):
        _core.RayScene(v, f, quality="ultra")
    with pytest.raises(DtypeError, match="ibrtools.Mesh"):
        ReferenceRenderer((v, f))


def test_bad_render_input():
    v, f = _tri()
    r = ReferenceRenderer(Mesh(v, f))
    cam = Camera.from_fov(8, 8, 40)
    with pytest.raises(BadValueError, match="unknown output 'colour'"):
        r.render(cam, outputs=("colour",))
    with pytest.raises(BadValueError, match="at least one"):
        r.render(cam, outputs=())
    with pytest.raises(DtypeError, match="ibrtools.Camera"):
        r.render(cam.to_core())
    with pytest.raises(DtypeError, match="ibrtools.Camera"):
        r.visible_objects("cam")
    with pytest.raises(BadValueError, match="light kind"):
        Light("spot", (0, 0, 1))
    with pytest.raises(BadValueError, match="must not be zero"):
        Light("directional", (0, 0, 0))
    with pytest.raises(ShapeError, match="3 numbers"):
        Light("point", (0, 0))
    with pytest.raises(BadValueError, match=">= 0"):
        Light("point", (0, 0, 1), (-1, 0, 0))
    with pytest.raises(DtypeError, match="lights\\[0\\]"):
        r.render(cam, lights=[("directional", (0, 0, 1), (1, 1, 1), True)])
    with pytest.raises(BadValueError, match="ambient"):
        r.render(cam, ambient=-1)
    with pytest.raises(BadValueError, match="background"):
        r.render(cam, background=(0, np.nan, 0))
    with pytest.raises(BadValueError, match="packet"):
        r.render(cam, packet=4)
    with pytest.raises(BadValueError, match="unknown output"):  # the binding checks too
        r._scene.render(cam.to_core(), ["depth", "nope"])
    with pytest.raises(BadValueError, match="kind must be"):
        r._scene.render(cam.to_core(), ["color"], [("spot", (0, 0, 1), (1, 1, 1), True)])
    with pytest.raises(ShapeError, match="bounds"):
        default_lights(np.zeros(3))
