"""Soft shadows from synthesised shadow maps (ibrtools.depthwarp.shadows; docs/shadows.md)."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import synth
from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.raycast.reference import ReferenceRenderer
from ibrtools.depthwarp.shadows import AreaLight, shadow_map_visibility, soft_shadows

pytestmark = [pytest.mark.asan, pytest.mark.kernel]

try:
    from ibrtools.depthwarp.core import warp_depth  # noqa: F401
    HAVE_WARP = True
except ImportError:
    HAVE_WARP = False

# A 16 x 16 ground at y = 0 (object 0) and a 2 x 0.2 x 2 slab floating at y = 2 (object 1).
GROUND = synth.ground_grid(16.0, cells=4, object_id=0)


def _renderer(occluder: bool = True) -> ReferenceRenderer:
    parts = [GROUND] + ([synth.boxes([(0, 2, 0)], [(2, 0.2, 2)], object_ids=1)] if occluder else [])
    return ReferenceRenderer(synth.merge(parts, [], None))


def _view() -> Camera:
    return Camera.from_fov(96, 72, 60.0, look_at((0, 9, -9), (0, 0, 0)))


def _light(size: float) -> AreaLight:
    # 6 above the ground looking straight down; up = +z so the light's x axis is world -x.
    return AreaLight((0, 6, 0), (0, 0, 0), (size, size), up=(0, 0, 1), fov_deg=110.0)


@pytest.fixture(scope="module")
def scene():
    r = _renderer()
    depth = r.render(_view(), outputs=("depth",), lights=[])["depth"]
    return r, depth


def test_samples_stratified():
    light = _light(2.0)
    p = light.samples(16, seed=3)
    assert p.shape == (16, 3) and p.dtype == np.float64
    np.testing.assert_allclose(p[:, 1], 6.0, atol=1e-12)  # in the light's plane
    # One sample in each 0.5 x 0.5 stratum of the 2 x 2 rectangle.
    cells = {(int(np.floor((x + 1) / 0.5)), int(np.floor((z + 1) / 0.5))) for x, _, z in p}
    assert len(cells) == 16
    assert np.all(np.abs(p[:, [0, 2]]) <= 1.0)
    np.testing.assert_array_equal(light.samples(16, seed=3), p)  # deterministic
    centres = light.samples(4, seed=None)
    np.testing.assert_allclose(np.sort(np.abs(centres[:, 0])), [0.5] * 4, atol=1e-12)
    # A point light: every sample at the centre.
    np.testing.assert_array_equal(_light(0.0).samples(8), np.tile([0.0, 6.0, 0.0], (8, 1)))
    assert light.samples(6).shape == (6, 3)  # 2 x 3 strata


def test_unoccluded_plane_fully_lit():
    r = _renderer(occluder=False)
    depth = r.render(_view(), outputs=("depth",), lights=[])["depth"]
    assert (depth > 0).mean() > 0.5  # the ground fills most of the view
    methods = ["render", "trace"] + (["warp"] if HAVE_WARP else [])
    for m in methods:
        res = soft_shadows(r, _light(2.0), _view(), depth, samples=16, resolution=128, method=m, layers=1)
        assert res.visibility.min() == 1.0, m  # no self-shadowing (bias) and no false occluder


def test_point_light_hard_shadows_match_embree(scene):
    r, depth = scene
    trace = soft_shadows(r, _light(0.0), _view(), depth, samples=4, method="trace").visibility
    assert set(np.unique(trace)) == {0.0, 1.0}  # all samples at one point: hard
    shadowed = trace == 0
    assert 0.02 < shadowed.mean() < 0.5
    methods = ["render"] + (["warp"] if HAVE_WARP else [])
    for m in methods:
        vis = soft_shadows(r, _light(0.0), _view(), depth, samples=4, resolution=512, method=m,
                           layers=1).visibility
        assert set(np.unique(vis)) <= {0.0, 1.0}
        # Shadow-map texels (512 over 110 deg at 6 m: ~3 cm on the ground) against exact rays:
        # only pixels on the shadow's outline may differ (the outline is ~ 4 * 35 = 140 pixels).
        differ = vis != trace
        assert differ.sum() <= 0.3 * shadowed.sum(), (m, differ.sum(), shadowed.sum())


def test_penumbra_grows_with_light_size(scene):
    r, depth = scene
    widths = {}
    for m in ["trace", "render"] + (["warp"] if HAVE_WARP else []):
        pen = []
        for size in (0.5, 2.0):
            vis = soft_shadows(r, _light(size), _view(), depth, samples=16, resolution=256, method=m,
                               layers=1, seed=1).visibility
            pen.append(int(((vis > 0) & (vis < 1)).sum()))
        widths[m] = pen
        assert pen[1] > 1.5 * pen[0] > 0, widths
    # The umbra shrinks: fewer fully shadowed pixels with the larger light.
    small = soft_shadows(r, _light(0.5), _view(), depth, samples=16, method="trace").visibility
    large = soft_shadows(r, _light(2.0), _view(), depth, samples=16, method="trace").visibility
    assert (large == 0).sum() < (small == 0).sum()


@pytest.mark.skipif(not HAVE_WARP, reason="ibrtools.depthwarp.core not built yet")
def test_warp_close_to_render(scene):
    r, depth = scene
    light = _light(1.0)
    ref = soft_shadows(r, light, _view(), depth, samples=16, resolution=256, method="render").visibility
    warp = soft_shadows(r, light, _view(), depth, samples=16, resolution=256, method="warp", layers=2,
                        ground_object=0)
    # Warped maps differ from rendered ones by at most a texel at depth edges: mean visibility
    # error well under one sample in 16 (0.0625).
    assert np.abs(warp.visibility - ref).mean() < 0.01
    # With umbra culling towards the samples while peeling: the same quality bound.
    umb = soft_shadows(r, light, _view(), depth, samples=16, resolution=256, method="warp", layers=2,
                       ground_object=0, umbra=True)
    assert np.abs(umb.visibility - ref).mean() < 0.01
    assert set(warp.times_ms) >= {"layers", "maps", "shade", "total"}


def test_no_surface_pixels_are_one(scene):
    r, depth = scene
    d = depth.copy()
    d[:5] = 0
    vis = soft_shadows(r, _light(1.0), _view(), d, samples=4, method="trace").visibility
    assert (vis[:5] == 1).all()


def test_bad_inputs(scene):
    r, depth = scene
    view, light = _view(), _light(1.0)
    with pytest.raises(DtypeError, match="renderer"):
        soft_shadows("r", light, view, depth)
    with pytest.raises(DtypeError, match="light"):
        soft_shadows(r, (0, 6, 0), view, depth)
    with pytest.raises(DtypeError, match="view"):
        soft_shadows(r, light, view.to_core(), depth)
    with pytest.raises(DtypeError, match="view_depth"):
        soft_shadows(r, light, view, list(depth))
    with pytest.raises(ShapeError, match="view_depth"):
        soft_shadows(r, light, view, depth[:-1], method="trace")
    with pytest.raises(DtypeError, match="view_depth"):
        soft_shadows(r, light, view, depth.astype(np.float64), method="render", resolution=16)
    with pytest.raises(BadValueError, match="method"):
        soft_shadows(r, light, view, depth, method="raster")
    with pytest.raises(DtypeError, match="umbra"):
        soft_shadows(r, light, view, depth, umbra="yes")
    with pytest.raises(BadValueError, match="samples"):
        soft_shadows(r, light, view, depth, samples=0)
    with pytest.raises(BadValueError, match="resolution"):
        soft_shadows(r, light, view, depth, resolution=0)
    with pytest.raises(BadValueError, match="bias"):
        soft_shadows(r, light, view, depth, bias=-1.0)
    with pytest.raises(BadValueError, match="light size"):
        AreaLight((0, 6, 0), (0, 0, 0), (-1, 1))
    with pytest.raises(BadValueError, match="coincide"):
        AreaLight((0, 6, 0), (0, 6, 0))
    with pytest.raises(BadValueError, match="parallel"):
        AreaLight((0, 6, 0), (0, 0, 0))  # default up (0, 1, 0) along the light's direction
    with pytest.raises(BadValueError, match="fov_deg"):
        AreaLight((0, 6, 0), (0, 0, 0), up=(0, 0, 1), fov_deg=180)
    with pytest.raises(ShapeError, match="light center"):
        AreaLight((0, 6), (0, 0, 0))
    cams = [light.camera(8)]
    with pytest.raises(ShapeError, match="maps"):
        shadow_map_visibility(view, depth, np.zeros((2, 8, 8), np.float32), cams)
    with pytest.raises(ShapeError, match="cameras"):
        shadow_map_visibility(view, depth, np.zeros((1, 8, 9), np.float32), cams)
    with pytest.raises(BadValueError, match="pinhole"):
        shadow_map_visibility(view, depth, np.zeros((1, 8, 8), np.float32),
                              [Camera.equirect(8, 8, cam_from_world=np.eye(4))])
    from ibrtools import _core
    with pytest.raises(BadValueError, match="light_positions"):
        _core.OcclusionScene(r.mesh.vertices, r.mesh.faces).visibility(
            depth, view.to_core(), np.full((1, 3), np.nan), 1e-4)


def test_gil_released_during_shadow_kernels(scene):
    """Structural (kernels release the GIL): while the shadow-map test and the traced reference run in another
    thread, this thread executes Python code (negative control: tests/gil.py)."""
    from gil import runs_python_during

    from ibrtools import _core
    r, depth = scene
    view, light = _view(), _light(1.0)
    cams = [light.camera(64, p) for p in light.samples(64)]
    maps = np.stack([r.render(c, outputs=("depth",), lights=[])["depth"] for c in cams])
    core_cams = [c.to_core() for c in cams]
    occ = _core.OcclusionScene(r.mesh.vertices, r.mesh.faces)
    pos = light.samples(64)
    _core.set_num_threads(1)  # leave a core for this thread
    try:
        for work in (lambda: [_core.shadow_map_visibility(depth, view.to_core(), maps, core_cams, 0.5, 1.0)
                              for _ in range(20)],
                     lambda: [occ.visibility(depth, view.to_core(), pos, 1e-4) for _ in range(5)]):
            assert runs_python_during(work), "no Python ran during the kernel (or it lasted < 20 ms)"
    finally:
        _core.set_num_threads(0)  # back to all cores (the default)


def test_equirect_view():
    # Surface points come from RayInCam * depth for any camera model: an equirect view of the
    # unoccluded ground is fully lit, and the slab's shadow appears in it for traced and rendered maps.
    view = Camera.equirect(64, 32, cam_from_world=look_at((0, 9, -9), (0, 0, 0)))
    lit = _renderer(occluder=False)
    depth = lit.render(view, outputs=("depth",), lights=[])["depth"]
    for m in ("trace", "render"):
        assert soft_shadows(lit, _light(1.0), view, depth, samples=4, resolution=128, method=m).visibility.min() == 1.0
    r = _renderer()
    depth = r.render(view, outputs=("depth",), lights=[])["depth"]
    tr = soft_shadows(r, _light(0.0), view, depth, samples=1, method="trace").visibility
    rd = soft_shadows(r, _light(0.0), view, depth, samples=1, resolution=512, method="render").visibility
    assert (tr == 0).sum() > 0
    assert (tr != rd).sum() <= 0.3 * (tr == 0).sum()
