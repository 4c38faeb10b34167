"""Cameras: conventions of camera.py / cpp/ibr/camera.h pinned down with hand-checked values."""

import numpy as np
import pytest

from ibrtools import BadValueError, Camera, DtypeError, ShapeError, look_at
from ibrtools.errors import FormatError

pytestmark = [pytest.mark.asan]


def test_pinhole_pixel_centres_and_projection():
    cam = Camera.pinhole(4, 2, 2.0, 2.0, 2.0, 1.0)
    # The optical axis hits the continuous point (cx, cy) = (2, 1): the corner between pixels.
    xy, d = cam.project(np.array([[0.0, 0.0, 5.0]]))
    assert np.allclose(xy, [[2.0, 1.0]]) and np.allclose(d, [5.0])
    # Pixel (0, 0) has its centre at (0.5, 0.5): its ray is ((0.5-2)/2, (0.5-1)/2, 1).
    x, y = cam.pixel_grid()
    assert x[0, 0] == 0.5 and y[0, 0] == 0.5
    assert np.allclose(cam.rays_in_cam(x, y)[0, 0], [-0.75, -0.25, 1.0])


def test_unproject_project_round_trip_and_core_agrees(rng):
    pose = look_at([1.0, 2.0, -3.0], [0.0, 0.0, 0.0])
    cam = Camera.pinhole(32, 24, 30.0, 31.0, 16.2, 11.7, pose)
    depth = rng.uniform(1.0, 5.0, (24, 32))
    pts = cam.unproject(depth)
    xy, d = cam.project(pts)
    gx, gy = cam.pixel_grid()
    assert np.allclose(xy[..., 0], gx, atol=1e-9) and np.allclose(xy[..., 1], gy, atol=1e-9)
    assert np.allclose(d, depth, rtol=1e-12)
    core = cam.to_core()
    ok, u, v, z = core.project(*pts[5, 7])
    assert ok and abs(u - 7.5) < 1e-9 and abs(v - 5.5) < 1e-9 and abs(z - depth[5, 7]) < 1e-9


def test_equirect_convention():
    cam = Camera.equirect(360, 180)
    # lon = 0, lat = 0 is +z (forward), at the image centre.
    xy, d = cam.project(np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]))
    assert np.allclose(xy[0], [180, 90]) and np.isclose(d[0], 2.0)
    assert np.allclose(xy[1], [270, 90])   # +x (right) is lon = +90 deg: right of centre
    assert np.isclose(xy[2, 1], 0.0)       # -y (up) is lat = +90: the top edge
    depth = np.full((180, 360), 3.0)
    pts = cam.unproject(depth)
    assert np.allclose(np.linalg.norm(pts, axis=-1), 3.0)
    ok, u, v, r = cam.to_core().project(0.0, 0.0, 2.0)
    assert ok and abs(u - 180) < 1e-9 and abs(v - 90) < 1e-9 and abs(r - 2) < 1e-12


def test_look_at_puts_target_at_the_centre():
    cam = Camera.from_fov(64, 48, 60.0, look_at([3, 1, 2], [0, 0.5, 0]))
    xy, d = cam.project(np.array([[0, 0.5, 0]]))
    assert np.allclose(xy, [[32, 24]]) and d[0] > 0
    # World up appears upwards on screen (smaller y).
    xy2, _ = cam.project(np.array([[0, 1.5, 0]]))
    assert xy2[0, 1] < 24


def test_dict_round_trip_exact():
    cams = [Camera.pinhole(10, 8, 7.5, 7.25, 5.1, 3.9, look_at([1, 2, 3], [0, 0, 0])),
            Camera.equirect(64, 32, (-170, 170), (-80, 85), look_at([0, 0, 1], [1, 0, 1]))]
    for c in cams:
        c2 = Camera.from_dict(c.to_dict())
        assert c2.allclose(c, 1e-12) and c2 == c


@pytest.mark.parametrize("kwargs, err", [
    (dict(fx=0.0), BadValueError), (dict(fx=-3.0), BadValueError), (dict(fy=float("nan")), BadValueError),
    (dict(width=0), BadValueError), (dict(width=2.5), DtypeError), (dict(height=-1), BadValueError),
])
def test_bad_intrinsics(kwargs, err):
    base = dict(width=8, height=6, fx=5.0, fy=5.0, cx=4.0, cy=3.0)
    base.update(kwargs)
    with pytest.raises(err, match=r"fx|fy|width|height"):
        Camera.pinhole(**base)


def test_non_rigid_pose_rejected():
    pose = np.eye(4)
    pose[0, 0] = 2.0
    with pytest.raises(BadValueError, match="not a rigid pose"):
        Camera.pinhole(8, 6, 5, 5, 4, 3, pose)
    with pytest.raises(ShapeError, match="cam_from_world"):
        Camera.pinhole(8, 6, 5, 5, 4, 3, np.eye(3))
    nan = np.eye(4)
    nan[0, 3] = np.nan
    with pytest.raises(BadValueError, match="NaN"):
        Camera.pinhole(8, 6, 5, 5, 4, 3, nan)


def test_from_dict_errors_name_the_place():
    with pytest.raises(FormatError, match="views\\[0\\].camera: missing key 'fx'"):
        Camera.from_dict({"model": "pinhole", "width": 4, "height": 4, "fy": 1, "cx": 1, "cy": 1,
                          "cam_from_world": np.eye(4).tolist()}, "views[0].camera")
    with pytest.raises(BadValueError, match="model"):
        Camera.from_dict({"model": "fisheye", "cam_from_world": np.eye(4).tolist()})


def test_equirect_ranges_checked():
    with pytest.raises(BadValueError, match="lat_range"):
        Camera.equirect(8, 4, (-180, 180), (-100, 90))
    with pytest.raises(BadValueError, match="lon_range"):
        Camera.equirect(8, 4, (10, -10))


def test_core_camera_rejects_bad_arrays():
    from ibrtools import _core
    with pytest.raises(DtypeError, match="params: expected float64"):
        _core.Camera(_core.CameraModel.PINHOLE, 4, 4, np.zeros(4, np.float32), np.eye(4))
    with pytest.raises(ShapeError, match=r"cam_from_world: expected float64 array of shape \(4, 4\)"):
        _core.Camera(_core.CameraModel.PINHOLE, 4, 4, np.ones(4), np.eye(3))
    with pytest.raises(BadValueError, match="width and height"):
        _core.Camera(_core.CameraModel.PINHOLE, 0, 4, np.ones(4), np.eye(4))
