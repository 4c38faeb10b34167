"""Texture atlas of the global mesh (python/ibrtools/hybrid/atlas.py) and its sampling kernel
(_core.sample_atlas): chart layout, baking of a plane with a known texture, bad input, thread
independence."""
import numpy as np
import pytest

from conftest import wall
from ibrtools import _core
from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.hybrid import atlas as A
from ibrtools.hybrid.globalmesh import densify, vertex_colors
from ibrtools.mesh import Mesh

pytestmark = [pytest.mark.asan]


def camera(w=64, h=64, f=64.0):
    return Camera.pinhole(w, h, f, f, w / 2, h / 2, look_at((0.0, 0.0, 0.0), (0.0, 0.0, 2.0), up=(0.0, -1.0, 0.0)))


def pattern(cam):
    """A smooth colour pattern of the image (periods of 16-32 px: resolvable at 1 texel per pixel)."""
    y, x = np.mgrid[0:cam.height, 0:cam.width] + 0.5
    return np.stack([0.5 + 0.4 * np.sin(2 * np.pi * x / 16), 0.5 + 0.4 * np.cos(2 * np.pi * y / 24),
                     0.5 + 0.3 * np.sin(2 * np.pi * (x + y) / 32)], -1).astype(np.float32)


def gbuffer(mesh, cam):
    from ibrtools.raycast.reference import ReferenceRenderer

    return ReferenceRenderer(mesh).render(cam, outputs=("depth", "prim_id", "bary"), lights=[], ambient=0.0)


def _assert_lookups_read_own_texels(mesh, lay, seed: int) -> None:
    """Bilinear lookups at random points inside every face read only texels of that face."""
    b = np.random.default_rng(seed).dirichlet((1, 1, 1), size=(len(mesh.faces), 8))
    p = np.einsum("fsk,fkc->fsc", b, lay.uv.astype(np.float64))
    x0 = np.floor(p[..., 0] - 0.5).astype(int)
    y0 = np.floor(p[..., 1] - 0.5).astype(int)
    own = np.arange(len(mesh.faces))[:, None]
    for dy in (0, 1):
        for dx in (0, 1):
            assert np.all(lay.face_of_texel[y0 + dy, x0 + dx] == own)


def test_layout_every_bilinear_lookup_inside_a_face_reads_its_own_texels():
    mesh = densify(wall(), 0.3)
    lay = A.layout(mesh, texel=0.05)
    _assert_lookups_read_own_texels(mesh, lay, seed=0)
    # Edges get at least their length in texels.
    ev = mesh.vertices[mesh.faces[:, 1]] - mesh.vertices[mesh.faces[:, 0]]
    eu = lay.uv[:, 1] - lay.uv[:, 0]
    assert np.all(np.linalg.norm(eu, axis=1) + 1e-3 >= np.linalg.norm(ev, axis=1) / 0.05)


def test_bake_plane_with_known_texture_reproduces_it():
    mesh = densify(wall(), 0.5)
    cam = camera()
    img = pattern(cam)
    depth = gbuffer(mesh, cam)["depth"].astype(np.float32)
    cams, cols, deps = {"a": cam}, {"a": img}, {"a": depth}
    texel = A.texel_size(cams, deps)
    assert texel == pytest.approx(2.0 / 64, rel=1e-3)  # depth 2, focal 64 px
    lay = A.layout(mesh, texel)
    vc, _ = vertex_colors(mesh, cams, cols, deps)
    atlas, unseen = A.bake(mesh, lay, cams, cols, deps, vc)
    assert unseen < 0.05  # texels at the wall's border project on or just outside the image edge
    gb = gbuffer(mesh, cam)
    out = _core.sample_atlas(gb["prim_id"], gb["bary"], lay.uv, atlas)
    inner = (slice(2, -2), slice(2, -2))  # the image's border pixels extrapolate (edge clamp)
    mse = float(np.mean((out[inner] - img[inner]) ** 2))
    psnr = 10 * np.log10(1.0 / mse)
    # Resampled twice (image -> texels -> image, bilinear each time, 1 texel per pixel): a
    # smoothing of at most ~1 px on patterns of period >= 16 px; measured ~38 dB. Bound 32 dB;
    # the per-vertex colour of the same mesh is far below (measured ~14 dB).
    assert psnr > 32.0
    per_vertex = _core.interpolate_vertex_attribute(gb["prim_id"], gb["bary"], mesh.faces, vc)
    assert 10 * np.log10(1.0 / np.mean((per_vertex[inner] - img[inner]) ** 2)) < psnr - 10


def test_atlas_above_the_old_cap_lays_out_bakes_and_renders():
    """An atlas of more than 2048^2 texels (docs/texture.md "Atlas"):
    512 faces at a texel of ~1/20 of the view's pixel footprint, cells of ~140 texels. It lays
    out (every bilinear lookup inside a face reads its own texels), bakes and renders back the
    view's known texture from the view itself, as the small atlas does, and its 8-bit sRGB storage
    renders within the quantisation of the float one."""
    mesh = densify(wall(), 0.25)
    cam = camera()
    img = pattern(cam)
    gb = gbuffer(mesh, cam)
    depth = gb["depth"].astype(np.float32)
    lay = A.layout(mesh, texel=0.0013)
    n_texels = lay.face_of_texel.size
    assert n_texels > 2048 * 2048 and lay.texel == 0.0013  # above the old cap, not grown
    _assert_lookups_read_own_texels(mesh, lay, seed=2)
    vc, _ = vertex_colors(mesh, {"a": cam}, {"a": img}, {"a": depth})
    atlas, unseen = A.bake(mesh, lay, {"a": cam}, {"a": img}, {"a": depth}, vc)
    assert atlas.shape == lay.face_of_texel.shape + (3,)
    assert unseen < 0.05  # texels at the wall's border project on or just outside the image edge
    out = _core.sample_atlas(gb["prim_id"], gb["bary"], lay.uv, atlas)
    inner = (slice(2, -2), slice(2, -2))
    psnr = 10 * np.log10(1.0 / float(np.mean((out[inner] - img[inner]) ** 2)))
    # Texels ~20x finer than the pixels: the texels hold the image's bilinear interpolant, and
    # the bilinear read at the pixel centres between texels 1/20 px apart returns it almost
    # exactly; measured 73 dB (per-vertex colour: 25 dB). Bound 50 dB (the small atlas of
    # test_bake_plane_with_known_texture_reproduces_it, 1 texel a pixel, gets ~38).
    assert psnr > 50.0
    per_vertex = _core.interpolate_vertex_attribute(gb["prim_id"], gb["bary"], mesh.faces, vc)
    assert 10 * np.log10(1.0 / np.mean((per_vertex[inner] - img[inner]) ** 2)) < psnr - 10
    # 8-bit sRGB storage: half an sRGB code step in linear light is <= 0.5/255 x the largest slope
    # of sRGB -> linear (2.4 / 1.055 x ((1 + 0.055) / 1.055)^1.4 = 2.27 at 1) = 0.0045; measured 0.0036.
    out8 = _core.sample_atlas(gb["prim_id"], gb["bary"], lay.uv, A.to_srgb8(atlas))
    assert np.abs(out8 - out).max() < 0.005


def test_unseen_texels_get_the_vertex_colour():
    mesh = wall()
    cam = camera()
    far = Camera.pinhole(8, 8, 8.0, 8.0, 4.0, 4.0, look_at((0.0, 0.0, 10.0), (0.0, 0.0, 20.0), up=(0.0, -1.0, 0.0)))
    lay = A.layout(mesh, 0.1)
    vc = np.full((4, 3), 0.25, np.float32)
    atlas, unseen = A.bake(mesh, lay, {"b": far}, {"b": np.ones((8, 8, 3), np.float32)},
                           {"b": np.ones((8, 8), np.float32)}, vc)
    assert unseen == 1.0
    used = lay.face_of_texel >= 0
    assert np.allclose(atlas[used], 0.25) and np.all(atlas[~used] == 0)
    assert cam.width == 64


def test_obj_uvs():
    uv = np.array([[[0.0, 0.0], [10.0, 5.0], [20.0, 10.0]]], np.float32)
    o = A.obj_uvs(uv, (10, 20))
    assert np.allclose(o[0], [[0, 1], [0.5, 0.5], [1, 0]])


def test_sample_atlas_bilinear_and_misses():
    atlas = np.zeros((2, 2, 3), np.float32)
    atlas[0, 1] = 1.0  # texel (x 1, y 0)
    uv = np.array([[[1.0, 0.5], [1.0, 0.5], [1.0, 0.5]]], np.float32)  # halfway between x-centres 0.5, 1.5
    prim = np.array([[0, -1]], np.int32)
    bary = np.full((1, 2, 2), 0.25, np.float32)
    out = _core.sample_atlas(prim, bary, uv, atlas)
    assert out.shape == (1, 2, 3)
    assert np.allclose(out[0, 0], 0.5) and np.all(out[0, 1] == 0)


def _bilinear_reference(prim, bary, uv, atlas_linear):
    """numpy: the hit face's uv at the barycentrics, read bilinearly with edge clamping."""
    ah, aw = atlas_linear.shape[:2]
    out = np.zeros(prim.shape + (3,))
    for (y, x), f in np.ndenumerate(prim):
        if f < 0:
            continue
        u, v = float(bary[y, x, 0]), float(bary[y, x, 1])
        t = uv[f].astype(np.float64)
        px, py = (1 - u - v) * t[0] + u * t[1] + v * t[2]
        fx, fy = np.clip(px - 0.5, 0, aw - 1), np.clip(py - 0.5, 0, ah - 1)
        x0, y0 = min(int(fx), aw - 1), min(int(fy), ah - 1)
        x1, y1 = min(x0 + 1, aw - 1), min(y0 + 1, ah - 1)
        ax, ay = fx - x0, fy - y0
        top = atlas_linear[y0, x0] * (1 - ax) + atlas_linear[y0, x1] * ax
        bot = atlas_linear[y1, x0] * (1 - ax) + atlas_linear[y1, x1] * ax
        out[y, x] = top * (1 - ay) + bot * ay
    return out


@pytest.mark.tsan
def test_sample_atlas_matches_a_numpy_reference_over_many_batches():
    """Random faces, misses and reads across a 300 x 200 atlas (the kernel reads in batches of
    pixels with prefetches; more pixels than a batch, misses interleaved, edges clamped)."""
    rng = np.random.default_rng(7)
    ah, aw, m = 200, 300, 50
    uv = (rng.random((m, 3, 2)) * [aw + 20, ah + 20] - 10).astype(np.float32)  # some beyond the edges
    prim = rng.integers(-1, m, (37, 41)).astype(np.int32)
    bary = rng.random((37, 41, 2)).astype(np.float32) * 0.6
    atlas = rng.random((ah, aw, 3), dtype=np.float32)
    got = _core.sample_atlas(prim, bary, uv, atlas)
    assert np.allclose(got, _bilinear_reference(prim, bary, uv, atlas), atol=2e-6)
    a8 = (rng.random((ah, aw, 4)) * 255).astype(np.uint8)
    lin = np.where(a8[..., :3] / 255.0 <= 0.04045, a8[..., :3] / 255.0 / 12.92,
                   ((a8[..., :3] / 255.0 + 0.055) / 1.055) ** 2.4)
    got8 = _core.sample_atlas(prim, bary, uv, a8)
    assert np.allclose(got8, _bilinear_reference(prim, bary, uv, lin), atol=2e-6)
    assert not got[prim < 0].any() and not got8[prim < 0].any()


@pytest.mark.tsan
def test_results_independent_of_thread_count():
    """The atlas read and the vertex-attribute interpolation split the pixels into chunks (16384
    pixels) run on the threads: the same output on 1 and 2 threads, and the same first bad pixel
    reported when several chunks hold one."""
    mesh = densify(wall(), 0.2)
    cam = camera(256, 200)  # 51200 pixels: 4 chunks
    lay = A.layout(mesh, 0.02)
    rng = np.random.default_rng(1)
    atlas = rng.random(lay.face_of_texel.shape + (3,), dtype=np.float32)
    attrib = rng.random((len(mesh.vertices), 3), dtype=np.float32)
    gb = gbuffer(mesh, cam)
    hits = np.flatnonzero(gb["prim_id"].ravel() >= 0)
    bad_faces = np.asarray(mesh.faces, np.int32).copy()
    bad_uv = lay.uv.copy()
    for p in (hits[-1], hits[len(hits) // 2]):  # hits in two chunks; the error names the first
        f = gb["prim_id"].ravel()[p]
        bad_faces[f, 2] = len(mesh.vertices)
        bad_uv[f, 1, 0] = np.nan
    first = hits[len(hits) // 2]
    where = rf"pixel \({first // cam.width}, {first % cam.width}\)"
    n = _core.get_num_threads()
    outs = []
    try:
        for threads in (1, 2):
            _core.set_num_threads(threads)
            outs.append((_core.sample_atlas(gb["prim_id"], gb["bary"], lay.uv, atlas),
                         _core.interpolate_vertex_attribute(gb["prim_id"], gb["bary"], mesh.faces, attrib)))
            with pytest.raises(BadValueError, match=where):
                _core.sample_atlas(gb["prim_id"], gb["bary"], bad_uv, atlas)
            with pytest.raises(BadValueError, match=where):
                _core.interpolate_vertex_attribute(gb["prim_id"], gb["bary"], bad_faces, attrib)
    finally:
        _core.set_num_threads(n)
    assert hits[len(hits) // 2] // 16384 != hits[-1] // 16384  # the two bad pixels in different chunks
    assert np.array_equal(outs[0][0], outs[1][0]) and np.array_equal(outs[0][1], outs[1][1])


def test_bad_input():
    with pytest.raises(BadValueError, match="no (faces|triangles)"):
        A.layout(Mesh(np.zeros((3, 3), np.float32), np.zeros((0, 3), np.int32)), 0.1)
    with pytest.raises(DtypeError):
        A.layout("mesh", 0.1)
    with pytest.raises(BadValueError, match="texel"):
        A.layout(wall(), 0.0)
    with pytest.raises(BadValueError, match="max_texels"):
        A.layout(wall(), 0.1, max_texels=0)
    with pytest.raises(BadValueError, match="max_texels"):
        A.layout(wall(), 0.1, max_texels=2 ** 30 + 1)
    with pytest.raises(BadValueError, match="more than max_texels"):
        A.layout(densify(wall(), 0.1), 0.1, max_texels=64)
    # A budget between the smallest possible cells (MIN_CELL + 1 texels a side for a pair with a
    # length) and MIN_CELL-sized ones: an error, not a layout whose texel grew to infinity.
    dense = densify(wall(), 0.1)
    n_pairs = (len(dense.faces) + 1) // 2
    with pytest.raises(BadValueError, match="more than max_texels"):
        A.layout(dense, 0.1, max_texels=A.MIN_CELL ** 2 * n_pairs + 1)
    fits = A.layout(dense, 0.1, max_texels=(A.MIN_CELL + 1) ** 2 * n_pairs)
    assert np.isfinite(fits.texel)
    lay = A.layout(wall(), 0.1)
    empty = A.AtlasLayout(lay.uv, np.zeros((0, 0), np.int32), 0.1)
    cam = camera()
    with pytest.raises(BadValueError, match="size 0"):
        A.bake(wall(), empty, {"a": cam}, {"a": pattern(cam)}, {"a": np.ones((64, 64), np.float32)},
               np.zeros((4, 3), np.float32))
    with pytest.raises(ShapeError):
        A.bake(wall(), lay, {"a": cam}, {"a": pattern(cam)}, {"a": np.ones((64, 64), np.float32)},
               np.zeros((3, 3), np.float32))
    with pytest.raises(BadValueError, match="valid depth"):
        A.texel_size({"a": cam}, {"a": np.zeros((64, 64), np.float32)})
    prim = np.zeros((2, 2), np.int32)
    bary = np.zeros((2, 2, 2), np.float32)
    uv = np.zeros((1, 3, 2), np.float32)
    with pytest.raises(ShapeError):
        _core.sample_atlas(prim, bary, uv, np.zeros((0, 0, 3), np.float32))
    with pytest.raises(ShapeError):
        _core.sample_atlas(prim, bary, uv, np.zeros((4, 4), np.float32))
    with pytest.raises(BadValueError, match="prim_id"):
        _core.sample_atlas(np.full((2, 2), 5, np.int32), bary, uv, np.zeros((4, 4, 3), np.float32))
    with pytest.raises(BadValueError, match="finite"):
        _core.sample_atlas(prim, bary, np.full((1, 3, 2), np.nan, np.float32), np.zeros((4, 4, 3), np.float32))
    # A non-finite barycentric at a hit made the texel index undefined (a crash, before the check);
    # huge finite ones are clamped to the atlas's edge.
    for bad in (np.nan, np.inf):
        b = bary.copy()
        b[1, 0, 1] = bad
        with pytest.raises(BadValueError, match=r"bary: .*pixel \(1, 0\)"):
            _core.sample_atlas(prim, b, uv, np.zeros((4, 4, 4), np.uint8))
    miss = np.full((2, 2), -1, np.int32)
    nan_bary = np.full((2, 2, 2), np.nan, np.float32)
    assert not _core.sample_atlas(miss, nan_bary, uv, np.ones((4, 4, 3), np.float32)).any()
    atlas = np.arange(48, dtype=np.float32).reshape(4, 4, 3)
    huge = _core.sample_atlas(prim, np.full((2, 2, 2), 1e30, np.float32), np.ones((1, 3, 2), np.float32) * 3, atlas)
    assert np.isfinite(huge).all() and (huge >= atlas.min()).all() and (huge <= atlas.max()).all()
    # Only the uv of the faces a pixel hits are read, so only those must be finite.
    uv2 = np.concatenate([uv, np.full((1, 3, 2), np.nan, np.float32)])
    assert np.isfinite(_core.sample_atlas(prim, bary, uv2, atlas)).all()
    with pytest.raises(BadValueError, match=r"uv: .*face 1 \(hit at pixel \(0, 1\)\)"):
        _core.sample_atlas(np.array([[0, 1], [0, 0]], np.int32), bary, uv2, atlas)
    with pytest.raises(ShapeError):
        _core.sample_atlas(prim, np.zeros((2, 3, 2), np.float32), uv, np.zeros((4, 4, 3), np.float32))


def _two_walls():
    """The wall at z = 2 (seen by camera()) and a copy at z = -2 (behind the camera)."""
    a = densify(wall(2.0), 0.3)
    b = densify(wall(-2.0), 0.3)
    return Mesh(np.concatenate([a.vertices, b.vertices]),
                np.concatenate([a.faces, b.faces + len(a.vertices)]).astype(np.int32))


def test_face_footprint_scale():
    mesh = _two_walls()
    cam = camera()  # f = 64 px, the near wall at depth 2: footprint 2 / 64 per pixel
    half = len(mesh.faces) // 2
    s = A.face_footprint_scale(mesh, {"a": cam}, texel=2.0 / 64, limits=(0.5, 8.0))
    assert s.shape == (len(mesh.faces),)
    assert np.allclose(s[:half], 1.0, rtol=1e-5)  # every near-wall centroid is at depth 2
    assert np.all(s[half:] == 8.0)  # behind the camera: no view holds it, the upper limit
    assert np.allclose(A.face_footprint_scale(mesh, {"a": cam}, texel=1.0 / 64)[:half], 2.0, rtol=1e-5)


def test_layout_face_scale_and_shelf_packing():
    mesh = _two_walls()
    half = len(mesh.faces) // 2
    scale = np.where(np.arange(len(mesh.faces)) < half, 1.0, 4.0)
    lay = A.layout(mesh, texel=0.02, face_scale=scale)
    # Each face's chart edges get at least the face's edge length in its own texels.
    ev = mesh.vertices[mesh.faces[:, 1]] - mesh.vertices[mesh.faces[:, 0]]
    eu = lay.uv[:, 1] - lay.uv[:, 0]
    assert np.all(np.linalg.norm(eu, axis=1) + 1e-3 >= np.linalg.norm(ev, axis=1) / (0.02 * scale))
    # The coarse half gets smaller charts than the fine half.
    d1, d2 = lay.uv[:, 1] - lay.uv[:, 0], lay.uv[:, 2] - lay.uv[:, 0]
    area = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    assert area[half:].max() < area[:half].min()
    # Shelf packing: cells of two sizes fill the atlas with little waste (cells cover >= 80 %).
    cells = (lay.face_of_texel >= 0).sum()
    assert cells >= 0.8 * lay.face_of_texel.size
    # Lookups inside every face still read only its own texels.
    _assert_lookups_read_own_texels(mesh, lay, seed=1)
    with pytest.raises(ShapeError):
        A.layout(mesh, 0.02, face_scale=np.ones(3))
    with pytest.raises(BadValueError, match="face_scale"):
        A.layout(mesh, 0.02, face_scale=np.zeros(len(mesh.faces)))
    with pytest.raises(DtypeError):
        A.face_footprint_scale("mesh", {"a": camera()}, 0.1)


def test_layout_places_neighbouring_faces_in_neighbouring_cells():
    mesh = densify(wall(), 0.05)  # ~3000 faces of one size: one length bin
    lay = A.layout(mesh, texel=0.01)
    cell_pos = lay.uv.mean(1)
    centre = mesh.vertices[mesh.faces].mean(1)
    # The atlas distance between the cells of the nearest surface neighbours, against random pairs.
    from scipy.spatial import cKDTree

    _, nn = cKDTree(centre).query(centre, k=2)
    near = np.linalg.norm(cell_pos - cell_pos[nn[:, 1]], axis=1)
    rng = np.random.default_rng(0)
    rand = np.linalg.norm(cell_pos - cell_pos[rng.permutation(len(centre))], axis=1)
    assert np.median(near) < 0.2 * np.median(rand)


def _numpy_texel_points(mesh, lay, normals):
    """The numpy expressions _core.texel_points replaced (bake's per-band barycentrics, einsum, norm)."""
    ys, xs = np.nonzero(lay.face_of_texel >= 0)
    face = lay.face_of_texel[ys, xs]
    p = np.stack([xs + 0.5, ys + 0.5], 1).astype(np.float64)
    t = lay.uv[face].astype(np.float64)
    d1, d2, dp = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0], p - t[:, 0]
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    b1 = (dp[:, 0] * d2[:, 1] - dp[:, 1] * d2[:, 0]) / det
    b2 = (d1[:, 0] * dp[:, 1] - d1[:, 1] * dp[:, 0]) / det
    bary = np.maximum(np.stack([1 - b1 - b2, b1, b2], 1), 0)
    bary /= bary.sum(1, keepdims=True)
    f3 = mesh.faces[face]
    pts = np.einsum("tk,tkc->tc", bary, mesh.vertices[f3].astype(np.float64))
    nrm = np.einsum("tk,tkc->tc", bary, normals[f3].astype(np.float64))
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    return (ys, xs, face), bary, pts, nrm


@pytest.mark.tsan
def test_texel_points_match_numpy_in_any_bands():
    mesh = densify(wall(), 0.25)
    rng = np.random.default_rng(5)
    mesh = Mesh((mesh.vertices + rng.normal(0, 0.02, mesh.vertices.shape)).astype(np.float32), mesh.faces)
    normals = rng.normal(0, 1, mesh.vertices.shape).astype(np.float32)
    normals[:3] = 0  # zero-length normals: divided by 1e-12, as numpy did
    lay = A.layout(mesh, texel=0.03)
    ref = _numpy_texel_points(mesh, lay, normals)
    got = A.texel_points(mesh, lay, normals)
    assert len(ref[0][0]) > 1000
    for a, b in zip(ref[0] + ref[1:], got[0] + got[1:]):
        assert np.array_equal(a, b)  # the same arithmetic in the same order: the same bits
    h = lay.face_of_texel.shape[0]
    bands = [A.texel_points(mesh, lay, normals, slice(lo, min(h, lo + 7))) for lo in range(0, h, 7)]
    assert np.array_equal(np.concatenate([b[0][0] for b in bands]), ref[0][0])
    assert np.array_equal(np.concatenate([b[2] for b in bands]), ref[2])


def test_texel_points_bad_input():
    mesh = densify(wall(), 0.5)
    lay = A.layout(mesh, texel=0.1)
    nrm = np.zeros(mesh.vertices.shape, np.float32)
    fot = lay.face_of_texel.copy()
    fot[0, 0] = len(mesh.faces)
    with pytest.raises(BadValueError, match="face_of_texel: face"):
        A.texel_points(mesh, A.AtlasLayout(lay.uv, fot, lay.texel), nrm)
    with pytest.raises(BadValueError, match="faces: vertex"):
        A.texel_points(Mesh(mesh.vertices[:3], mesh.faces), lay, nrm[:3])
    with pytest.raises(ShapeError, match="normals"):
        A.texel_points(mesh, lay, nrm[:-1])
    with pytest.raises(BadValueError, match="row0"):
        _core.texel_points(fot, -1, lay.uv, mesh.vertices, mesh.faces, nrm)
