"""Batches of cameras: light-field grids, and the MP4 of a rendered image sequence.

Light-field grid (``ibr-render --lightfield NxM --baseline B [--center NAME]``): N columns by M
rows of cameras on the image plane of a centre camera, spaced ``B`` scene units apart, with the
centre camera's intrinsics and rotation: all optical axes are parallel to the centre's viewing
direction (the parallel-axis arrangement of light-field displays and camera arrays, no toe-in).
Column ``c`` moves the camera along the centre's x axis (image right), row ``r`` along its y
axis (image down), by ``(c - (N - 1) / 2) * B`` and ``(r - (M - 1) / 2) * B``: row 0 is the
top row, column 0 the left one, and with N and M odd the middle camera is the centre camera
itself. Frames are numbered in row-major order, ``lf_0000`` (top left), ``lf_0001`` (its right
neighbour), ... ``index = row * N + col``.

The centre camera (``--center NAME``): a stored target of that name, else the input view of that
name; without a name, the scene's first target, else its first input view.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ibrtools.camera import Camera
from ibrtools.checks import check_float
from ibrtools.errors import BadValueError, InputError
from ibrtools.scene import Scene
from ibrtools.imageio import atomic_path, read_image, srgb8
from ibrtools.pipeline.report_html import check_output

PREFIX = "lf_"
VIDEO_HINT = "install the video extra: pip install 'ibrtools[video]' (imageio-ffmpeg)"


class MissingVideoError(InputError):
    """An MP4 asked for but imageio-ffmpeg is not installed."""


def parse_grid(text: str) -> tuple[int, int]:
    """``"NxM"`` -> (N columns, M rows), both positive."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX×]\s*(\d+)\s*", str(text))
    if not m:
        raise BadValueError.about("lightfield", f"expected NxM (columns x rows, e.g. 9x8), got {text!r}")
    n, rows = int(m.group(1)), int(m.group(2))
    if n < 1 or rows < 1:
        raise BadValueError.about("lightfield", f"the grid needs at least 1x1 cameras, got {text!r}")
    if n * rows > 100_000:
        raise BadValueError.about("lightfield", f"{n * rows} cameras is more than 100000", text)
    return n, rows


def check_baseline(baseline) -> float:
    b = check_float(baseline, "baseline", argument=True)
    if not b > 0:
        raise BadValueError.about("baseline", f"expected a positive spacing in scene units, got {b}")
    return b


def grid_offsets(n: int, m: int, baseline: float) -> np.ndarray:
    """(M * N, 2) offsets (x right, y down) in the centre camera's frame, row-major."""
    cols = (np.arange(n, dtype=np.float64) - (n - 1) / 2.0) * baseline
    rows = (np.arange(m, dtype=np.float64) - (m - 1) / 2.0) * baseline
    yy, xx = np.meshgrid(rows, cols, indexing="ij")
    return np.stack([xx.ravel(), yy.ravel()], axis=1)


def grid_poses(cam_from_world: np.ndarray, n: int, m: int, baseline: float) -> np.ndarray:
    """``cam_from_world`` (M * N, 4, 4) of the grid around a centre pose: the same rotation R,
    centres ``c + R^T (dx, dy, 0)``, i.e. translations ``t - (dx, dy, 0)``."""
    pose = np.asarray(cam_from_world, dtype=np.float64)
    off = grid_offsets(n, m, baseline)
    poses = np.broadcast_to(pose, (len(off), 4, 4)).copy()
    poses[:, 0, 3] -= off[:, 0]
    poses[:, 1, 3] -= off[:, 1]
    return poses


def centre_camera(scene: Scene, name: str | None = None) -> tuple[str, Camera]:
    """The centre of the grid: target ``name``, else input view ``name``; default the first
    target, else the first input view."""
    if name is not None:
        for t in scene.targets:
            if t.name == name:
                return t.name, t.camera
        for v in scene.views:
            if v.name == name:
                return v.name, v.camera
        known = [t.name for t in scene.targets] + [v.name for v in scene.views]
        raise BadValueError.about("centre", f"no target or input view of that name (known: "
                                            f"{', '.join(known[:10]) or 'none'}{' ...' if len(known) > 10 else ''})",
                                  name)
    if scene.targets:
        return scene.targets[0].name, scene.targets[0].camera
    if scene.views:
        return scene.views[0].name, scene.views[0].camera
    raise BadValueError.about("lightfield", "the scene has neither targets nor input views to centre the grid on")


def lightfield_cameras(scene: Scene, n: int, m: int, baseline: float,
                       centre: str | None = None) -> tuple[str, list[tuple[str, int, int, Camera]]]:
    """The grid's cameras: (centre name, [(frame name, row, col, camera), ...] row-major)."""
    n, m = parse_grid(f"{n}x{m}")
    baseline = check_baseline(baseline)
    cname, cam = centre_camera(scene, centre)
    poses = grid_poses(cam.cam_from_world, n, m, baseline)
    width = max(4, len(str(n * m - 1)))
    out = []
    for k, pose in enumerate(poses):
        out.append((f"{PREFIX}{k:0{width}d}", k // n, k % n, cam.with_pose(pose)))
    return cname, out


# --- video -------------------------------------------------------------------------------------
def require_video() -> None:
    """Fail before any work when imageio-ffmpeg (the ``video`` extra) is missing."""
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        raise MissingVideoError.about("mp4", f"writing video needs imageio-ffmpeg; {VIDEO_HINT}") from None


def check_video_path(path: str | os.PathLike) -> Path:
    """The MP4 path: not a directory, ends in .mp4, and its folder can be written."""
    p = Path(path)
    if p.is_dir():
        raise BadValueError.about("mp4", "is a directory", str(p))
    if p.suffix.lower() != ".mp4":
        raise BadValueError.about("mp4", "expected a file name ending in .mp4", str(p))
    return check_output(p, "mp4")


def write_mp4(images: list[str | os.PathLike], path: str | os.PathLike, *, fps: float = 24.0) -> Path:
    """Encode the 8-bit PNG frames ``images`` (in this order, all of one size) as an H.264 MP4,
    atomically (a temporary file renamed over ``path`` once complete). Odd sizes are padded to
    even by repeating the last row/column (yuv420p needs even sizes)."""
    require_video()
    import imageio_ffmpeg

    fps = check_float(fps, "fps", argument=True)
    if not fps > 0:
        raise BadValueError.about("fps", f"expected a positive frame rate, got {fps}")
    if not images:
        raise BadValueError.about("mp4", "no frame to encode")
    path = check_video_path(path)
    first = None
    with atomic_path(path) as tmp:
        writer = None
        try:
            for f in images:
                rgb = srgb8(read_image(f)[..., :3])
                if first is None:
                    first = rgb.shape
                    h, w = rgb.shape[0] + rgb.shape[0] % 2, rgb.shape[1] + rgb.shape[1] % 2
                    writer = imageio_ffmpeg.write_frames(str(tmp), (w, h), fps=fps, codec="libx264",
                                                         pix_fmt_out="yuv420p", macro_block_size=1,
                                                         output_params=["-movflags", "+faststart"])
                    writer.send(None)
                elif rgb.shape != first:
                    raise BadValueError.about("mp4", f"frame {Path(f).name} is {rgb.shape[1]}x{rgb.shape[0]}, the "
                                                     f"first was {first[1]}x{first[0]}: a video needs frames of one "
                                                     "size")
                if rgb.shape[0] != h or rgb.shape[1] != w:
                    rgb = np.pad(rgb, ((0, h - rgb.shape[0]), (0, w - rgb.shape[1]), (0, 0)), mode="edge")
                writer.send(np.ascontiguousarray(rgb))
        finally:
            if writer is not None:
                writer.close()
    return path


def check_same_size(cameras: list[Camera]) -> None:
    """An MP4's frames must have one size (checked before rendering)."""
    sizes = {(c.width, c.height) for c in cameras}
    if len(sizes) > 1:
        raise BadValueError.about("mp4", f"the frames have {len(sizes)} different sizes "
                                         f"({', '.join(f'{w}x{h}' for w, h in sorted(sizes)[:4])}); a video needs one")
