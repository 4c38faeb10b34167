"""Cameras: pinhole and equirectangular, posed by ``cam_from_world``.

One convention everywhere (OpenCV), the same as ``cpp/ibr/camera.h``:

* camera axes are OpenCV's: x right, y down, z forward;
* pixel (col u, row v) has its centre at continuous image coordinates (u + 0.5, v + 0.5);
* ``cam_from_world`` is a rigid 4x4 (float64): ``point_in_cam = R @ point_in_world + t``;
* pinhole depth is z (``depth_z``); equirect depth is the distance along the ray (``depth_ray``);
* equirect longitude grows to the right from ``lon_range[0]`` at the left edge to
  ``lon_range[1]`` at the right edge; latitude falls from ``lat_range[1]`` at the top edge
  to ``lat_range[0]`` at the bottom; the ray of (lon, lat) is
  ``(cos lat sin lon, -sin lat, cos lat cos lon)``. Ranges are radians in memory and degrees
  in ``scene.json``.

Importers convert other conventions (OpenGL/Blender, OMAF, COLMAP, ...) into this one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ibrtools.checks import check_float, check_int
from ibrtools.errors import BadValueError, DtypeError, FormatError, ShapeError

PINHOLE = "pinhole"
EQUIRECT = "equirect"
MODELS = (PINHOLE, EQUIRECT)

# A pose is rigid when R^T R = I and det R = 1 to this tolerance (poses written as text with
# ~7 significant digits are still accepted; anything beyond is a scale or shear, not noise).
RIGID_TOLERANCE = 1e-4

# Bounds of sane cameras, so that arithmetic on them never overflows (a 1e308 translation or focal
# length would make numpy warn and produce inf far from the file that held it): image sides up to
# 65536 pixels, focal lengths and principal points within 1e9 pixels, translations within 1e12
# scene units (1e12 m is seven times the Earth-Sun distance; a world that large needs other units).
MAX_SIDE = 65536
MAX_FOCAL = 1e9
MIN_FOCAL = 1e-3  # a 1920-pixel image of 179.9 degrees field of view still has f = 0.84
MAX_TRANSLATION = 1e12


def check_rigid(cam_from_world: Any, name: str = "cam_from_world") -> np.ndarray:
    """Return ``cam_from_world`` as a float64 (4, 4) array after checking it is rigid."""
    try:
        m = np.array(cam_from_world, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise DtypeError(f"{name}: expected a 4x4 matrix of numbers ({e})") from None
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    if m.shape != (4, 4):
        raise ShapeError(f"{name}: expected shape (4, 4) or (3, 4), got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise BadValueError(f"{name}: contains NaN or infinity")
    big = float(np.abs(m[:3, 3]).max())
    if big > MAX_TRANSLATION:
        raise BadValueError(f"{name}: translation {big:.3g} is beyond +-{MAX_TRANSLATION:g} "
                            "(expected a pose in sane scene units)")
    if float(np.abs(m[:3, :3]).max()) > 2.0:  # a rotation's entries are within [-1, 1]
        raise BadValueError(f"{name}: not a rigid pose (rotation entry {float(np.abs(m[:3, :3]).max()):.3g}); "
                            "expected a rotation and a translation, no scale or shear")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise BadValueError(f"{name}: last row must be (0, 0, 0, 1), got {m[3].tolist()}")
    r = m[:3, :3]
    err = np.abs(r.T @ r - np.eye(3)).max()
    det = np.linalg.det(r)
    if err > RIGID_TOLERANCE or abs(det - 1.0) > RIGID_TOLERANCE:
        raise BadValueError(
            f"{name}: not a rigid pose (|R^T R - I| = {err:.2e}, det R = {det:.6f}); "
            "expected a rotation and a translation, no scale or shear")
    return m


def orthonormalize(r: np.ndarray) -> np.ndarray:
    """Nearest rotation to ``r`` (SVD), for poses read from text with few digits."""
    u, _, vt = np.linalg.svd(np.asarray(r, dtype=np.float64))
    rot = u @ vt
    if np.linalg.det(rot) < 0:
        u[:, -1] *= -1
        rot = u @ vt
    return rot


def look_at(eye: Any, target: Any, up: Any = (0.0, 1.0, 0.0)) -> np.ndarray:
    """``cam_from_world`` of a camera at ``eye`` looking at ``target`` with ``up`` upwards
    on screen (OpenCV axes: y down, so -up becomes the camera's y)."""
    eye = np.asarray(eye, dtype=np.float64)
    fwd = np.asarray(target, dtype=np.float64) - eye
    n = np.linalg.norm(fwd)
    if not n > 0:
        raise BadValueError("look_at: eye and target coincide")
    z = fwd / n
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    if not np.linalg.norm(x) > 1e-12:
        raise BadValueError("look_at: up is parallel to the viewing direction")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, :3] = np.stack([x, y, z])
    m[:3, 3] = -m[:3, :3] @ eye
    return m


@dataclass(frozen=True, eq=False)
class Camera:
    """A camera: intrinsics of one model plus a rigid ``cam_from_world`` pose."""

    model: str
    width: int
    height: int
    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0
    lon_range: tuple[float, float] = (-math.pi, math.pi)
    lat_range: tuple[float, float] = (-math.pi / 2, math.pi / 2)
    cam_from_world: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise BadValueError(f"camera model: expected one of {MODELS}, got {self.model!r}")
        object.__setattr__(self, "width", check_int(self.width, "camera width", 1, MAX_SIDE))
        object.__setattr__(self, "height", check_int(self.height, "camera height", 1, MAX_SIDE))
        if self.model == PINHOLE:
            for k in ("fx", "fy"):
                v = check_float(getattr(self, k), k)
                if v <= 0:
                    raise BadValueError(f"{k}: focal length must be positive, got {v}")
                if not MIN_FOCAL <= v <= MAX_FOCAL:
                    raise BadValueError(f"{k}: focal length {v:.3g} is outside {MIN_FOCAL:g} to {MAX_FOCAL:g} pixels")
                object.__setattr__(self, k, v)
            for k in ("cx", "cy"):
                v = check_float(getattr(self, k), k)
                if abs(v) > MAX_FOCAL:
                    raise BadValueError(f"{k}: principal point {v:.3g} is beyond +-{MAX_FOCAL:g} pixels")
                object.__setattr__(self, k, v)
        else:
            lon = tuple(check_float(v, "lon_range") for v in self.lon_range)
            lat = tuple(check_float(v, "lat_range") for v in self.lat_range)
            if len(lon) != 2 or not (lon[0] < lon[1]) or lon[1] - lon[0] > 2 * math.pi + 1e-9:
                raise BadValueError(f"lon_range: expected (min, max) with 0 < max - min <= 360 deg, got {lon}")
            if (len(lat) != 2 or not (lat[0] < lat[1]) or lat[0] < -math.pi / 2 - 1e-9
                    or lat[1] > math.pi / 2 + 1e-9):
                raise BadValueError(f"lat_range: expected (min, max) within [-90, 90] deg, got {lat}")
            object.__setattr__(self, "lon_range", lon)
            object.__setattr__(self, "lat_range", lat)
        pose = check_rigid(self.cam_from_world)
        pose.setflags(write=False)
        object.__setattr__(self, "cam_from_world", pose)

    # --- constructors -------------------------------------------------------------------
    @classmethod
    def pinhole(cls, width: int, height: int, fx: float, fy: float, cx: float, cy: float,
                cam_from_world: Any = None) -> "Camera":
        return cls(PINHOLE, width, height, fx, fy, cx, cy,
                   cam_from_world=np.eye(4) if cam_from_world is None else cam_from_world)

    @classmethod
    def from_fov(cls, width: int, height: int, fov_x_deg: float, cam_from_world: Any = None) -> "Camera":
        """Pinhole with square pixels, principal point at the image centre."""
        f = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2)
        return cls.pinhole(width, height, f, f, width / 2, height / 2, cam_from_world)

    @classmethod
    def equirect(cls, width: int, height: int, lon_range_deg=(-180.0, 180.0),
                 lat_range_deg=(-90.0, 90.0), cam_from_world: Any = None) -> "Camera":
        return cls(EQUIRECT, width, height,
                   lon_range=tuple(math.radians(v) for v in lon_range_deg),
                   lat_range=tuple(math.radians(v) for v in lat_range_deg),
                   cam_from_world=np.eye(4) if cam_from_world is None else cam_from_world)

    # --- pose ---------------------------------------------------------------------------
    @property
    def world_from_cam(self) -> np.ndarray:
        r, t = self.cam_from_world[:3, :3], self.cam_from_world[:3, 3]
        m = np.eye(4)
        m[:3, :3] = r.T
        m[:3, 3] = -r.T @ t
        return m

    @property
    def centre(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        return self.world_from_cam[:3, 3]

    @property
    def K(self) -> np.ndarray:
        if self.model != PINHOLE:
            raise BadValueError("K: only pinhole cameras have an intrinsic matrix")
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def with_pose(self, cam_from_world: Any) -> "Camera":
        return Camera(self.model, self.width, self.height, self.fx, self.fy, self.cx, self.cy,
                      self.lon_range, self.lat_range, cam_from_world)

    def scaled(self, width: int, height: int) -> "Camera":
        """The same camera for an image resized to width x height (pixel-centre exact)."""
        sx, sy = width / self.width, height / self.height
        return Camera(self.model, width, height, self.fx * sx, self.fy * sy, self.cx * sx,
                      self.cy * sy, self.lon_range, self.lat_range, self.cam_from_world)

    # --- geometry (vectorised numpy; kernels use cpp/ibr/camera.h) ---------------------------
    def rays_in_cam(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Rays through continuous image points; pinhole: z = 1, equirect: unit length."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if self.model == PINHOLE:
            return np.stack([(x - self.cx) / self.fx, (y - self.cy) / self.fy, np.ones_like(x)], -1)
        lon = self.lon_range[0] + x / self.width * (self.lon_range[1] - self.lon_range[0])
        lat = self.lat_range[1] - y / self.height * (self.lat_range[1] - self.lat_range[0])
        cl = np.cos(lat)
        return np.stack([cl * np.sin(lon), -np.sin(lat), cl * np.cos(lon)], -1)

    def pixel_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Continuous coordinates of the pixel centres, each (H, W)."""
        return np.meshgrid(np.arange(self.width) + 0.5, np.arange(self.height) + 0.5)

    def unproject(self, depth: np.ndarray) -> np.ndarray:
        """World points (H, W, 3) of a depth map in this camera's convention."""
        depth = np.asarray(depth, dtype=np.float64)
        if depth.shape != (self.height, self.width):
            raise ShapeError(f"depth: expected shape (H, W) = ({self.height}, {self.width}), got {depth.shape}")
        x, y = self.pixel_grid()
        p_cam = self.rays_in_cam(x, y) * depth[..., None]
        wfc = self.world_from_cam
        return p_cam @ wfc[:3, :3].T + wfc[:3, 3]

    def project(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Image coordinates (..., 2) and depth (...) of world points; depth <= 0 or NaN
        where a point has no image position."""
        p = np.asarray(points_world, dtype=np.float64)
        pc = p @ self.cam_from_world[:3, :3].T + self.cam_from_world[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.model == PINHOLE:
                z = pc[..., 2]
                ok = z > 0
                zs = np.where(ok, z, 1.0)
                xy = np.stack([self.fx * pc[..., 0] / zs + self.cx, self.fy * pc[..., 1] / zs + self.cy], -1)
                return np.where(ok[..., None], xy, np.nan), np.where(ok, z, np.nan)
            r = np.linalg.norm(pc, axis=-1)
            lon = np.arctan2(pc[..., 0], pc[..., 2])
            lat = np.arcsin(np.clip(-pc[..., 1] / np.where(r > 0, r, 1.0), -1, 1))
            x = (lon - self.lon_range[0]) / (self.lon_range[1] - self.lon_range[0]) * self.width
            y = (self.lat_range[1] - lat) / (self.lat_range[1] - self.lat_range[0]) * self.height
            ok = r > 0
            return np.where(ok[..., None], np.stack([x, y], -1), np.nan), np.where(ok, r, np.nan)

    def depth_z_to_ray(self, depth_z: np.ndarray) -> np.ndarray:
        """Distance along each pixel's ray for a z-depth map (pinhole only)."""
        x, y = self.pixel_grid()
        return depth_z * np.linalg.norm(self.rays_in_cam(x, y), axis=-1).astype(depth_z.dtype)

    def depth_ray_to_z(self, depth_ray: np.ndarray) -> np.ndarray:
        x, y = self.pixel_grid()
        return depth_ray / np.linalg.norm(self.rays_in_cam(x, y), axis=-1).astype(depth_ray.dtype)

    # --- interchange --------------------------------------------------------------------------
    def to_core(self):
        """The C++ camera (ibrtools._core.Camera)."""
        from ibrtools import _core

        if self.model == PINHOLE:
            return _core.Camera(_core.CameraModel.PINHOLE, self.width, self.height,
                                np.array([self.fx, self.fy, self.cx, self.cy]),
                                np.ascontiguousarray(self.cam_from_world))
        return _core.Camera(_core.CameraModel.EQUIRECT, self.width, self.height,
                            np.array([*self.lon_range, *self.lat_range]),
                            np.ascontiguousarray(self.cam_from_world))

    def to_dict(self) -> dict:
        d: dict[str, Any] = {"model": self.model, "width": self.width, "height": self.height}
        if self.model == PINHOLE:
            d.update(fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy)
        else:
            d["lon_range_deg"] = [math.degrees(v) for v in self.lon_range]
            d["lat_range_deg"] = [math.degrees(v) for v in self.lat_range]
        d["cam_from_world"] = self.cam_from_world.tolist()
        return d

    @classmethod
    def from_dict(cls, d: Any, where: str = "camera") -> "Camera":
        if not isinstance(d, dict):
            raise FormatError(f"{where}: expected a JSON object, got {type(d).__name__}")
        if "cam_from_world" not in d:
            raise FormatError(f"{where}: missing 'cam_from_world'")
        try:
            model = d.get("model", PINHOLE)
            pose = check_rigid(d["cam_from_world"], f"{where}.cam_from_world")
            if model == PINHOLE:
                return cls.pinhole(d["width"], d["height"], d["fx"], d["fy"], d["cx"], d["cy"], pose)
            if model == EQUIRECT:
                return cls.equirect(d["width"], d["height"], tuple(d.get("lon_range_deg", (-180, 180))),
                                    tuple(d.get("lat_range_deg", (-90, 90))), pose)
            raise BadValueError(f"{where}.model: expected one of {MODELS}, got {model!r}")
        except KeyError as e:
            raise FormatError(f"{where}: missing key {e.args[0]!r}") from None
        except (BadValueError, DtypeError, ShapeError) as e:
            msg = str(e)  # check_rigid's already names f"{where}.cam_from_world"
            raise type(e)(msg if msg.startswith(where) else f"{where}: {msg}") from None
        except (TypeError, ValueError, OverflowError) as e:
            # a value of the wrong JSON type (null focal, string range...): found by
            # tests/formats/test_fuzz_importers.py; bad input, not a bug
            raise FormatError(f"{where}: malformed camera ({type(e).__name__}: {e})") from None

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Camera) and self.to_dict() == other.to_dict()

    def allclose(self, other: "Camera", tol: float = 1e-9) -> bool:
        if self.model != other.model or (self.width, self.height) != (other.width, other.height):
            return False
        a = np.array([self.fx, self.fy, self.cx, self.cy, *self.lon_range, *self.lat_range])
        b = np.array([other.fx, other.fy, other.cx, other.cy, *other.lon_range, *other.lat_range])
        return bool(np.allclose(a, b, rtol=tol, atol=tol)
                    and np.allclose(self.cam_from_world, other.cam_from_world, rtol=tol, atol=tol))

    def __repr__(self) -> str:
        c = self.centre
        if self.model == PINHOLE:
            return (f"Camera(pinhole {self.width}x{self.height}, f=({self.fx:.2f}, {self.fy:.2f}), "
                    f"c=({self.cx:.2f}, {self.cy:.2f}), centre=({c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}))")
        return f"Camera(equirect {self.width}x{self.height}, centre=({c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}))"
