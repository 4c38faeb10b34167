"""The global mesh (ibrtools.hybrid.globalmesh): which geometry is used, TSDF fusion of a known
plane, densification, ULR-weighted per-vertex colour with a depth test, depth from the mesh,
bad input."""
import numpy as np
import pytest

from conftest import wall
from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.hybrid.globalmesh import (GlobalMeshOptions, build_global_mesh, choose_source, densify,
                                        depth_extent, depth_from_mesh, fuse_depth, smooth_normals,
                                        vertex_colors, vertex_normals)
from ibrtools.mesh import Mesh
from ibrtools.scene import Scene, View

pytestmark = [pytest.mark.asan]


def quad(z=0.0, size=1.0, kind="ground_truth"):
    """A square of side 2 * size in the plane y = z, normal +y."""
    v = np.array([[-size, z, -size], [size, z, -size], [size, z, size], [-size, z, size]], np.float32)
    # Counter-clockwise seen from +y: normal (0, 1, 0).
    f = np.array([[0, 2, 1], [0, 3, 2]], np.int32)
    return Mesh(v, f, kind=kind)


def cam_at(eye, w=40, h=30, f=30.0, target=(0.0, 0.0, 2.0)):
    return Camera.pinhole(w, h, f, f, w / 2, h / 2, look_at(eye, target, up=(0.0, -1.0, 0.0)))


def test_choose_source():
    c = cam_at((0, 0, 0))
    d = np.full((30, 40), 2.0, np.float32)
    col = np.zeros((30, 40, 3), np.float32)
    with_depth = [View.create("a", c, color=col, depth=d)]
    no_depth = [View.create("a", c, color=col)]
    gt = wall(size=3.0)
    rec = Mesh(gt.vertices, gt.faces, kind="reconstructed")
    assert choose_source(Scene(views=with_depth, meshes={"ground_truth": gt, "reconstructed": rec})) == "reconstructed"
    # Ground truth is not used when depth can be fused: no leak of ground truth into a method.
    assert choose_source(Scene(views=with_depth, meshes={"ground_truth": gt})) == "fusion"
    assert choose_source(Scene(views=no_depth, meshes={"ground_truth": gt})) == "ground_truth"
    assert choose_source(Scene(views=with_depth, meshes={"ground_truth": gt}), "ground_truth") == "ground_truth"
    with pytest.raises(BadValueError, match="no view has depth and the scene has no mesh.*stereo/depth_maps"):
        choose_source(Scene(views=no_depth))
    mixed = [with_depth[0], View.create("b", c, color=col), View.create("c", c, color=col)]
    with pytest.raises(BadValueError, match=r"2 of 3 views have no depth \(first: b\)"):
        choose_source(Scene(views=mixed))
    with pytest.raises(BadValueError, match="no 'reconstructed' mesh"):
        choose_source(Scene(views=with_depth), "reconstructed")
    with pytest.raises(BadValueError, match="fusion needs a depth map"):
        choose_source(Scene(views=no_depth, meshes={"ground_truth": gt}), "fusion")
    with pytest.raises(BadValueError, match="mesh source"):
        choose_source(Scene(views=with_depth), "magic")


def test_fusion_of_a_plane_lies_on_it():
    cams = {f"v{i}": cam_at((x, 0.0, 0.0)) for i, x in enumerate((-0.3, 0.0, 0.3))}
    depths = {n: depth_from_mesh(wall(size=3.0), {n: c})[n] for n, c in cams.items()}
    m = fuse_depth(cams, depths, GlobalMeshOptions(resolution=64))
    assert m.kind == "reconstructed" and len(m.faces) > 100
    voxel = float(np.ptp(np.concatenate([c.unproject(depths[n]).reshape(-1, 3) for n, c in cams.items()]),
                         axis=0).max()) / 64
    # Marching cubes on a TSDF of exact depth: vertices on the plane within a small part of a voxel.
    assert np.abs(m.vertices[:, 2] - 2.0).max() < 0.25 * voxel
    # Normals face the cameras (-z).
    assert vertex_normals(m.vertices, m.faces)[:, 2].mean() < -0.9


def test_fusion_far_from_the_world_origin_and_in_a_canonical_order():
    # open3d integrates in float32: the grid lives in a frame whose origin is its first voxel
    # sample, so a scene 10 km from the world origin fuses as well as one at it (float32 world
    # coordinates there are 1 mm apart, 1/30 of this voxel).
    off = np.array([1e4, -2e3, 5e3])
    cams = {f"v{i}": cam_at(np.array((x, 0.0, 0.0)) + off, target=off + (0.0, 0.0, 2.0))
            for i, x in enumerate((-0.3, 0.0, 0.3))}
    w = wall(size=3.0)
    shifted = Mesh((w.vertices + off).astype(np.float32), w.faces)
    depths = {n: depth_from_mesh(shifted, {n: c})[n] for n, c in cams.items()}
    m = fuse_depth(cams, depths, GlobalMeshOptions(resolution=64))
    voxel = float(np.ptp(np.concatenate([c.unproject(depths[n]).reshape(-1, 3) for n, c in cams.items()]),
                         axis=0).max()) / 64
    assert len(m.faces) > 100
    assert np.abs(m.vertices[:, 2].astype(np.float64) - (off[2] + 2.0)).max() < 0.25 * voxel
    assert vertex_normals(m.vertices, m.faces)[:, 2].mean() < -0.9
    # open3d extracts vertices and faces in thread order; ours are sorted, so the same depth maps
    # give the same arrays (the stage cache and everything downstream depend on it).
    again = fuse_depth(dict(reversed(list(cams.items()))), depths, GlobalMeshOptions(resolution=64))
    np.testing.assert_array_equal(m.vertices, again.vertices)
    np.testing.assert_array_equal(m.faces, again.faces)
    a, b = m.vertices[:-1], m.vertices[1:]
    assert np.all((a[:, 0] < b[:, 0]) | ((a[:, 0] == b[:, 0]) & ((a[:, 1] < b[:, 1]) | ((a[:, 1] == b[:, 1])
                                                                                     & (a[:, 2] <= b[:, 2])))))
    assert np.all(m.faces[:, 0] < m.faces[:, 1]) and np.all(m.faces[:, 0] < m.faces[:, 2])
    # A view without a valid depth pixel adds nothing.
    blank = dict(cams, empty=cam_at(off + (0.0, 0.3, 0.0), target=off + (0.0, 0.0, 2.0)))
    with_blank = fuse_depth(blank, dict(depths, empty=np.zeros((30, 40), np.float32)), GlobalMeshOptions(resolution=64),
                            extent=depth_extent(cams, depths))
    alone = fuse_depth(cams, depths, GlobalMeshOptions(resolution=64), extent=depth_extent(cams, depths))
    np.testing.assert_array_equal(with_blank.vertices, alone.vertices)


def test_fusion_without_a_surface_says_so():
    # A single depth sample leaves no zero crossing between two observed voxels: open3d's own
    # error (it fails to attach an empty mesh's colours) becomes the one-line BadValueError.
    cam = cam_at((0.0, 0.0, 0.0))
    box = (np.array([-1.0, -1.0, 1.0]), np.array([1.0, 1.0, 3.0]))
    for y, x in ((15, 20), (0, 0)):
        d = np.zeros((30, 40), np.float32)
        d[y, x] = 2.0
        with pytest.raises(BadValueError, match="TSDF fusion produced no surface"):
            fuse_depth({"a": cam}, {"a": d}, GlobalMeshOptions(resolution=8), extent=box)


def test_fusion_reads_the_stored_depth_when_the_importer_filtered_it():
    # View.fusion_depth: a view with depth_stored fuses that (here the plane z = 2) and not its
    # filtered depth (here moved to z = 2.2); without depth_stored the depth itself is fused.
    cams = {f"v{i}": cam_at((x, 0.0, 0.0)) for i, x in enumerate((-0.3, 0.0, 0.3))}
    exact = {n: depth_from_mesh(wall(size=3.0), {n: c})[n] for n, c in cams.items()}
    col = np.zeros((30, 40, 3), np.float32)
    opts = GlobalMeshOptions(resolution=64)

    def fused_z(**stored):
        views = [View.create(n, c, color=col, depth=np.where(exact[n] > 0, exact[n] * 1.1, 0).astype(np.float32),
                             **({"depth_stored": exact[n]} if stored else {})) for n, c in cams.items()]
        mesh, rec = build_global_mesh(Scene(views=views), opts)
        assert rec.get("views_depth_as_stored", 0) == (3 if stored else 0)
        return float(np.median(mesh.vertices[:, 2]))

    assert abs(fused_z(stored=True) - 2.0) < 0.02
    assert abs(fused_z() - 2.2) < 0.02
    c = cams["v0"]
    with pytest.raises(BadValueError, match="depth_stored given without depth"):
        View.create("a", c, color=col, depth_stored=exact["v0"])
    with pytest.raises(ShapeError, match="depth_stored"):
        View.create("a", c, color=col, depth=exact["v0"], depth_stored=exact["v0"][:, :5])


def test_depth_from_mesh_exact_plane():
    c = cam_at((0.0, 0.0, 0.0))
    d = depth_from_mesh(wall(size=3.0), {"a": c})["a"]
    np.testing.assert_allclose(d, 2.0, rtol=1e-5)  # z-depth of the plane z = 2 (float32 ray hits)
    d = depth_from_mesh(quad(z=5.0, size=0.1), {"a": c})["a"]
    assert np.all(d == 0)  # nothing hit: 0 = unknown
    with pytest.raises(DtypeError):
        depth_from_mesh("mesh", {"a": c})


def test_densify_bounds_edges_and_keeps_area():
    m = quad(size=1.0)
    d = densify(m, 0.3)
    e = d.vertices[d.faces]
    lengths = np.linalg.norm(e - np.roll(e, 1, axis=1), axis=-1)
    assert lengths.max() <= 0.3 + 1e-6

    def area(mm):
        v = mm.vertices.astype(np.float64)
        return 0.5 * np.linalg.norm(np.cross(v[mm.faces[:, 1]] - v[mm.faces[:, 0]],
                                             v[mm.faces[:, 2]] - v[mm.faces[:, 0]]), axis=1).sum()
    assert area(d) == pytest.approx(area(m), rel=1e-6)
    # Orientation kept: every normal still +y.
    assert np.all(vertex_normals(d.vertices, d.faces)[:, 1] > 0.99)
    # The face cap stops subdivision.
    assert len(densify(m, 1e-3, max_faces=100).faces) <= 100
    with pytest.raises(BadValueError):
        densify(m, 0.0)


def test_vertex_colors_blend_and_depth_test():
    mesh = densify(wall(size=1.0), 0.2)
    c_red, c_green = cam_at((-0.2, 0.0, 0.0)), cam_at((0.2, 0.0, 0.0))
    cams = {"red": c_red, "green": c_green}
    red = np.zeros((30, 40, 3), np.float32)
    red[..., 0] = 1
    green = np.zeros((30, 40, 3), np.float32)
    green[..., 1] = 1
    depths = depth_from_mesh(mesh, cams)
    col, seen = vertex_colors(mesh, cams, {"red": red, "green": green}, depths, GlobalMeshOptions(k_views=2))
    both = seen == 2
    assert both.any()
    # Convex blend of the two views: r + g = 1 and b = 0 wherever both see the vertex.
    np.testing.assert_allclose(col[both].sum(1), 1.0, rtol=1e-5)
    # The green view's depth says an occluder stands in front (z = 1): it sees no vertex.
    occluded = {"red": depths["red"], "green": np.full_like(depths["green"], 1.0)}
    col, seen = vertex_colors(mesh, cams, {"red": red, "green": green}, occluded)
    vis = seen > 0
    assert vis.any() and seen.max() == 1
    np.testing.assert_allclose(col[vis], [[1.0, 0.0, 0.0]] * int(vis.sum()), atol=1e-6)
    with pytest.raises(BadValueError, match="no views"):
        vertex_colors(mesh, {}, {}, {})


def test_build_global_mesh_from_given_mesh_and_errors():
    c = cam_at((0.0, 0.0, 0.0))
    v = View.create("a", c, color=np.zeros((30, 40, 3), np.float32))
    mesh, rec = build_global_mesh(Scene(views=[v], meshes={"ground_truth": wall(size=3.0)}),
                                  GlobalMeshOptions(resolution=16))
    assert rec["source"] == "ground_truth" and len(mesh.faces) > 2
    # Degenerate: all vertices at one point.
    flat = Mesh(np.zeros((3, 3), np.float32), np.array([[0, 1, 2]], np.int32))
    with pytest.raises(BadValueError, match="degenerate"):
        build_global_mesh(Scene(views=[v], meshes={"ground_truth": flat}))
    with pytest.raises(BadValueError, match="no view has depth and the scene has no mesh"):
        build_global_mesh(Scene(views=[v]))
    # Depth maps with no finite surface (all sky): empty bounds.
    v0 = View.create("a", c, color=np.zeros((30, 40, 3), np.float32), depth=np.full((30, 40), np.inf, np.float32))
    with pytest.raises(BadValueError, match="empty bounds"):
        build_global_mesh(Scene(views=[v0]))
    with pytest.raises(BadValueError, match="resolution"):
        GlobalMeshOptions(resolution=2)


def test_fusion_of_a_synthetic_scene_lies_on_its_ground_truth():
    """TSDF fusion of exact depth maps: the fused vertices lie on the ground-truth surface to a
    fraction of a voxel (distances by open3d's RaycastingScene, independent of our code)."""
    import open3d as o3d

    from ibrtools.synth import make_scene

    s = make_scene("objects", size=(160, 120), views=6, holdout_targets=0)
    m, rec = build_global_mesh(s, GlobalMeshOptions(resolution=128))
    assert rec["source"] == "fusion"
    gt = s.meshes["ground_truth"]
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(o3d.core.Tensor(gt.vertices), o3d.core.Tensor(gt.faces.astype(np.uint32)))
    d = rs.compute_distance(o3d.core.Tensor(m.vertices)).numpy() / rec["voxel"]
    # Measured: median 0.05, 95th percentile 0.17, max 1.7 voxels (rounded edges of the boxes, where
    # the truncated SDF of two faces overlaps). Bounds: 0.2, 0.5 and 3 voxels.
    assert np.median(d) < 0.2 and np.percentile(d, 95) < 0.5 and d.max() < 3


def test_equirect_cube_faces_and_fusion_of_a_room():
    from ibrtools.hybrid.globalmesh import equirect_to_cube_faces

    eye = np.array([0.3, -0.2, 0.1])
    cam = Camera.equirect(256, 128, cam_from_world=look_at(eye, eye + [0.0, 0.0, 1.0], up=(0.0, -1.0, 0.0)))
    # A sphere of radius 1.5 around the camera: every face's points at distance 1.5 (the depth is
    # constant, so nearest sampling is exact).
    faces = equirect_to_cube_faces(cam, np.full((128, 256), 1.5, np.float32))
    assert len(faces) == 6
    for fc, z in faces:
        assert np.all(z > 0)
        p = fc.unproject(z).reshape(-1, 3)
        np.testing.assert_allclose(np.linalg.norm(p - eye, axis=1), 1.5, rtol=1e-5)
    # A cubic room of half-size 2 around the origin: ray distance to its walls, fused.
    x, y = cam.pixel_grid()
    rays = cam.rays_in_cam(x, y) @ cam.world_from_cam[:3, :3].T  # unit world directions
    t = np.min(np.where(rays != 0, (np.sign(rays) * 2.0 - eye) / np.where(rays != 0, rays, 1), np.inf), axis=-1)
    m = fuse_depth({"e": cam}, {"e": t.astype(np.float32)}, GlobalMeshOptions(resolution=64))
    voxel = 4.0 * (1 + 2 * 4.0 / 64) / 64  # extent plus the truncation margin, / resolution
    assert len(m.faces) > 1000
    # On the walls (|coordinate| = 2 for the largest one): the equirect depth is sampled at the
    # nearest pixel into the cube faces (up to half an equirect pixel of error along the wall).
    err = np.abs(np.abs(m.vertices).max(axis=1) - 2.0) / voxel
    # Measured: median 0.09, 95th percentile 0.41, max 0.76 voxel.
    assert np.median(err) < 0.2 and np.percentile(err, 95) < 0.6 and err.max() < 1.0


# -- the point-colour kernel (_core.point_colors, cpp/kernels/hybrid/atlas8.cpp) against numpy ------------
def _sample_bilinear_ref(img, x, y):
    h, w = img.shape[:2]
    xf, yf = np.clip(x - 0.5, 0, w - 1), np.clip(y - 0.5, 0, h - 1)
    x0 = np.minimum(xf.astype(np.int64), w - 2 if w > 1 else 0)
    y0 = np.minimum(yf.astype(np.int64), h - 2 if h > 1 else 0)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    tx, ty = (xf - x0)[:, None], (yf - y0)[:, None]
    top = img[y0, x0] * (1 - tx) + img[y0, x1] * tx
    bot = img[y1, x0] * (1 - tx) + img[y1, x1] * tx
    return top * (1 - ty) + bot * ty


def point_colors_ref(v, nrm, cameras, colors, depths, k_views=4, depth_tol=0.02):
    """The numpy implementation point_colors had before the kernel (same float32/float64 steps)."""
    names = list(cameras)
    n_v, n_views = len(v), len(names)
    penalty = np.full((n_views, n_v), np.inf, np.float32)
    dist = np.full((n_views, n_v), np.inf, np.float32)
    for i, n in enumerate(names):
        cam, d = cameras[n], depths[n]
        xy, z = cam.project(v)
        with np.errstate(invalid="ignore"):
            inside = (np.isfinite(z) & (xy[:, 0] >= 0) & (xy[:, 0] < cam.width)
                      & (xy[:, 1] >= 0) & (xy[:, 1] < cam.height))
        idx = np.flatnonzero(inside)
        px = np.minimum(xy[idx, 0].astype(np.int64), cam.width - 1)
        py = np.minimum(xy[idx, 1].astype(np.int64), cam.height - 1)
        dz = d[py, px]
        vis = np.isfinite(dz) & (dz > 0) & (np.abs(z[idx] - dz) <= np.float32(depth_tol) * dz)
        idx = idx[vis]
        to_cam = cam.centre[None] - v[idx]
        r = np.linalg.norm(to_cam, axis=1)
        ang = np.arccos(np.clip(np.einsum("ij,ij->i", to_cam, nrm[idx]) / np.maximum(r, 1e-12), -1, 1))
        ok = ang < np.pi / 2 - 1e-3
        penalty[i, idx[ok]] = ang[ok]
        dist[i, idx[ok]] = r[ok]
    seen = np.isfinite(penalty).sum(0).astype(np.int32)
    dmin = np.min(dist, axis=0)
    with np.errstate(invalid="ignore"):
        penalty = penalty + np.float32(0.5) * np.maximum(np.float32(0), dist / np.where(np.isfinite(dmin), dmin, np.float32(1)) - np.float32(1))
    k = min(k_views, n_views)
    thresh = np.partition(penalty, k, axis=0)[k] if n_views > k else np.full(n_v, np.inf, np.float32)
    acc = np.zeros((n_v, 3), np.float64)
    wsum = np.zeros(n_v, np.float64)
    for i, n in enumerate(names):
        p = penalty[i]
        use = np.flatnonzero(np.isfinite(p) & (p < thresh))
        t = thresh[use]
        w = np.where(np.isfinite(t), np.float32(1) - p[use] / np.where(t > 0, t, np.float32(1)), np.float32(1))
        w = np.maximum(w, np.float32(1e-3))
        xy, _ = cameras[n].project(v[use])
        acc[use] += w[:, None] * _sample_bilinear_ref(colors[n], xy[:, 0], xy[:, 1])
        wsum[use] += w
    out = np.where(wsum[:, None] > 0, acc / np.where(wsum > 0, wsum, 1)[:, None], 0).astype(np.float32)
    return out, seen


def test_point_colors_kernel_matches_the_numpy_reference():
    """Seven views (pinhole around a bumpy wall, one equirect; k = 4 of them, so the (k+1)-th
    penalty threshold, the resolution term, the depth test and the back-face test all act; one
    view's depth has an occluder band and unknown pixels). The kernel does the numpy steps in the
    same precision; only the 3x3 projection's summation order may differ (~1e-16 relative in the
    image position), hence 1e-5 and not bit equality; ``seen`` must be equal."""
    from ibrtools.hybrid.globalmesh import point_colors

    rng = np.random.default_rng(3)
    mesh = densify(wall(size=1.0), 0.1)
    v = mesh.vertices.astype(np.float64).copy()
    v[:, 2] += 0.05 * np.sin(3 * v[:, 0]) * np.cos(2 * v[:, 1])  # not a plane: varied normals
    mesh = Mesh(v.astype(np.float32), mesh.faces)
    eyes = [(-0.6, 0.1, 0.0), (0.5, -0.2, 0.3), (0.0, 0.0, -0.5), (0.3, 0.4, 0.8), (-0.2, -0.5, 0.2),
            (0.0, 0.0, 3.5)]  # the last one behind the wall: back-facing
    cams = {f"p{i}": cam_at(e, w=48 + 4 * i, h=36) for i, e in enumerate(eyes)}
    cams["eq"] = Camera.equirect(64, 32, cam_from_world=look_at((0.1, 0.1, -0.2), (0.0, 0.0, 2.0), up=(0.0, -1.0, 0.0)))
    depths = depth_from_mesh(mesh, cams)
    depths["p1"][10:14] = 1.0  # an occluder band in front of the wall
    depths["p2"][:, :5] = 0.0  # unknown depth
    colors = {n: rng.random((c.height, c.width, 3)).astype(np.float32) for n, c in cams.items()}
    vn = vertex_normals(mesh.vertices, mesh.faces).astype(np.float64)
    pts = mesh.vertices.astype(np.float64)
    for k in (1, 4, 8):
        ref, seen_ref = point_colors_ref(pts, vn, cams, colors, depths, k_views=k)
        got, seen = point_colors(pts, vn, cams, colors, depths, GlobalMeshOptions(k_views=k))
        assert got.dtype == np.float32 and seen.dtype == np.int32
        np.testing.assert_array_equal(seen, seen_ref)
        assert (seen >= 3).any() and (seen == 0).any() and (seen < len(cams)).all()
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-5)


def test_point_colors_bad_input():
    from ibrtools import _core
    from ibrtools.errors import ShapeError
    from ibrtools.hybrid.globalmesh import point_colors

    c = cam_at((0.0, 0.0, 0.0))
    col, dep = np.zeros((30, 40, 3), np.float32), np.full((30, 40), 2.0, np.float32)
    p = np.zeros((5, 3))
    with pytest.raises(BadValueError, match="no views"):
        point_colors(p, p, {}, {}, {})
    with pytest.raises(ShapeError, match="points, normals"):
        point_colors(p, p[:4], {"a": c}, {"a": col}, {"a": dep})
    with pytest.raises(ShapeError, match="view 'a'"):
        point_colors(p, p, {"a": c}, {"a": col[:-1]}, {"a": dep})
    views = [(c.to_core(), col, dep)]
    with pytest.raises(BadValueError, match="k"):
        _core.point_colors(p, p, views, k=0)
    with pytest.raises(BadValueError, match="depth_tol"):
        _core.point_colors(p, p, views, depth_tol=float("nan"))
    with pytest.raises(DtypeError, match="points"):
        _core.point_colors(p.astype(np.float32), p, views)
    with pytest.raises(BadValueError, match="views"):
        _core.point_colors(p, p, [])
    with pytest.raises(DtypeError, match=r"views\[0\]"):
        _core.point_colors(p, p, [(c.to_core(), col)])


def test_smooth_normals_against_loops():
    """1-ring averaging (each edge neighbour once, plus the vertex itself, renormalised) against
    a plain-loop implementation on a small noisy grid; isolated vertices keep their normal."""
    rng = np.random.default_rng(5)
    nx = 6
    v = np.array([[x, y, 0.0] for y in range(nx) for x in range(nx)] + [[9.0, 9.0, 9.0]], np.float32)
    f = np.array([[y * nx + x, y * nx + x + 1, (y + 1) * nx + x] for y in range(nx - 1) for x in range(nx - 1)]
                 + [[y * nx + x + 1, (y + 1) * nx + x + 1, (y + 1) * nx + x] for y in range(nx - 1)
                    for x in range(nx - 1)], np.int32)
    n = rng.normal(size=(len(v), 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    nbrs = [set() for _ in range(len(v))]
    for a, b, c in f:
        for p, q in ((a, b), (b, c), (c, a)):
            nbrs[p].add(q)
            nbrs[q].add(p)
    ref = n.copy()
    for _ in range(3):
        new = ref.copy()
        for i in range(len(v)):
            if nbrs[i]:
                s = ref[i] + sum(ref[j] for j in nbrs[i])
                new[i] = s / np.linalg.norm(s)
        ref = new
    got = smooth_normals(n, f, 3)
    assert got.dtype == np.float32
    # float32 output of float64 sums in another order: agreement to float32 rounding.
    np.testing.assert_allclose(got, ref, atol=1e-6)
    assert np.array_equal(got[-1], n[-1].astype(np.float32))
    np.testing.assert_array_equal(smooth_normals(n, f, 0), n.astype(np.float32))
    # Many rounds on a connected surface: every normal tends to the same direction.
    many = smooth_normals(n, f, 200)[:-1]
    assert np.ptp(many, axis=0).max() < 1e-3


def test_smooth_normals_bad_input():
    n = np.zeros((3, 3))
    f = np.array([[0, 1, 2]])
    with pytest.raises(BadValueError):
        smooth_normals(n, f, -1)
    with pytest.raises(BadValueError, match="vertex index"):
        smooth_normals(n, np.array([[0, 1, 3]]), 1)
    with pytest.raises(ShapeError):
        smooth_normals(np.zeros((3, 2)), f, 1)
    with pytest.raises(ShapeError):
        smooth_normals(n, np.zeros((2, 2), np.int32), 1)
    with pytest.raises(BadValueError, match="bake_normal_rounds"):
        GlobalMeshOptions(bake_normal_rounds=-1)
    with pytest.raises(BadValueError, match="gain_model"):
        GlobalMeshOptions(gain_model="median")
    with pytest.raises(BadValueError, match="gain_max_ratio"):
        GlobalMeshOptions(gain_max_ratio=-0.1)
