"""A typed program using the public API and the C++ module, checked by ``make typecheck``
(mypy --strict, configured in pyproject.toml) and run by tests/test_stubs.py. It is what a
user's own typed code looks like: every value below has a precise type without a cast."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

import ibrtools
from ibrtools import _core

if TYPE_CHECKING:
    from typing_extensions import assert_type
else:
    def assert_type(value: object, _type: object) -> object:
        return value


def render_all(scene_dir: Path) -> dict[str, float]:
    """Render every target and the first camera of every path; the coverage of each frame."""
    scene: ibrtools.Scene = ibrtools.load_scene(scene_dir)
    coverage: dict[str, float] = {}
    for target in scene.targets:
        result = ibrtools.render(scene, target.name, method="dibr", inputs=2)
        assert_type(result, ibrtools.RenderResult)
        assert_type(result.color, npt.NDArray[np.float32])
        assert_type(result.hole, "npt.NDArray[np.bool_] | None")
        coverage[target.name] = result.coverage
    for name, cameras in scene.paths.items():
        cam: ibrtools.Camera = cameras[0]
        coverage[name] = ibrtools.render(scene, cam, method="dibr", inputs=2).coverage
    return coverage


def core_calls() -> tuple[float, int]:
    """The C++ module through its stub: array dtypes are part of the signatures."""
    image = np.zeros((8, 8, 3), np.float32)
    hole = np.zeros((8, 8), np.bool_)
    hole[2:4, 2:4] = True
    filled, no_hole = _core.pushpull(image, hole)
    assert_type(filled, npt.NDArray[np.float32])
    assert_type(no_hole, bool)
    mean, ssim_map = _core.ssim(filled, image, return_map=True)
    assert_type(ssim_map, "npt.NDArray[np.float32] | None")
    cam = _core.Camera(_core.CameraModel.PINHOLE, 8, 8, np.array([6.0, 6.0, 4.0, 4.0]), np.eye(4))
    assert_type(cam.width, int)
    levels = _core.mip_build(filled)
    assert_type(levels, list[npt.NDArray[np.float32]])
    return mean, len(levels) + _core.get_num_threads() * 0
