"""Per-view meshes and their two-level voxel tiles (ibrtools.hybrid.pvm, cpp/kernels/hybrid/pvm.h):
hand-checked grids, cut discontinuities, planar merging, tiles that reassemble the PVM and lie
in their cells, thread independence, bad input."""
import numpy as np
import pytest

from ibrtools import _core
from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.hybrid.pvm import (MAX_PLANE_TOL, PvmOptions, PvmTiles, build_tiles, depth_noise, grid_bounds,
                                  plane_tolerance, snap_depth, view_mesh)

pytestmark = [pytest.mark.kernel, pytest.mark.tsan]


def cam(w=33, h=25, eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, 1.0), f=30.0):
    return Camera.pinhole(w, h, f, f, w / 2, h / 2, look_at(eye, target, up=(0.0, -1.0, 0.0)))


def tri_normals(v, f):
    return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])


def areas(v, f):
    return 0.5 * np.linalg.norm(tri_normals(v.astype(np.float64), f), axis=1)


def test_single_quad_hand_checked():
    # 2 x 2 pixels = one quad a b / c d; b-c is the flatter diagonal -> (a, c, b), (b, c, d).
    d = np.array([[1.0, 2.0], [2.0, 1.5]], np.float32)
    f = _core.pvm_triangulate(d, None, 10.0, 0.0, 1)
    assert f.tolist() == [[0, 2, 1], [1, 2, 3]]
    d = np.array([[1.0, 2.0], [3.0, 1.1]], np.float32)  # a-d flatter -> (a, c, d), (a, d, b)
    assert _core.pvm_triangulate(d, None, 10.0, 0.0, 1).tolist() == [[0, 2, 3], [0, 3, 1]]
    d[0, 0] = 0  # a unknown: only the triangle without a
    assert _core.pvm_triangulate(d, None, 10.0, 0.0, 1).tolist() == [[1, 2, 3]]


def test_fronto_parallel_plane_exact_and_merged():
    c = cam()
    depth = np.full((c.height, c.width), 2.0, np.float32)
    v, f = view_mesh(c, depth, PvmOptions(max_block=8))
    # 32 x 24 quads -> 4 x 3 blocks of 8, two triangles each, only the 20 block corners used.
    assert len(f) == 24 and len(v) == 5 * 4
    pc = v @ c.cam_from_world[:3, :3].T.astype(np.float32) + c.cam_from_world[:3, 3].astype(np.float32)
    np.testing.assert_allclose(pc[:, 2], 2.0, rtol=1e-6)  # exact up to float32 rounding
    # Counter-clockwise seen from the camera: normals point back towards it (-z in the camera).
    nz = tri_normals(pc.astype(np.float64), f)[:, 2]
    assert np.all(nz < 0)
    # Unmerged: every quad as 2 triangles, same total area (the plane's extent).
    v1, f1 = view_mesh(c, depth, PvmOptions(max_block=1))
    assert len(f1) == 2 * 32 * 24
    np.testing.assert_allclose(areas(v1, f1).sum(), areas(v, f).sum(), rtol=1e-5)


def test_slanted_plane_merges_and_stays_on_plane():
    c = cam(65, 49)
    # Plane z = 3 + 0.5 x (world = camera here): 1/z is affine in the pixel coordinates.
    x, y = c.pixel_grid()
    rx = (x - c.cx) / c.fx
    depth = (3.0 / (1 - 0.5 * rx)).astype(np.float32)
    v, f = view_mesh(c, depth, PvmOptions(max_block=16, plane_tol=1e-4))
    # Unmerged, with a jump threshold above this steep slope's 3.6 % per pixel (at 3 % some
    # edges would be cut: a slope and a step look alike to a relative-jump test).
    v1, f1 = view_mesh(c, depth, PvmOptions(max_block=1, max_rel_jump=0.2))
    assert len(f1) == 2 * 64 * 48 and len(f) < len(f1) / 50
    pc = (v.astype(np.float64) - c.centre) @ c.cam_from_world[:3, :3].T
    np.testing.assert_allclose(pc[:, 2], 3 + 0.5 * pc[:, 0], rtol=1e-5)
    np.testing.assert_allclose(areas(v, f).sum(), areas(v1, f1).sum(), rtol=1e-4)


def test_depth_noise_estimate_and_the_merge_tolerance():
    c = cam(129, 97, f=100.0)
    x, y = c.pixel_grid()
    depth = (3.0 / (1 - 0.5 * (x - c.cx) / c.fx)).astype(np.float32)  # a slanted plane, exact
    assert depth_noise(depth) < 1e-6  # 1/z affine: every second difference vanishes (float32 rounding)
    assert plane_tolerance(c, depth) == PvmOptions().plane_tol
    rng = np.random.default_rng(3)
    for sigma in (0.005, 0.01, 0.02):
        noisy = (depth * (1 + sigma * rng.standard_normal(depth.shape))).astype(np.float32)
        # 25 k triples: the MAD estimate's own spread is ~1 %; 5 % is 5 of those.
        assert depth_noise(noisy) == pytest.approx(sigma, rel=0.05)
        assert plane_tolerance(c, noisy) == pytest.approx(4 * depth_noise(noisy), rel=1e-12)
    noisy = (depth * (1 + 0.01 * rng.standard_normal(depth.shape))).astype(np.float32)
    # A step of 20 % (a discontinuity) and unknown pixels do not move the estimate.
    stepped = noisy.copy()
    stepped[:, 64:] *= 1.2
    stepped[::7, ::5] = 0
    assert depth_noise(stepped) == pytest.approx(depth_noise(noisy), rel=0.05)
    # Merging at the noise-matched tolerance: far fewer triangles than at 0.1 %; noise_tol 0 = plane_tol.
    v, f = view_mesh(c, noisy)
    v0, f0 = view_mesh(c, noisy, PvmOptions(noise_tol=0))
    assert len(f) < len(f0) / 8
    # Every vertex is still a pixel centre at its own (noisy) depth.
    pc = (v.astype(np.float64) - c.centre) @ c.cam_from_world[:3, :3].T
    u = np.round(pc[:, 0] / pc[:, 2] * c.fx + c.cx - 0.5).astype(int)
    w = np.round(pc[:, 1] / pc[:, 2] * c.fy + c.cy - 0.5).astype(int)
    np.testing.assert_allclose(pc[:, 2], noisy[w, u], rtol=1e-5)
    # Capped: wildly inconsistent depth keeps MAX_PLANE_TOL.
    assert plane_tolerance(c, depth, PvmOptions(noise_tol=1e6, plane_tol=0.0)) == 0.0  # exact: 0 noise
    wild = (depth * (1 + 0.2 * rng.random(depth.shape))).astype(np.float32)
    assert plane_tolerance(c, wild, PvmOptions(noise_tol=100)) == MAX_PLANE_TOL
    # Equirect views are never merged: plane_tol.
    eq = Camera.equirect(64, 32)
    assert plane_tolerance(eq, np.ones((32, 64), np.float32)) == PvmOptions().plane_tol
    # Too few triples: 0.
    assert depth_noise(np.ones((2, 2), np.float32)) == 0.0
    with pytest.raises(ShapeError, match="depth"):
        depth_noise(np.ones((4, 4, 1), np.float32))
    with pytest.raises(DtypeError, match="depth"):
        depth_noise(np.ones((4, 4), np.int32))
    with pytest.raises(BadValueError, match="noise_tol"):
        PvmOptions(noise_tol=-1)


def test_depth_discontinuity_is_cut():
    c = cam()
    depth = np.full((c.height, c.width), 2.0, np.float32)
    depth[:, 17:] = 3.0  # a step between columns 16 and 17
    for mb in (1, 16):
        v, f = view_mesh(c, depth, PvmOptions(max_block=mb, max_rel_jump=0.05))
        z = ((v.astype(np.float64) - c.centre) @ c.cam_from_world[:3, :3].T)[:, 2]
        zf = z[f]
        assert np.all(np.ptp(zf, axis=1) < 1e-5), "a triangle spans the step"
    # Unmerged count: every quad but the 24 rows of the cut column.
    v, f = view_mesh(c, depth, PvmOptions(max_block=1, max_rel_jump=0.05))
    assert len(f) == 2 * (32 - 1) * 24
    # A gentle slope under the threshold is kept whole.
    ramp = np.tile(np.linspace(2.0, 2.5, c.width, dtype=np.float32), (c.height, 1))
    v, f = view_mesh(c, ramp, PvmOptions(max_block=1, max_rel_jump=0.05))
    assert len(f) == 2 * 32 * 24


def test_unknown_and_infinite_depth_make_no_triangles():
    c = cam()
    depth = np.full((c.height, c.width), 2.0, np.float32)
    depth[:5] = 0
    depth[:, :4] = np.inf
    v, f = view_mesh(c, depth, PvmOptions(max_block=1))
    assert len(f) == 2 * (32 - 4) * (24 - 5)
    assert np.all(np.isfinite(v))


def test_equirect_view_mesh_ray_distance():
    c = Camera.equirect(32, 16)
    depth = np.full((16, 32), 1.5, np.float32)  # a sphere of radius 1.5 around the camera
    v, f = view_mesh(c, depth)
    np.testing.assert_allclose(np.linalg.norm(v - c.centre, axis=1), 1.5, rtol=1e-5)
    assert len(f) == 2 * 31 * 15  # no merging for equirect


def two_plane_scene():
    """Two cameras looking at a floor and a box-like step: depth rendered analytically."""
    cams, depths = {}, {}
    for i, eye in enumerate([(-0.6, -1.5, -3.0), (0.7, -1.2, -2.8)]):
        c = Camera.pinhole(48, 36, 40.0, 40.0, 24.0, 18.0, look_at(eye, (0.0, 0.0, 0.0), up=(0.0, -1.0, 0.0)))
        x, y = c.pixel_grid()
        r = c.rays_in_cam(x, y) @ c.world_from_cam[:3, :3].T  # world ray directions (z = 1 in cam)
        o = c.centre
        with np.errstate(divide="ignore", invalid="ignore"):
            t_floor = (0.0 - o[1]) / r[..., 1]      # floor y = 0
            t_wall = (0.6 - o[2]) / r[..., 2]       # wall z = 0.6
        t = np.where((t_floor > 0) & ((t_floor < t_wall) | ~(t_wall > 0)), t_floor, t_wall)
        t = np.where(np.isfinite(t) & (t > 0) & (t < 50), t, 0)
        cams[f"v{i}"] = c
        depths[f"v{i}"] = t.astype(np.float32)  # t is the z-depth (rays have z = 1 in the camera)
    return cams, depths


@pytest.mark.parametrize("clip", ["all", "large"])
def test_tiles_reassemble_the_pvm_and_lie_in_their_cells(tmp_path, clip):
    cams, depths = two_plane_scene()
    opts = PvmOptions(coarse=4, sub=4, clip=clip)
    t = build_tiles(cams, depths, opts)
    assert t.num_tiles > 1 and len(t.pvm_faces) > 0
    if clip == "large":
        # Every PVM face in one tile: the merged blocks (16 quads) here lie within the coarse cells
        # next to their centroid's.
        assert np.array_equal(np.sort(t.face_source), np.arange(len(t.pvm_faces)))
    # Every PVM face is covered by its pieces: the areas add up (slivers < 1e-7 of a face dropped;
    # float32 vertices of cut points: 1e-4 relative).
    a_pvm = areas(t.pvm_vertices, t.pvm_faces)
    a_pieces = np.bincount(t.face_source, weights=areas(t.vertices, t.faces), minlength=len(a_pvm))
    np.testing.assert_allclose(a_pieces, a_pvm, rtol=1e-4, atol=1e-9)
    # Same triangle set: uncut pieces are the PVM faces themselves.
    assert set(np.unique(t.face_source)) == set(range(len(t.pvm_faces)))
    # Clipping keeps each piece's orientation (counter-clockwise seen from its camera).
    n_piece = tri_normals(t.vertices.astype(np.float64), t.faces)
    n_src = tri_normals(t.pvm_vertices.astype(np.float64), t.pvm_faces)[t.face_source]
    big = np.linalg.norm(n_piece, axis=1) > 1e-6 * np.linalg.norm(n_src, axis=1)
    assert np.all(np.einsum("ij,ij->i", n_piece[big], n_src[big]) > 0)
    ext = (t.pvm_vertices.max(0) - t.pvm_vertices.min(0)).max()
    for k in range(t.num_tiles):
        tv, tf = t.tile(k)
        assert len(tf) > 0 and tf.min() >= 0 and tf.max() < len(tv)
        b = t.cell_bounds(k)
        eps = 1e-5 * ext  # float32 rounding of a cut point exactly on a cell face
        f0, f1 = t.face_offsets[k], t.face_offsets[k + 1]
        if clip == "all":
            assert np.all(tv >= b[0] - eps) and np.all(tv <= b[1] + eps)
        else:
            # A whole face: its centroid in the tile's cell, its vertices within the coarse cells
            # next to the cell's coarse cell; the vertices are the PVM face's own.
            cen = tv[tf].astype(np.float64).mean(1)
            assert np.all(cen >= b[0] - eps) and np.all(cen <= b[1] + eps)
            side = opts.sub * t.cell  # a coarse cell
            c0 = t.origin + (t.tile_cell[k] // opts.sub) * side
            inner = (t.tile_cell[k] // opts.sub > 0) & (t.tile_cell[k] // opts.sub < opts.coarse - 1)
            lo, hi = np.where(inner, c0 - side, -np.inf), np.where(inner, c0 + 2 * side, np.inf)
            assert np.all(tv >= lo - eps) and np.all(tv <= hi + eps)
            np.testing.assert_array_equal(tv[tf], t.pvm_vertices[t.pvm_faces[t.face_source[f0:f1]]])
        np.testing.assert_allclose(t.tile_bounds[k], np.stack([tv.min(0), tv.max(0)]))
        src = t.face_source[f0:f1]
        assert np.all(t.pvm_face_view[src] == t.tile_view[k])
    # Sorted by coarse cell, fine cell, view; the coarse lookup covers every tile exactly once.
    cc = t.tile_cell // opts.sub
    cid = (cc[:, 2] * opts.coarse + cc[:, 1]) * opts.coarse + cc[:, 0]
    assert np.all(np.diff(cid) >= 0)
    assert t.coarse_offsets[0] == 0 and t.coarse_offsets[-1] == t.num_tiles
    for c in np.unique(cid)[:5]:
        cx, cy, cz = c % 4, (c // 4) % 4, c // 16
        r = t.coarse_tiles(cx, cy, cz)
        assert np.all(cid[r.start:r.stop] == c) and len(r) == int((cid == c).sum())
    # Round trip through the cache file.
    p = t.save(tmp_path / "tiles.npz")
    u = PvmTiles.load(p)
    assert u.views == t.views and u.coarse == 4 and u.sub == 4
    for name in ("vertices", "faces", "face_offsets", "tile_view", "tile_cell", "coarse_offsets", "pvm_faces"):
        np.testing.assert_array_equal(getattr(u, name), getattr(t, name))


def test_grid_cells_are_cubic_and_cover_a_flat_scene():
    # A flat scene (10 x 0.5 x 4): the fine cells are cubes of the largest extent / (coarse * sub)
    # (the grid was per axis: 0.5 / 128 tall cells that noisy triangles crossed several times).
    rng = np.random.default_rng(0)
    v = (rng.random((500, 3)) * [10.0, 0.5, 4.0] + [-3.0, 1.0, 2.0]).astype(np.float32)
    origin, cell = grid_bounds(v, 32, 4)
    v64 = v.astype(np.float64)
    side = float((v64.max(0) - v64.min(0)).max()) * (1 + 2e-4)  # padded by 1e-4 of it on each side
    np.testing.assert_allclose(cell, side / 128, rtol=1e-12)
    # Centred on the bounds, covering every vertex with the padding along the longest axis.
    np.testing.assert_allclose(origin + 64 * cell, (v64.min(0) + v64.max(0)) / 2, rtol=1e-12)
    assert np.all(v >= origin) and np.all(v <= origin + 128 * cell)
    assert v[:, 0].min() - origin[0] == pytest.approx(1e-4 * side / (1 + 2e-4), rel=1e-6)
    with pytest.raises(BadValueError, match="empty"):
        grid_bounds(np.zeros((0, 3), np.float32), 32, 4)
    with pytest.raises(BadValueError, match="one point"):
        grid_bounds(np.ones((3, 3), np.float32), 32, 4)


@pytest.mark.parametrize("clip", ["all", "large"])
def test_same_result_for_any_thread_count(clip):
    cams, depths = two_plane_scene()
    out = []
    for n in (1, 2):
        _core.set_num_threads(n)
        try:
            t = build_tiles(cams, depths, PvmOptions(coarse=8, sub=4, max_block=4, clip=clip))
        finally:
            _core.set_num_threads(0)
        out.append(t)
    for name in ("vertices", "faces", "face_source", "face_offsets", "tile_view", "pvm_faces"):
        np.testing.assert_array_equal(getattr(out[0], name), getattr(out[1], name))


def test_slice_single_triangle_hand_checked():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    tri, view0 = np.array([[0, 1, 2]], np.int32), np.zeros(1, np.int32)
    r = _core.pvm_slice(v, tri, view0, 1, [0.0, 0.0, 0.0], [0.25, 0.25, 0.25], 1, 4, clip_all=True)
    # The triangle x + y <= 1 in z = 0 meets the 10 cells with i + j <= 3 of a 4 x 4 x 4 grid.
    assert len(r["keys"]) == 10
    a = areas(r["vertices"], r["faces"]).sum()
    assert a == pytest.approx(0.5, rel=1e-6)
    # Not clipping every crossing triangle (the default): it lies in the one coarse cell, so it
    # stays whole, in the fine cell of its centroid (1/3, 1/3, 0): (1, 1, 0), key (0 * 4 + 1) * 4 + 1.
    r = _core.pvm_slice(v, tri, view0, 1, [0.0, 0.0, 0.0], [0.25, 0.25, 0.25], 1, 4)
    assert r["keys"].tolist() == [5] and r["faces"].tolist() == [[0, 1, 2]]
    np.testing.assert_array_equal(r["vertices"], v)
    np.testing.assert_array_equal(r["bounds"][0], [[0, 0, 0], [1, 1, 0]])


@pytest.mark.parametrize("xs, cells", [
    ((0.5, 2.5), [1]),           # centroid x 1.17 (cell 1), x cells 0 .. 2: within the next coarse cells
    ((0.0, 3.0), [0, 1, 2]),     # centroid x 1 (cell 1), x cells 0 .. 3 (x = 3 on its face: no area there)
    ((0.2, 3.5), [0, 1, 2, 3]),  # centroid x 1.3 (cell 1), x cells 0 .. 3
])
def test_slice_keeps_triangles_whole(xs, cells):
    """sub 1 (fine = coarse cells of size 1): a long thin triangle along x lies in the tile of its
    centroid's cell when it lies within one coarse cell of it; when not, it is in the tile of every
    cell it has area in, whole each time (no new vertices, so no T-junction with its neighbours);
    clip_all cuts it into pieces whose areas add up to the triangle's."""
    a, b = xs
    v = np.array([[a, 0.1, 0.1], [b, 0.1, 0.1], [a, 0.2, 0.1]], np.float32)
    tri, view0 = np.array([[0, 1, 2]], np.int32), np.zeros(1, np.int32)
    r = _core.pvm_slice(v, tri, view0, 1, [0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 8, 1)
    assert r["keys"].tolist() == cells and (r["face_source"] == 0).all()
    assert r["faces"].tolist() == [[3 * i, 3 * i + 1, 3 * i + 2] for i in range(len(cells))]
    np.testing.assert_array_equal(r["vertices"], np.tile(v, (len(cells), 1)))
    # A tile's bounds: the triangle's, for a copy cut to its cell (the renderer draws no more).
    for i, cx in enumerate(cells):
        x0, x1 = (a, b) if len(cells) == 1 else (max(a, cx), min(b, cx + 1))
        np.testing.assert_allclose(r["bounds"][i], [[x0, 0.1, 0.1], [x1, 0.2, 0.1]], rtol=0, atol=1e-7)
    c = _core.pvm_slice(v, tri, view0, 1, [0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 8, 1, clip_all=True)
    assert c["keys"].tolist() == ([0, 1, 2] if a < 1 and b < 3 else cells)
    assert areas(c["vertices"], c["faces"]).sum() == pytest.approx(areas(v, tri)[0], rel=1e-6)


def test_bad_input():
    d = np.ones((4, 4), np.float32)
    with pytest.raises(DtypeError, match="depth"):
        _core.pvm_triangulate(d.astype(np.float64), None)
    with pytest.raises(ShapeError, match="2 x 2"):
        _core.pvm_triangulate(np.ones((1, 4), np.float32), None)
    with pytest.raises(ShapeError, match="plane_field"):
        _core.pvm_triangulate(d, np.ones((3, 4), np.float32))
    with pytest.raises(BadValueError, match="max_block"):
        _core.pvm_triangulate(d, None, 0.03, 1e-3, 3)
    with pytest.raises(BadValueError, match="max_rel_jump"):
        _core.pvm_triangulate(d, None, -1.0)
    v = np.zeros((3, 3), np.float32)
    f = np.array([[0, 1, 3]], np.int32)
    with pytest.raises(BadValueError, match="out of range"):
        _core.pvm_slice(v, f, np.zeros(1, np.int32), 1, [0, 0, 0], [1, 1, 1])
    with pytest.raises(BadValueError, match="face_view"):
        _core.pvm_slice(v, np.array([[0, 1, 2]], np.int32), np.ones(1, np.int32), 1, [0, 0, 0], [1, 1, 1])
    with pytest.raises(BadValueError, match="empty bounds"):
        _core.pvm_slice(v, np.array([[0, 1, 2]], np.int32), np.zeros(1, np.int32), 1, [0, 0, 0], [0, 1, 1])
    with pytest.raises(ShapeError, match="face_view"):
        _core.pvm_slice(v, np.array([[0, 1, 2]], np.int32), np.zeros(2, np.int32), 1, [0, 0, 0], [1, 1, 1])
    c = cam()
    with pytest.raises(ShapeError, match="match the camera"):
        view_mesh(c, np.ones((3, 3), np.float32))
    with pytest.raises(DtypeError):
        view_mesh("cam", np.ones((3, 3), np.float32))
    with pytest.raises(BadValueError, match="without depth"):
        build_tiles({"a": c}, {})
    with pytest.raises(BadValueError, match="empty"):
        build_tiles({"a": c}, {"a": np.zeros((c.height, c.width), np.float32)})
    with pytest.raises(BadValueError, match="no views"):
        build_tiles({}, {})
    with pytest.raises(BadValueError, match="power of two"):
        PvmOptions(max_block=6)
    with pytest.raises(BadValueError, match="max_rel_jump"):
        PvmOptions(max_rel_jump=0)
    with pytest.raises(BadValueError, match="clip: expected one of large, all"):
        PvmOptions(clip=True)


def test_snap_depth_hand_checked():
    d = np.array([[1.0, 1.0, 1.0, 0.0, np.inf, 1.0]], np.float32)
    m = np.array([[1.01, 1.03, 0.0, 1.0, 1.0, np.nan]], np.float32)
    out = snap_depth(d, m, 0.02)
    # within 0.02 -> the mesh's; 0.03 away -> its own; no surface in either -> its own (0 stays 0).
    np.testing.assert_array_equal(out, np.array([[1.01, 1.0, 1.0, 0.0, np.inf, 1.0]], np.float32))
    assert out.dtype == np.float32 and snap_depth(d, m, 0.0)[0, 0] == 1.0  # 0: only equal depths


def test_view_mesh_snaps_to_the_mesh_depth_and_keeps_what_departs():
    """A noisy plane at z = 2 with a box 0.5 in front that the global mesh lacks: snapped, the
    plane's vertices lie on the mesh's plane exactly, the box keeps its own depth, and the merge
    tolerance is still the noisy depth's (no more triangles than unsnapped)."""
    c = cam(64, 48)
    rng = np.random.default_rng(0)
    depth = (2.0 * (1 + 0.004 * rng.standard_normal((c.height, c.width)))).astype(np.float32)
    depth[10:20, 10:20] = 1.5
    mesh = np.full_like(depth, 2.0)
    v0, f0 = view_mesh(c, depth)
    v, f = view_mesh(c, depth, mesh_depth=mesh, snap=0.05)
    zc = v[:, 2]  # the camera sits at the origin looking along +z: world z is the depth
    on_box = np.isclose(zc, 1.5)
    assert on_box.sum() >= 4 and np.all(np.isclose(zc[~on_box], 2.0, rtol=0, atol=1e-6))
    assert np.abs(v0[:, 2] - 2.0).max() > 0.01  # unsnapped: the noise is there
    assert len(f) <= len(f0)
    # snap 0 or no mesh depth: the unsnapped mesh, bit for bit.
    for kw in ({"mesh_depth": mesh, "snap": 0.0}, {"snap": 0.05}):
        v1, f1 = view_mesh(c, depth, **kw)
        assert np.array_equal(v1, v0) and np.array_equal(f1, f0)
    # build_tiles passes them per view.
    t = build_tiles({"a": c}, {"a": depth}, mesh_depths={"a": mesh}, snap=0.05)
    assert np.array_equal(t.pvm_vertices, v) and np.array_equal(t.pvm_faces, f)
    with pytest.raises(ShapeError, match="mesh_depth"):
        view_mesh(c, depth, mesh_depth=mesh[:4], snap=0.05)
    with pytest.raises(BadValueError, match="snap"):
        view_mesh(c, depth, mesh_depth=mesh, snap=-1.0)
    with pytest.raises(BadValueError, match="mesh_snap"):
        PvmOptions(mesh_snap=-1)


def test_kernels_release_the_gil():
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from gil import runs_python_during

    rng = np.random.default_rng(3)
    depth = (2 + 0.2 * rng.random((600, 800))).astype(np.float32)  # rough: nothing merges
    _core.set_num_threads(1)
    try:
        assert runs_python_during(lambda: [_core.pvm_triangulate(depth, 1 / depth, 0.5, 1e-3, 16)
                                           for _ in range(3)]), "no Python ran during pvm_triangulate"
        # 200 k small triangles (side ~0.04 in a grid of 1/16 cells: many are clipped).
        base = rng.random((200_000, 1, 3))
        v = (base + 0.04 * rng.random((200_000, 3, 3))).reshape(-1, 3).astype(np.float32)
        f = np.arange(len(v), dtype=np.int32).reshape(-1, 3)
        fv = np.zeros(len(f), np.int32)
        assert runs_python_during(lambda: _core.pvm_slice(v, f, fv, 1, [0, 0, 0], [1 / 16] * 3, 4, 4)), \
            "no Python ran during pvm_slice"
    finally:
        _core.set_num_threads(0)


def test_pvm_reproduces_its_view_depth():
    """Ray-casting a view's PVM from its own camera gives back its depth: exactly at the vertices
    of unmerged quads, within plane_tol inside merged blocks."""
    from ibrtools.mesh import Mesh
    from ibrtools.raycast.reference import ReferenceRenderer
    from ibrtools.synth import make_scene

    scene = make_scene("objects", size=(96, 72), views=2, holdout_targets=0)
    v = scene.views[0]
    depth = v.depth
    verts, faces = view_mesh(v.camera, depth)
    d = ReferenceRenderer(Mesh(verts, faces)).render(v.camera, outputs="depth")["depth"]
    valid = np.isfinite(depth) & (depth > 0)
    both = valid & (d > 0)
    # Covered: all but pixels next to cut edges and unknown depth (a few % on this scene).
    assert both.sum() > 0.85 * valid.sum()
    # 2e-3: plane_tol (1e-3) on 1/z inside merged blocks plus float32 ray-hit rounding.
    np.testing.assert_allclose(d[both], depth[both], rtol=2e-3)
