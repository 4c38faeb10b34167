"""Warping-based occlusion culling (ibrtools.depthwarp.culling; docs/culling.md)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ibrtools import _core, synth
from ibrtools.camera import Camera, look_at
from ibrtools.depthwarp.culling import CullResult, cull_objects, object_boxes
from ibrtools.errors import BadValueError, DtypeError, NotBuiltError, ShapeError
from ibrtools.raycast.reference import ReferenceRenderer

pytestmark = [pytest.mark.asan, pytest.mark.kernel]

W, H = 64, 48


def _camera() -> Camera:
    # At the origin looking down +z (world = camera axes: x right, y down).
    return Camera.pinhole(W, H, 40.0, 40.0, W / 2, H / 2, np.eye(4))


def _mesh(centers, sizes):
    part = synth.boxes(centers, sizes, object_ids=np.arange(len(centers)))
    return synth.merge([part], [], None)


# Object 0: a wall 10 x 10 at z = 5 (drawn into the depth below as a constant 5: it covers the
# whole 90 deg-ish view at 40 px focal length: |x| <= 5 at z = 5 spans +-40 px > W / 2);
# 1: a box fully behind the wall (z 9.5..10.5); 2: a box in front of it (z 2.5..3.5);
# 3: a box behind the camera; 4: a box far to the side (outside the left plane);
# 5: a box around the camera centre (crosses the near plane).
CENTERS = [(0, 0, 5), (0.3, -0.2, 10), (0.2, 0.1, 3), (0, 0, -4), (-40, 0, 5), (0, 0, 0.2)]
SIZES = [(10, 10, 0.02), (1, 1, 1), (1, 1, 1), (1, 1, 1), (1, 1, 1), (1, 1, 1)]


@pytest.fixture(scope="module")
def wall_scene():
    mesh = _mesh(CENTERS, SIZES)
    depth = np.full((H, W), 5.0 - 0.01, np.float32)  # the wall's front face
    return mesh, object_boxes(mesh), depth


def test_object_boxes_exact():
    mesh = _mesh([(1, 2, 3), (-1, 0, 5)], [(2, 4, 6), (1, 1, 1)])
    b = object_boxes(mesh)
    assert b.shape == (2, 2, 3) and b.dtype == np.float32
    # Axis-aligned boxes (yaw 0): the corners are exact up to float32 rounding of the vertices.
    np.testing.assert_allclose(b[0], [[0, 0, 0], [2, 4, 6]], atol=1e-6)
    np.testing.assert_allclose(b[1], [[-1.5, -0.5, 4.5], [-0.5, 0.5, 5.5]], atol=1e-6)


def test_empty_object_id_is_culled():
    mesh = _mesh([(0, 0, 5)], [(1, 1, 1)])
    mesh.object_ids[:] = 1  # object 0 has no face
    b = object_boxes(mesh)
    assert np.all(np.isinf(b[0])) and np.isfinite(b[1]).all()
    res = cull_objects(np.zeros((H, W), np.float32), None, _camera(), b)
    assert res.frustum_culled[0] and res.visible[1]


def test_wall_culls_behind_keeps_front(wall_scene):
    _, boxes, depth = wall_scene
    res = cull_objects(depth, np.zeros((H, W), bool), _camera(), boxes)
    assert isinstance(res, CullResult)
    assert res.occlusion_culled.tolist() == [False, True, False, False, False, False]
    assert res.frustum_culled.tolist() == [False, False, False, True, True, False]
    assert res.visible.tolist() == [True, False, True, False, False, True]
    # Disjoint sets, and the drawn set is their complement.
    assert not (res.frustum_culled & res.occlusion_culled).any()
    np.testing.assert_array_equal(res.visible, ~(res.frustum_culled | res.occlusion_culled))
    assert set(res.times_ms) >= {"nbuffer", "test"}
    assert res.stats["near"] == 1


def test_holes_never_cull(wall_scene):
    _, boxes, depth = wall_scene
    res = cull_objects(depth, np.ones((H, W), bool), _camera(), boxes)
    assert not res.occlusion_culled.any()
    # Empty pixels (depth 0) are far too, even when not flagged as holes.
    res = cull_objects(np.zeros((H, W), np.float32), None, _camera(), boxes)
    assert not res.occlusion_culled.any()


def test_one_hole_pixel_under_the_box_keeps_it(wall_scene):
    _, boxes, depth = wall_scene
    from ibrtools._core import cull_project_boxes
    state, rect, _ = cull_project_boxes(boxes, _camera().to_core(), 1e-3, 1)
    x0, y0, x1, y1 = rect[1]
    hole = np.zeros((H, W), bool)
    hole[(y0 + y1) // 2, x1 - 1] = True  # one pixel inside the (padded) rectangle
    assert not cull_objects(depth, hole, _camera(), boxes).occlusion_culled[1]
    hole[:] = False
    # Well outside it: no effect. (The Y-map answers for blocks of 2^mip_levels pixels and
    # N-buffer tiles, so a hole right beside the rectangle may be counted: conservative.)
    hole[y1 + 8, x1 + 8] = True
    assert cull_objects(depth, hole, _camera(), boxes).occlusion_culled[1]
    assert cull_objects(depth, hole, _camera(), boxes, mip_levels=0).occlusion_culled[1]


def test_rectangles_cover_the_projection():
    # A unit box at z 9.5..10.5 centred on the axis: corners project to x = 32 +- 40 * 0.5 / 9.5.
    boxes = np.array([[[-0.5, -0.5, 9.5], [0.5, 0.5, 10.5]]], np.float32)
    state, rect, min_z = _core.cull_project_boxes(boxes, _camera().to_core(), 1e-3, 0)
    e = 40 * 0.5 / 9.5
    assert state[0] == 2
    assert rect[0].tolist() == [int(np.floor(32 - e)), int(np.floor(24 - e)), int(np.floor(32 + e)) + 1,
                                int(np.floor(24 + e)) + 1]
    assert min_z[0] <= 9.5 and min_z[0] == np.float32(9.5)
    # pad grows it by one pixel on every side.
    _, rect1, _ = _core.cull_project_boxes(boxes, _camera().to_core(), 1e-3, 1)
    assert (rect1[0] - rect[0]).tolist() == [-1, -1, 1, 1]


def test_box_touching_the_occluder_depth_is_kept():
    # min z equal to the max depth: not strictly behind, so kept.
    boxes = np.array([[[-0.5, -0.5, 5.0], [0.5, 0.5, 6.0]]], np.float32)
    res = cull_objects(np.full((H, W), 5.0, np.float32), None, _camera(), boxes)
    assert res.visible[0]
    res = cull_objects(np.full((H, W), 4.99, np.float32), None, _camera(), boxes)
    assert res.occlusion_culled[0]


def test_crowd_against_reference():
    """The crowd preset, small: occlusion map = the reference depth of the same frame (a perfect
    warp) and, when the depth warp is built, the warp of the previous path frame. Target: no
    falsely culled object of more than 2 pixels."""
    mesh, built = synth.build_mesh("crowd", size=(160, 90), path_frames=48)
    boxes = object_boxes(mesh)
    ref = ReferenceRenderer(mesh)
    cams = built.paths["orbit"]
    prev, cam = cams[0], cams[1]
    out = ref.render(cam, outputs=("depth", "object_id"), lights=[])
    ids = ref.visible_objects(cam)
    counts = np.bincount(out["object_id"][out["object_id"] >= 0], minlength=len(boxes))
    res = cull_objects(out["depth"], None, cam, boxes)
    ev = res.evaluate(ids, counts)
    assert ev["falsely_culled_large"] == 0, ev["false_ids"]
    assert ev["drawn"] >= ev["ideal"] - ev["falsely_culled"]
    # The crowd hides part of itself: 246 of 3001 boxes with exact rectangle maxima at 160 x 90,
    # 63 with the Y-map's (4-pixel blocks are coarse for boxes of a few pixels).
    assert ev["occlusion_culled"] > 30
    assert 0 < ev["culled_fraction"] <= ev["ideal_culled_fraction"] + 1e-9
    try:
        from ibrtools.depthwarp.core import DepthWarpParams, warp_depth
    except ImportError:
        pytest.skip("ibrtools.depthwarp.core.warp_depth not built yet")
    src = ref.render(prev, outputs=("depth",), lights=[])["depth"]
    w = warp_depth(src, prev, cam, DepthWarpParams(dilate=False))
    ev = cull_objects(w.depth, w.hole, cam, boxes).evaluate(ids, counts)
    assert ev["falsely_culled_large"] == 0, ev["false_ids"]
    assert ev["occlusion_culled"] > 0


def test_evaluate_counts():
    res = CullResult(visible=np.array([True, False, False, True]), frustum_culled=np.array([False, True, False, False]),
                     occlusion_culled=np.array([False, False, True, False]),
                     max_depth=np.zeros(4, np.float32), min_z=np.zeros(4, np.float32))
    ev = res.evaluate(np.array([0, 1, 2], np.int32), np.array([50, 1, 9, 0]))
    assert ev["drawn"] == 2 and ev["ideal"] == 3
    assert ev["falsely_culled"] == 2 and ev["falsely_culled_small"] == 1 and ev["falsely_culled_large"] == 1
    assert ev["false_ids"] == [1, 2]
    assert ev["culled_fraction"] == 0.5 and ev["ideal_culled_fraction"] == 0.25
    with pytest.raises(BadValueError, match="ideal_visible_ids"):
        res.evaluate(np.array([7]))
    with pytest.raises(ShapeError, match="pixel_counts"):
        res.evaluate(np.array([0]), np.zeros(3, int))
    with pytest.raises(DtypeError, match="ideal_visible_ids"):
        res.evaluate(np.array([0.5]))


def test_bad_inputs(wall_scene):
    mesh, boxes, depth = wall_scene
    cam = _camera()
    with pytest.raises(DtypeError, match="mesh"):
        object_boxes("mesh")
    with pytest.raises(DtypeError, match="warped_depth"):
        cull_objects(depth.astype(np.float64), None, cam, boxes)
    with pytest.raises(ShapeError, match="warped_depth"):
        cull_objects(depth[:-1], None, cam, boxes)
    with pytest.raises(DtypeError, match="hole"):
        cull_objects(depth, np.zeros((H, W), np.float32), cam, boxes)
    with pytest.raises(ShapeError, match="hole"):
        cull_objects(depth, np.zeros((H, W + 1), bool), cam, boxes)
    with pytest.raises(DtypeError, match="camera"):
        cull_objects(depth, None, cam.to_core(), boxes)
    eq = Camera.equirect(W, H, cam_from_world=np.eye(4))
    with pytest.raises(BadValueError, match="pinhole"):
        cull_objects(depth, None, eq, boxes)
    with pytest.raises(DtypeError, match="boxes"):
        cull_objects(depth, None, cam, boxes.astype(np.float64))
    with pytest.raises(ShapeError, match="boxes"):
        cull_objects(depth, None, cam, boxes.reshape(-1, 3, 2))
    bad = boxes.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(BadValueError, match="boxes"):
        cull_objects(depth, None, cam, bad)
    with pytest.raises(BadValueError, match="near"):
        cull_objects(depth, None, cam, boxes, near=0.0)
    with pytest.raises(BadValueError, match="pad"):
        cull_objects(depth, None, cam, boxes, pad=-1)
    with pytest.raises(DtypeError, match="approximate"):
        cull_objects(depth, None, cam, boxes, approximate="yes")
    with pytest.raises(BadValueError, match="source_depth"):
        cull_objects(depth, None, cam, boxes, approximate=True)
    # The C++ front checks face indices and pinhole cameras itself.
    with pytest.raises(BadValueError, match="faces"):
        _core.cull_object_boxes(mesh.vertices, mesh.faces + 10_000, mesh.object_ids, 6)
    with pytest.raises(BadValueError, match="pinhole"):
        _core.cull_project_boxes(boxes, eq.to_core(), 1e-3, 1)


def test_empty_box_list(wall_scene):
    _, _, depth = wall_scene
    res = cull_objects(depth, None, _camera(), np.zeros((0, 2, 3), np.float32))
    assert res.visible.shape == (0,)
    assert res.evaluate(np.zeros(0, np.int32))["drawn"] == 0


def test_awoc_fill_uniform_motion_exact():
    # Every source pixel moves by (+10, 0): the bound of target pixel p collapses to q = p - (10, 0),
    # whose moved depth is 1 + q.x (dst_depth below); every target pixel is a hole.
    h, w = 24, 40
    motion = np.zeros((h, w, 2), np.float32)
    motion[..., 0] = 10
    dst = np.broadcast_to(1.0 + np.arange(w, dtype=np.float32), (h, w)).copy()
    depth = np.zeros((h, w), np.float32)
    hole = np.ones((h, w), bool)
    _core.cull_awoc_fill(depth, hole, motion, dst, 3)
    np.testing.assert_array_equal(depth[:, 10:], np.broadcast_to(1.0 + np.arange(w - 10), (h, w - 10)))
    assert not hole[:, 10:].any()


def test_awoc_fill_takes_nearest_corner_and_keeps_non_holes():
    h, w = 16, 16
    motion = np.zeros((h, w, 2), np.float32)
    motion[:, 8:, 0] = 4  # right half moves right by 4: bound width 4 for pixels near the seam
    dst = np.full((h, w), 9.0, np.float32)
    dst[:, 8:] = 3.0       # the moving half is nearer
    depth = np.full((h, w), 7.0, np.float32)
    hole = np.zeros((h, w), bool)
    hole[5, 10] = True     # bound x in [10 - 4, 10 - 0] = [6, 10]: corners 6 (9.0) and 10 (3.0)
    _core.cull_awoc_fill(depth, hole, motion, dst, 0)
    assert depth[5, 10] == 3.0 and not hole[5, 10]
    assert (np.delete(depth.ravel(), 5 * w + 10) == 7.0).all()  # non-holes untouched
    # No valid source pixel: holes stay holes.
    hole[5, 10] = True
    depth[5, 10] = 0
    _core.cull_awoc_fill(depth, hole, motion, np.zeros((h, w), np.float32), 3)
    assert hole[5, 10] and depth[5, 10] == 0
    with pytest.raises(BadValueError, match="steps"):
        _core.cull_awoc_fill(depth, hole, motion, dst, -1)
    with pytest.raises(ShapeError, match="dst_depth"):
        _core.cull_awoc_fill(depth, hole, motion, dst[:-1], 3)
    with pytest.raises(BadValueError, match="writeable"):
        ro = depth.copy()
        ro.flags.writeable = False
        _core.cull_awoc_fill(ro, hole, motion, dst, 3)


def test_awoc_culls_behind_holes_woc_keeps():
    """Camera moves right by 1.5 units in front of the wall: the right edge of the new view was not
    seen before (holes), so WOC keeps the box behind the wall there; AWOC fills those holes with the
    wall's depth (the nearest bound-corner source pixels) and culls it."""
    pytest.importorskip("ibrtools.depthwarp.core", reason="ibrtools.depthwarp.core not built yet")
    src = _camera()
    dst = Camera.pinhole(W, H, 40.0, 40.0, W / 2, H / 2, np.array(
        [[1, 0, 0, -1.5], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], float))  # centre at x = +1.5
    # The source sees a wall at z = 5 over its whole image; the warp leaves the new view's right
    # band (1.5 units at z = 5 = 12 px, plus 2 px) as holes.
    src_depth = np.full((H, W), 5.0, np.float32)
    tgt_depth = np.full((H, W), 5.0, np.float32)
    hole = np.zeros((H, W), bool)
    hole[:, W - 14:] = True   # 1.5 units at z = 5 is 12 px: the unseen band (and 2 px of margin)
    tgt_depth[hole] = 0
    # A box behind the wall, projecting inside the hole band of the new view.
    boxes = np.array([[[6.0, -0.3, 9.0], [6.5, 0.3, 9.5]]], np.float32)  # x = 50.9 .. 54.2 px
    woc = cull_objects(tgt_depth, hole, dst, boxes)
    assert woc.visible[0]
    awoc = cull_objects(tgt_depth, hole, dst, boxes, approximate=True, source_depth=src_depth, source_camera=src)
    assert awoc.occlusion_culled[0]
    assert awoc.stats["approximate"]


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 40))
def test_exact_depth_never_culls_a_visible_object(seed, n):
    """Property: with the frame's own reference depth as the occlusion map (no warp error), no object
    the reference renderer sees (any pixel) is culled, whatever the boxes and the camera."""
    rng = np.random.default_rng(seed)
    centers = rng.uniform([-3, -1, 2], [3, 1, 12], (n, 3))
    sizes = rng.uniform(0.05, 2.5, (n, 3))
    part = synth.boxes(centers, sizes, rng.uniform(0, np.pi, n), object_ids=np.arange(n))
    mesh = synth.merge([part], [], None)
    eye = rng.uniform([-2, -1, -3], [2, 1, 1])
    cam = Camera.from_fov(48, 36, float(rng.uniform(40, 100)),
                          look_at(eye, eye + [rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3), 1.0]))
    ref = ReferenceRenderer(mesh)
    out = ref.render(cam, outputs=("depth",), lights=[])
    res = cull_objects(out["depth"], None, cam, object_boxes(mesh))
    ev = res.evaluate(ref.visible_objects(cam))
    assert ev["falsely_culled"] == 0, ev["false_ids"]


def test_gil_released_during_awoc_fill():
    """Structural (kernels release the GIL): AwocFill runs without the GIL (negative control: tests/gil.py)."""
    from gil import runs_python_during

    h, w = 540, 960
    rng = np.random.default_rng(0)
    motion = rng.uniform(-40, 40, (h, w, 2)).astype(np.float32)
    dst = rng.uniform(1, 10, (h, w)).astype(np.float32)
    depth = np.zeros((h, w), np.float32)
    _core.set_num_threads(1)  # leave a core for this thread
    try:
        def work():
            for _ in range(5):
                hole = np.ones((h, w), bool)
                _core.cull_awoc_fill(depth, hole, motion, dst, 3)
        assert runs_python_during(work), "no Python ran during the kernel (or it lasted < 20 ms)"
    finally:
        _core.set_num_threads(0)


def test_walk_path_frames_cull_no_visible_object():
    """Frames 42-44 of the crowd's walk path at 480 x 270 with ibr-render --method depthwarp --layers 3
    --seeds 4 --cull (DepthWarpMethod). The warped depth with its holes as the occlusion map culls
    objects the reference sees: 976 (frame 43) and 171 (frame 44), both > 2 px, seen through sub-pixel
    gaps between two neighbouring occluders that the converged samples close (each lands within the
    0.5 px threshold beyond its surface's edge). The method culls with the proven occluder depth
    instead (WarpResult.occluder): no visible object is culled, and some objects still are."""
    from ibrtools.depthwarp.method import DepthWarpMethod
    from ibrtools.scene import Scene

    mesh, built = synth.build_mesh("crowd", size=(480, 270), views=1, holdout_targets=0)
    cams = built.paths["walk"][42:45]
    m = DepthWarpMethod({"layers": 3, "seeds": 4, "cull": True})
    m.prepare(Scene(meshes={"ground_truth": mesh}))
    m.render(cams[0])  # the first frame: the reference depth, nothing to cull from
    ref, boxes = ReferenceRenderer(mesh), object_boxes(mesh)
    plain_false, culled = [], 0
    for cam in cams[1:]:
        out, _ = m.render(cam)
        ev = m.frame_report()["cull"]
        assert ev["falsely_culled_large"] == 0 and ev["falsely_culled_small"] == 0, ev["false_ids"]
        culled += ev["occlusion_culled"]
        oid = ref.render(cam, outputs=("object_id",), lights=[])["object_id"]
        counts = np.bincount(oid[oid >= 0], minlength=len(boxes))
        plain = cull_objects(out["depth"], out["hole"], cam, boxes).evaluate(np.flatnonzero(counts), counts)
        plain_false.append(plain["false_ids"])
    assert 976 in plain_false[0] and 171 in plain_false[1]  # the path reproduces the false culls
    assert culled > 0
