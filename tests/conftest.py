"""Shared fixtures. Real data lives in ../shared/data (or $IBR_SHARED_DATA); tests that use it
skip with a reason when it is absent (a user's fresh clone has no ../shared)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data() -> Path:
    return Path(os.environ.get("IBR_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture
def data_dir():
    d = shared_data()
    if not d.is_dir():
        pytest.skip(f"real test data not found at {d} (set IBR_SHARED_DATA)")
    return d


def need_data(sub: str) -> Path:
    """The shared data set ``sub`` (a path under the data root), or skip the test with the reason."""
    d = shared_data() / sub
    if not d.is_dir():
        pytest.skip(f"{sub} not found in the shared data at {shared_data()} (set IBR_SHARED_DATA)")
    return d


@pytest.fixture(scope="module")
def dibr_accuracy_bench():
    """benchmarks/bench_dibr_accuracy.py as a module (its protocols are what the real-data DIBR tests check)."""
    if not shared_data().is_dir():
        pytest.skip(f"real data not found at {shared_data()} (set IBR_SHARED_DATA)")
    import sys

    sys.path.insert(0, str(REPO / "benchmarks"))
    import bench_dibr_accuracy

    return bench_dibr_accuracy


def photos_only(src: Path, dst: Path) -> Path:
    """A copy at ``dst`` of the native scene at ``src`` whose views have colour only: no depth,
    no mesh, no stage records (a capture of photographs and cameras, for multi-view stereo)."""
    import json
    import shutil

    shutil.copytree(src, dst)
    doc = json.loads((dst / "scene.json").read_text())
    for v in doc["views"]:
        v.pop("depth", None)
        v.pop("depth_stored", None)
    doc["meshes"], doc["stages"] = {}, {}
    (dst / "scene.json").write_text(json.dumps(doc))
    return dst


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture(params=["baseline", "avx2"])
def isa(request):
    """The forward-warp kernel's instruction set for one test (both paths; AVX2 skipped without it),
    restored to "auto" afterwards."""
    from ibrtools import _core

    if request.param == "avx2" and not _core.cpu_has_avx2():
        pytest.skip("this CPU has no AVX2")
    _core.set_warp_isa(request.param)
    yield request.param
    _core.set_warp_isa("auto")


def wall(zw: float = 2.0, size: float = 1.0):
    """A square mesh (two triangles) in the plane z = zw, half-width ``size``, facing -z (towards
    cameras at z < zw)."""
    from ibrtools.hybrid.globalmesh import vertex_normals
    from ibrtools.mesh import Mesh

    v = np.array([[-size, -size, zw], [size, -size, zw], [size, size, zw], [-size, size, zw]], np.float32)
    f = np.array([[0, 2, 1], [0, 3, 2]], np.int32)
    if vertex_normals(v, f)[0, 2] > 0:
        f = f[:, [0, 2, 1]]
    return Mesh(v, f)


def synth_scene_dir(tmp_path_factory, *flags: str, preset: str = "objects", name: str = "synth") -> Path:
    """A synthetic scene made by ``ibr-preprocess synth:PRESET -o DIR FLAGS... -q`` in a new
    temporary directory (one per call: a module's fixture owns its scene and may change it)."""
    from ibrtools_cli import preprocess

    d = tmp_path_factory.mktemp(name) / "scene"
    assert preprocess.main([f"synth:{preset}", "-o", str(d), *flags, "-q"]) == 0
    return d
