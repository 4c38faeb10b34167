"""Camera paths generated from a scene's input cameras, for any scene (imported or synthetic):
``ibr-render SCENE --path interpolate|spiral|orbit`` (docs/render.md "Camera paths").

* ``interpolate``: a smooth path through the input cameras in the scene's view order. Centres
  by a uniform Catmull-Rom spline (C1; Catmull & Rom 1974), the end tangents from reflected
  phantom points; rotations (world_from_cam) by squad, the C1 quaternion spline of Shoemake
  1987 ("Animating rotation with quaternion curves", eq. for s_i and squad). Each segment between
  two consecutive inputs gets the same time; the path passes exactly through every input camera.
* ``spiral``: the LLFF spiral (Mildenhall et al. 2019, "Local Light Field Fusion"; NeRF's
  ``render_path_spiral``): around the mean pose (mean centre, average rotation), two turns, the
  radius per axis of the mean pose's frame the 90th percentile of the inputs' offsets from the
  mean centre, the depth oscillating at half the turn rate, every camera looking at the focus
  point on the mean optical axis at LLFF's focus distance ``1 / ((1 - 0.75) / near + 0.75 /
  far)`` with ``near = 0.9 x`` the 1st percentile and ``far = 5 x`` the 99th percentile of the
  scene's depth as the input cameras see it (depth maps, else the mesh); a scene with neither
  focuses where the optical axes meet. Meant for forward-facing captures (LLFF): around an
  object captured from all sides the mean pose is inside the scene; use ``orbit`` there.
* ``orbit``: one turn of a circle around the scene's centre (the least-squares closest point of
  the input cameras' optical axes, or the centre of the scene bounds when the axes are near
  parallel or that point lies behind the cameras) at the inputs' mean distance from the
  centre's vertical axis and mean height, up = the cameras' mean up, looking at the centre,
  starting at the first input camera's azimuth and turning the way the inputs go round.

Every camera of a generated path has the first input view's intrinsics (model and size). Frames
are named as those of a stored path: ``<path>_0000``, ... A path stored in the scene under the
same name wins (:func:`camera_path`).
"""
from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np

from ibrtools.camera import Camera, look_at, orthonormalize
from ibrtools.checks import check_int
from ibrtools.errors import BadValueError
from ibrtools.scene import Scene

GENERATED = ("interpolate", "spiral", "orbit")
# Frames of a generated path unless --path-frames says otherwise: the same as the synthetic
# scenes' stored paths (synth.make_scene path_frames), 2 s at 24 fps.
DEFAULT_FRAMES = 48
MAX_FRAMES = 100_000

# LLFF's spiral constants (imgs2poses / NeRF load_llff.py): the focus distance's weight on the far
# plane, the margins on the depth percentiles, the turns and the depth oscillation rate.
SPIRAL_DT = 0.75
SPIRAL_NEAR_MARGIN, SPIRAL_FAR_MARGIN = 0.9, 5.0
SPIRAL_ROTATIONS, SPIRAL_ZRATE = 2, 0.5
SPIRAL_PERCENTILE = 90.0
# Depth percentiles of the near and far planes (robust to stray depth and mesh outliers).
DEPTH_PERCENTILES = (1.0, 99.0)
# The optical axes' least-squares point is used when the normal matrix sum(I - d d^T) has its
# smallest eigenvalue above this fraction of the number of cameras (axes at least ~6 degrees
# apart on average); otherwise (near-parallel axes: forward-facing captures) the bounds centre.
AXES_CONDITION = 0.01
# Views (evenly spaced) and pixels per view sampled for the depth range.
DEPTH_VIEWS, DEPTH_SAMPLES = 16, 4096


# --- quaternions (w, x, y, z), Hamilton convention ---------------------------------------------
def quat_from_matrix(r: np.ndarray) -> np.ndarray:
    """Unit quaternion of a rotation matrix (Shepperd's method: the largest diagonal term first)."""
    m = np.asarray(r, dtype=np.float64)
    t = np.trace(m)
    if t > 0:
        s = 2.0 * math.sqrt(t + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + m[i, i] - m[j, j] - m[k, k], 1e-300))
        q = [0.0] * 4
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    out = np.array(q)
    return out / np.linalg.norm(out)


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _qconj(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def _qlog(q: np.ndarray) -> np.ndarray:
    """The pure quaternion log of a unit quaternion (its vector part; 0 for the identity)."""
    v = q[1:]
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        return np.zeros(3)
    return v / s * math.atan2(s, float(np.clip(q[0], -1.0, 1.0)))


def _qexp(v: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(v))
    if a < 1e-12:
        return np.array([1.0, *v])  # first order; normalised by the callers' use
    return np.array([math.cos(a), *(v / a * math.sin(a))])


def slerp(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (the shorter arc); normalised linear
    interpolation when they are within 1e-6 rad (sin of the angle ~ 0)."""
    d = float(np.dot(a, b))
    if d < 0:
        b, d = -b, -d
    if d > 1.0 - 1e-12:
        q = a + t * (b - a)
    else:
        th = math.acos(min(d, 1.0))
        q = (math.sin((1 - t) * th) * a + math.sin(t * th) * b) / math.sin(th)
    return q / np.linalg.norm(q)


def _hemisphere(quats: list[np.ndarray]) -> list[np.ndarray]:
    """Each quaternion's sign chosen nearest its predecessor (q and -q are one rotation)."""
    out = [quats[0]]
    for q in quats[1:]:
        out.append(-q if np.dot(out[-1], q) < 0 else q)
    return out


def _squad_controls(q: list[np.ndarray]) -> list[np.ndarray]:
    """Shoemake's inner quaternions s_i = q_i exp(-(log(q_i^-1 q_{i+1}) + log(q_i^-1 q_{i-1})) / 4);
    s_0 = q_0 and s_{n-1} = q_{n-1} (no neighbour beyond the ends)."""
    s = [q[0]]
    for i in range(1, len(q) - 1):
        inv = _qconj(q[i])
        e = _qexp(-(_qlog(_qmul(inv, q[i + 1])) + _qlog(_qmul(inv, q[i - 1]))) / 4.0)
        si = _qmul(q[i], e)
        s.append(si / np.linalg.norm(si))
    if len(q) > 1:
        s.append(q[-1])
    return s


def mean_rotation(rotations: Sequence[np.ndarray]) -> np.ndarray:
    """The rotation nearest (Frobenius, SVD projection) to the mean of ``rotations``; the first
    rotation when the mean is degenerate (opposite rotations cancel)."""
    m = np.mean(np.asarray(rotations, dtype=np.float64), axis=0)
    if not np.linalg.norm(m) > 1e-9 or np.linalg.matrix_rank(m, 1e-9) < 3:
        return np.asarray(rotations[0], dtype=np.float64)
    return orthonormalize(m)


# --- the three paths --------------------------------------------------------------------------
def check_frames(n: object) -> int:
    """A path's number of frames (render_job's ``path_frames``): an integer in [2, MAX_FRAMES]."""
    return check_int(n, "path_frames", 2, MAX_FRAMES, argument=True)


def spline(cameras: Sequence[Camera]) -> Callable[[float], np.ndarray]:
    """The interpolating path through ``cameras`` as a function of s in [0, len - 1] returning
    ``cam_from_world``: input i at s = i exactly (centre and rotation), C1 in between."""
    if len(cameras) < 2:
        raise BadValueError.about("path", f"needs at least 2 input views, the scene has {len(cameras)}",
                                 "interpolate")
    c = np.array([cam.centre for cam in cameras])
    rot = [cam.world_from_cam[:3, :3] for cam in cameras]
    q = _hemisphere([quat_from_matrix(r) for r in rot])
    s = _squad_controls(q)
    # Catmull-Rom with phantom end points reflected through the ends: the end tangents along the end chords.
    p = np.vstack([2 * c[0] - c[1], c, 2 * c[-1] - c[-2]])
    k = len(cameras)

    def at(t: float) -> np.ndarray:
        t = min(max(float(t), 0.0), k - 1.0)
        i = min(int(math.floor(t)), k - 2)
        u = t - i
        p0, p1, p2, p3 = p[i], p[i + 1], p[i + 2], p[i + 3]
        pos = 0.5 * ((2 * p1) + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u * u
                     + (-p0 + 3 * p1 - 3 * p2 + p3) * u ** 3)
        if u == 0.0:
            r = rot[i]  # exactly the input (no quaternion round trip)
        elif i + 1 == k - 1 and u == 1.0:
            r = rot[k - 1]
        else:
            qt = slerp(slerp(q[i], q[i + 1], u), slerp(s[i], s[i + 1], u), 2 * u * (1 - u))
            r = matrix_from_quat(qt)
        m = np.eye(4)
        m[:3, :3] = r.T
        m[:3, 3] = -r.T @ pos
        return m
    return at


def interpolate(cameras: Sequence[Camera], frames: int = DEFAULT_FRAMES) -> list[Camera]:
    """``frames`` cameras along :func:`spline` through ``cameras`` (uniform in the spline
    parameter: the first and the last are the first and the last input; with frames - 1 a
    multiple of len - 1 every input is a frame)."""
    n = check_frames(frames)
    at = spline(cameras)
    k = len(cameras)
    intr = cameras[0]
    return [intr.with_pose(at(j * (k - 1) / (n - 1))) for j in range(n)]


def _up(cameras: Sequence[Camera]) -> np.ndarray:
    """The cameras' mean up (OpenCV: -y of each camera, in the world), unit length; the first
    camera's up when the mean cancels."""
    ups = np.array([-c.cam_from_world[1, :3] for c in cameras])
    u = ups.mean(0)
    n = float(np.linalg.norm(u))
    return u / n if n > 1e-9 else ups[0]


def _scale(cameras: Sequence[Camera], scene: Scene | None) -> float:
    """A length of the scene (for fallbacks): the spread of the centres, else the bounds' diagonal, else 1."""
    c = np.array([cam.centre for cam in cameras])
    spread = float(np.linalg.norm(c.max(0) - c.min(0))) if len(c) > 1 else 0.0
    if spread > 1e-9:
        return spread
    if scene is not None:
        b = scene.bounds()
        d = float(np.linalg.norm(b[1] - b[0]))
        if d > 1e-9 and math.isfinite(d):
            return d
    return 1.0


def axes_point(cameras: Sequence[Camera]) -> np.ndarray | None:
    """The least-squares closest point of the cameras' optical axes, or None when the axes are
    near parallel (AXES_CONDITION) or the point is behind most of the cameras."""
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras:
        d = cam.cam_from_world[2, :3]  # the optical axis (z) in the world
        proj = np.eye(3) - np.outer(d, d)
        a += proj
        b += proj @ cam.centre
    if np.linalg.eigvalsh(a)[0] < AXES_CONDITION * len(cameras):
        return None
    x = np.linalg.solve(a, b)
    ahead = sum(float(cam.cam_from_world[2, :3] @ (x - cam.centre)) > 0 for cam in cameras)
    return x if 2 * ahead > len(cameras) else None


def scene_centre(scene: Scene, cameras: Sequence[Camera]) -> np.ndarray:
    """The point the cameras look at (:func:`axes_point`), else the centre of the scene bounds."""
    x = axes_point(cameras)
    if x is not None:
        return x
    b = scene.bounds()
    return 0.5 * (b[0] + b[1])


def _view_depths(scene: Scene) -> np.ndarray | None:
    """The depth values of the views that have depth (DEPTH_VIEWS views evenly spaced,
    DEPTH_SAMPLES pixels of each), finite and positive only; None when no view has depth."""
    views = [v for v in scene.views if v.has_depth]
    if not views:
        return None
    pick = np.unique(np.linspace(0, len(views) - 1, min(len(views), DEPTH_VIEWS)).round().astype(int))
    zs = []
    for i in pick:
        d = views[int(i)].depth
        if d is None:
            continue
        step = max(1, int(math.sqrt(d.size / DEPTH_SAMPLES)))
        ds = d[::step, ::step]
        zs.append(ds[np.isfinite(ds) & (ds > 0)].astype(np.float64))
    z = np.concatenate(zs) if zs else np.zeros(0)
    return z if len(z) else None


def _point_depths(points: np.ndarray, cameras: Sequence[Camera], inside: bool) -> np.ndarray:
    """z of ``points`` in every camera, those in front (and, with ``inside``, in its image) only."""
    zs = []
    for cam in cameras:
        z = points @ cam.cam_from_world[2, :3] + cam.cam_from_world[2, 3]
        ok = np.isfinite(z) & (z > 1e-9)
        if inside:
            xy, _ = cam.project(points)
            with np.errstate(invalid="ignore"):
                ok &= (xy[:, 0] >= 0) & (xy[:, 0] <= cam.width) & (xy[:, 1] >= 0) & (xy[:, 1] <= cam.height)
        zs.append(z[ok])
    return np.concatenate(zs) if zs else np.zeros(0)


def depth_range(scene: Scene, cameras: Sequence[Camera]) -> tuple[float, float] | None:
    """(near, far): the DEPTH_PERCENTILES of the depth the input cameras see: their depth maps,
    else the z of the mesh's vertices inside each camera's image; None when the scene has
    neither (a capture of photographs only, before the mvs stage)."""
    z = _view_depths(scene)
    if z is None and scene.mesh is not None and len(scene.mesh.vertices):
        vert = np.asarray(scene.mesh.vertices, dtype=np.float64)
        z = _point_depths(vert[::max(1, len(vert) // DEPTH_SAMPLES)], cameras, inside=True)
    if z is None or not len(z):
        return None
    near, far = (float(v) for v in np.percentile(z, DEPTH_PERCENTILES))
    return (near, far) if near > 0 and far >= near and math.isfinite(far) else None


def focus_distance(scene: Scene, cameras: Sequence[Camera], centre: np.ndarray, forward: np.ndarray) -> float:
    """The spiral's focus distance from ``centre`` along ``forward``: LLFF's
    ``1 / ((1 - dt) / near + dt / far)`` of the margined :func:`depth_range`; without any depth,
    the distance along ``forward`` to the point the optical axes meet (:func:`axes_point`); else
    the scene's scale (the spread of the input centres)."""
    rng = depth_range(scene, cameras)
    if rng is not None:
        near, far = SPIRAL_NEAR_MARGIN * rng[0], SPIRAL_FAR_MARGIN * rng[1]
        return 1.0 / ((1.0 - SPIRAL_DT) / near + SPIRAL_DT / far)
    x = axes_point(cameras)
    if x is not None:
        d = float((x - centre) @ forward)
        if d > 1e-9:
            return d
    return _scale(cameras, None)


def spiral(scene: Scene, frames: int = DEFAULT_FRAMES, cameras: Sequence[Camera] | None = None
           ) -> tuple[list[Camera], np.ndarray]:
    """The LLFF spiral of ``frames`` cameras around the mean pose of the inputs; returns the
    cameras and the focus point they all look at."""
    n = check_frames(frames)
    cams = [v.camera for v in scene.views] if cameras is None else list(cameras)
    if not cams:
        raise BadValueError.about("path", "the scene has no input view", "spiral")
    centres = np.array([c.centre for c in cams])
    mean_c = centres.mean(0)
    r_cw = mean_rotation([c.cam_from_world[:3, :3] for c in cams])  # world -> mean camera
    fwd = r_cw[2]
    focal = focus_distance(scene, cams, mean_c, fwd)
    focus = mean_c + focal * fwd
    rads = np.percentile(np.abs((centres - mean_c) @ r_cw.T), SPIRAL_PERCENTILE, axis=0)
    if not float(rads[:2].max()) > 1e-9 * max(focal, 1e-300):
        # one view, or every input at one place: a circle of a tenth of the focus distance
        rads = np.array([0.1 * focal, 0.1 * focal, rads[2]])
    up = _up(cams)
    out = []
    for th in np.linspace(0.0, 2.0 * math.pi * SPIRAL_ROTATIONS, n + 1)[:-1]:
        # LLFF's (cos, -sin, -sin(zrate th)) offsets in OpenGL camera axes; ours are OpenCV (y, z flipped)
        off = np.array([math.cos(th), math.sin(th), math.sin(th * SPIRAL_ZRATE)]) * rads
        eye = mean_c + r_cw.T @ off
        out.append(cams[0].with_pose(_look(eye, focus, up, fwd)))
    return out, focus


def _look(eye: np.ndarray, target: np.ndarray, up: np.ndarray, fallback_fwd: np.ndarray) -> np.ndarray:
    """look_at, with the up vector replaced by one perpendicular to the view when it is parallel
    to it (a camera straight above the target)."""
    fwd = target - eye
    if not np.linalg.norm(fwd) > 1e-12:
        fwd = fallback_fwd
        target = eye + fwd
    f = fwd / np.linalg.norm(fwd)
    if np.linalg.norm(np.cross(f, up)) < 1e-6:
        up = np.eye(3)[int(np.argmin(np.abs(f)))]
    return look_at(eye, target, up)


def orbit(scene: Scene, frames: int = DEFAULT_FRAMES, cameras: Sequence[Camera] | None = None
          ) -> tuple[list[Camera], np.ndarray]:
    """One turn of ``frames`` cameras around :func:`scene_centre`; returns the cameras and the centre."""
    n = check_frames(frames)
    cams = [v.camera for v in scene.views] if cameras is None else list(cameras)
    if not cams:
        raise BadValueError.about("path", "the scene has no input view", "orbit")
    centre = scene_centre(scene, cams)
    up = _up(cams)
    rel = np.array([c.centre for c in cams]) - centre
    height = float((rel @ up).mean())
    flat = rel - np.outer(rel @ up, up)
    radius = float(np.linalg.norm(flat, axis=1).mean())
    if not radius > 1e-9:
        radius = 0.5 * _scale(cams, scene)
    e1 = flat[int(np.argmax(np.linalg.norm(flat, axis=1) > 1e-9))]  # the first input off the axis
    if not np.linalg.norm(e1) > 1e-9:
        e1 = np.cross(up, np.eye(3)[int(np.argmin(np.abs(up)))])
    e1 = e1 / np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    # the way the inputs go round (the sum of their wrapped azimuth steps), counter-clockwise about up if none
    az = np.arctan2(flat @ e2, flat @ e1)
    steps = np.angle(np.exp(1j * np.diff(az))) if len(az) > 1 else np.zeros(1)
    sense = -1.0 if float(steps.sum()) < 0 else 1.0
    fwd = cams[0].cam_from_world[2, :3]
    out = []
    for th in np.linspace(0.0, 2.0 * math.pi, n + 1)[:-1]:
        eye = centre + radius * (math.cos(sense * th) * e1 + math.sin(sense * th) * e2) + height * up
        out.append(cams[0].with_pose(_look(eye, centre, up, fwd)))
    return out, centre


def generate(scene: Scene, name: str, frames: int = DEFAULT_FRAMES) -> list[Camera]:
    """The cameras of generated path ``name`` (one of GENERATED) of ``scene``."""
    if name == "interpolate":
        return interpolate([v.camera for v in scene.views], frames)
    if name == "spiral":
        return spiral(scene, frames)[0]
    if name == "orbit":
        return orbit(scene, frames)[0]
    raise BadValueError.about("path", f"not a generated path (expected one of {', '.join(GENERATED)})", name)


def path_names(scene: Scene) -> list[str]:
    """Every path ``--path`` accepts on ``scene``: the stored ones, then the generated ones not
    stored under the same name."""
    return list(scene.paths) + [g for g in GENERATED if g not in scene.paths]


def camera_path(scene: Scene, name: str, frames: int | None = None) -> list[Camera]:
    """The cameras of path ``name``: the scene's stored path of that name, else the generated
    one (``frames`` cameras, default DEFAULT_FRAMES). ``frames`` with a stored path is refused
    (a stored path has its own cameras)."""
    if name in scene.paths:
        if frames is not None:
            raise BadValueError.about("path_frames", f"path {name!r} is stored in the scene with "
                                      f"{len(scene.paths[name])} cameras; a number of frames applies to the "
                                      f"generated paths ({', '.join(GENERATED)}) only")
        return list(scene.paths[name])
    if name not in GENERATED:
        stored = ", ".join(scene.paths) or "none"
        raise BadValueError.about("path", f"not a path of the scene (stored: {stored}; generated: "
                                  f"{', '.join(GENERATED)})", name)
    return generate(scene, name, DEFAULT_FRAMES if frames is None else check_frames(frames))


def all_paths(scene: Scene, frames: int = DEFAULT_FRAMES) -> dict[str, list[Camera]]:
    """{name: cameras} of every path of :func:`path_names` that ``scene`` can make (a generated
    path the scene cannot make, e.g. interpolate of one view, is left out)."""
    out = dict(scene.paths)
    for g in GENERATED:
        if g not in out:
            try:
                out[g] = generate(scene, g, frames)
            except BadValueError:
                pass
    return out
